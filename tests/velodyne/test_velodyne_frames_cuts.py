"""VLP-16 frame cuts, counted exactly (issue 19: the survivors of a mutation run over velodyne/frames.py).

The packets are made with the encoder from the manual's layout: a head turning 40 × 0.01° per block
(20 per firing sequence, so 1800 columns a turn, ≈ 10.05 Hz), one column per firing sequence, packets
1327.104 µs apart (663.552 µs in dual mode), the sensor's µs past the hour matching the capture
clock. Where a column wraps, how wide each frame is, which frames are partial and every counter
follow from those rules by arithmetic, written out beside each assertion.
"""

from __future__ import annotations

import datetime as dt

import numpy as np
import pytest

from conftest import under_mutmut

from lidarpkt.errors import CalibrationError, SkippedPacketWarning
from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.velodyne import VelodyneDecoder, encode_data_packets, encode_position_packets
from lidarpkt.vendors.velodyne.calibration import VelodyneCalibration, stock_calibration
from lidarpkt.vendors.velodyne.models import VLP16

HOUR0_NS = 1_699_999_200 * 10**9  # a top of the hour: packet time = this + µs past the hour
T0_US = 1_000_000
STEP_CDEG = 40  # per block (per block pair in dual): 20 per firing sequence
TURN_COLUMNS = 36_000 // 20
PERIOD_US = {"strongest": 1327.104, "last": 1327.104, "dual": 663.552}  # the manual's packet periods
MANUAL_ELEVATION = [-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15]



