"""VLP-16 frames: layout, cuts, VeloView's own expected output, losses, bad input, absolute time, dual slots."""

from __future__ import annotations

import dataclasses
import struct

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import SkippedPacketWarning
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne.detect import data_kind
from lidarpkt.vendors.velodyne import (
    VelodyneDecoder,
    classify,
    describe_stream,
    encode_data_packets,
    encode_position_packets,
)

MANUAL_ELEVATION = [-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15]
HOUR_NS = 3_600_000_000_000


def row_of_laser(laser: int) -> int:
    """Row 0 = highest elevation: the rank of the laser's elevation, highest first."""
    return sorted(MANUAL_ELEVATION, reverse=True).index(MANUAL_ELEVATION[laser])


def einride(ext) -> np.ndarray:
    return np.fromfile(ext("einride-vlp16-go/recording.bin"), np.uint8).reshape(-1, 1206)


def decode_all(batches, **options):
    dec = VelodyneDecoder(**options)
    frames = []
    for b in batches:
        kind = classify(b)
        if kind == "data":
            frames += dec.push(b)
        elif kind == "position":
            dec.push_position(b)
    return frames + dec.finish(), dec


def pcap_batches(path):
    from lidarpkt.containers.pcap_reader import PcapReader

    return list(PcapReader(path).batches())


# ------------------------------------------------------------------ layout on a real recording
def test_einride_frames_are_lossless_and_in_firing_order(ext):
    payload = einride(ext)
    frames, dec = decode_all([PacketBatch.from_payloads(payload)])
    assert len(frames) == 14  # 13 wraps in the recording
    assert frames[0].partial and frames[-1].partial
    assert not any(f.partial for f in frames[1:-1])
    assert sum(f.shape[2] for f in frames) == 24 * 1000  # one column per firing sequence
    for f in frames[1:-1]:
        assert f.shape == (1, 16, f.shape[2]) and f.shape[2] in (1808, 1809)  # 10 Hz
        assert f.column_valid.all()
        assert np.all(np.diff(f.azimuth_deg) > 0) and 0 <= f.azimuth_deg[0] < 0.5 and f.azimuth_deg[-1] > 359.5
        steps = np.diff(f.column_timestamp_ns)
        assert np.all(np.abs(steps - 55_296) <= 1000)  # 55.296 µs per sequence (packet stamps are whole µs)
        assert f.return_labels == ("strongest",)
        assert f.sensor.model == "VLP-16" and f.sensor.product_id == 0x22 and f.sensor.return_mode == "strongest"
        assert f.sensor.frequency_hz == pytest.approx(10, abs=0.1)
    # every return of the recording, counted straight from the bytes, is in exactly one pixel
    dist = payload[:, :1200].reshape(-1, 12, 100)[:, :, 4:].reshape(-1, 12, 32, 3)
    n_returns = np.count_nonzero(dist[..., 0].astype(np.uint16) | (dist[..., 1].astype(np.uint16) << 8))
    assert sum(f.n_returns for f in frames) == n_returns
    assert dec.stats.decoded_packets == 1000 and dec.stats.malformed == 0


def test_pixels_hold_the_bytes_of_their_firing(ext):
    payload = einride(ext)
    frames, _ = decode_all([PacketBatch.from_payloads(payload)])
    cols = np.cumsum([0] + [f.shape[2] for f in frames])
    rng = np.random.default_rng(0)
    for _ in range(200):
        p, b, j = int(rng.integers(1000)), int(rng.integers(12)), int(rng.integers(32))
        off = 100 * b + 4 + 3 * j
        dist, refl = struct.unpack_from("<HB", payload[p].tobytes(), off)
        g = 24 * p + 2 * b + j // 16  # global firing-sequence index
        k = int(np.searchsorted(cols, g, side="right") - 1)
        f, c, row = frames[k], g - cols[k], row_of_laser(j % 16)
        assert f.range_mm[0, row, c] == 2 * dist
        assert f.reflectivity[0, row, c] == refl
        assert f.pixel_time_offset_ns[row, c] == 2304 * (j % 16)


