"""The records of an MCAP file, written without copying the messages: what
:class:`~lidarpkt.writers.mcap.writer.McapWriter` writes with.

:class:`ChunkWriter` writes the file the ``mcap`` library's ``Writer`` writes (chunked, every index,
statistics, summary offsets; record for record the same bytes when ``chunk_crcs`` is true), but a message is
held by reference until its chunk closes: an uncompressed chunk goes to the file in one gathered write
(``os.writev``) of the record headers and the messages' own buffers, with no copy of its messages in
memory, and a message may be given in pieces (a point cloud's CDR header and its points, see
:func:`lidarpkt.writers.mcap.pointcloud.pointcloud_cdr`). A compressed chunk is joined, compressed and
written as the library writes it.

The records other than chunks and messages are the library's (:mod:`mcap.records`).
"""

from __future__ import annotations

import os
import struct
import zlib
from typing import Any, BinaryIO, Sequence, Union

import numpy as np

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (Channel, ChunkIndex, DataEnd, Footer, Header, MessageIndex, Metadata, MetadataIndex, Schema,
                          Statistics, SummaryOffset)

MAGIC = b"\x89MCAP0\r\n"

Buffer = Union[bytes, bytearray, memoryview, np.ndarray]
#: A message's data: its bytes, or its pieces in order (C-contiguous buffers: their bytes as they lie in memory).
Data = Union[Buffer, Sequence[Buffer]]

_MESSAGE = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log time, publish time
_CHUNK = struct.Struct("<BQQQQI")  # opcode, record length, start, end, uncompressed size, uncompressed crc
_IOV_MAX = 512  # buffers per writev call (Linux allows 1024)
_WRITEV = hasattr(os, "writev")  # POSIX; elsewhere one write per buffer


def _view(p: Buffer) -> memoryview:
    """The bytes of ``p`` (C-contiguous) as a flat view."""
    return (p.data if isinstance(p, np.ndarray) else memoryview(p)).cast("B")


def _pieces(data: Data) -> tuple[list[memoryview], int]:
    """``data`` as flat byte views and their total length (bytes)."""
    if isinstance(data, (bytes, bytearray, memoryview, np.ndarray)):
        parts = [_view(data)]
    else:
        parts = [_view(p) for p in data]
    return parts, sum(p.nbytes for p in parts)


def _record(*records) -> bytes:
    builder = RecordBuilder()
    for r in records:
        r.write(builder)
    return builder.end()


