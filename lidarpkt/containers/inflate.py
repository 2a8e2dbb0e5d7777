"""Bounded inflation of compressed bag data: a few KB of a hostile file must not become gigabytes.

rosbags inflates a ROS 1 bag's bz2/lz4 chunks, a rosbag2's zstd-compressed messages, the chunks of a
rosbag2's MCAP storage and a rosbag2's zstd-compressed files with no limit (bz2.decompress,
lz4.frame.decompress, zstd's content size from the frame header, a stream copy to disk). Bounded here:

- ROS 1 chunks and rosbag2 messages: after rosbags has opened a bag, :func:`bound_rosbags` swaps, on
  that reader only, each ROS 1 chunk's decompressor for one that inflates into at most the size the
  chunk's header declares (itself at most :data:`MAX_INFLATED_BYTES`), and inflates rosbag2 messages
  itself into at most :data:`MAX_INFLATED_BYTES`.
- rosbag2 compressed files (``compression_mode: file``): before rosbags opens the bag,
  :func:`inflate_rosbag2_files` inflates them itself into a temporary folder, in a stream, stopping at
  :data:`MAX_FILE_INFLATION` times the compressed size (at least :data:`MAX_INFLATED_BYTES`) and before
  the disk is full, and hands rosbags the inflated files.
- rosbag2 MCAP storage chunks: rosbags looks their decompressor up, at each chunk, in the module table
  ``rosbags.rosbag2.storage_mcap.DECOMPRESSORS``, in methods that offer no per-reader hook (even the
  index scan of ``open()`` inflates chunks). :func:`bounded` is the one interception: it puts a view in
  front of that table, once, that hands out the table's own functions unless the calling thread is
  inside ``with bounded(path):``, where it hands out bounded ones. A user's own rosbags reads, and
  lidarpkt's own between two of its calls, get the stock decompressors.

The MCAP file path (:mod:`lidarpkt.containers.bags`) bounds its chunks with its own reader.
"""

from __future__ import annotations

import contextlib
import contextvars
import io
import os
import shutil
import struct
import tempfile
import threading
from collections.abc import MutableMapping
from functools import partial
from pathlib import Path
from typing import Any, Iterator

from ..errors import CaptureFormatError

__all__ = ["MAX_INFLATED_BYTES", "MAX_FILE_INFLATION", "inflate_bounded", "bound_rosbags", "bounded",
           "needs_scope", "next_bounded", "inflate_rosbag2_files"]

MAX_INFLATED_BYTES = 256 << 20  # one chunk or message, uncompressed (recorders write chunks of a few MB)
MAX_FILE_INFLATION = 64  # inflated bytes per compressed byte of a rosbag2 file (zstd on packet data: 2-5)
_DISK_MARGIN_BYTES = 64 << 20  # left free on the temporary folder's disk


def inflate_bounded(data: bytes, compression: str, limit: int, what: str) -> bytes:
    """``data`` inflated (``"bz2"``, ``"lz4"`` or ``"zstd"``), holding at most ``limit + 1`` bytes at a time.

    Raises:
        CaptureFormatError: it inflates to more than ``limit`` bytes (``what`` names the part of the file).
    """
    want = limit + 1  # one byte more than allowed tells data that holds more
    if compression == "bz2":
        import bz2

        out = bz2.BZ2Decompressor().decompress(data, max_length=want)
    elif compression == "lz4":
        import lz4.frame

        out = lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=want)
    elif compression == "zstd":
        import zstandard

        parts = []
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data)) as reader:
            while want > 0 and (part := reader.read(want)):
                parts.append(part)
                want -= len(part)
        out = b"".join(parts)
    else:
        raise CaptureFormatError(f"{what}: compression {compression!r} is not supported")
    if len(out) > limit:
        raise CaptureFormatError(
            f"{what} inflates to more than {limit} bytes (it is {len(data)} bytes compressed): the file is damaged "
            "or hostile there; lidarpkt does not inflate it")
    return out