def test_rows_follow_elevation(ext):
    frames, _ = decode_all([PacketBatch.from_payloads(einride(ext))])
    np.testing.assert_allclose(frames[1].sensor.beam_altitude_deg, np.arange(15, -16, -2), atol=1e-9)
    xyz = frames[1].xyz()
    assert xyz.shape == frames[1].shape + (3,)
    empty = frames[1].range_mm == 0
    assert np.all(xyz[empty] == 0)
    # elevation of every point equals its row's beam elevation (stock vertical offsets are < 12 mm)
    has = ~empty[0]
    r = np.linalg.norm(xyz[0], axis=-1)
    el = np.degrees(np.arcsin(xyz[0, ..., 2] / np.where(has, r, 1)))
    expected = np.broadcast_to(np.arange(15, -16, -2)[:, None], el.shape)
    far = has & (r > 5)
    assert np.abs(el[far] - expected[far]).max() < 0.2


def test_batches_of_any_size_give_the_same_frames(ext):
    payload = einride(ext)[:300]
    whole, _ = decode_all([PacketBatch.from_payloads(payload)])
    pieces, _ = decode_all([PacketBatch.from_payloads(payload[i:i + 7], first_index=i) for i in range(0, 300, 7)])
    assert len(whole) == len(pieces)
    for a, b in zip(whole, pieces):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
        np.testing.assert_array_equal(a.column_timestamp_ns, b.column_timestamp_ns)
        np.testing.assert_array_equal(a.extra["packet_index"], b.extra["packet_index"])
        assert a.partial == b.partial


def test_on_grid_gives_the_fixed_azimuth_grid(ext):
    frames, _ = decode_all([PacketBatch.from_payloads(einride(ext))])
    g = frames[2].on_grid()
    assert g.shape == (1, 16, 1800)
    # 1808 firings 0.199° apart into 1800 bins of 0.2° (azimuths in whole 0.01°): some bins get two
    # firings (the first is kept, the others counted), a few none (invalid: no sample)
    assert g.counters.grid_collisions == frames[2].column_valid.sum() - g.column_valid.sum() > 0
    assert g.column_valid.sum() >= 1750
    src = g.extra["packet_index"][g.column_valid]
    assert np.all(np.diff(src) >= 0)  # bins in azimuth order hold firings in firing order


