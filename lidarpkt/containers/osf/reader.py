"""One OSF file read: its header, metadata entries and chunk index (:class:`FrameFile`), the stored
messages of each frame stream in file or receive-time order, and the fields a frame message stores
(:func:`stored_fields`), as arrays.

Metadata entries read: the sensor entries (their text: the sensor's description, handed to the caller
as is), the frame streams (which sensor each is) and the streaming index (the chunks of each stream);
others are not read. What the fields mean, and the frames made of them, is the caller's.

Damage is an error where ouster-sdk's reader logs it and skips the chunk or field: a block whose CRC
fails, a field that does not decode, an offset outside the file are each a
:class:`~lidarpkt.errors.CaptureFormatError` naming the file and what is wrong (inside the package,
:class:`~lidarpkt.containers.osf.format.Damaged` until the file's name is put in front). Nothing is
allocated from a size the file claims before that size is checked against the file (blocks,
vectors) or the frame's own size (decoded fields).
"""

from __future__ import annotations

import heapq
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from lidarpkt.errors import CaptureFormatError
from .codecs import decode_image
from .format import (CHAN_FIELDS, CHUNK_ID, FIELD_TYPES, FORMAT, HEADER_ID, HEADER_STATUS_VALID, LIDAR_SCAN_STREAM,
                     LIDAR_SENSOR, METADATA_ID, STREAMING_INFO, VERSION_2_0, Damaged, FlatTable, root_table)

_MAX_ELEMENTS_PER_PIXEL = 64  # a decoded field holds at most this many values per pixel of the frame
_MAX_FRAME_BYTES_PER_PIXEL = 256  # the named fields of a frame decode to at most this (a dual frame's fields: 18 B)
#: what every damage is called in the errors: ``f"{path}: {DAMAGED}: ..."``
DAMAGED = f"damaged {FORMAT} file"


@dataclass
class FrameStream:
    """One sensor's stream of frame messages: its metadata entry id, its sensor's entry id and
    description text, and its chunks (offsets from the first chunk)."""

    stream_id: int
    sensor_id: int
    sensor_text: str
    chunk_offsets: list[int]