class ChunkWriter:
    """Writes one MCAP file to ``out`` (see the module doc).

    Args:
        out: a file opened for binary writing; unbuffered (``buffering=0``) or flushed by the caller before
            anything else writes to it. Gathered writes go to its descriptor.
        chunk_size: a chunk closes once its uncompressed records exceed this many bytes.
        compression: ``""`` (none), ``"zstd"`` or ``"lz4"``.
        chunk_crcs: compute each chunk's CRC-32 of its uncompressed records (as the library's ``enable_crcs``);
            ``False`` writes 0, which the MCAP specification reads as "not computed" (readers check no CRC
            of that chunk). The summary's CRC is always computed.

    Raises:
        OSError: from the file's writes (each method that writes).
    """

    def __init__(self, out: BinaryIO, *, chunk_size: int = 1 << 20, compression: str = "",
                 chunk_crcs: bool = True) -> None:
        if compression not in ("", "zstd", "lz4"):
            raise ValueError(f"compression={compression!r}: none (''), 'zstd' or 'lz4'")
        self._out = out
        self._fd = out.fileno()
        self._pos = out.tell()
        self.chunk_size = chunk_size
        self.compression = compression
        self.chunk_crcs = chunk_crcs
        self._schemas: list[Schema] = []
        self._channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}  # messages per channel id
        self._messages = 0
        self._start = self._end = 0  # log times of the file's first and last message
        self._new_chunk()

    # ------------------------------------------------------------------ output
    def _write(self, parts: Sequence[bytes | memoryview]) -> None:
        """Write ``parts`` in order, all of them (gathered, short writes resumed)."""
        views = [v for v in (memoryview(p).cast("B") for p in parts) if v.nbytes]
        while views:
            n = os.writev(self._fd, views[:_IOV_MAX]) if _WRITEV else os.write(self._fd, views[0])
            self._pos += n
            while views and n >= views[0].nbytes:
                n -= views[0].nbytes
                views.pop(0)
            if n:
                views[0] = views[0][n:]

    def tell(self) -> int:
        """Bytes written to the file so far."""
        return self._pos

    # ------------------------------------------------------------------ chunk
    def _new_chunk(self) -> None:
        self._parts: list[bytes | memoryview] = []
        self._size = 0  # uncompressed bytes of the chunk's records
        self._first = self._last = 0  # log times of its first and last message
        self._chunk_messages = 0
        self._index: dict[int, list[tuple[int, int]]] = {}  # channel id: (log time, offset in the chunk)

    def _add_record(self, data: bytes) -> None:
        self._parts.append(data)
        self._size += len(data)
        if self._size > self.chunk_size:
            self._close_chunk()

    def _close_chunk(self) -> None:
        if not self._chunk_messages:
            return
        size = self._size
        if self.compression:
            data = b"".join(self._parts)
            crc = zlib.crc32(data) if self.chunk_crcs else 0
            if self.compression == "zstd":
                import zstandard

                body: list[bytes | memoryview] = [zstandard.compress(data)]
            else:
                import lz4.frame  # type: ignore[import-untyped]

                body = [lz4.frame.compress(data)]
        else:
            body = self._parts
            crc = 0
            if self.chunk_crcs:
                for p in body:
                    crc = zlib.crc32(p, crc)
        compressed = sum(len(p) for p in body)
        name = self.compression.encode()
        length = 8 + 8 + 8 + 4 + 4 + len(name) + 8 + compressed
        start = self._pos
        head = _CHUNK.pack(Opcode.CHUNK, length, self._first, self._last, size, crc) + struct.pack(
            "<I", len(name)) + name + struct.pack("<Q", compressed)
        indexes = [MessageIndex(channel_id=cid, records=records) for cid, records in self._index.items()]
        index_bytes = _record(*indexes)
        offsets, at = {}, start + 9 + length
        for m in indexes:
            offsets[m.channel_id] = at
            at += 9 + 2 + 4 + 16 * len(m.records)
        self._write([head, *body, index_bytes])
        self._chunk_indexes.append(ChunkIndex(
            message_start_time=self._first, message_end_time=self._last, chunk_start_offset=start,
            chunk_length=9 + length, message_index_offsets=offsets, message_index_length=len(index_bytes),
            compression=self.compression, compressed_size=compressed, uncompressed_size=size))
        self._new_chunk()

    # ------------------------------------------------------------------ records
    def start(self, profile: str, library: str) -> None:
        """The magic and the Header record."""
        self._write([MAGIC, _record(Header(profile=profile, library=library))])

    def register_schema(self, name: str, encoding: str, data: bytes) -> int:
        """A Schema record (in the current chunk); its id."""
        schema = Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(schema)
        self._add_record(_record(schema))
        return schema.id

    def register_channel(self, topic: str, message_encoding: str, schema_id: int, metadata: dict[str, str]) -> int:
        """A Channel record (in the current chunk); its id."""
        channel = Channel(id=len(self._channels) + 1, topic=topic, message_encoding=message_encoding,
                          schema_id=schema_id, metadata=metadata)
        self._channels.append(channel)
        self._add_record(_record(channel))
        return channel.id

    def add_message(self, channel_id: int, log_time: int, data: Data, publish_time: int, sequence: int = 0) -> None:
        """A Message record in the current chunk, its data held by reference until the chunk is written (the
        caller must not change it meanwhile)."""
        parts, n = _pieces(data)
        if self._messages == 0:
            self._start = log_time
        else:
            self._start = min(self._start, log_time)
        self._end = max(self._end, log_time)
        self._counts[channel_id] = self._counts.get(channel_id, 0) + 1
        self._messages += 1
        if self._chunk_messages == 0:
            self._first = log_time
        else:
            self._first = min(self._first, log_time)
        self._last = max(self._last, log_time)
        self._chunk_messages += 1
        self._index.setdefault(channel_id, []).append((log_time, self._size))
        self._parts.append(_MESSAGE.pack(Opcode.MESSAGE, 22 + n, channel_id, sequence, log_time, publish_time))
        self._parts.extend(parts)
        self._size += _MESSAGE.size + n
        if self._size > self.chunk_size:
            self._close_chunk()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record, written at once (outside the chunk)."""
        offset = self._pos
        record = _record(Metadata(name=name, metadata=data))
        self._write([record])
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(record), name=name))

    def flush(self) -> None:
        """Close the current chunk (if it holds a message) and write it."""
        self._close_chunk()

    def finish(self) -> None:
        """The last chunk, DataEnd, the summary (schemas, channels, statistics, chunk, attachment and metadata
        indexes, summary offsets), the Footer and the closing magic. Does not close the file."""
        self._close_chunk()
        self._write([_record(DataEnd(data_section_crc=0))])
        summary_start = self._pos
        stats = Statistics(message_count=self._messages, schema_count=len(self._schemas),
                           channel_count=len(self._channels), attachment_count=0,
                           metadata_count=len(self._metadata_indexes), chunk_count=len(self._chunk_indexes),
                           message_start_time=self._start, message_end_time=self._end,
                           channel_message_counts=dict(self._counts))
        groups: list[tuple[Opcode, Sequence[Any]]] = [(Opcode.SCHEMA, self._schemas), (Opcode.CHANNEL, self._channels), (Opcode.STATISTICS, [stats]),
                  (Opcode.CHUNK_INDEX, self._chunk_indexes), (Opcode.ATTACHMENT_INDEX, []),
                  (Opcode.METADATA_INDEX, self._metadata_indexes)]
        builder = RecordBuilder()
        offsets = []
        for opcode, records in groups:
            at = builder.count
            for r in records:
                r.write(builder)
            offsets.append(SummaryOffset(group_opcode=opcode, group_start=summary_start + at,
                                         group_length=builder.count - at))
        offset_start = summary_start + builder.count
        for o in offsets:
            o.write(builder)
        summary = builder.end()
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, offset_start), zlib.crc32(summary))
        footer = _record(Footer(summary_start=summary_start, summary_offset_start=offset_start, summary_crc=crc))
        self._write([summary, footer, MAGIC])


__all__ = ["ChunkWriter", "Data"]
