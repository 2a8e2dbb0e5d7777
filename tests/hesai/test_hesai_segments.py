"""A Pandar pcap (the XT32 bag's packets re-encoded as a UDP stream) read in segments, by several threads:
the frames, their ids, packet ordinals and arrays are those of one thread."""

from __future__ import annotations

import glob
import warnings

import numpy as np
import pytest

import lidarpkt
from lidarpkt.pipeline import parallel
from lidarpkt.vendors.hesai import decode_packets, detect_model, encode_packets
from lidarpkt.core.packet import Endpoint, Packet, PacketBatch
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.writers.pcap import write_pcap


@pytest.fixture
def xt32_pcap(ext, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batch = PacketBatch.concatenate(list(BagReader(glob.glob(str(ext("nebula/hesai/xt32")) + "/*/")[0], messages=bag_messages()).batches()))
    model = detect_model(batch.payload)
    raw = decode_packets(batch.payload, model)
    span = int(raw.timestamp_ns[-1] - raw.timestamp_ns[0]) + 200_000
    copies = [encode_packets(model, azimuth_cdeg=raw.azimuth_cdeg, distance=raw.distance, reflectivity=raw.reflectivity,
                             return_mode=raw.return_mode, timestamp_ns=raw.timestamp_ns + k * span,
                             udp_sequence=raw.udp_sequence + np.uint32(k * len(raw)), confidence=raw.confidence)
              for k in range(2)]
    payload = np.concatenate(copies)
    src, dst = Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368)
    path = tmp_path / "xt32.pcap"
    t0 = int(raw.timestamp_ns[0])
    write_pcap(path, (Packet(t0 + i * 200_000, src, dst, payload[i].tobytes()) for i in range(len(payload))),
               udp_checksum=False)
    return path, ext("nebula/hesai/PandarXT32.csv")


def test_segments_give_the_frames_of_one_thread(xt32_pcap, monkeypatch):
    monkeypatch.setattr(parallel, "MIN_SEGMENT_BYTES", 100_000)
    monkeypatch.setattr(parallel, "MAX_SEGMENT_BYTES", 400_000)
    path, csv = xt32_pcap
    one = list(lidarpkt.open(path, metadata=csv))
    reader = lidarpkt.open(path, metadata=csv, workers=3)
    assert isinstance(reader, parallel.ParallelFrameReader) and len(reader.segments) >= 4
    three = list(reader)
    assert [f.frame_id for f in three] == [f.frame_id for f in one] == list(range(9))
    assert [f.partial for f in three] == [f.partial for f in one]
    for a, b in zip(one, three):
        assert np.array_equal(a.range_mm, b.range_mm) and np.array_equal(a.column_timestamp_ns, b.column_timestamp_ns)
        assert np.array_equal(a.extra["packet_index"], b.extra["packet_index"])
        assert np.array_equal(a.xyz(), b.xyz())
