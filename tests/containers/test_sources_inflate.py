"""Bounded inflation of ROS bags (lidarpkt.containers.inflate): compressed ROS 1 chunks (bz2, lz4) and rosbag2
zstd messages read as before, and a zero "bomb" of a few hundred bytes is refused without inflating it
(the peak memory of a child process that reads it, VmHWM, is measured)."""

from __future__ import annotations

import sqlite3
import struct
import subprocess
import sys
import threading
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

from lidarpkt.containers.bags import BagReader

from lidarpkt.vendors.registry import ros_definitions

from lidarpkt.vendors.registry import bag_messages
from lidarpkt.errors import CaptureFormatError
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.pcap_reader import read_packets
from lidarpkt.containers.inflate import MAX_INFLATED_BYTES, inflate_bounded

from conftest import REPO_ROOT

ROOT = Path(__file__).resolve().parents[2]


def _payloads(n: int = 60):
    pk = [p for p in read_packets(REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-strongest.pcap") if len(p.payload) == 1206]
    pk = pk[:n]
    return np.stack([np.frombuffer(p.payload, np.uint8) for p in pk]), np.array([p.timestamp_ns for p in pk], np.int64)


def _store(ros1: bool):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = {}
    for name, text in ros_definitions().items():
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


def _rosbag2_compressed(path: Path, mode: str = "MESSAGE") -> None:
    """A rosbag2 (sqlite3) of the 60 packets, zstd-compressed by message or (``mode="FILE"``) by file."""
    from rosbags.rosbag2 import Writer

    store = _store(ros1=False)
    payload, host = _payloads()
    w = Writer(path)
    w.set_compression(getattr(Writer.CompressionMode, mode), Writer.CompressionFormat.ZSTD)
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
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.errors import LidarpktError
n, outcome = 0, "ok"
try:
    for b in BagReader(sys.argv[1], messages=bag_messages()).batches():
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
    batch = PacketBatch.concatenate(list(BagReader(path, messages=bag_messages()).batches()))
    np.testing.assert_array_equal(batch.payload, payload)
    np.testing.assert_array_equal(batch.timestamp_ns, host)


def test_message_compressed_rosbag2_reads_as_before(tmp_path):
    payload, host = _payloads()
    _rosbag2_compressed(tmp_path / "bag")
    batch = PacketBatch.concatenate(list(BagReader(tmp_path / "bag", messages=bag_messages()).batches()))
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
    _rosbag2_compressed(tmp_path / "bag")
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
        list(BagReader(path, messages=bag_messages()).batches())


# ----------------------------------------------------------------- rosbag2 MCAP storage, rosbag2 compressed files
def _scan_mcap_rosbag2(folder: Path, n: int = 90):
    """A rosbag2 folder whose MCAP storage (official mcap_ros2 writer, zstd chunks of ~30 KB) holds ``n``
    one-packet VelodyneScan messages; returns (folder, MCAP chunk records as (offset, length), payloads)."""
    from reference_tools import velodyne_scan_mcap
    from test_fuzz_regressions import _mcap_storage_rosbag2

    payload, host = _payloads(n)
    raw = velodyne_scan_mcap(list(payload), list(host), chunk_size=30_000)
    _mcap_storage_rosbag2(folder, raw)
    return folder, list(_mcap_chunks(raw)), payload


def _mcap_chunks(raw: bytes):
    pos = 8
    while pos + 9 <= len(raw) - 8:  # records: opcode, u64 length, body
        length = int.from_bytes(raw[pos + 1 : pos + 9], "little")
        if raw[pos] == 0x06:
            yield pos, length
        pos += 9 + length


def _bomb_in_place(storage: Path, at: int, compression: str, size: int) -> int:
    """Put a ``size``-byte zero bomb in place of the compressed records of the chunk at ``at``, padded to
    their length with a zstd skippable frame (every offset of the file, and so its index, stays right);
    returns the size the chunk declares."""
    raw = bytearray(storage.read_bytes())
    body = at + 9
    name_len = int.from_bytes(raw[body + 28 : body + 32], "little")
    assert raw[body + 32 : body + 32 + name_len] == compression.encode()
    records_at = body + 40 + name_len
    n = int.from_bytes(raw[records_at - 8 : records_at], "little")
    bomb = _zero_bomb(compression, size)
    assert len(bomb) + 8 <= n, (len(bomb), n)
    raw[records_at : records_at + n] = bomb + b"\x50\x2a\x4d\x18" + struct.pack("<I", n - len(bomb) - 8) + bytes(
        n - len(bomb) - 8)
    storage.write_bytes(bytes(raw))
    return int.from_bytes(raw[body + 16 : body + 24], "little")


def test_rosbag2_mcap_storage_reads_as_before_and_leaves_rosbags_table_alone(tmp_path):
    """The bounded chunk inflater is only handed out while lidarpkt calls into rosbags: between two
    batches, and after, ``DECOMPRESSORS`` gives rosbags' own functions (a user's rosbags reads unchanged)."""
    from rosbags.rosbag2 import storage_mcap

    folder, chunks, payload = _scan_mcap_rosbag2(tmp_path / "bag")
    assert len(chunks) >= 3
    stock = {k: storage_mcap.DECOMPRESSORS[k] for k in ("", "lz4", "zstd")}
    seen_by_other_thread: list[bool] = []
    reading = threading.Event()

    def other_thread() -> None:  # a user's rosbags use beside lidarpkt's reading, in another thread
        while not reading.is_set():
            time.sleep(0)
        while reading.is_set():
            seen_by_other_thread.append(all(storage_mcap.DECOMPRESSORS[k] is f for k, f in stock.items()))

    watcher = threading.Thread(target=other_thread)
    watcher.start()
    got = []
    try:
        reading.set()
        for _ in range(20):
            for batch in BagReader(folder, messages=bag_messages()).batches():
                got.append(batch.payload)
                assert all(storage_mcap.DECOMPRESSORS[k] is f for k, f in stock.items())
    finally:
        reading.clear()
        watcher.join(timeout=60)
    assert seen_by_other_thread and all(seen_by_other_thread)
    got = got[: len(got) // 20]
    np.testing.assert_array_equal(np.concatenate(got), payload)
    assert all(storage_mcap.DECOMPRESSORS[k] is f for k, f in stock.items())
    small = _zero_bomb("zstd", 2 << 20)
    assert storage_mcap.DECOMPRESSORS["zstd"](small, 1000) == bytes(2 << 20)  # stock: the frame's size, not 1000


def test_rosbag2_mcap_storage_chunk_bomb_is_not_inflated(tmp_path):
    """rosbags inflates a zstd chunk of a rosbag2's MCAP storage into the size its zstd frame header names
    (512 MB here), whatever the chunk declares; now into at most what the chunk declares: the packets of
    the chunks before it, then a CaptureFormatError, and a small peak."""
    folder, chunks, _ = _scan_mcap_rosbag2(tmp_path / "bag")
    declared = _bomb_in_place(folder / "b_0.mcap", chunks[1][0], "zstd", 512 << 20)
    assert declared < 40_000
    n, outcome, peak_mb = _peak(folder)
    assert 0 < n < 90 and outcome == "CaptureFormatError"
    assert peak_mb < 300, f"peak RSS {peak_mb} MB reading a chunk that declares {declared} bytes"


def test_rosbag2_mcap_storage_without_summary_is_bounded_while_opening(tmp_path):
    """Without a summary rosbags' open() scans every chunk for the schemas: a 512 MB lz4 bomb (2 MB) there
    is refused while opening."""
    folder, chunks, _ = _scan_mcap_rosbag2(tmp_path / "bag")
    storage = folder / "b_0.mcap"
    raw = bytearray(storage.read_bytes())
    raw[-37 + 9 : -37 + 17] = bytes(8)  # the footer's summary_start: no summary
    at, length = chunks[1]
    bomb = _zero_bomb("lz4", 512 << 20)
    fields = raw[at + 9 : at + 33] + bytes(4) + struct.pack("<I", 3) + b"lz4" + struct.pack("<Q", len(bomb)) + bomb
    storage.write_bytes(bytes(raw[:at] + bytes([0x06]) + struct.pack("<Q", len(fields)) + fields + raw[at + 9 + length:]))
    n, outcome, peak_mb = _peak(folder)
    assert n == 0 and outcome == "CaptureFormatError"
    assert peak_mb < 300, f"peak RSS {peak_mb} MB"


_READ_FILE_BOMB = r"""
import os, sys
import lidarpkt.containers.inflate as inflate
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages
from lidarpkt.errors import CaptureFormatError
inflate.MAX_INFLATED_BYTES = int(sys.argv[2])  # the floor of the file limit, small so the test writes little
inflate._DISK_MARGIN_BYTES = int(sys.argv[3])
try:
    list(BagReader(sys.argv[1], messages=bag_messages()).batches())
    print("ok")
except CaptureFormatError as exc:
    print(exc)
"""


def test_file_compressed_rosbag2_reads_as_before_and_leaves_no_temporary_files(tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    _rosbag2_compressed(tmp_path / "bag", "FILE")
    assert [p.name for p in (tmp_path / "bag").glob("*.zstd")] == ["bag.db3.zstd"]
    payload, host = _payloads()
    res = subprocess.run([sys.executable, "-c", _READ_FILE_BOMB, str(tmp_path / "bag"), str(1 << 30), "0"],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert res.stdout.strip() == "ok", res.stderr[-2000:]
    batch = PacketBatch.concatenate(list(BagReader(tmp_path / "bag", messages=bag_messages()).batches()))
    np.testing.assert_array_equal(batch.payload, payload)
    np.testing.assert_array_equal(batch.timestamp_ns, host)
    assert list((tmp_path / "tmp").iterdir()) == []
    # a file of two zstd frames (rosbags inflates every frame) reads alike
    import zstandard

    compressed = tmp_path / "bag" / "bag.db3.zstd"
    db = zstandard.ZstdDecompressor().decompressobj().decompress(compressed.read_bytes())
    half = len(db) // 2
    compressed.write_bytes(zstandard.ZstdCompressor().compress(db[:half]) + zstandard.ZstdCompressor().compress(db[half:]))
    again = PacketBatch.concatenate(list(BagReader(tmp_path / "bag", messages=bag_messages()).batches()))
    np.testing.assert_array_equal(again.payload, payload)
    assert list((tmp_path / "tmp").iterdir()) == []


@pytest.mark.parametrize("margin, said", [(0, "more than 8388608 bytes"), (1 << 60, "free in")])
def test_file_compressed_rosbag2_bomb_is_not_inflated_on_disk(tmp_path, monkeypatch, margin, said):
    """rosbags inflates a compressed rosbag2 file into a temporary folder whatever its size: a 16 KB file
    of 512 MB of zeros took 512 MB of disk. Now lidarpkt inflates it, in a stream, into at most 64 times
    its size (at least MAX_INFLATED_BYTES, 8 MiB in this child), and never past the free disk space;
    the half-inflated file is removed."""
    monkeypatch.setenv("TMPDIR", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    _rosbag2_compressed(tmp_path / "bag", "FILE")
    (tmp_path / "bag" / "bag.db3.zstd").write_bytes(_zero_bomb("zstd", 512 << 20))
    res = subprocess.run([sys.executable, "-c", _READ_FILE_BOMB, str(tmp_path / "bag"), str(8 << 20), str(margin)],
                         capture_output=True, text=True, timeout=120, cwd=ROOT)
    out = res.stdout.strip()
    assert out.startswith(f"{tmp_path / 'bag'}: the compressed file bag.db3.zstd inflates to") and said in out, (
        out, res.stderr[-2000:])
    assert list((tmp_path / "tmp").iterdir()) == []


def test_file_compressed_rosbag2_with_mcap_storage_inflates_the_file_then_bounds_its_chunks(tmp_path):
    """Both bounds at once: the MCAP storage file is zstd-compressed as a whole (lidarpkt inflates it to
    disk) and one of its chunks is a 512 MB zero bomb (inflated into at most what it declares)."""
    import zstandard

    folder, chunks, payload = _scan_mcap_rosbag2(tmp_path / "bag")
    plain = PacketBatch.concatenate(list(BagReader(folder, messages=bag_messages()).batches())).payload
    np.testing.assert_array_equal(plain, payload)
    _bomb_in_place(folder / "b_0.mcap", chunks[1][0], "zstd", 512 << 20)
    storage = folder / "b_0.mcap"
    (folder / "b_0.mcap.zstd").write_bytes(zstandard.ZstdCompressor().compress(storage.read_bytes()))
    storage.unlink()
    meta = folder / "metadata.yaml"
    meta.write_text(meta.read_text().replace("compression_format: ''\n  compression_mode: ''",
                                             "compression_format: zstd\n  compression_mode: file")
                    .replace("- b_0.mcap\n", "- b_0.mcap.zstd\n"))
    n, outcome, peak_mb = _peak(folder)
    assert 0 < n < 90 and outcome == "CaptureFormatError"
    assert peak_mb < 300, f"peak RSS {peak_mb} MB"
