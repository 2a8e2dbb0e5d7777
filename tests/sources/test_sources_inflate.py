"""Bounded inflation of ROS bags (lidarpkt.sources.inflate): compressed ROS 1 chunks (bz2, lz4) and rosbag2
zstd messages read as before, and a zero "bomb" of a few hundred bytes is refused without inflating it
(the peak memory of a child process that reads it, VmHWM, is measured)."""

from __future__ import annotations

import sqlite3
import struct
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from lidarpkt.bags import MESSAGE_DEFINITIONS, BagReader
from lidarpkt.errors import CaptureFormatError
from lidarpkt.packet import PacketBatch
from lidarpkt.pcap import read_packets
from lidarpkt.sources.inflate import MAX_INFLATED_BYTES, inflate_bounded

from conftest import REPO_ROOT

ROOT = Path(__file__).resolve().parents[2]


def _payloads(n: int = 60):
    pk = [p for p in read_packets(REPO_ROOT / "fixtures" / "canned" / "vlp16-strongest.pcap") if len(p.payload) == 1206]
    pk = pk[:n]
    return np.stack([np.frombuffer(p.payload, np.uint8) for p in pk]), np.array([p.timestamp_ns for p in pk], np.int64)


def _store(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for name, text in MESSAGE_DEFINITIONS.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def _scans(store, payload, host, per: int = 10):
    T = store.types
    for start in range(0, len(payload), per):
        pk = [T["velodyne_msgs/msg/VelodynePacket"](
            stamp=T["builtin_interfaces/msg/Time"](sec=int(host[i] // 10**9), nanosec=int(host[i] % 10**9)),
            data=payload[i].copy()) for i in range(start, start + per)]
        seq = {"seq": start} if "seq" in T["std_msgs/msg/Header"].__dataclass_fields__ else {}  # ROS 1 only
        header = T["std_msgs/msg/Header"](**seq, stamp=pk[0].stamp, frame_id="velodyne")
        yield int(host[start + per - 1]), T["velodyne_msgs/msg/VelodyneScan"](header=header, packets=pk)


def _ros1_bag(path: Path, compression: str) -> None:
    from rosbags.rosbag1 import Writer

    store = _store(ros1=True)
    payload, host = _payloads()
    w = Writer(path)
    w.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    w.chunk_threshold = 20_000  # a chunk every ~2 messages
    with w:
        conn = w.add_connection("/velodyne_packets", "velodyne_msgs/msg/VelodyneScan", typestore=store)
        for t, msg in _scans(store, payload, host):
            w.write(conn, t, store.serialize_ros1(msg, "velodyne_msgs/msg/VelodyneScan"))


def _rosbag2_message_compressed(path: Path) -> None:
    from rosbags.rosbag2 import Writer

    store = _store(ros1=False)
    payload, host = _payloads()
    w = Writer(path)
    w.set_compression(Writer.CompressionMode.MESSAGE, Writer.CompressionFormat.ZSTD)
    with w:
        conn = w.add_connection("/velodyne_packets", "velodyne_msgs/msg/VelodyneScan", typestore=store)
        for t, msg in _scans(store, payload, host):
            w.write(conn, t, store.serialize_cdr(msg, "velodyne_msgs/msg/VelodyneScan"))


def _ros1_records(raw: bytes):
    """(offset, header fields, data offset, data length) of each record after the version line."""
    pos = raw.index(b"\n") + 1
    while pos + 4 <= len(raw):
        (hlen,) = struct.unpack_from("<I", raw, pos)
        header, fields, p = raw[pos + 4 : pos + 4 + hlen], {}, 0
        while p < len(header):
            (n,) = struct.unpack_from("<I", header, p)
            k, _, v = header[p + 4 : p + 4 + n].partition(b"=")
            fields[k] = v
            p += 4 + n
        (dlen,) = struct.unpack_from("<I", raw, pos + 4 + hlen)
        yield pos, fields, pos + 8 + hlen, dlen
        pos += 8 + hlen + dlen


def _with_last_chunk_replaced(path: Path, body: bytes) -> None:
    """Put ``body`` in place of the compressed data of the bag's last chunk (its header, and so its
    declared uncompressed size, kept) and move the index position the bag header names."""
    raw = bytearray(path.read_bytes())
    records = list(_ros1_records(bytes(raw)))
    bag_header = next(r for r in records if r[1][b"op"] == b"\x03")
    last = [r for r in records if r[1][b"op"] == b"\x05"][-1]
    _, _, data_at, dlen = last
    delta = len(body) - dlen
    new = raw[: data_at - 4] + struct.pack("<I", len(body)) + body + raw[data_at + dlen :]
    # the bag header's index_pos field: its value sits after "index_pos=" in the header record
    at = bytes(new).index(b"index_pos=", bag_header[0]) + len(b"index_pos=")
    (index_pos,) = struct.unpack_from("<Q", new, at)
    struct.pack_into("<Q", new, at, index_pos + delta)
    path.write_bytes(bytes(new))


@lru_cache(maxsize=None)
def _zero_bomb(compression: str, size: int) -> bytes:
    block = bytes(1 << 20)
    if compression == "bz2":
        import bz2

        c = bz2.BZ2Compressor(1)
        return b"".join(c.compress(block) for _ in range(size >> 20)) + c.flush()
    if compression == "lz4":
        import lz4.frame

        c = lz4.frame.LZ4FrameCompressor()
        return c.begin(source_size=size) + b"".join(c.compress(block) for _ in range(size >> 20)) + c.flush()
    import zstandard

    obj = zstandard.ZstdCompressor(write_content_size=True).compressobj(size=size)
    return b"".join(obj.compress(block) for _ in range(size >> 20)) + obj.flush()


_READ_AND_REPORT_PEAK = r"""
import sys
from lidarpkt.bags import BagReader
from lidarpkt.errors import LidarpktError
n, outcome = 0, "ok"
try:
    for b in BagReader(sys.argv[1]).batches():
        n += len(b)
except LidarpktError as exc:
    outcome = type(exc).__name__
hwm = next(l.split()[1] for l in open('/proc/self/status') if l.startswith('VmHWM'))
print(n, outcome, int(hwm) // 1024)
"""


def _peak(path: Path) -> tuple[int, str, int]:
    res = subprocess.run([sys.executable, "-c", _READ_AND_REPORT_PEAK, str(path)], capture_output=True, text=True,
                         timeout=300, cwd=ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    n, outcome, peak_mb = res.stdout.split()
    return int(n), outcome, int(peak_mb)


@pytest.mark.parametrize("compression", ["bz2", "lz4"])
def test_compressed_ros1_bags_read_as_before(tmp_path, compression):
    payload, host = _payloads()
    path = tmp_path / f"{compression}.bag"
    _ros1_bag(path, compression)
    chunks = [r for r in _ros1_records(path.read_bytes()) if r[1][b"op"] == b"\x05"]
    assert len(chunks) >= 3 and {r[1][b"compression"] for r in chunks} == {compression.encode()}
    batch = PacketBatch.concatenate(list(BagReader(path).batches()))
    np.testing.assert_array_equal(batch.payload, payload)
    np.testing.assert_array_equal(batch.timestamp_ns, host)


def test_message_compressed_rosbag2_reads_as_before(tmp_path):
    payload, host = _payloads()
    _rosbag2_message_compressed(tmp_path / "bag")
    batch = PacketBatch.concatenate(list(BagReader(tmp_path / "bag").batches()))
    np.testing.assert_array_equal(batch.payload, payload)
    np.testing.assert_array_equal(batch.timestamp_ns, host)


@pytest.mark.parametrize("compression, size_mb", [("lz4", 512), ("bz2", 320)])
def test_ros1_chunk_bomb_is_not_inflated(tmp_path, compression, size_mb):
    path = tmp_path / f"bomb-{compression}.bag"
    _ros1_bag(path, compression)
    bomb = _zero_bomb(compression, size_mb << 20)
    assert len(bomb) < 4 << 20
    _with_last_chunk_replaced(path, bomb)
    n, outcome, peak_mb = _peak(path)
    assert 0 < n < 60 and outcome == "CaptureFormatError"  # the packets of the chunks before it, then the error
    assert peak_mb < 250, f"peak RSS {peak_mb} MB reading a {len(bomb)}-byte chunk of {size_mb} MB of zeros"


def test_rosbag2_message_bomb_is_not_inflated(tmp_path):
    _rosbag2_message_compressed(tmp_path / "bag")
    bomb = _zero_bomb("zstd", 512 << 20)
    with sqlite3.connect(tmp_path / "bag" / "bag.db3") as db:
        db.execute("UPDATE messages SET data = ? WHERE id = 3", (bomb,))
    n, outcome, peak_mb = _peak(tmp_path / "bag")
    assert n == 20 and outcome == "CaptureFormatError"
    assert peak_mb < 350, f"peak RSS {peak_mb} MB reading a {len(bomb)}-byte message of 512 MB of zeros"


def test_chunk_larger_than_declared_or_than_the_limit(tmp_path):
    for compression in ("bz2", "lz4", "zstd"):
        small = _zero_bomb(compression, 2 << 20)
        assert inflate_bounded(small, compression, 2 << 20, "x") == bytes(2 << 20)
        with pytest.raises(CaptureFormatError, match="inflates to more than 1000 bytes"):
            inflate_bounded(small, compression, 1000, "the chunk")
    path = tmp_path / "big.bag"
    _ros1_bag(path, "lz4")
    raw = bytearray(path.read_bytes())
    last = [r for r in _ros1_records(bytes(raw)) if r[1][b"op"] == b"\x05"][-1]
    at = bytes(raw).index(b"size=", last[0]) + len(b"size=")
    struct.pack_into("<I", raw, at, MAX_INFLATED_BYTES + 1)
    path.write_bytes(bytes(raw))
    with pytest.raises(CaptureFormatError, match="MiB"):
        list(BagReader(path).batches())
