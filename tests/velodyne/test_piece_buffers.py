"""The Velodyne decoder makes each run of columns (a piece) from buffers its pool recycles: a frame the
caller keeps keeps its numbers while decoding goes on, and a frame the caller drops gives its buffers back."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

import lidarpkt
from lidarpkt import fixtures
from lidarpkt.vendors.velodyne import VelodyneDecoder
from lidarpkt.vendors.velodyne import frames as velodyne_frames
from lidarpkt.vendors.velodyne.columns import POOL_BYTES
from lidarpkt.containers.pcap_reader import read_batches
from lidarpkt.core.packet import PacketBatch


def digest(frame) -> str:
    h = hashlib.sha256()
    arrays = [frame.range_mm, frame.reflectivity, frame.column_timestamp_ns, frame.column_valid, frame.azimuth_deg,
              frame.pixel_time_offset_ns] + [frame.extra[k] for k in sorted(frame.extra)]
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


# 240 columns: pieces of 10 packets, so that every frame is joined from many pieces and buffers turn over fast
@pytest.mark.parametrize("piece_columns", [240, velodyne_frames.PIECE_COLUMNS])
@pytest.mark.parametrize("name", ["vlp16-strongest", "vlp16-dual"])
def test_frames_kept_keep_their_numbers(name, piece_columns, monkeypatch):
    monkeypatch.setattr(velodyne_frames, "PIECE_COLUMNS", piece_columns)
    pcap = fixtures.canned(name)
    streamed = [digest(f) for f in lidarpkt.open(pcap)]  # each frame dropped once read
    assert len(streamed) > 3
    kept = list(lidarpkt.open(pcap))
    assert [digest(f) for f in kept] == streamed
    some = [f for i, f in enumerate(lidarpkt.open(pcap)) if i % 3 == 0]  # the others dropped as they come
    assert [digest(f) for f in some] == streamed[::3]


@pytest.mark.parametrize("piece_columns", [240, velodyne_frames.PIECE_COLUMNS])
def test_dropped_frames_give_their_buffers_back(piece_columns, monkeypatch):
    monkeypatch.setattr(velodyne_frames, "PIECE_COLUMNS", piece_columns)
    packets = PacketBatch.concatenate([b for b in read_batches(fixtures.canned("vlp16-strongest"))
                                       if b.payload_size == 1206])
    dec = VelodyneDecoder()
    pool = dec._pool
    frames = []
    half = len(packets) // 2
    for lo in range(0, len(packets) - 49, 50):  # 50 packets at a time (no shorter tail), each frame dropped at once
        frames += [f.frame_id for f in dec.push(packets.select(slice(lo, lo + 50)))]
        if lo < half <= lo + 50:
            made, reused = pool.made, pool.reused
    assert len(frames) > 3
    assert pool.made == made  # the second half of the capture takes no new buffer
    assert pool.reused > reused
    assert pool.nbytes <= POOL_BYTES
