"""Hesai packets built by hand for each model and return count: the encoder and the decoder are
inverses, detection names the model, frames put each block's returns where the layout says; and the
fields of the real bags survive decode → encode → decode.

The expected values here come from the manuals' layouts (block k·n + r is return r of firing k;
range = distance × dis_unit mm) and from Python's own calendar (``datetime``), not from lidarpkt.
"""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from lidarpkt.errors import PacketFormatError
from lidarpkt.vendors.hesai import HesaiDecoder, decode_packets, detect_model, encode_packets
from lidarpkt.vendors.hesai.models import MODELS, RETURN_MODES, model_named
from lidarpkt.core.packet import PacketBatch

MODES_BY_COUNT = {1: [0x33, 0x34, 0x37, 0x38], 2: [0x39, 0x3A, 0x3B, 0x3C, 0x3E], 3: [0x3D]}
CASES = [(m.name, mode, size) for m in MODELS for n in m.returns for mode in MODES_BY_COUNT[n] for size in m.sizes]
T0 = int(dt.datetime(2024, 2, 29, 23, 59, 58, tzinfo=dt.timezone.utc).timestamp()) * 10**9 + 123_456_000


def _fields(model, n, mode, rng):
    nret = len(RETURN_MODES[mode])
    groups = model.blocks // nret
    step = 18  # 0.18° between firings
    col = np.arange(n * groups).reshape(n, groups)
    start = 36000 - (n * groups // 2) * step
    az = np.repeat((start + col * step) % 36000, nret, axis=1).astype(np.uint16)  # wraps through 0° halfway
    dist = rng.integers(0, 65536, (n, model.blocks, model.channels), dtype=np.uint16)
    refl = rng.integers(0, 256, dist.shape, dtype=np.uint8)
    ts = T0 + np.arange(n, dtype=np.int64) * 555_000
    return az, dist, refl, ts


@pytest.mark.parametrize("name, mode, size", CASES, ids=[f"{c[0]}-{c[1]:#x}-{c[2]}" for c in CASES])
def test_hand_built_packets_round_trip(name, mode, size):
    model = model_named(name)
    rng = np.random.default_rng(mode * 1000 + size)
    n = 40
    az, dist, refl, ts = _fields(model, n, mode, rng)
    unit = model.dis_unit_mm or 4
    seq = np.arange(1000, 1000 + n, dtype=np.uint32)
    flag = (np.arange(n) % 2).astype(np.uint8)
    payload = encode_packets(model, azimuth_cdeg=az, distance=dist, reflectivity=refl, return_mode=mode,
                             timestamp_ns=ts, motor_speed_rpm=600, dis_unit_mm=unit, udp_sequence=seq,
                             mode_flag=flag, size=size)
    assert payload.shape == (n, size)
    assert detect_model(payload) is model
    raw = decode_packets(payload, model)
    assert raw.valid.all()
    assert np.array_equal(raw.azimuth_cdeg, az) and np.array_equal(raw.distance, dist)
    assert np.array_equal(raw.reflectivity, refl) and np.array_equal(raw.timestamp_ns, ts)
    assert (raw.return_mode == mode).all() and (raw.motor_speed_rpm == 600).all() and (raw.dis_unit_mm == unit).all()
    if raw.udp_sequence is not None:
        assert np.array_equal(raw.udp_sequence, seq)
    # the frames: slot r of column k is block k·n + r, row h channel h (no calibration), packets in order
    dec = HesaiDecoder(model=model)
    batch = PacketBatch.from_payloads(payload, ts)
    frames = dec.push(batch) + dec.finish()
    nret = len(RETURN_MODES[mode])
    assert len(frames) == 2 and dec.stats.malformed == 0 and dec.stats.lost_packets == 0
    rng_mm = np.concatenate([f.range_mm for f in frames], axis=2)  # [R, C, W]
    expect = dist.reshape(n, model.blocks // nret, nret, model.channels).transpose(2, 3, 0, 1)
    expect = expect.reshape(nret, model.channels, -1).astype(np.uint32) * unit
    assert np.array_equal(rng_mm, expect)
    assert frames[0].return_labels == model.labels(mode) and len(frames[0].return_labels) == nret
    az_cols = np.concatenate([f.azimuth_deg for f in frames])
    assert np.array_equal(np.rint(az_cols * 100), az[:, ::nret].reshape(-1))
    assert frames[0].azimuth_deg[-1] > 359.5 and frames[1].azimuth_deg[0] < 1.0  # cut at the wrap through 0°
    assert all(f.sensor.model == model.name for f in frames)


def test_utc_time_is_the_calendars():
    for name in ("Pandar40P", "Pandar64", "PandarXT32"):
        model = model_named(name)
        z = np.zeros((1, model.blocks), np.uint16)
        d = np.zeros((1, model.blocks, model.channels), np.uint16)
        p = encode_packets(model, azimuth_cdeg=z, distance=d, reflectivity=d.astype(np.uint8), return_mode=0x37,
                           timestamp_ns=np.array([T0]))
        utc = decode_packets(p, model).utc[0]
        assert utc.tolist() == [2024 - model.year_offset, 2, 29, 23, 59, 58]


def test_the_xt32_bag_first_packet_time(ext):
    """Tail bytes of the bag's first packet, read by hand: year 0x77 (1900 + 119), July 25, 03:19:29, 619 165 µs."""
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    batch = next(iter(BagReader(ext("nebula/hesai/xt32/1673400677802009732"), messages=bag_messages()).batches()))
    raw = decode_packets(batch.payload, model_named("PandarXT32"))
    want = dt.datetime(2019, 7, 25, 3, 19, 29, tzinfo=dt.timezone.utc)
    assert int(raw.timestamp_ns[0]) == int(want.timestamp()) * 10**9 + 619_165_000
    assert bytes(batch.payload[0, 1052:1072]).hex().startswith("000086f1078301000100" + "39" + "5702")


@pytest.mark.parametrize("folder", ["40p", "64", "qt64", "qt128", "xt16", "xt32", "xt32m"])
def test_real_packets_survive_decode_encode_decode(ext, folder):
    import glob

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages

    bag = glob.glob(str(ext(f"nebula/hesai/{folder}")) + "/*/")[0]
    batch = next(iter(BagReader(bag, messages=bag_messages()).batches()))
    model = detect_model(batch.payload)
    raw = decode_packets(batch.payload, model)
    assert raw.valid.all()
    again = encode_packets(model, azimuth_cdeg=raw.azimuth_cdeg, distance=raw.distance, reflectivity=raw.reflectivity,
                           return_mode=raw.return_mode, timestamp_ns=raw.timestamp_ns,
                           motor_speed_rpm=raw.motor_speed_rpm, dis_unit_mm=int(raw.dis_unit_mm[0]),
                           factory_information=int(raw.factory_information[0]), udp_sequence=raw.udp_sequence,
                           mode_flag=raw.mode_flag, confidence=raw.confidence, size=batch.payload_size)
    back = decode_packets(again, model)
    for name in ("azimuth_cdeg", "distance", "reflectivity", "return_mode", "timestamp_ns", "motor_speed_rpm",
                 "utc", "factory_information"):
        assert np.array_equal(getattr(back, name), getattr(raw, name)), name
    # the blocks are byte for byte the bag's
    blocks = model.layout.fields["blocks"]
    off, length = blocks[1], blocks[0].itemsize
    assert np.array_equal(again[:, off:off + length], batch.payload[:, off:off + length])


def test_encoder_refuses_what_the_model_cannot_send():
    xt32 = model_named("PandarXT32")
    z = np.zeros((1, 8), np.uint16)
    d = np.zeros((1, 8, 32), np.uint16)
    with pytest.raises(PacketFormatError, match="return mode"):
        encode_packets(xt32, azimuth_cdeg=z, distance=d, reflectivity=d.astype(np.uint8), return_mode=0x3D,
                       timestamp_ns=np.array([T0]))
    with pytest.raises(PacketFormatError, match="1080"):
        encode_packets(xt32, azimuth_cdeg=z, distance=d, reflectivity=d.astype(np.uint8), return_mode=0x37,
                       timestamp_ns=np.array([T0]), size=1000)
