"""The recorder's live counts and the decoder's agree on the same capture (packets, packets lost,
rotations), because both use the vendor packages' stream rules; and the time resolution the
recorder and the decoder share (hour of a VLP-16 stamp, day of an NMEA time of day)."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt import fixtures
from conftest import external
from lidarpkt.vendors.ouster import OusterDecoder, load_metadata
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches
from lidarpkt.vendors.velodyne import VelodyneDecoder
from lidarpkt.core.nmea import DAY_NS, on_nearest_day_ns
from lidarpkt.vendors.velodyne.clock import HOUR_NS, in_nearest_hour_ns
from lidarpkt.recorder.gps import sentence_time_ns
from lidarpkt.writers.mcap.writer import McapWriter
from lidarpkt.writers.mcap.packets import PacketSink
from lidarpkt.vendors.velodyne.ros import sensor_time_ns as velodyne_sensor_time_ns


def _vlp_batch(rel: str) -> PacketBatch:
    batches = [b for b in read_batches(external(rel)) if b.payload_size == 1206]
    payload = np.concatenate([b.payload for b in batches])
    host = np.concatenate([b.timestamp_ns for b in batches])
    return PacketBatch.from_payloads(payload, host)


def _drop(batch: PacketBatch, rows: list[int]) -> PacketBatch:
    keep = np.setdiff1d(np.arange(len(batch)), rows)
    return PacketBatch.from_payloads(batch.payload[keep], batch.timestamp_ns[keep])


def _record(tmp_path, batch: PacketBatch, metadata=None, parts: int = 5) -> PacketSink:
    """The recorder's path: the batch, in parts, through a PacketSink into a real MCAP file."""
    writer = McapWriter(tmp_path / "out.mcap")
    sink = PacketSink(writer, metadata=metadata)
    for rows in np.array_split(np.arange(len(batch)), parts):
        sink.push(PacketBatch(batch.src, batch.dst, batch.timestamp_ns[rows], batch.payload[rows], batch.index[rows]))
    sink.finish()
    writer.close()
    return sink


def _decode_velodyne(batch: PacketBatch) -> tuple[list, VelodyneDecoder]:
    dec = VelodyneDecoder()
    frames = []
    for rows in np.array_split(np.arange(len(batch)), 3):
        frames += dec.push(PacketBatch.from_payloads(batch.payload[rows], batch.timestamp_ns[rows]))
    return frames + dec.finish(), dec


@pytest.mark.parametrize("rel", ["veloview/vlp-16-test-90deg-1-50-frames.pcap", "rust-lidar-utils/velodyne_vlp16.pcap",
                                 "rust-lidar-utils/velodyne_example.pcap"])
@pytest.mark.parametrize("drop", [[], [10, 11, 12, 40, 41]])
def test_velodyne_recorder_and_decoder_agree(tmp_path, rel, drop):
    batch = _drop(_vlp_batch(rel), drop)
    sink = _record(tmp_path, batch)
    frames, dec = _decode_velodyne(batch)
    assert sink.packets == dec.stats.packets == len(batch)
    assert sink.lost == dec.stats.lost_packets == len(drop)
    assert sink.frames == len(frames) - 1  # every frame but the last ends at a completed rotation
    assert sink.out_of_order == dec.stats.out_of_order_packets == 0


def test_velodyne_dual_recorder_and_decoder_agree(tmp_path):
    from lidarpkt.containers.bags import BagReader
    from lidarpkt.vendors.registry import bag_messages

    batches = list(BagReader(external("nebula/vlp16/1673400471837873222"), messages=bag_messages()).batches())
    batch = _drop(PacketBatch.from_payloads(np.concatenate([b.payload for b in batches]),
                                            np.concatenate([b.timestamp_ns for b in batches])), [7, 8, 300])
    sink = _record(tmp_path, batch)
    frames, dec = _decode_velodyne(batch)
    assert sink.lost == dec.stats.lost_packets == 3
    assert sink.frames == len(frames) - 1


def test_ouster_recorder_and_decoder_agree(tmp_path):
    pcap = fixtures.canned("os1-64-dual")
    md = load_metadata(fixtures.metadata_path(pcap))
    batch = PacketBatch.concatenate([b for b in read_batches(pcap) if b.payload_size == md.packet_size])
    per_frame = md.columns_per_frame // md.columns_per_packet
    drop = [3, 4, per_frame + 10]  # inside the frames: lost packets for both
    keep = np.setdiff1d(np.arange(len(batch)), drop)
    batch = PacketBatch(batch.src, batch.dst, batch.timestamp_ns[keep], batch.payload[keep], batch.index[keep])
    sink = _record(tmp_path, batch, md)
    dec = OusterDecoder(md)
    frames = dec.push(batch) + dec.finish()
    assert sink.lost == dec.stats.lost_packets == len(drop)
    assert sink.frames == len(frames) - 1 == dec.stats.frames - 1
    assert sink.packets == dec.stats.packets


# ---------------------------------------------------------------------- time resolution, once
def test_the_hour_nearest_the_reference():
    hour = 1_780_315_200 * 10**9  # a top of the hour
    ts_us = np.array([3_599_999_000, 0, 1_000, 1_800_000_000])
    ref = np.full(4, hour + 500_000)  # 0.5 ms after the top of the hour
    got = in_nearest_hour_ns(ts_us, ref)
    np.testing.assert_array_equal(got, [hour - 1_000_000, hour, hour + 1_000_000, hour + 1_800_000_000_000])
    # the recorder's scan stamp is the same function
    np.testing.assert_array_equal(velodyne_sensor_time_ns(ts_us, ref), got)
    # exact integers at 1.8e18 ns: 1 µs either side of the half hour decides, a tie goes to the later hour
    assert int(in_nearest_hour_ns(5, hour - HOUR_NS // 2 + 4_000)) == hour - HOUR_NS + 5_000
    assert int(in_nearest_hour_ns(5, hour - HOUR_NS // 2 + 6_000)) == hour + 5_000
    assert int(in_nearest_hour_ns(5, hour - HOUR_NS // 2 + 5_000)) == hour + 5_000


def test_the_day_nearest_the_reference_and_the_recorders_gga_stamp():
    midnight = 1_780_272_000 * 10**9  # 2026-06-01 00:00 UTC
    late = 23 * HOUR_NS + 59 * 60 * 10**9 + 59 * 10**9  # 23:59:59
    assert on_nearest_day_ns(late, midnight + 5 * 10**9) == midnight - DAY_NS + late  # yesterday
    assert on_nearest_day_ns(10**9, midnight - 5 * 10**9) == midnight + 10**9  # tomorrow
    body = "GPGGA,235959.00,4224.4412,N,07107.1395,W,1,08,0.9,10.0,M,0.0,M,,"
    cs = 0
    for ch in body.encode():
        cs ^= ch
    gga = f"${body}*{cs:02X}"
    assert sentence_time_ns(gga, midnight + 5 * 10**9) == midnight - DAY_NS + late
    assert sentence_time_ns("$GPTXT,hello*00", 42) == 42
