"""Bounded inflation of compressed bag data: a few KB of a hostile file must not become gigabytes.

rosbags inflates a ROS 1 bag's bz2/lz4 chunks and a rosbag2's zstd-compressed messages with no
limit (bz2.decompress, lz4.frame.decompress, zstd's content size from the frame header). After
rosbags has opened a bag, :func:`bound_rosbags` swaps, on that reader only, each ROS 1 chunk's
decompressor for one that inflates into at most the size the chunk's header declares (itself at
most :data:`MAX_INFLATED_BYTES`), and inflates rosbag2 messages itself into at most
:data:`MAX_INFLATED_BYTES`. The MCAP path (:mod:`lidarpkt.sources.bags`) bounds its chunks alike.

Not bounded here: a rosbag2 whose *files* are compressed (``compression_mode: file``) is inflated by
rosbags into a temporary directory in a stream (memory stays small; disk use is the inflated size).
"""

from __future__ import annotations

import io
import struct
from functools import partial
from pathlib import Path
from typing import Any, Iterator

from ..errors import CaptureFormatError

__all__ = ["MAX_INFLATED_BYTES", "inflate_bounded", "bound_rosbags"]

MAX_INFLATED_BYTES = 256 << 20  # one chunk or message, uncompressed (recorders write chunks of a few MB)


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
