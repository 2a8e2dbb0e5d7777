"""The RoboSense layouts, model table and encoder: offsets as the manuals give them, firing tables as the
manuals' formulas give them, and hand-built packets of every model in single and dual return through
the encoder, the field decoder and the frame decoder, each slot landing where the manuals put it."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.robosense import (MODELS, RobosenseDecoder, decode_difop, decode_packets, detect_model,
                                        encode_difop, encode_packets, model_named, packet as P, timing)
from lidarpkt.vendors.robosense.detect import firings_per_block

T0 = 1_700_000_000_000_000_000  # ns, on a whole second
MODES = [(m, n) for m in MODELS for n in (1, 2)]


def _offset(dtype, *path):
    off = 0
    for name in path:
        field = dtype.fields[name]
        off += field[1]
        dtype = field[0].base if field[0].subdtype else field[0]
    return off


def test_layout_offsets_are_the_manuals():
    # RS-Helios (-16P) manual, Table 9 "MSOP Header"; the type is at 30 where units send it (see the nebula test)
    h = P.HEADER_HELIOS
    assert [_offset(h, f) for f in ("protocol_version", "top_board_packet_count", "bottom_board_packet_count",
                                    "range_resolution", "angle_pulse_interval_count", "timestamp", "lidar_type")] == \
        [4, 8, 12, 17, 18, 20, 30]
    # RS-LiDAR-16 manual 5.1.1: bytes 21-30 (1-based) the time, byte 31 the LiDAR model
    v1 = P.header_v1(P.TIME_YMD)
    assert (_offset(v1, "timestamp"), _offset(v1, "lidar_model_flag"), v1.itemsize) == (20, 30, 42)
    # RS-Ruby (Plus) manual, "MSOP Header": wave_mode 7, temperature 8, timestamp 10; 80 bytes
    assert (_offset(P.HEADER_V2, "wave_mode"), _offset(P.HEADER_V2, "timestamp"), P.HEADER_V2.itemsize) == (7, 10, 80)
    assert P.BLOCK_32.itemsize == 100 and P.BLOCK_128.itemsize == 388
    for layout in (P.MSOP_V1_YMD, P.MSOP_V1_UTC, P.MSOP_HELIOS, P.MSOP_RUBY):
        assert layout.itemsize == 1248
    # DIFOP: return mode at 300, angles from 468 (Helios manual B; Ruby Plus manual: 468 and 852, 384 B each)
    assert _offset(P.DIFOP_HELIOS, "horizontal_angles") == 564 and _offset(P.DIFOP_RUBY, "horizontal_angles") == 852
    assert _offset(P.DIFOP_RS16, "pitch_calibration") == 1165 and _offset(P.DIFOP_HELIOS, "time") == 303
    for layout in (P.DIFOP_RS16, P.DIFOP_V1_32, P.DIFOP_HELIOS, P.DIFOP_RUBY):
        assert (_offset(layout, "return_mode"), _offset(layout, "tail"), layout.itemsize) == (300, 1246, 1248)


def test_firing_tables_are_the_manuals_formulas():
    # RS-LiDAR-16 manual, Appendix A: 55.5 µs × (sequence − 1) + 2.8 µs × (channel − 1), two sequences a block
    assert timing.RS16 == tuple(round(55500 * (s // 16) + 2800 * (s % 16)) for s in range(32))
    # RS-Bpearl manual, Appendix A: 2.56 µs × ((i−1) mod 16) + 1.28 µs × ⌊(i−1)/16⌋, + 5.2 µs for channels 9-16, 25-32
    assert timing.BPEARL == tuple(round(2560 * (i % 16) + 1280 * (i // 16) + (5200 if i % 16 >= 8 else 0))
                                  for i in range(32))
    assert timing.HELIOS == tuple(1730 * s for s in range(32))
    # RS-Ruby Plus: groups of four lasers, rising
    groups = np.asarray(timing.RUBY_PLUS).reshape(32, 4)
    assert np.all(groups == groups[:, :1]) and np.all(np.diff(groups[:, 0]) > 0) and groups[-1, 0] == 50530


def test_model_table():
    assert [m.name for m in MODELS] == ["RS-LiDAR-16", "RS-LiDAR-32", "RS-Bpearl", "RS-Bpearl-V4", "RS-Helios",
                                        "RS-Helios-16P", "RS-Ruby", "RS-Ruby-Plus"]
    assert model_named("RS-Bpearl").labels(0x00, 2) == ("strongest", "second_strongest")
    assert model_named("RS-Ruby-Plus").labels(0x03, 2) == ("last", "strongest")
    assert model_named("RS-Helios").labels(0x04, 1) == ("strongest",)
    assert model_named("RS-Helios").labels(None, 1) == ("unknown",)
    assert model_named("RS-Helios-16P").grid_resolution_deg(10) == 0.1
    assert model_named("RS-Helios").grid_resolution_deg(10) == 0.2
    for name in ("rs128", "RSP128", "bpearl", "RS-LiDAR-16"):
        assert model_named(name) in MODELS
    with pytest.raises(Exception, match="unknown RoboSense model"):
        model_named("RS-M1")


def hand_built(model, n_returns, n_packets=120, seed=0, hz=10, start_cdeg=None):
    """Fields of ``n_packets`` packets of a sensor turning at ``hz`` from ``start_cdeg``: block azimuths as it
    turns (by default through 0°: two frames at least), random ranges."""
    rng = np.random.default_rng(seed)
    blocks = model.blocks
    if n_returns == 2 and model.dual_layout == "ret_id":  # A A B, A B B ...: 1.5 firings a packet
        period = model.block_period_ns
        firing = np.arange(n_packets * blocks) // 2
        ret_id = (np.arange(n_packets * blocks) % 2 + 1).reshape(n_packets, blocks)
        times = T0 + (np.arange(n_packets) * period * 3 // 2) // 1000 * 1000
    else:
        period = model.group_period_ns(n_returns)
        per_group = 2 if (n_returns == 2 and model.dual_layout == "block_pairs") else 1
        firing = np.arange(n_packets * blocks) // per_group
        ret_id = None
        times = T0 + (np.arange(n_packets) * period * blocks // per_group) // 1000 * 1000
    turned = np.rint(firing * 36000.0 * hz * period * 1e-9).astype(np.int64).reshape(n_packets, blocks)
    if start_cdeg is None:
        start_cdeg = 36000 - int(turned[-1, -1]) // 2
    azimuth = (turned + start_cdeg) % 36000
    shape = (n_packets, blocks, model.channels)
    return dict(azimuth_cdeg=azimuth, distance=rng.integers(0, 65536, shape).astype(np.uint16),
                reflectivity=rng.integers(0, 256, shape).astype(np.uint8), timestamp_ns=times, ret_id=ret_id,
                wave_mode=(3 if n_returns == 2 else 1) if model.family == "ruby" else None)


def difop_for(model, n_returns, **kw):
    mode = model.dual_mode() if n_returns == 2 else next(k for k, v in model.return_modes.items() if len(v) == 1)
    if model.name == "RS-LiDAR-16":  # its DIFOP: channels 1-8 down, 9-16 up
        elevation = np.r_[-np.linspace(15, 1, 8), np.linspace(1, 15, 8)]
    else:
        elevation = np.linspace(15, -25, model.lasers)
    return encode_difop(model, return_mode=mode, elevation_deg=elevation, **kw)


def expected_slots(model, n_returns, fields):
    """``{(return, laser, column): distance}`` of hand-built fields, by the manuals' definitions of a block."""
    n, blocks, channels = fields["distance"].shape
    out = {}
    column = -1
    prev = None
    for p in range(n):
        for b in range(blocks):
            d = fields["distance"][p, b]
            if model.family == "ruby":
                if n_returns == 1:
                    column += 1
                    r = 0
                else:
                    r = int(fields["ret_id"][p, b]) - 1
                    key = int(fields["azimuth_cdeg"][p, b])
                    if r == 0 or key != prev:
                        column += 1
                    prev = key
                for laser in range(channels):
                    out[(r, laser, column)] = d[laser]
            elif model.firings_per_block == 2:  # 16 lasers: two firings (single) or two returns (dual)
                base = p * blocks + b
                for s in range(32):
                    col = 2 * base + s // 16 if n_returns == 1 else base
                    out[(0 if n_returns == 1 else s // 16, s % 16, col)] = d[s]
            else:  # 32 lasers once a block; dual: blocks 2k, 2k+1 are the two returns of one firing
                base = p * blocks + b
                for s in range(32):
                    out[(0 if n_returns == 1 else base % 2, s, base if n_returns == 1 else base // 2)] = d[s]
    return out


@pytest.mark.parametrize("model,n_returns", MODES, ids=[f"{m.name}-{n}" for m, n in MODES])
def test_hand_built_packets_round_trip(model, n_returns):
    fields = hand_built(model, n_returns)
    payload = encode_packets(model, **fields)
    raw = decode_packets(payload, model)
    assert raw.valid.all()
    for name in ("azimuth_cdeg", "distance", "reflectivity", "timestamp_ns"):
        assert np.array_equal(getattr(raw, name), fields[name]), name
    assert detect_model(payload) is model
    difop = difop_for(model, n_returns, motor_speed_rpm=600)
    info = decode_difop(difop, model)
    assert info is not None and info.motor_speed_rpm == 600 and len(info.elevation_deg) == model.lasers
    decoder = RobosenseDecoder()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing is skipped
        frames = decoder.push(PacketBatch.from_payloads(difop[None], [T0 - 1000]))
        frames += decoder.push(PacketBatch.from_payloads(payload, fields["timestamp_ns"]))
        frames += decoder.finish()
    assert decoder.model is model and decoder.stats.decoded_packets == len(payload)
    assert decoder.stats.lost_packets == 0 and decoder.stats.malformed == 0
    unit_um = model.distance_unit_um or 2500
    expected = expected_slots(model, n_returns, fields)
    got = {}
    column = 0
    for f in frames:
        assert f.shape[0] == n_returns and f.sensor.model == model.name
        assert f.return_labels == model.labels(decode_difop(difop, model).return_mode, n_returns)
        rows = np.asarray(f.sensor.metadata["row_laser"])
        r, h, c = np.nonzero(f.range_mm >= 0)
        for rr, hh, cc in zip(r.tolist(), h.tolist(), c.tolist()):
            got[(rr, int(rows[hh]), column + cc)] = f.range_mm[rr, hh, cc]
        column += f.shape[2]
    assert len(frames) >= 2 and len(got) == len(expected)  # cut where the azimuth passes 0°
    want = np.array([expected[k] for k in sorted(expected)], np.int64)
    have = np.array([got[k] for k in sorted(expected)], np.int64)
    assert np.array_equal(have, (want * unit_um + 500) // 1000)
    # columns in time order, each a firing after the packet time
    times = np.concatenate([f.column_timestamp_ns for f in frames])
    assert np.all(np.diff(times) >= 0) and times[0] == fields["timestamp_ns"][0]


def test_difop_round_trip_and_refusals():
    helios = model_named("RS-Helios")
    elevation = np.round(np.linspace(15, -55, 32), 2)
    offset = np.round(np.tile([-4.05, 3.61], 16), 2)
    payload = encode_difop(helios, return_mode=0x00, elevation_deg=elevation, azimuth_offset_deg=offset,
                           motor_speed_rpm=1200, time_ns=T0 + 123_456_000, serial_number=bytes(range(6)))
    info = decode_difop(payload, helios)
    assert np.array_equal(info.elevation_deg, elevation) and np.array_equal(info.azimuth_offset_deg, offset)
    assert (info.return_mode, info.motor_speed_rpm, info.time_ns, info.serial_number) == \
        (0, 1200, T0 + 123_456_000, "000102030405")
    rs32 = model_named("RS-LiDAR-32")  # 0.001° units
    fine = np.round(np.linspace(15, -25, 32), 3)
    assert np.allclose(decode_difop(difop_for(rs32, 1)[None][0], rs32).elevation_deg, np.linspace(15, -25, 32),
                       atol=5e-4)
    assert np.array_equal(decode_difop(encode_difop(rs32, return_mode=1, elevation_deg=fine), rs32).elevation_deg, fine)
    bad = payload.copy()
    bad[468] = 0x02  # a sign byte neither 0 nor 1
    assert decode_difop(bad, helios) is None
    bad = payload.copy()
    bad[469:471] = (0x50, 0x00)  # 204.8°
    assert decode_difop(bad, helios) is None
    bad = payload.copy()
    bad[300] = 0x09  # no Helios return mode
    assert decode_difop(bad, helios) is None
    bad = payload.copy()
    bad[-1] = 0
    assert decode_difop(bad, helios) is None


def test_xyz_of_a_hand_built_point():
    model = model_named("RS-Helios")
    fields = hand_built(model, 1, n_packets=2, start_cdeg=0)
    fields["distance"][:] = 0
    fields["distance"][0, 3, 5] = 4001  # laser 5 of block 3: 10.0025 m
    elevation = np.round(np.linspace(15, -55, 32), 2)  # the DIFOP's 0.01°
    difop = encode_difop(model, return_mode=0x04, elevation_deg=elevation, azimuth_offset_deg=np.full(32, 1.5))
    decoder = RobosenseDecoder()
    frames = decoder.push(PacketBatch.from_payloads(difop[None], [T0]))
    frames += decoder.push(PacketBatch.from_payloads(encode_packets(model, **fields), fields["timestamp_ns"]))
    frames += decoder.finish()
    (frame,) = frames
    r, h, c = np.argwhere(frame.range_mm > 0)[0]
    assert frame.sensor.metadata["row_laser"][h] == 5 and c == 3
    alpha = np.radians(frame.extra["azimuth_cdeg"][h, c] / 100.0)
    # block 3's azimuth plus the step to block 4 times laser 5's share (8.65 of 55.56 µs), whole 0.01°
    step = fields["azimuth_cdeg"][0, 4] - fields["azimuth_cdeg"][0, 3]
    assert frame.extra["azimuth_cdeg"][h, c] == fields["azimuth_cdeg"][0, 3] + int(step * np.float32(8.65 / 55.56))
    el = np.radians(elevation[5])
    theta = alpha + np.radians(1.5)
    d = 4001 * 0.0025
    want = (d * np.cos(el) * np.cos(theta) + 0.03498 * np.cos(alpha),
            -d * np.cos(el) * np.sin(theta) - 0.03498 * np.sin(alpha), d * np.sin(el))
    np.testing.assert_allclose(frame.xyz()[r, h, c], want, atol=1e-12)
    assert np.count_nonzero(frame.xyz()) == 3  # every other pixel is zeros
    assert frame.points()["timestamp_ns"][0] == fields["timestamp_ns"][0] + 3 * 55560 + 5 * 1730


def test_firings_per_block_from_the_returns():
    rng = np.random.default_rng(3)
    scene = rng.integers(400, 40000, (64, 12, 16))  # a laser's range changes between blocks
    two_firings = np.concatenate([scene, scene + rng.integers(-3, 4, scene.shape)], axis=2)
    two_firings[:, 1::2] = two_firings[:, ::2]  # and holds between consecutive blocks half the time
    assert firings_per_block(two_firings.astype(np.uint16)) == 2
    lasers32 = np.concatenate([scene, rng.integers(400, 40000, scene.shape)], axis=2)
    lasers32[:, 1::2] = lasers32[:, ::2]
    assert firings_per_block(lasers32.astype(np.uint16)) == 1
    assert firings_per_block(np.zeros((4, 12, 32), np.uint16)) is None


@pytest.mark.parametrize("model", MODELS, ids=[m.name for m in MODELS])
def test_the_header_names_the_model_and_unnamed_units_fall_back(model):
    fields = hand_built(model, 1, n_packets=40)
    assert detect_model(encode_packets(model, **fields)) is model
    unnamed = detect_model(encode_packets(model, **fields, name_model=False))
    assert unnamed.family == model.family and unnamed.layout == model.layout or model.name == "RS-Bpearl-V4"


@pytest.mark.parametrize("model,n_returns", MODES, ids=[f"{m.name}-{n}" for m, n in MODES])
def test_batches_of_any_size_give_the_same_frames(model, n_returns):
    fields = hand_built(model, n_returns, seed=5)
    payload = np.concatenate([difop_for(model, n_returns)[None], encode_packets(model, **fields)])
    times = np.concatenate([[T0 - 1000], fields["timestamp_ns"]])

    def frames(chunk):
        decoder = RobosenseDecoder()
        out = []
        for a in range(0, len(payload), chunk):
            out += decoder.push(PacketBatch.from_payloads(payload[a:a + chunk], times[a:a + chunk], first_index=a))
        return out + decoder.finish()

    whole, pieces = frames(len(payload)), frames(7)
    assert len(whole) == len(pieces)
    for a, b in zip(whole, pieces):
        assert np.array_equal(a.range_mm, b.range_mm) and np.array_equal(a.column_timestamp_ns, b.column_timestamp_ns)
        assert np.array_equal(a.extra["azimuth_cdeg"], b.extra["azimuth_cdeg"]) and a.partial == b.partial


def test_drop_reasons_are_lidarpkts():
    from lidarpkt.core.dropped import REASONS

    decoder = RobosenseDecoder()
    assert set(decoder.stats.drops()) <= set(REASONS)


@pytest.mark.parametrize("form", [P.TIME_UTC, P.TIME_YMD], ids=["utc", "year-month-day"])
def test_time_fields_round_trip(form):
    from lidarpkt.vendors.robosense.decode import time_ns
    from lidarpkt.vendors.robosense.encode import set_time

    rng = np.random.default_rng(2)
    seconds = np.concatenate([[951782400, 951868799, 4107542399], rng.integers(946684800, 8000000000, 3000)])
    ns = seconds * 1_000_000_000 + rng.integers(0, 1_000_000, seconds.size) * 1000  # leap days, year 2100 ...
    stamp = np.zeros(ns.size, form)
    set_time(stamp, ns)
    back, possible = time_ns(stamp)
    assert possible.all() and np.array_equal(back, ns)
    if form is P.TIME_YMD:
        assert (stamp[0]["month"], stamp[0]["day"], stamp[1]["day"]) == (2, 29, 29)  # 2000-02-29
        stamp[5]["month"] = 13
        assert not time_ns(stamp)[1][5]
