"""The Decoder protocol (lidarpkt/core/decoder.py): both vendor decoders meet it, and code typed against
it drives either one; the vendor stream counters meet StreamCounter."""

from __future__ import annotations

import typing

import numpy as np

from lidarpkt import fixtures
import lidarpkt
from lidarpkt.core.decoder import Decoder, StreamCounter, StreamCounts
from lidarpkt.core.frame import Frame
from lidarpkt.core.sensor import SensorInfo
from lidarpkt.vendors.ouster import OusterDecoder, load_metadata
from lidarpkt.vendors.ouster import stream as ouster_stream
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_batches
from lidarpkt.vendors.velodyne import VelodyneDecoder
from lidarpkt.vendors.velodyne import stream as velodyne_stream


def decode_capture(decoder: Decoder, lidar: list[PacketBatch], auxiliary: list[PacketBatch]) -> list[Frame]:
    """Code typed against the protocol only: what lidarpkt.open does with a decoder."""
    frames: list[Frame] = []
    for batch in auxiliary:
        decoder.push_auxiliary(batch)
    for batch in lidar:
        frames += decoder.push(batch)
    frames += decoder.finish()
    return frames


def _streams(pcap, lidar_size: int, aux_size: int) -> tuple[list[PacketBatch], list[PacketBatch]]:
    batches = list(read_batches(pcap))
    return ([b for b in batches if b.payload_size == lidar_size], [b for b in batches if b.payload_size == aux_size])


def test_both_decoders_are_decoders():
    md = load_metadata(fixtures.metadata_path(fixtures.canned("os1-64-dual")))
    assert isinstance(VelodyneDecoder(), Decoder)
    assert isinstance(OusterDecoder(md), Decoder)
    assert not isinstance(object(), Decoder)
    hints = typing.get_type_hints(decode_capture)
    assert hints["decoder"] is Decoder


def test_a_typed_call_drives_the_velodyne_decoder_like_lidarpkt_open():
    pcap = fixtures.canned("vlp16-strongest")
    lidar, position = _streams(pcap, 1206, 512)
    assert lidar and position
    dec = VelodyneDecoder()
    frames = decode_capture(dec, lidar, position)
    reference = list(lidarpkt.open(pcap))
    assert [f.frame_id for f in frames] == [f.frame_id for f in reference]
    assert all(np.array_equal(a.range_mm, b.range_mm) and np.array_equal(a.column_timestamp_ns, b.column_timestamp_ns)
               for a, b in zip(frames, reference))
    assert dec.stats.gps_fixes > 0  # push_auxiliary took the position packets
    assert dec.stats.frames == len(frames) and dec.stats.packets == sum(len(b) for b in lidar)
    info = dec.sensor_info()
    assert isinstance(info, SensorInfo) and info.return_mode == "strongest" and info is frames[0].sensor


def test_a_typed_call_drives_the_ouster_decoder_like_lidarpkt_open():
    pcap = fixtures.canned("os1-64-legacy")
    md = load_metadata(fixtures.metadata_path(pcap))
    lidar, imu = _streams(pcap, md.packet_size, md.imu_packet_size)
    assert lidar and imu
    dec = OusterDecoder(md)
    frames = decode_capture(dec, lidar, imu)
    reference = list(lidarpkt.open(pcap, metadata=fixtures.metadata_path(pcap)))
    assert [f.frame_id for f in frames] == [f.frame_id for f in reference]
    assert all(np.array_equal(a.range_mm, b.range_mm) for a, b in zip(frames, reference))
    assert dec.stats.imu_packets == sum(len(b) for b in imu) and len(dec.imu_samples()) == dec.stats.imu_packets
    assert dec.sensor_info() is dec.sensor and dec.stats.frames == len(frames)


def test_vendor_stream_counters_are_stream_counters():
    md = load_metadata(fixtures.metadata_path(fixtures.canned("os1-64-dual")))
    for counter in (velodyne_stream.PacketCounter(), ouster_stream.PacketCounter(md)):
        assert isinstance(counter, StreamCounter) and isinstance(counter.count, StreamCounts)