def bound_rosbags(reader: Any, path: Path) -> None:
    """Bound the inflation of an opened rosbags ``AnyReader`` (its ROS 1 chunks, its rosbag2 messages)."""
    for sub in getattr(reader, "readers", ()):
        chunks = getattr(sub, "chunks", None)
        if isinstance(chunks, dict):  # a ROS 1 bag: every chunk's header says its compression and size
            for pos, chunk in list(chunks.items()):
                compression, size = _ros1_chunk_header(sub.bio, pos, path)
                if compression not in ("", "none"):
                    chunks[pos] = chunk._replace(decompressor=partial(_ros1_chunk, compression, size, path, pos))
        elif getattr(sub, "compression_mode", None) == "message" and sub.storage is not None:
            sub.storage.messages = partial(_inflated_messages, sub.storage.messages, path)
            sub.metadata["compression_mode"] = ""  # inflated above: rosbags must not inflate them again


def _ros1_chunk(compression: str, size: int, path: Path, pos: int, data: bytes) -> bytes:
    what = f"{path}: the ROS 1 bag chunk at offset {pos}"
    if size > MAX_INFLATED_BYTES:
        raise CaptureFormatError(
            f"{what} declares {size} bytes uncompressed, more than the {MAX_INFLATED_BYTES >> 20} MiB lidarpkt inflates "
            "at once (recorders write chunks of about 768 KB): the file is damaged or hostile there")
    out = inflate_bounded(data, compression, size, what)
    if len(out) != size:
        raise CaptureFormatError(f"{what} inflates to {len(out)} bytes where its header declares {size}")
    return out


def _inflated_messages(messages, path: Path, *args, **kwargs) -> Iterator[tuple[Any, int, bytes]]:
    for connection, timestamp, data in messages(*args, **kwargs):
        what = f"{path}: the message on {connection.topic} at {timestamp} ns"
        yield connection, timestamp, inflate_bounded(data, "zstd", MAX_INFLATED_BYTES, what)


def _ros1_chunk_header(bio, pos: int, path: Path) -> tuple[str, int]:
    """(compression, uncompressed size) from the header of the ROS 1 chunk record at ``pos``."""
    bio.seek(pos)
    (header_len,) = struct.unpack("<I", bio.read(4))
    header = bio.read(min(header_len, 1 << 16))
    fields: dict[str, bytes] = {}
    p = 0
    while p + 4 <= len(header):
        (n,) = struct.unpack_from("<I", header, p)
        name, _, value = header[p + 4 : p + 4 + n].partition(b"=")
        fields[name.decode("ascii", "replace")] = value
        p += 4 + n
    size = fields.get("size", b"")
    if len(size) != 4:
        raise CaptureFormatError(f"{path}: the ROS 1 bag chunk at offset {pos} has no uncompressed size in its header")
    return fields.get("compression", b"none").decode("ascii", "replace"), struct.unpack("<I", size)[0]


# --------------------------------------------------------------------- rosbag2 MCAP storage chunks
_BOUNDED_PATH: contextvars.ContextVar[Path | None] = contextvars.ContextVar("lidarpkt_bounded_bag", default=None)
_INSTALL_LOCK = threading.Lock()


class _ScopedDecompressors(MutableMapping):
    """A view of rosbags' ``DECOMPRESSORS`` table: its own entries (a user's changes to the table
    included), except inside ``with bounded(path):`` where ``[compression]`` is a bounded inflater."""

    def __init__(self, table: dict) -> None:
        self.table = table

    def __getitem__(self, compression: str):
        stock = self.table[compression]  # an unknown compression: rosbags' own KeyError, as before
        path = _BOUNDED_PATH.get()
        return stock if path is None else partial(_mcap_chunk, compression, path)

    def __setitem__(self, key, value) -> None:
        self.table[key] = value

    def __delitem__(self, key) -> None:
        del self.table[key]

    def __iter__(self):
        return iter(self.table)

    def __len__(self) -> int:
        return len(self.table)


def _install() -> None:
    from rosbags.rosbag2 import storage_mcap

    if isinstance(storage_mcap.DECOMPRESSORS, _ScopedDecompressors):
        return
    with _INSTALL_LOCK:
        if not isinstance(storage_mcap.DECOMPRESSORS, _ScopedDecompressors):
            # rosbags annotates its table as a dict; it only ever looks entries up, which a mapping serves
            storage_mcap.DECOMPRESSORS = _ScopedDecompressors(storage_mcap.DECOMPRESSORS)  # type: ignore[assignment]