def block_azimuths(slots, mode: str = "strongest", first_cdeg: int = 0) -> np.ndarray:
    """``[n, 12]`` block azimuths of packet ordinals ``slots`` (dual: a block pair shares one)."""
    slots = np.asarray(slots, np.int64)
    per, block = (6, np.arange(12) // 2) if mode == "dual" else (12, np.arange(12))
    return (first_cdeg + STEP_CDEG * (slots[:, None] * per + block[None, :])) % 36_000


def packets(slots, mode: str = "strongest", first_cdeg: int = 0, *, az=None, t_us=None) -> PacketBatch:
    """Packets at ordinals ``slots`` of one turning head (``az``/``t_us`` override the azimuths and times).

    ``batch.index`` is the slot, so ``packet_index`` names the packet; the reflectivity is the slot
    (mod 200, + 1) so that a pixel tells which packet it came from."""
    slots = np.asarray(slots, np.int64)
    n = len(slots)
    az = block_azimuths(slots, mode, first_cdeg) if az is None else np.asarray(az)
    t_us = T0_US + np.rint(slots * PERIOD_US[mode]).astype(np.int64) if t_us is None else np.asarray(t_us, np.int64)
    refl = np.broadcast_to((slots % 200 + 1)[:, None, None], (n, 12, 32))
    payload = encode_data_packets(az, np.full((n, 12, 32), 1000), refl, t_us % 3_600_000_000, mode)
    batch = PacketBatch.from_payloads(payload, HOUR0_NS + t_us * 1000)
    return PacketBatch(batch.src, batch.dst, batch.timestamp_ns, batch.payload, slots.copy())


def decode(batches, **options):
    dec = VelodyneDecoder(**options)
    frames = []
    for b in batches:
        frames += dec.push(b)
    frames += dec.finish()
    assert dec.stats.frames == len(frames)
    return frames, dec


def one_by_one(batch: PacketBatch) -> list[PacketBatch]:
    return [batch.select(np.array([i])) for i in range(len(batch))]


def true_azimuth_deg(columns: np.ndarray, first_cdeg: int) -> np.ndarray:
    """Azimuth of laser 0 in column (firing sequence) ``columns`` of the turning head, degrees."""
    return ((first_cdeg + 20 * np.asarray(columns, np.int64)) % 36_000) / 100.0


# ------------------------------------------------------------------ where a frame is cut
@pytest.mark.parametrize("packet,column", [(3, 0), (3, 1), (3, 23), (0, 1)])
def test_a_wrap_at_any_column_cuts_there_whatever_the_batches(packet, column):
    """The first column whose azimuth wrapped opens the next frame, also when it is the first or
    last column of a batch (its predecessor is then the previous batch's last column)."""
    g = 24 * packet + column  # the wrapping column: column g - 1 at 359.90°, column g at 0.10°
    first = (36_010 - 20 * g) % 36_000
    # the stream ends one column after its second wrap when the wrap is a packet's last column
    n = (g + TURN_COLUMNS + 1) // 24 if column == 23 else 3 + 75 + 10
    whole_batch = packets(np.arange(n), first_cdeg=first)
    widths = [g, TURN_COLUMNS, 24 * n - g - TURN_COLUMNS]
    for batches in ([whole_batch], one_by_one(whole_batch)):
        frames, dec = decode(batches)
        assert [f.shape[2] for f in frames] == widths
        # the first frame does not begin at the cut, the last does not end at it; the middle one is a turn
        assert [f.partial for f in frames] == [True, False, True]
        assert frames[1].azimuth_deg[0] == 0.1 and frames[1].azimuth_deg[-1] == 359.9
        assert dec.stats.frames == 3


def test_frames_are_cut_the_same_way_after_finish():
    """``finish`` releases the last frame and the decoder goes on; a packet lost across the two uses
    is an invalid column like any other."""
    g = 77
    first = 36_010 - 20 * g
    stream = packets(np.arange(88), first_cdeg=first)
    dec = VelodyneDecoder()
    part1 = dec.push(stream.select(np.arange(40))) + dec.finish()
    part2 = dec.push(stream.select(np.arange(41, 88))) + dec.finish()
    assert [f.shape[2] for f in part1] == [g, 40 * 24 - g]
    assert [f.shape[2] for f in part2] == [g + TURN_COLUMNS - 40 * 24, 88 * 24 - g - TURN_COLUMNS]
    assert dec.stats.lost_packets == 1 and part2[0].counters.lost_packets == 1
    assert np.flatnonzero(~part2[0].column_valid).tolist() == list(range(24))  # packet 40
    assert dec.stats.frames == 4


def test_cut_angle_is_taken_modulo_a_turn():
    stream = packets(np.arange(160), first_cdeg=100)
    reference, _ = decode([stream], cut_angle_deg=270)
    for angle in (-90, 630):
        frames, dec = decode([stream], cut_angle_deg=angle)
        assert dec.cut_cdeg == 27_000
        assert [f.shape[2] for f in frames] == [f.shape[2] for f in reference]
    # the turn starts at 270°: column c has azimuth 1 + 0.2 c degrees, so 270° is column 1345
    assert reference[0].shape[2] == 1345 and reference[1].azimuth_deg[0] == 270.0


def test_cut_on_block_judges_the_first_frame_by_its_first_block():
    """A stream whose first block fires at 0.30°: within one block (0.40°) of the cut, so with
    ``cut_on_block`` the first frame is whole; per firing sequence (0.20°) it is not."""
    stream = packets(np.arange(100), first_cdeg=30)
    frames, _ = decode([stream], cut_on_block=True)
    assert [(f.shape[2], f.partial) for f in frames] == [(1800, False), (600, True)]  # block 900 wraps: column 1800
    frames, _ = decode([stream])
    assert [(f.shape[2], f.partial) for f in frames] == [(1799, True), (601, True)]  # 0.30 + 0.20 × 1799 wraps


# ------------------------------------------------------------------ overlong frames
def stop_after_wrap(n_still: int, n_turning: int = 0) -> PacketBatch:
    """Packet 0 turns and wraps at its column 15 (9 columns of the new turn); then the head stands
    still at 50° for ``n_still`` packets, then turns again from 50° for ``n_turning`` packets."""
    first = 36_010 - 20 * 15
    az = [block_azimuths([0], first_cdeg=first)[0]]
    az += [np.full(12, 5000)] * n_still
    az += list(block_azimuths(np.arange(n_turning), first_cdeg=5000))
    return packets(np.arange(1 + n_still + n_turning), az=np.array(az))


def test_default_max_frame_columns_is_8192_and_the_frame_after_is_partial():
    """9 columns after the wrap + 341 still packets × 24 = 8193 > 8192: that frame is released. Then
    the head turns again from 50°: 24 still columns + 1550 to the wrap (a frame that did not begin
    at the cut: partial), a whole turn, and the rest."""
    stream = stop_after_wrap(342, n_turning=146)
    frames, dec = decode(one_by_one(stream))
    assert [f.shape[2] for f in frames] == [15, 8193, 24 + 1550, 1800, 146 * 24 - 1550 - 1800]
    assert [f.partial for f in frames] == [True, True, True, False, True]
    assert dec.stats.overlong_frames == 1


def test_an_overlong_frame_is_released_past_max_frame_columns():
    stream = stop_after_wrap(11)
    # one batch: the wrap's frame and the overlong one come back together (9 + 11 × 24 = 273 > 249);
    # the overlong one began at a wrap and is partial all the same
    dec = VelodyneDecoder(max_frame_columns=249)
    got = dec.push(stream)
    assert [(f.shape[2], f.partial) for f in got] == [(15, True), (273, True)]
    assert dec.stats.overlong_frames == 1
    # packet by packet: 9 + 10 × 24 = 249 columns is not more than 249; one packet more is
    frames, dec = decode(one_by_one(stream), max_frame_columns=249)
    assert [(f.shape[2], f.partial) for f in frames] == [(15, True), (273, True)]
    assert dec.stats.overlong_frames == 1


# ------------------------------------------------------------------ gaps
def test_default_max_gap_is_200_ms():
    """A gap of exactly 0.2 s is filled with lost packets (rint(200000 / 1327.104) − 1 = 150); one µs
    more ends the frame."""
    t_us = T0_US + np.rint(np.arange(20) * PERIOD_US["strongest"]).astype(np.int64)
    for extra_us, long_gaps, lost in ((0, 0, 150), (1, 1, 150)):
        t = t_us.copy()
        t[10:] += t[9] + 200_000 + extra_us - t[10]
        frames, dec = decode([packets(np.arange(20), t_us=t)])
        assert dec.stats.long_gaps == long_gaps and dec.stats.lost_packets == lost
        assert sum(int((~f.column_valid).sum()) for f in frames) == (0 if long_gaps else 24 * lost)


def test_long_gaps_inside_one_batch():
    """Packets 0–99, 261–360 without 300, 522–560 in one batch: two gaps of 162 periods (0.215 s >
    0.2 s: 161 packets lost each, frame cut, nothing inserted) and one lost packet (24 invalid
    columns). The head is at 1° + 0.2° per column: it wraps at columns 1795 + 1800 k."""
    slots = np.r_[0:100, 261:300, 301:361, 522:561]
    stream = packets(slots, first_cdeg=100)
    frames, dec = decode([stream])
    assert dec.stats.long_gaps == 2 and dec.stats.lost_packets == 161 + 1 + 161
    # cuts: wrap 1795, gap after column 2399, gap 261 × 24 = 6264 → wrap 7195, gap after 8663,
    # 522 × 24 = 12528 → wrap 12595, end 13463
    assert [f.shape[2] for f in frames] == [1795, 605, 931, 1469, 67, 869]
    assert all(f.partial for f in frames)
    assert [f.counters.lost_packets for f in frames] == [0, 161, 0, 1 + 161, 0, 0]
    assert [int(f.column_valid.sum()) for f in frames] == [1795, 605, 931, 1445, 67, 869]
    # the same frames as with one batch per stretch
    split = [stream.select(np.flatnonzero((slots >= a) & (slots < b))) for a, b in ((0, 100), (261, 361), (522, 561))]
    reference, _ = decode(split)
    for f, r in zip(frames, reference):
        np.testing.assert_array_equal(f.range_mm, r.range_mm)
        np.testing.assert_array_equal(f.reflectivity, r.reflectivity)
        np.testing.assert_array_equal(f.extra["packet_index"], r.extra["packet_index"])
    # the lost packet's columns: no sample, packet index −1, documented dtypes
    f = frames[3]
    hole = ~f.column_valid
    assert np.flatnonzero(hole).tolist() == list(range(300 * 24 - 7195, 301 * 24 - 7195))
    assert f.range_mm.dtype == np.uint32 and f.reflectivity.dtype == np.uint8
    assert f.extra["azimuth_cdeg"].dtype == np.uint16 and f.column_timestamp_ns.dtype == np.int64
    assert f.extra["packet_index"].dtype == np.int64 and f.pixel_time_offset_ns.dtype == np.int64
    assert (f.extra["packet_index"][hole] == -1).all() and (f.pixel_time_offset_ns[:, hole] == 0).all()
    assert not f.range_mm[..., hole].any() and not f.column_timestamp_ns[hole].any()
    rows = [sorted(MANUAL_ELEVATION, reverse=True).index(e) for e in MANUAL_ELEVATION]  # row of laser l
    np.testing.assert_array_equal(f.pixel_time_offset_ns[rows, 0], 2304 * np.arange(16))
    assert frames[0].extra["packet_index"].dtype == np.int64  # a frame without losses too


def test_lost_columns_take_the_azimuth_of_the_turn():
    """Lost packets inside a batch after a wrap (77) and at the start of the next batch (80–82): their
    columns' azimuths continue the turn exactly (interpolated from the last column of the previous
    batch and the next received one)."""
    stream = packets(np.arange(121), first_cdeg=100)
    first = stream.select(np.setdiff1d(np.arange(80), [77]))
    second = stream.select(np.arange(83, 121))
    frames, dec = decode([first, second])
    assert dec.stats.lost_packets == 4
    azimuth = np.concatenate([f.azimuth_deg for f in frames])
    np.testing.assert_array_equal(azimuth, true_azimuth_deg(np.arange(121 * 24), 100))
    valid = np.concatenate([f.column_valid for f in frames])
    assert np.flatnonzero(~valid).tolist() == [c for p in (77, 80, 81, 82) for c in range(24 * p, 24 * p + 24)]


# ------------------------------------------------------------------ return modes
def test_mode_change_and_dual_losses_in_one_batch():
    """Strongest packets 0–99 (a wrap at column 1795), then dual packets 663.552 µs apart with one
    lost: three frames, the first two from the strongest run, the losses counted in dual periods."""
    strongest = packets(np.arange(100), first_cdeg=100)
    dual_slots = np.setdiff1d(np.arange(40), [20])
    t_dual = T0_US + np.rint(99 * PERIOD_US["strongest"] + 1327 + dual_slots * PERIOD_US["dual"]).astype(np.int64)
    dual = packets(dual_slots, "dual", first_cdeg=5000, t_us=t_dual)
    batch = PacketBatch.concatenate([strongest, dual])
    dec = VelodyneDecoder()
    pushed = dec.push(batch)
    assert [(f.return_labels, f.shape[2]) for f in pushed] == [(("strongest",), 1795), (("strongest",), 605)]
    (last,) = dec.finish()
    assert last.return_labels == ("last", "strongest") and last.shape == (2, 16, 40 * 12)
    assert last.partial and last.counters.lost_packets == 1 and dec.stats.lost_packets == 1
    assert np.flatnonzero(~last.column_valid).tolist() == list(range(240, 252))
    assert dec.sensor_info().return_mode == "dual"
    # the rate measured on dual packets: 5 block pairs × 0.40° in 10 firing sequences of 55.296 µs
    (only_dual,), _ = decode([dual])
    assert only_dual.sensor.frequency_hz == 10.05


# ------------------------------------------------------------------ counters
def _flag_and_mode(batch: PacketBatch, bad_flag: int | None, bad_mode: int | None) -> PacketBatch:
    payload = batch.payload.copy()
    if bad_flag is not None:
        payload[bad_flag, 100 * 5] = 0x00  # block 5's flag
    if bad_mode is not None:
        payload[bad_mode, 1204] = 0x40  # not a return mode
    return PacketBatch(batch.src, batch.dst, batch.timestamp_ns, payload, batch.index)


def test_every_counter_adds_up_over_batches():
    """One frame (60 packets, no wrap) pushed in pieces, each kind of trouble in two batches."""
    s = packets(np.arange(60), first_cdeg=100)
    junk = PacketBatch.from_payloads(np.zeros((3, 1212), np.uint8))
    batches = [
        s.select(np.arange(10)),
        junk,  # 3 of the wrong size
        _flag_and_mode(s.select(np.r_[10, 12, 11, 13:20]), bad_flag=4, bad_mode=None),  # 11 ↔ 12; 14 bad flag
        s.select(np.arange(19, 30)),  # 19 again: a duplicate of the last packet of the batch before, not late
        junk.select(np.arange(2)),  # 2 of the wrong size
        _flag_and_mode(s.select(np.r_[30:35, 36, 35, 37:40]), bad_flag=2, bad_mode=7),  # 35 ↔ 36; 32 flag; 37 mode
        s.select(np.r_[25, 40:50, 49]),  # 25 late, 49 twice
        _flag_and_mode(s.select(np.r_[40, 50:60]), bad_flag=None, bad_mode=3),  # 40 late; 52 unknown mode
    ]
    dec = VelodyneDecoder(source="10.0.0.1:2368")
    frames = []
    with pytest.warns(SkippedPacketWarning):
        for b in batches:
            frames += dec.push(b)
    frames += dec.finish()
    st = dec.stats
    assert st.packets == 10 + 3 + 10 + 11 + 2 + 10 + 12 + 11
    assert (st.malformed_size, st.malformed_flag, st.unknown_return_mode) == (5, 2, 2)
    # a late packet is also older than the packet before it: out of order too (11, 35, 25, 40)
    assert (st.out_of_order_packets, st.duplicate_packets, st.late_packets) == (4, 2, 2)
    assert st.decoded_packets == 60 - 4 and st.lost_packets == 4  # the 4 skipped packets leave holes
    assert st.frames == 1 == len(frames)
    c = frames[0].counters
    assert c.malformed_packets == 5 + 2 + 2
    assert (c.out_of_order_packets, c.duplicate_packets, c.late_packets, c.lost_packets) == (4, 2, 2, 4)


def test_warnings_name_the_source_and_point_at_the_caller():
    dec = VelodyneDecoder(source="10.0.0.1:2368")
    with pytest.warns(SkippedPacketWarning) as caught:
        dec.push(PacketBatch.from_payloads(np.zeros((3, 1212), np.uint8)))
    (w,) = caught
    assert str(w.message) == "10.0.0.1:2368: skipped 3 packets of 1212 B (a VLP-16 data packet has 1206 B)"
    assert under_mutmut() or w.filename == __file__
    with pytest.warns(SkippedPacketWarning) as caught:
        dec.push(_flag_and_mode(packets(np.arange(5)), bad_flag=1, bad_mode=2))
    (w,) = caught
    assert str(w.message) == ("10.0.0.1:2368: skipped 1 packets with a bad block flag or azimuth and "
                              "1 with an unknown return mode")
    assert under_mutmut() or w.filename == __file__


def _nmea(body: str) -> str:
    from lidarpkt.core.nmea import checksum

    return f"${body}*{checksum(body):02X}"


def test_position_packet_counters_add_up():
    t_us = T0_US - 5000
    utc = dt.datetime.fromtimestamp((HOUR0_NS + t_us * 1000) // 10**9, dt.timezone.utc)
    good = _nmea(f"GPRMC,{utc:%H%M%S},A,4807.038,N,01131.000,E,022.4,084.4,{utc:%d%m%y},003.1,W")
    bad = good[:-2] + ("00" if good[-2:] != "00" else "01")  # wrong checksum
    host = HOUR0_NS + t_us * 1000

    def pos(nmea):
        return PacketBatch.from_payloads(encode_position_packets(np.full(len(nmea), t_us), 2, nmea),
                                         np.full(len(nmea), host))

    dec = VelodyneDecoder()
    dec.push_position(pos(["", ""]))  # no sentence: neither an error nor a fix
    assert (dec.stats.nmea_errors, dec.stats.gps_fixes) == (0, 0)
    dec.push_auxiliary(pos([good, bad]))
    dec.push_position(pos([bad, good]))
    for n in (3, 2):
        dec.push_position(PacketBatch.from_payloads(np.zeros((n, 500), np.uint8)))
    st = dec.stats
    assert (st.position_packets, st.position_malformed) == (2 + 2 + 2 + 3 + 2, 5)
    assert (st.nmea_errors, st.gps_fixes) == (2, 2)
    # the fix agrees with the capture clock: data packets keep their times
    (f,) = decode_with(dec, packets(np.arange(3)))
    assert f.column_timestamp_ns[0] == HOUR0_NS + T0_US * 1000


def decode_with(dec: VelodyneDecoder, batch: PacketBatch):
    return dec.push(batch) + dec.finish()


# ------------------------------------------------------------------ what the decoder says about itself
def test_sensor_info_fields_and_defaults():
    assert VelodyneDecoder().sensor_info().return_labels == ("strongest",)  # before any packet
    assert VelodyneDecoder().sensor_info("dual").return_labels == ("last", "strongest")
    assert VelodyneDecoder(model="VLP-16").model is VLP16
    rot_deg = np.arange(16) * 0.25 - 2.0
    cal = VelodyneCalibration(vert_correction_rad=stock_calibration().vert_correction_rad,
                              rot_correction_rad=np.radians(rot_deg))
    dec = VelodyneDecoder(calibration=cal, source="10.0.0.1:2368")
    frames = decode_with(dec, packets(np.arange(100), first_cdeg=100))
    info = frames[0].sensor
    assert (info.vendor, info.model, info.rows, info.return_mode, info.profile) == ("velodyne", "VLP-16", 16, "strongest", "strongest")
    assert info.return_labels == ("strongest",) and info.source == "10.0.0.1:2368" and info.product_id == 0x22
    assert info.frequency_hz == 10.05  # 11 blocks × 0.40° in 22 firing sequences of 55.296 µs
    assert info.columns_per_frame == round(1e9 / (10.05 * 55_296)) == 1799
    rows = [sorted(MANUAL_ELEVATION, reverse=True).index(e) for e in MANUAL_ELEVATION]  # row of laser l
    np.testing.assert_allclose(info.beam_azimuth_deg[rows], rot_deg, atol=1e-12)
    np.testing.assert_allclose(info.beam_altitude_deg, np.arange(15, -16, -2), atol=1e-9)


def test_bad_options_are_named():
    with pytest.raises(TypeError, match=r"^unknown VelodyneDecoder options: \['bogus'\]$"):
        VelodyneDecoder(bogus=1)
    with pytest.raises(CalibrationError, match=r"a calibration of 32 lasers for a VLP-16, which has 16; pass the sensor's own"):
        VelodyneDecoder(model="VLP-16", calibration=VelodyneCalibration(vert_correction_rad=np.zeros(32)))


def test_sensor_info_asked_before_any_packet_is_not_kept_for_the_frames():
    """sensor_info() before the first packet knew no rate nor product id; it was cached, and every
    frame after it carried frequency_hz None, product_id None and 1808 columns per frame."""
    import lidarpkt
    from conftest import external
    from lidarpkt.vendors.velodyne.frames import VelodyneDecoder

    path = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    reference = next(iter(lidarpkt.open(path))).sensor
    early = VelodyneDecoder()
    before = early.sensor_info()
    assert before.frequency_hz is None and before.product_id is None
    frames = []
    from lidarpkt.containers.pcap_reader import read_batches

    for batch in read_batches(path):
        frames += early.push(batch)
        if frames:
            break
    got = frames[0].sensor
    assert (got.frequency_hz, got.product_id, got.columns_per_frame) == \
        (reference.frequency_hz, reference.product_id, reference.columns_per_frame)
    assert got.frequency_hz is not None and got.product_id is not None


def test_a_gps_fix_from_another_day_does_not_move_packets_already_placed():
    """A capture replayed (or recorded) long after its GPS fixes: the data packets are placed by the
    host clock, then a position packet says another day. Re-anchoring on it made every later packet
    hours or days older than the ones before, so all were dropped as late. The fix is counted as
    ignored and the stream goes on; a fix that agrees still anchors."""
    t_us = T0_US + 5000
    old_day = dt.datetime(2019, 6, 1, 10, 0, 0, tzinfo=dt.timezone.utc)
    fix = _nmea(f"GPRMC,{old_day:%H%M%S},A,4807.038,N,01131.000,E,022.4,084.4,{old_day:%d%m%y},003.1,W")
    position = PacketBatch.from_payloads(encode_position_packets(np.array([t_us]), 2, [fix]),
                                         np.array([HOUR0_NS + t_us * 1000]))
    dec = VelodyneDecoder()
    frames = dec.push(packets(np.arange(0, 40)))
    dec.push_position(position)
    frames += dec.push(packets(np.arange(40, 2 * TURN_COLUMNS // 24 + 40))) + dec.finish()
    st = dec.stats
    assert (st.gps_fixes, st.gps_fixes_ignored, st.late_packets) == (1, 1, 0)
    assert st.decoded_packets == 2 * TURN_COLUMNS // 24 + 40
    times = np.concatenate([f.column_timestamp_ns[f.column_valid] for f in frames])
    assert np.all(np.diff(times) > 0) and abs(int(times[0]) - (HOUR0_NS + T0_US * 1000)) < 10**9
    # before any data packet the same fix anchors (nothing is placed yet): times on 2019-06-01
    fresh = VelodyneDecoder()
    fresh.push_position(position)
    (first, *_) = fresh.push(packets(np.arange(0, TURN_COLUMNS // 24 + 10))) + fresh.finish()
    assert fresh.stats.gps_fixes_ignored == 0
    day = dt.datetime.fromtimestamp(int(first.column_timestamp_ns[0]) // 10**9, dt.timezone.utc).date()
    assert day == old_day.date()
