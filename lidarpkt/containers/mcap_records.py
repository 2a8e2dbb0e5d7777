"""Plain MCAP files read record by record, bounded: ``(schema, channel, message)`` in file order as the
mcap library's non-seeking reader gives them, with every chunk inflated into at most the size it
declares (itself at most :data:`MAX_MCAP_CHUNK_BYTES`), and reads that never ask for more than the file
holds. So a damaged or hostile file costs what it holds, and a file whose writer was killed (no
summary, a cut last chunk) yields everything up to the damage."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Iterator

from ..errors import CaptureFormatError


def _decompression_errors() -> tuple[type[BaseException], ...]:
    """What the MCAP reader's chunk decompressors raise on damaged chunks (zstd; lz4 raises RuntimeError)."""
    out: list[type[BaseException]] = [RuntimeError]
    try:
        from zstandard import ZstdError

        out.append(ZstdError)
    except ImportError:  # pragma: no cover - zstandard is a dependency
        pass
    return tuple(out)


DECOMPRESSION_ERRORS = _decompression_errors()


class _FileRemainder:
    """A binary file whose ``read(n)`` asks for no more than the bytes left in the file.

    A damaged MCAP record length (up to 2**64 - 1) would otherwise make the mcap reader's
    ``read(length)`` allocate that much up front (a ``MemoryError``, or gigabytes); capped, the read
    comes back short and the reader reports the file as cut short.
    """

    def __init__(self, fh) -> None:
        self._fh = fh
        self._size = os.fstat(fh.fileno()).st_size

    def read(self, n: int = -1) -> bytes:
        left = max(0, self._size - self._fh.tell())
        return self._fh.read(left if n is None or n < 0 else min(n, left))

    def __getattr__(self, name: str):
        return getattr(self._fh, name)


MAX_MCAP_CHUNK_BYTES = 256 << 20  # uncompressed bytes of one MCAP chunk (writers use a few MB; ours ~1 s of data)


def mcap_stream_messages(fh, path: Path) -> Iterator[tuple[Any, Any, Any]]:
    """``(schema, channel, message)`` of an MCAP file in file order, as the mcap library's
    ``NonSeekingReader.iter_messages`` gives them, but with every chunk inflated into at most the
    size it declares, itself at most :data:`MAX_MCAP_CHUNK_BYTES`.

    The library inflates a zstd chunk into whatever size the zstd frame header names and an lz4
    chunk without a limit: a few KB could ask for gigabytes.

    Raises:
        CaptureFormatError: a chunk declares more than :data:`MAX_MCAP_CHUNK_BYTES`.
        mcap.exceptions.McapError: a chunk inflates to another size than it declares, or a message
            names a channel (a channel a schema) not seen before.
    """
    from mcap.exceptions import McapError
    from mcap.records import Channel, Chunk, Message, Schema
    from mcap.stream_reader import StreamReader, breakup_chunk

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    # mcap annotates its input as a union of file classes; it only calls read(), which _FileRemainder has
    for record in StreamReader(_FileRemainder(fh), emit_chunks=True).records:  # type: ignore[arg-type]
        for rec in breakup_chunk(_inflated(record, path)) if isinstance(record, Chunk) else (record,):
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                if rec.schema_id != 0 and rec.schema_id not in schemas:
                    raise McapError(f"no schema record found with id {rec.schema_id}")
                channels[rec.id] = rec
            elif isinstance(rec, Message):
                channel = channels.get(rec.channel_id)
                if channel is None:
                    raise McapError(f"no channel record found with id {rec.channel_id}")
                yield schemas.get(channel.schema_id) if channel.schema_id else None, channel, rec


def _inflated(chunk, path: Path):
    """``chunk`` with its records uncompressed (compression ``""``), inflated into at most the size it
    declares; an unknown compression is left for the mcap library to refuse."""
    import io

    from mcap.exceptions import McapError
    from mcap.records import Chunk

    declared = chunk.uncompressed_size
    if declared > MAX_MCAP_CHUNK_BYTES:
        raise CaptureFormatError(
            f"{path}: an MCAP chunk declares {declared} bytes uncompressed, more than the {MAX_MCAP_CHUNK_BYTES >> 20} MiB "
            "lidarpkt inflates at once (recorders write chunks of a few MB): the file is damaged or hostile there")
    if chunk.compression == "zstd":
        import zstandard

        parts, want = [], declared + 1  # one byte more than declared tells a chunk that holds more
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data)) as reader:
            while want > 0 and (part := reader.read(want)):
                parts.append(part)
                want -= len(part)
        data = b"".join(parts)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=declared + 1)
    elif chunk.compression == "":
        data = chunk.data
    else:
        return chunk
    if len(data) != declared:
        raise McapError(f"an MCAP chunk inflates to {'more than ' if len(data) > declared else ''}"
                        f"{min(len(data), declared)} bytes where it declares {declared}")
    return Chunk(compression="", data=data, message_start_time=chunk.message_start_time,
                 message_end_time=chunk.message_end_time, uncompressed_size=declared,
                 uncompressed_crc=chunk.uncompressed_crc)
