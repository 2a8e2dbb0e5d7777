"""Property tests: any bytes in the VLP-16 layout survive decode → encode, and frames lose no firing."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import (
    VelodyneDecoder,
    decode_packets,
    decode_position_packets,
    encode_data_packets,
    encode_position_packets,
)


@settings(max_examples=40, deadline=None)
@given(st.binary(min_size=1206 * 3, max_size=1206 * 3))
def test_any_data_bytes_roundtrip(blob):
    payload = np.frombuffer(blob, np.uint8).reshape(3, 1206)
    d = decode_packets(payload)
    enc = encode_data_packets(d.azimuth_cdeg, d.distance_2mm, d.reflectivity, d.timestamp_us, d.return_mode,
                              d.product_id, flag=d.flag)
    assert enc.tobytes() == blob
    v = decode_packets(payload, copy=False)  # views give the same values
    np.testing.assert_array_equal(v.distance_2mm, d.distance_2mm)
    np.testing.assert_array_equal(v.azimuth_cdeg, d.azimuth_cdeg)


@settings(max_examples=40, deadline=None)
@given(st.binary(min_size=512 * 2, max_size=512 * 2))
def test_any_position_bytes_roundtrip(blob):
    p = decode_position_packets(np.frombuffer(blob, np.uint8).reshape(2, 512))
    enc = encode_position_packets(p.timestamp_us, p.pps_status, p.nmea, thermal_status=p.thermal_status,
                                  last_shutdown_temperature=p.last_shutdown_temperature,
                                  powerup_temperature=p.powerup_temperature, unused_head=p.unused_head,
                                  unused_tail=p.unused_tail)
    assert enc.tobytes() == blob


@settings(max_examples=25, deadline=None)
@given(
    mode=st.sampled_from(["strongest", "last", "dual"]),
    n=st.integers(1, 120),
    start_cdeg=st.integers(0, 35999),
    rpm=st.sampled_from([300, 600, 1200]),
    split=st.integers(1, 50),
    seed=st.integers(0, 2**16),
)
def test_frames_hold_every_firing_once(mode, n, start_cdeg, rpm, split, seed):
    rng = np.random.default_rng(seed)
    dual = mode == "dual"
    period_us = 1327.104 / (2 if dual else 1)
    t_us = 3_599_000_000 + np.rint(np.arange(n) * period_us).astype(np.int64)  # crosses the top of the hour
    block_t = np.arange(12) // (2 if dual else 1) * 110.592
    az = np.rint(start_cdeg + (np.arange(n)[:, None] * period_us + block_t) * rpm * 6e-4).astype(np.int64) % 36000
    dist = rng.integers(0, 65536, size=(n, 12, 32)) * (rng.random((n, 12, 32)) < 0.7)
    refl = rng.integers(0, 256, size=(n, 12, 32))
    payload = encode_data_packets(az, dist, refl, t_us % 3_600_000_000, mode)
    host = 1_700_000_000_000_000_000 + t_us * 1000
    dec = VelodyneDecoder()
    frames = []
    for i in range(0, n, split):
        frames += dec.push(PacketBatch.from_payloads(payload[i:i + split], host[i:i + split], first_index=i))
    frames += dec.finish()
    # partial = columns of the rotation missing: the first frame is whole only if it starts within
    # one firing interval after 0°, the last only if it ends within one before 0° (±1 for rounding)
    step_cdeg = rpm * 6e-4 * 55.296
    seqs = n * (12 if dual else 24)
    last_cdeg = (start_cdeg + (seqs - 1) * step_cdeg) % 36000
    assert frames
    if start_cdeg > step_cdeg + 1 or (len(frames) == 1 and last_cdeg < 36000 - step_cdeg - 1):
        assert frames[0].partial
    if len(frames) > 1 and start_cdeg < step_cdeg - 1:
        assert not frames[0].partial
    if last_cdeg < 36000 - step_cdeg - 1:
        assert frames[-1].partial
    assert not any(f.partial for f in frames[1:-1])
    per_packet = 12 if dual else 24
    assert sum(f.shape[2] for f in frames) == n * per_packet
    assert all(f.column_valid.all() for f in frames)
    assert sum(f.n_returns for f in frames) == np.count_nonzero(dist)
    ts = np.concatenate([f.column_timestamp_ns for f in frames])
    assert np.all(np.diff(ts) > 0)  # firing order, through the top of the hour
    assert [f.frame_id for f in frames] == list(range(len(frames)))
    for f in frames:
        az_deg = f.azimuth_deg
        assert np.all((az_deg >= 0) & (az_deg < 360))
        assert np.count_nonzero(np.diff(az_deg) < -180) == 0  # a frame never contains a wrap


_VALID = encode_data_packets((np.arange(8)[:, None] * 480 + np.arange(12) * 40) % 36000,
                             np.full((8, 12, 32), 1234), np.full((8, 12, 32), 50), 1000 + np.arange(8) * 1327, "dual")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 8 * 1206 - 1), st.integers(0, 255)), max_size=12),
       st.lists(st.tuples(st.integers(0, 2 * 512 - 1), st.integers(0, 255)), max_size=12))
def test_damaged_packets_never_raise_a_traceback(data_edits, pos_edits):
    import warnings

    from lidarpkt.vendors.velodyne import classify, describe_stream

    data = _VALID.copy().reshape(-1)
    for at, value in data_edits:
        data[at] = value
    posb = encode_position_packets([5, 6], 2, "$GPRMC,120000,A,4807.038,N,01131.000,E,0,0,010124,,*1F").reshape(-1)
    for at, value in pos_edits:
        posb[at] = value
    batch = PacketBatch.from_payloads(data.reshape(8, 1206), 1_700_000_000_000_000_000 + np.arange(8) * 663_552)
    pos = PacketBatch.from_payloads(posb.reshape(2, 512))
    classify(batch), describe_stream(batch), classify(pos), describe_stream(pos)
    dec = VelodyneDecoder()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = dec.push(batch) + dec.finish()
        dec.push_position(pos)
    s = dec.stats
    assert s.decoded_packets + s.malformed + s.duplicate_packets + s.late_packets + s.corrupted_packets == 8
    assert sum(int(f.column_valid.sum()) for f in frames) % 12 == 0


def test_garbage_in_the_flag_and_mode_bytes_is_counted():
    import warnings

    rng = np.random.default_rng(0)
    payload = encode_data_packets(np.zeros((50, 12)), rng.integers(0, 99, (50, 12, 32)), np.zeros((50, 12, 32)),
                                  np.arange(50) * 1327, "strongest")
    payload[::7, 1204] = 0x55
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        dec = VelodyneDecoder()
        dec.push(PacketBatch.from_payloads(payload, 1_700_000_000_000_000_000 + np.arange(50) * 1_327_104))
    assert dec.stats.unknown_return_mode == 8 and dec.stats.decoded_packets == 42