@contextlib.contextmanager
def bounded(path: Path) -> Iterator[None]:
    """Within this block (this thread or task only), rosbags inflates a rosbag2's MCAP chunks into at most
    the size each declares, itself at most :data:`MAX_INFLATED_BYTES`; ``path`` names the bag in errors.
    Enter it around each call into rosbags, never across a ``yield`` to the caller."""
    _install()
    token = _BOUNDED_PATH.set(path)
    try:
        yield
    finally:
        _BOUNDED_PATH.reset(token)


def needs_scope(reader: Any) -> bool:
    """Does reading this opened rosbags ``AnyReader`` inflate through rosbags' MCAP ``DECOMPRESSORS`` (a
    rosbag2 with MCAP storage)? Other bags are read without :func:`next_bounded`'s cost."""
    return any(getattr(sub, "metadata", {}).get("storage_identifier") == "mcap" for sub in getattr(reader, "readers", ()))


def next_bounded(it: Iterator, path: Path) -> Any:
    """``next(it)`` inside ``with bounded(path):``, at a fraction of its cost (a step per message)."""
    token = _BOUNDED_PATH.set(path)
    try:
        return next(it)
    finally:
        _BOUNDED_PATH.reset(token)


def _mcap_chunk(compression: str, path: Path, data: bytes, declared: int) -> bytes:
    what = f"{path}: an MCAP chunk of the bag's storage"
    if declared > MAX_INFLATED_BYTES:
        raise CaptureFormatError(
            f"{what} declares {declared} bytes uncompressed, more than the {MAX_INFLATED_BYTES >> 20} MiB lidarpkt "
            "inflates at once (recorders write chunks of a few MB): the file is damaged or hostile there")
    out = data if compression == "" else inflate_bounded(data, compression, declared, what)
    if len(out) != declared:
        raise CaptureFormatError(f"{what} inflates to {len(out)} bytes where it declares {declared}")
    return out


# --------------------------------------------------------------------- rosbag2 compressed files
def inflate_rosbag2_files(reader: Any, path: Path) -> None:
    """Inflate the zstd-compressed files of each rosbag2 of an unopened rosbags ``AnyReader`` into a
    temporary folder (the sub-reader's ``tmpdir``, removed by its ``close()``) and point it there, so
    that rosbags does not inflate them without a limit.

    Raises:
        CaptureFormatError: a file inflates to more than :data:`MAX_FILE_INFLATION` times its size (at
            least :data:`MAX_INFLATED_BYTES`), or to more than the temporary folder's disk holds, or is
            no zstd data; what was inflated is removed.
    """
    for sub in getattr(reader, "readers", ()):
        if getattr(sub, "compression_mode", None) != "file":
            continue
        sub.tmpdir = tempfile.TemporaryDirectory(prefix="lidarpkt-bag-")
        inflated = []
        for file in sub.paths:
            out = Path(sub.tmpdir.name, file.stem)  # bag_0.db3.zstd -> bag_0.db3, as rosbags names it
            _inflate_file(file, out, path)
            inflated.append(out)
        sub.paths = inflated
        sub.metadata["compression_mode"] = ""  # inflated above: rosbags must not inflate them again


def _inflate_file(src: Path, dst: Path, bag: Path) -> None:
    import zstandard

    limit = max(MAX_INFLATED_BYTES, MAX_FILE_INFLATION * os.path.getsize(src))
    free = shutil.disk_usage(dst.parent).free - _DISK_MARGIN_BYTES
    written, done = 0, False
    try:
        with src.open("rb") as fin, dst.open("wb") as fout, zstandard.ZstdDecompressor().stream_reader(
                fin, read_across_frames=True) as zin:  # as rosbags' copy_stream: every frame
            while block := zin.read(1 << 20):
                written += len(block)
                if written > min(limit, free):
                    why = (f"more than {limit} bytes ({MAX_FILE_INFLATION} times its size): the file is damaged "
                           "or hostile; lidarpkt does not inflate it" if limit <= free else
                           f"more than the {max(free, 0) >> 20} MiB free in {dst.parent.parent}; free some "
                           "space there (or set TMPDIR to a larger disk)")
                    raise CaptureFormatError(f"{bag}: the compressed file {src.name} inflates to {why}")
                fout.write(block)
        done = True
    except zstandard.ZstdError as exc:
        raise CaptureFormatError(f"{bag}: the compressed file {src.name} is no zstd data ({exc})") from None
    finally:
        if not done:  # no half-inflated file left behind
            dst.unlink(missing_ok=True)