class FrameFile:
    """The header, metadata entries and chunk index of one OSF file; the stored messages of its streams.

    Args:
        path: the file.

    Raises:
        CaptureFormatError: not an OSF file, a version before 2.0, an unfinished file (header not
            marked valid), a header or metadata block that is damaged (CRC, sizes, offsets), no
            streaming index, a stream naming a sensor entry that is not there.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        try:
            self._fh = self.path.open("rb")
        except OSError as exc:
            raise CaptureFormatError(f"{self.path}: cannot read ({exc.strerror})") from None
        try:
            self.size = os.fstat(self._fh.fileno()).st_size
            self._read_index()
        except Damaged as exc:
            self.close()
            raise CaptureFormatError(f"{self.path}: {DAMAGED}: {exc}") from None
        except (struct.error, ValueError, IndexError, OverflowError) as exc:
            self.close()
            raise CaptureFormatError(f"{self.path}: {DAMAGED} ({type(exc).__name__}: {exc})") from None
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self._fh.close()

    def _block(self, offset: int, end: int, what: str) -> bytes:
        """The size-prefixed flatbuffer at ``offset`` (prefix included), its CRC checked; it must end by ``end``."""
        if offset + 4 > end:
            raise Damaged(f"the {what} at byte {offset} lies beyond the end of its region (byte {end})")
        self._fh.seek(offset)
        size = struct.unpack("<I", self._fh.read(4))[0]
        if offset + 4 + size + 4 > end:
            raise Damaged(f"the {what} at byte {offset} declares {size} B, beyond the end of its region (byte {end}; "
                          f"the file has {self.size} B)")
        body = self._fh.read(size)
        (crc,) = struct.unpack("<I", self._fh.read(4))
        block = struct.pack("<I", size) + body
        if zlib.crc32(block) != crc:
            raise Damaged(f"the {what} at byte {offset} fails its CRC-32")
        return block

    def _read_index(self) -> None:
        header_block = self._block(0, self.size, "header")
        if header_block[8:12] != HEADER_ID:
            raise Damaged(f"no {FORMAT} header (identifier {HEADER_ID.decode()!r})")
        header = root_table(header_block, "Header", HEADER_ID)
        self.version = int(header.version)
        if self.version < VERSION_2_0:
            raise Damaged(f"{FORMAT} version {self.version} predates 2.0, the first version lidarpkt (and the format's own "
                          "reader) read")
        if header.status != HEADER_STATUS_VALID:
            raise Damaged("the header is not marked valid: the recording was not closed (its writer was stopped)")
        self.chunks_start = len(header_block) + 4
        self.metadata_offset = int(header.metadata_offset)
        if not self.chunks_start <= self.metadata_offset < self.size or header.file_length > self.size:
            raise Damaged(f"the metadata is said to lie at bytes {self.metadata_offset}-{header.file_length}, outside "
                          f"the file's {self.size} B")
        meta = root_table(self._block(self.metadata_offset, self.size, "metadata block"), "Metadata", METADATA_ID)
        self.metadata_id = meta.id
        entries = {}
        for entry in meta.entries or []:
            buf = entry.buffer
            entries[int(entry.id)] = (entry.type, bytes(buf) if buf is not None else b"")
        self.entry_types = {k: t for k, (t, _) in entries.items()}
        sensors: dict[int, str] = {}
        streams: dict[int, int] = {}
        chunks: dict[int, list[int]] = {}
        streaming = False
        for entry_id, (kind, buf) in entries.items():
            if kind == LIDAR_SENSOR:
                sensors[entry_id] = root_table(buf, "LidarSensor").metadata
            elif kind == LIDAR_SCAN_STREAM:
                streams[entry_id] = int(root_table(buf, "LidarScanStream").sensor_id)
            elif kind == STREAMING_INFO:
                streaming = True
                for info in root_table(buf, "StreamingInfo").chunks or []:
                    chunks.setdefault(int(info.stream_id), []).append(int(info.offset))
        if streams and not streaming:
            raise Damaged(f"no streaming index (StreamingInfo): an {FORMAT} of the old standard layout, which "
                          "the format's own reader no longer reads either")
        self.sensor_json = sensors
        self.streams: list[FrameStream] = []
        for stream_id, sensor_id in sorted(streams.items()):
            if sensor_id not in sensors:
                raise Damaged(f"the frame stream {stream_id} names the sensor entry {sensor_id}, which is not there")
            self.streams.append(FrameStream(stream_id, sensor_id, sensors[sensor_id],
                                            sorted(set(chunks.get(stream_id, [])))))  # a chunk listed twice: read once

    @property
    def version_text(self) -> str:
        """The format version as ``"major.minor.patch"``."""
        if self.version < (1 << 16):  # the old enum: V_2_0 = 20, V_2_1 = 21
            return f"2.{self.version - VERSION_2_0}.0"
        return f"{self.version >> 48 & 0xFFFF}.{self.version >> 32 & 0xFFFF}.{self.version >> 16 & 0xFFFF}"

    # ------------------------------------------------------------------ messages
    def messages(self, stream: FrameStream) -> Iterator[tuple[int, int, bytes]]:
        """``(receive ts, stream id, LidarScanMsg buffer)`` of one stream, in file order.

        Raises:
            Damaged: a chunk is damaged.
        """
        for rel in stream.chunk_offsets:
            block = self._block(self.chunks_start + rel, self.metadata_offset, "chunk")
            chunk = root_table(block, "Chunk", CHUNK_ID)
            seen: set[int] = set()
            for msg in chunk.messages or []:
                if msg.id == stream.stream_id:
                    buf = msg.buffer
                    if buf is None:
                        continue
                    # messages sharing one buffer would decode one frame's fields many times from few bytes
                    where = buf.ctypes.data  # its place in the chunk (a view of it)
                    if buf.size and where in seen:
                        raise Damaged(f"two messages of the chunk at byte {self.chunks_start + rel} share one buffer")
                    seen.add(where)
                    yield int(msg.ts), stream.stream_id, bytes(buf)

    def messages_by_time(self) -> Iterator[tuple[int, int, bytes]]:
        """The messages of every stream, by receive time (ties: stream order), as ouster-sdk gives them.

        Raises:
            Damaged: a chunk is damaged.
        """
        order = {s.stream_id: i for i, s in enumerate(self.streams)}
        yield from heapq.merge(*(self.messages(s) for s in self.streams), key=lambda m: (m[0], order[m[1]]))


def stored_fields(msg: FlatTable, rows: int, columns: int, pixel_shift_by_row: np.ndarray | None
                  ) -> dict[str, np.ndarray]:
    """The fields a frame message (``LidarScanMsg``) stores, by name: the standard channels (``RANGE``,
    ``SIGNAL``... ``[rows, columns]``, staggered back by ``pixel_shift_by_row`` where their PNG image is
    destaggered), then the fields stored by name (``ZONE_MASK``, ``ZONE_STATES``...) in their shapes.

    Raises:
        Damaged: a field does not decode, or the fields hold more than a frame of this size can.
    """
    return {**_channel_fields(msg, rows, columns, pixel_shift_by_row), **_custom_fields(msg, rows, columns)}


def _channel_fields(msg: FlatTable, h: int, w: int, shift: np.ndarray | None) -> dict[str, np.ndarray]:
    """The standard channels of a frame message (RANGE, SIGNAL... ``[H, W]``), by name."""
    out: dict[str, np.ndarray] = {}
    types, channels = msg.field_types, msg.channels
    if types is None or not types.size:
        return out
    if channels is None or len(channels) < types.size:
        raise Damaged(f"a frame lists {types.size} fields but stores {0 if channels is None else len(channels)}")
    for (chan, tag), channel in zip(types.tolist(), channels):
        name = CHAN_FIELDS.get(chan)
        element = FIELD_TYPES.get(tag)
        if name is None or element is None or element.kind not in "ui":
            raise Damaged(f"a frame stores the channel {chan} of type {tag}, which the format does not define")
        if name in out:
            raise Damaged(f"a frame stores the channel {name} twice")
        data = channel.buffer
        try:
            out[name] = decode_image(data if data is not None else b"", (h, w), element, shift)
        except Damaged as exc:
            raise Damaged(f"frame {msg.frame_id}, field {name}: {exc}") from None
    return out


def _custom_fields(msg: FlatTable, h: int, w: int) -> dict[str, np.ndarray]:
    """The fields of a frame message stored by name (ZONE_MASK, ZONE_STATES...), in their shapes."""
    out: dict[str, np.ndarray] = {}
    budget = h * w * _MAX_FRAME_BYTES_PER_PIXEL
    for field in msg.custom_fields or []:
        name: str = field.name
        if name in out:
            raise Damaged(f"a frame stores the field {name!r} twice")
        element = FIELD_TYPES.get(field.tag)
        stored = field.shape
        shape = tuple(int(n) for n in (stored.tolist() if stored is not None else ()))
        if element is None:
            raise Damaged(f"the field {name!r} has the unknown type {field.tag}")
        most = h * w * _MAX_ELEMENTS_PER_PIXEL
        if not shape or any(n > most for n in shape) or int(np.prod(shape, dtype=object)) > most:
            raise Damaged(f"the field {name!r} has the shape {shape}, beyond what a frame of {h}x{w} holds")
        data = field.data if field.data is not None else b""
        size = element.itemsize
        budget -= int(np.prod(shape)) * size
        if budget < 0:  # fields sharing their bytes could otherwise decode to any size
            raise Damaged(f"the fields of frame {msg.frame_id} add up to more than {_MAX_FRAME_BYTES_PER_PIXEL} B a pixel")
        if len(shape) == 1:  # stored raw
            if len(data) != shape[0] * size:
                raise Damaged(f"the field {name!r} holds {len(data)} B, not the {shape[0] * size} B of "
                              f"{shape[0]} {element}")
            out[name] = np.frombuffer(bytes(data), element).copy()
        elif int(np.prod(shape)) == 0:
            out[name] = np.zeros(shape, element)
        else:
            try:
                out[name] = decode_image(data, shape, element, None)
            except Damaged as exc:
                raise Damaged(f"frame {msg.frame_id}, field {name}: {exc}") from None
    return out