# ------------------------------------------------------------------ VeloView's own test
def test_veloview_expected_frames_and_point_counts(ext):
    """vlp-16.test: 52 frames (partial first and last) and its per-frame point counts.

    VeloView splits frames where a *block* azimuth wraps (cut_on_block=True): our frame i is
    VeloView's frame i, and a point is a firing with a non-zero distance.
    """
    expected = {}
    for line in ext("veloview/vlp-16.test").read_text().split("frame ")[1:5]:
        idx, count = line.split()[:1], line.split("point_count")[1].split()[0]
        expected[int(idx[0])] = int(count)
    assert expected == {0: 5736, 2: 13898, 16: 13860, 51: 274}
    frames, dec = decode_all(pcap_batches(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")), cut_on_block=True)
    assert len(frames) == 52
    assert frames[0].partial and frames[-1].partial and not any(f.partial for f in frames[1:-1])
    for i, count in expected.items():
        assert frames[i].n_returns == count, i
    assert dec.stats.malformed == 0 and dec.stats.lost_packets == 0
    assert frames[5].sensor.frequency_hz == pytest.approx(20, abs=0.2)
    assert frames[5].sensor.product_id == 0x21


def test_veloview_expected_points_of_frame_16(ext):
    """The two points vlp-16.test lists for frame 16, within its 1e-4 tolerance.

    VeloView (2014) orders points by firing (column, then laser id), uses x right / y forward
    (x_vv = −y, y_vv = x) and one azimuth per firing sequence (no per-laser interpolation):
    we reproduce that by giving every pixel its column's azimuth.
    """
    frames, _ = decode_all(pcap_batches(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")), cut_on_block=True,
                           calibration=ext("veloview/VLP-16.xml"))
    f = frames[16]
    per_sequence = np.broadcast_to(np.rint(f.azimuth_deg * 100).astype(np.uint16), (16, f.shape[2]))
    xyz = dataclasses.replace(f, extra=dict(f.extra, azimuth_cdeg=per_sequence)).xyz()[0]
    rows = np.array([row_of_laser(l) for l in range(16)])
    col = np.repeat(np.arange(f.shape[2]), 16)
    row = np.tile(rows, f.shape[2])
    hit = f.range_mm[0, row, col] > 0
    col, row = col[hit], row[hit]
    assert col.size == 13860
    for index, x, y, z, intensity in [(0, 0.0801272, 6.04037, -1.61865, 4), (13859, -0.0308793, 4.91453, 1.31687, 29)]:
        p = xyz[row[index], col[index]]
        assert (-p[1], p[0], p[2]) == pytest.approx((x, y, z), abs=1e-4)
        assert f.reflectivity[0, row[index], col[index]] == intensity


def test_default_cut_differs_from_veloview_by_one_firing_sequence_at_most(ext):
    frames, _ = decode_all(pcap_batches(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")))
    assert len(frames) == 52
    for i, count in {0: 5736, 2: 13898, 16: 13860, 51: 274}.items():
        assert abs(frames[i].n_returns - count) <= 16
    for f in frames[1:-1]:  # per-sequence cut: azimuths rise monotonically through each frame
        assert np.all(np.diff(f.azimuth_deg) > 0)


# ------------------------------------------------------------------ which streams are VLP-16
def test_early_unit_with_hdl32e_product_id_is_a_vlp16(ext):
    batches = pcap_batches(ext("rust-lidar-utils/velodyne_vlp16.pcap"))
    kinds = {b.payload_size: classify(b) for b in batches}
    assert kinds == {1206: "data", 512: "position"}
    data = next(b for b in batches if b.payload_size == 1206)
    info = describe_stream(data)
    assert info["kind"] == "VLP-16 data" and info["product_id"] == 0x21 and "early VLP-16" in info["note"]
    assert classify(data.select(np.array([0]))) == "data"  # one packet: the layout decides
    pos = describe_stream(next(b for b in batches if b.payload_size == 512))
    assert pos["kind"] == "VLP-16 position" and pos["nmea_first"] is None
    frames = list(lidarpkt.open(ext("rust-lidar-utils/velodyne_vlp16.pcap")))
    assert len(frames) == 2 and frames[0].sensor.model == "VLP-16"


def test_hdl32e_capture_is_decoded_as_an_hdl32e_not_a_vlp16(ext):
    path = ext("rust-lidar-utils/velodyne_vlp32.pcap")
    batches = pcap_batches(path)
    data = next(b for b in batches if b.payload_size == 1206)
    assert describe_stream(data)["kind"] == "HDL-32E data"
    assert data_kind(data.select(np.array([3]))) == "hdl32e"  # one packet: the layout decides
    pos = describe_stream(next(b for b in batches if b.payload_size == 512))
    assert pos["kind"].startswith("HDL-32E position")
    frames = list(lidarpkt.open(path))
    assert frames and all(f.sensor.model == "HDL-32E" and f.sensor.rows == 32 for f in frames)


def test_lidarpkt_open_reads_every_real_vlp16_capture(ext):
    example = list(lidarpkt.open(ext("rust-lidar-utils/velodyne_example.pcap")))
    assert len(example) == 2 and sum(f.shape[2] for f in example) == 84 * 24
    bag = list(lidarpkt.open(ext("nebula/vlp16/1673400471837873222")))
    assert bag[1].return_labels == ("last", "strongest") and bag[1].shape[:2] == (2, 16)
    veloview = list(lidarpkt.open(ext("veloview/vlp-16-test-90deg-1-50-frames.pcap")))
    assert len(veloview) == 52


# ------------------------------------------------------------------ losses and bad input
def test_lost_packets_leave_invalid_columns(ext):
    payload = einride(ext)
    host = 1_600_000_000_000_000_000 + np.arange(1000, dtype=np.int64) * 1_327_104
    keep = np.ones(1000, bool)
    keep[100:105] = False
    full, _ = decode_all([PacketBatch.from_payloads(payload, host)])
    holed, dec = decode_all([PacketBatch.from_payloads(payload, host).select(keep)])
    assert dec.stats.lost_packets == 5
    assert [f.shape for f in holed] == [f.shape for f in full]
    f, g = holed[1], full[1]  # packets 100–104 fall in the second frame
    assert f.counters.lost_packets == 5
    invalid = ~f.column_valid
    assert invalid.sum() == 5 * 24
    assert np.all(f.range_mm[:, :, invalid] == 0) and np.all(f.column_timestamp_ns[invalid] == 0)
    np.testing.assert_array_equal(f.range_mm[:, :, ~invalid], g.range_mm[:, :, ~invalid])
    # the lost columns' azimuths are interpolated between their neighbours (for on_grid)
    assert np.all(np.abs(f.azimuth_deg[invalid] - g.azimuth_deg[invalid]) < 0.2)


def test_malformed_packets_are_counted_and_skipped(ext):
    payload = einride(ext)[:200].copy()
    host = 1_600_000_000_000_000_000 + np.arange(200, dtype=np.int64) * 1_327_104
    payload[50, 301] = 0x00  # block 3's flag
    payload[60, 1204] = 0x40  # an unknown return mode
    with pytest.warns(SkippedPacketWarning, match="bad block flag"):
        frames, dec = decode_all([PacketBatch.from_payloads(payload, host)])
    assert dec.stats.malformed_flag == 1 and dec.stats.unknown_return_mode == 1
    assert dec.stats.decoded_packets == 198 and dec.stats.lost_packets == 2
    assert sum(f.counters.malformed_packets for f in frames) == 2
    assert sum(int(f.column_valid.sum()) for f in frames) == 198 * 24
    with pytest.warns(SkippedPacketWarning, match="1212"):
        assert dec.push(PacketBatch.from_payloads(np.zeros((3, 1212), np.uint8))) == []
    assert dec.stats.malformed_size == 3


def test_duplicate_and_out_of_order_packets_are_counted(ext):
    payload = einride(ext)[:100]
    host = 1_600_000_000_000_000_000 + np.arange(100, dtype=np.int64) * 1_327_104
    order = np.r_[0:40, 39, 41, 40, 42:100]  # one duplicate, one swapped pair
    frames, dec = decode_all([PacketBatch.from_payloads(payload[order], host[order])])
    assert dec.stats.duplicate_packets == 1 and dec.stats.out_of_order_packets == 1
    assert sum(f.counters.duplicate_packets for f in frames) == 1
    assert dec.stats.lost_packets == 0  # within a batch the late packet is put back in its place
    reference, _ = decode_all([PacketBatch.from_payloads(payload, host)])
    for a, b in zip(frames, reference):
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
    # a packet older than an earlier batch's last one is dropped and counted as late
    dec = VelodyneDecoder()
    dec.push(PacketBatch.from_payloads(payload[:50], host[:50]))
    dec.push(PacketBatch.from_payloads(payload[45:46], host[45:46]))
    assert dec.stats.late_packets == 1 and dec.stats.decoded_packets == 50


def test_a_long_gap_cuts_the_frame(ext):
    payload = einride(ext)[:300]
    host = 1_600_000_000_000_000_000 + np.arange(300, dtype=np.int64) * 1_327_104
    frames, dec = decode_all([PacketBatch.from_payloads(payload[:120], host[:120]),
                              PacketBatch.from_payloads(payload[280:], host[280:])], max_gap_s=0.1)
    assert dec.stats.long_gaps == 1 and dec.stats.lost_packets == 160
    assert all(f.partial for f in frames)
    assert all(f.column_valid.all() for f in frames)  # nothing inserted for a long gap


# ------------------------------------------------------------------ absolute time
def _packets_at(t_us: np.ndarray, mode: str = "strongest") -> np.ndarray:
    n = len(t_us)
    az = (np.arange(n)[:, None] * 480 + np.arange(12)[None, :] * 40) % 36000
    dist = np.full((n, 12, 32), 1000)
    return encode_data_packets(az, dist, np.full((n, 12, 32), 7), t_us % 3_600_000_000, mode)


def test_hour_from_capture_time_across_the_top_of_the_hour():
    start_ns = 1_700_002_800_000_000_000 + 3_599_900_000_000  # 0.1 s before a top of the hour... plus an hour
    start_ns -= start_ns % HOUR_NS
    true_ns = start_ns + 3_599_900_000_000 + np.arange(200, dtype=np.int64) * 1_327_104
    toh_us = (true_ns // 1000) % 3_600_000_000
    assert toh_us[-1] < toh_us[0]  # the sensor's counter wrapped
    host = true_ns + 2_000_000  # received 2 ms later
    frames, _ = decode_all([PacketBatch.from_payloads(_packets_at(toh_us), host)])
    ts = np.concatenate([f.column_timestamp_ns for f in frames]).reshape(-1, 24)[:, 0]
    np.testing.assert_array_equal(ts, (true_ns // 1000) * 1000)
    # without a capture clock (raw payloads) the decoder carries the hour across the wrap itself
    frames, _ = decode_all([PacketBatch.from_payloads(_packets_at(toh_us))])
    ts = np.concatenate([f.column_timestamp_ns for f in frames]).reshape(-1, 24)[:, 0]
    assert np.all(np.diff(ts) > 0) and np.all(np.abs(np.diff(ts) - 1_327_104) < 1000)


def test_hour_from_gps_when_position_packets_have_a_fix():
    hour = 1_700_002_800_000_000_000 - 1_700_002_800_000_000_000 % HOUR_NS
    true_ns = hour + 1_000_000_000_000 + np.arange(50, dtype=np.int64) * 1_327_104  # 16:40 past the hour
    toh_us = (true_ns // 1000) % 3_600_000_000
    host = true_ns + 45 * 60 * 1_000_000_000  # the host clock is 45 min fast: nearest hour is wrong
    data = PacketBatch.from_payloads(_packets_at(toh_us), host)
    frames, _ = decode_all([data])
    assert frames[0].column_timestamp_ns[0] == true_ns[0] // 1000 * 1000 + HOUR_NS  # capture time alone misleads
    import datetime as dt

    utc = dt.datetime.fromtimestamp(int(true_ns[0]) // 10**9, dt.timezone.utc)
    body = f"GPRMC,{utc:%H%M%S},A,4807.038,N,01131.000,E,022.4,084.4,{utc:%d%m%y},003.1,W"
    chk = 0
    for ch in body.encode():
        chk ^= ch
    pos = encode_position_packets([int(toh_us[0]) - 20_000], 2, f"${body}*{chk:02X}")
    pos_batch = PacketBatch.from_payloads(pos, [int(host[0]) - 20_000_000])
    assert classify(pos_batch) == "position"
    assert describe_stream(pos_batch)["fix_valid"] is True
    frames, dec = decode_all([pos_batch, data])
    assert dec.stats.gps_fixes == 1
    assert frames[0].column_timestamp_ns[0] == true_ns[0] // 1000 * 1000


# ------------------------------------------------------------------ dual mode and mode changes
def test_dual_slots_and_second_strongest_marks():
    n = 4
    az = np.repeat(np.arange(6) * 80, 2)[None, :] + np.arange(n)[:, None] * 480
    dist = np.zeros((n, 12, 32), np.int64)
    refl = np.zeros((n, 12, 32), np.int64)
    # pair 0, sequence 0 (distances in 2 mm units; the signal is estimated as reflectivity / range²):
    # laser 0 one return (both blocks equal); laser 1: last 6 m refl 10, strongest 2 m refl 80;
    # laser 2: the last was the strongest (200/6² > 20/2²): block 1 holds the second strongest;
    # laser 3: the last has the higher reflectivity (90 > 20) but the weaker signal (90/6² < 20/2²):
    # block 1 is the strongest (the rule before issue 17 marked it); laser 4: equal signals
    # (90/6² = 10/2²): the tie is not marked
    dist[:, 0, 0], dist[:, 1, 0], refl[:, 0, 0], refl[:, 1, 0] = 500, 500, 40, 40
    dist[:, 0, 1], dist[:, 1, 1], refl[:, 0, 1], refl[:, 1, 1] = 3000, 1000, 10, 80
    dist[:, 0, 2], dist[:, 1, 2], refl[:, 0, 2], refl[:, 1, 2] = 3000, 1000, 200, 20
    dist[:, 0, 3], dist[:, 1, 3], refl[:, 0, 3], refl[:, 1, 3] = 3000, 1000, 90, 20
    dist[:, 0, 4], dist[:, 1, 4], refl[:, 0, 4], refl[:, 1, 4] = 3000, 1000, 90, 10
    t_us = 1_000_000 + np.arange(n) * 664
    batch = PacketBatch.from_payloads(encode_data_packets(az % 36000, dist, refl, t_us, "dual"),
                                      1_700_000_000_000_000_000 + t_us * 1000)
    dec = VelodyneDecoder()
    (f,) = dec.push(batch) + dec.finish()
    assert f.return_labels == ("last", "strongest") and f.shape == (2, 16, 12 * n)
    r0, r1, r2 = row_of_laser(0), row_of_laser(1), row_of_laser(2)
    assert f.range_mm[:, r0, 0].tolist() == [1000, 1000]  # one return: both slots, as sent
    assert f.range_mm[:, r1, 0].tolist() == [6000, 2000]
    assert f.range_mm[:, r2, 0].tolist() == [6000, 2000]
    ss = f.extra["second_strongest"]
    assert ss.shape == (16, 12 * n)
    assert not ss[r0, 0] and not ss[r1, 0] and ss[r2, 0]
    assert not ss[row_of_laser(3), 0] and not ss[row_of_laser(4), 0]
    assert int(ss.sum()) == n * 1  # only laser 2 of the first firing sequence of each packet
    np.testing.assert_array_equal(np.diff(f.column_timestamp_ns[:12]), 55_296)


def test_return_mode_change_starts_a_new_frame():
    t_us = 2_000_000 + np.arange(40) * 1327
    raw = np.concatenate([_packets_at(t_us[:20], "strongest"), _packets_at(t_us[20:], "last")])
    frames, _ = decode_all([PacketBatch.from_payloads(raw, 1_700_000_000_000_000_000 + t_us * 1000)])
    assert [f.return_labels for f in frames] == [("strongest",), ("last",)]
    assert all(f.partial for f in frames)
    # the split is exactly at the change: 20 packets × 24 firings on each side, none lost or moved
    assert [int(f.column_valid.sum()) for f in frames] == [480, 480]
    first, second = (f.column_timestamp_ns[f.column_valid] for f in frames)
    assert second[0] - first[0] == 20 * 1327 * 1000  # frame 2 starts with packet 20
    assert second[0] - first[-1] == 1327 * 1000 - 23 * 55_296  # packet 19's last firing ends frame 1


def test_cut_angle(ext):
    frames, _ = decode_all([PacketBatch.from_payloads(einride(ext))], cut_angle_deg=90)
    for f in frames[1:-1]:
        assert 90 <= f.azimuth_deg[0] < 90.5
        assert 89.5 < f.azimuth_deg[-1] < 90


def test_a_sensor_that_stops_turning_cannot_grow_a_frame_forever():
    n = 2000
    t_us = 1_000_000 + np.rint(np.arange(n) * 1327.104).astype(np.int64)
    az = np.full((n, 12), 4500)  # the head stands still at 45°
    payload = encode_data_packets(az, np.full((n, 12, 32), 800), np.full((n, 12, 32), 9), t_us, "strongest")
    dec = VelodyneDecoder(max_frame_columns=10_000)
    frames = []
    for i in range(0, n, 100):
        frames += dec.push(PacketBatch.from_payloads(payload[i:i + 100], 1_700_000_000_000_000_000 + t_us[i:i + 100] * 1000))
    frames += dec.finish()
    assert dec.stats.overlong_frames >= 4
    assert all(f.partial and f.shape[2] <= 10_000 + 2400 for f in frames)
    assert sum(f.shape[2] for f in frames) == n * 24  # nothing lost


def test_calibration_through_lidarpkt_open(ext):
    stock = list(lidarpkt.open(ext("rust-lidar-utils/velodyne_example.pcap")))[1]
    yaml = list(lidarpkt.open(ext("rust-lidar-utils/velodyne_example.pcap"), metadata=ext("rust-lidar-utils/VLP16db.yaml")))[1]
    a, b = stock.xyz(), yaml.xyz()
    np.testing.assert_array_equal(a[..., :2], b[..., :2])  # same elevations and azimuths
    hit = stock.range_mm > 0
    # the stock calibration's vertical offsets (velodyne_decoder's) are the only difference
    dz = (a[..., 2] - b[..., 2])[hit]
    assert 0 < np.abs(dz).max() < 0.012


def _nmea(body: str) -> str:
    from lidarpkt.core.nmea import checksum

    return f"${body}*{checksum(body):02X}"


def test_gpgga_fix_and_bad_sentences_in_position_packets():
    import datetime as dt

    hour = 1_700_002_800_000_000_000 - 1_700_002_800_000_000_000 % HOUR_NS
    true_ns = hour + 2_000_000_000_000 + np.arange(30, dtype=np.int64) * 1_327_104  # 33:20 past the hour
    toh_us = (true_ns // 1000) % 3_600_000_000
    host = true_ns - 40 * 60 * 1_000_000_000  # host clock 40 min slow
    utc = dt.datetime.fromtimestamp(int(true_ns[0]) // 10**9, dt.timezone.utc)
    gga = _nmea(f"GPGGA,{utc:%H%M%S},4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,")
    bad = gga[:-2] + ("00" if gga[-2:] != "00" else "01")  # wrong checksum
    pos = encode_position_packets(np.repeat(toh_us[0] - 5000, 3), 2, [bad, gga, gga])
    pos_batch = PacketBatch.from_payloads(pos, np.repeat(host[0] - 5_000_000, 3))
    frames, dec = decode_all([pos_batch, PacketBatch.from_payloads(_packets_at(toh_us), host)])
    assert dec.stats.nmea_errors == 1 and dec.stats.gps_fixes == 2
    assert frames[0].column_timestamp_ns[0] == true_ns[0] // 1000 * 1000
    # a sentence that fails its checksum never sets the hour
    pos_bad = PacketBatch.from_payloads(encode_position_packets([int(toh_us[0])], 2, bad), [int(host[0])])
    frames, dec = decode_all([pos_bad, PacketBatch.from_payloads(_packets_at(toh_us), host)])
    assert dec.stats.nmea_errors == 1 and dec.stats.gps_fixes == 0
    assert frames[0].column_timestamp_ns[0] != true_ns[0] // 1000 * 1000


def test_a_gap_across_the_wrap_is_counted_on_both_sides(ext):
    payload = einride(ext)
    host = 1_600_000_000_000_000_000 + np.arange(1000, dtype=np.int64) * 1_327_104
    full, _ = decode_all([PacketBatch.from_payloads(payload, host)])
    # the packets around the first wrap inside the recording: the last 3 of frame 0, the first 4 of frame 1
    first_of_1 = int(full[1].extra["packet_index"][0])
    keep = np.ones(1000, bool)
    keep[first_of_1 - 3:first_of_1 + 4] = False
    holed, dec = decode_all([PacketBatch.from_payloads(payload, host).select(keep)])
    assert dec.stats.lost_packets == 7
    assert len(holed) == len(full)
    assert holed[0].counters.lost_packets + holed[1].counters.lost_packets == 7
    assert 2 <= holed[0].counters.lost_packets <= 4  # the cut falls where the interpolated azimuth wraps
    for a, b in zip(holed, full):
        assert a.shape[2] == b.shape[2] or abs(a.shape[2] - b.shape[2]) <= 24


def test_other_velodyne_models_are_named_by_their_factory_byte(ext):
    payload = einride(ext)[:20].copy()
    payload[:, 1205] = 0x28  # VLP-32C
    batch = PacketBatch.from_payloads(payload, 1_600_000_000_000_000_000 + np.arange(20) * 1_327_104)
    assert classify(batch) == "data"
    assert describe_stream(batch)["kind"] == "VLP-32C data"
    payload[:, 1205] = 0x99  # no Velodyne product: routed, and the decoder names the byte
    desc = describe_stream(PacketBatch.from_payloads(payload))
    assert desc["kind"] == "unknown 0x99 data" and "factory byte 0x99 names no model" in desc["note"]
    payload[:, :2] = 0  # not a Velodyne block flag
    assert describe_stream(PacketBatch.from_payloads(payload)) is None


def test_one_packet_without_returns_is_classified_by_its_azimuth_step(ext):
    vlp = next(b for b in pcap_batches(ext("rust-lidar-utils/velodyne_vlp16.pcap")) if b.payload_size == 1206)
    hdl = next(b for b in pcap_batches(ext("rust-lidar-utils/velodyne_vlp32.pcap")) if b.payload_size == 1206)
    for batch, expected in ((vlp, "vlp16"), (hdl, "hdl32e")):
        one = batch.select(np.array([5]))
        empty = one.payload.copy()
        for blk in range(12):  # clear every distance: no returns to compare
            rows = 100 * blk + 4 + 3 * np.arange(32)
            empty[0, rows] = 0
            empty[0, rows + 1] = 0
        assert data_kind(PacketBatch.from_payloads(empty)) == expected


def test_timing_still_decides_with_lost_packets(ext):
    vlp = next(b for b in pcap_batches(ext("rust-lidar-utils/velodyne_vlp16.pcap")) if b.payload_size == 1206)
    hdl = next(b for b in pcap_batches(ext("rust-lidar-utils/velodyne_vlp32.pcap")) if b.payload_size == 1206)
    assert classify(vlp.select(np.array([0, 2, 3, 7]))) == "data"  # steps of 2, 1 and 4 periods
    assert classify(vlp.select(np.array([0, 2]))) == "data"
    assert data_kind(hdl.select(np.array([0, 3, 4, 9]))) == "hdl32e"
    assert data_kind(hdl.select(np.array([0, 2]))) == "hdl32e"
