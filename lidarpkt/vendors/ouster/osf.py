"""OSF, ouster-sdk's recording format: decoded, compressed Ouster frames and their sensor metadata.

An OSF file holds frames, not packets, so it is a frame source beside the packet sources:
``lidarpkt.open("x.osf")`` gives :class:`OsfReader`. The layout (ouster-sdk's ``ouster_osf/fb/*.fbs``
and its reader) is a sequence of flatbuffers blocks, each a 4-byte little-endian size, the buffer
and a CRC-32 (zlib's) of both::

    Header ("OSF$": version, status, metadata_offset, file_length)
    Chunk ("OSF!": StampedMessage[] of one stream), Chunk, ...
    Metadata ("OSF#", at metadata_offset: the entries, each a buffer of its own type)

Metadata entries: ``LidarSensor`` (the sensor's metadata JSON), ``LidarScanStream`` (the stream of
one sensor's frames), ``StreamingInfo`` (the chunks of each stream); others (``Extrinsics``: lidarpkt's
points are in the sensor frame) are not read. A frame
message (``LidarScanMsg``) carries per-column arrays (timestamp, measurement id, status), per-packet
ones (packet timestamp, alert flags), frame scalars (frame id, frame status, countdowns) and its
fields: the standard channels (RANGE, SIGNAL, ... by enum) and custom fields (by name, with shape
and class). A field of one dimension is stored raw; one of two or more as an image of its unsigned
bits, either PNG (8-bit grey, 16-bit grey, 8-bit RGBA or 16-bit RGBA for 8/16/32/64-bit values; a
standard channel's image is destaggered) or ZPNG (zstd over byte deltas, staggered as is).

Frames come out as ouster-sdk's ``OsfFrameSetSource`` gives them (by receive time across the
sensors' streams), as :class:`~lidarpkt.core.frame.Frame` s like those decoded from the sensor's packets
(columns by measurement id): ``range_mm``, ``reflectivity``, ``signal``, ``flags`` (``[R, H, W]``, R = 2
when the file stores the second return), ``near_ir``; ``column_timestamp_ns``, ``measurement_id``,
``status``; ``column_valid`` = status bit 0. Every other field the file stores is in ``frame.extra``
under its name in lower case (``zone_mask``, ``window``, ``zone_states``...), and so are the packet header
values, one per column as in frames decoded from packets (the value of the column's packet; the file keeps
them per packet or per frame): ``alert_flags``, ``thermal_shutdown``, ``shot_limiting``,
``countdown_thermal_shutdown``, ``countdown_shot_limiting`` (``uint8[W]``) and ``packet_timestamp_ns``
(``uint64[W]``, the host time the packet was received); and ``pose`` (``float64[4, 4, W]``, only when the
file stores one). ``partial`` is True when a column of the sensor's column window is not valid.

Damage is an error where ouster-sdk's reader logs it and skips the chunk or field: a block whose CRC
fails, a field that does not decode, an offset outside the file are each a
:class:`~lidarpkt.errors.CaptureFormatError` naming the file and what is wrong, after the frames before it. Nothing is allocated from a size the file claims before that size
is checked against the file (blocks, vectors) or the frame's own size (decoded fields).
"""

from __future__ import annotations

import heapq
import io
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generator, Iterator

import numpy as np

from lidarpkt.errors import CaptureFormatError, LidarpktError
from lidarpkt.core.frame import Frame, FrameCounters
from lidarpkt.core.sequence import FrameIterator
from lidarpkt.core.grid import restagger

# --------------------------------------------------------------------------- the schema, declared once
# Each table: field name -> (slot, kind, default). The slot is the field's place in the .fbs table
# (deprecated fields keep theirs). Kinds: a NumPy scalar type code, "str", "[code]" (vector of
# scalars), "[Struct]" (vector of a struct of STRUCTS), "[Table]" (vector of tables).
TABLES: dict[str, dict[str, tuple[int, str, Any]]] = {
    "Header": {"version": (0, "<u8", 0), "status": (1, "u1", 0), "metadata_offset": (2, "<u8", 1),
               "file_length": (3, "<u8", 1)},
    "Metadata": {"id": (0, "str", ""), "start_ts": (1, "<u8", 0), "end_ts": (2, "<u8", 0),
                 "chunks": (3, "[ChunkOffset]", None), "entries": (4, "[MetadataEntry]", None)},
    "MetadataEntry": {"id": (0, "<u4", 0), "type": (1, "str", ""), "buffer": (2, "[u1]", None)},
    "Chunk": {"messages": (0, "[StampedMessage]", None), "type": (1, "str", "")},
    "StampedMessage": {"ts": (0, "<u8", 0), "id": (1, "<u4", 0), "buffer": (2, "[u1]", None),
                       "ts_sensor": (3, "<u8", 0)},
    "LidarSensor": {"metadata": (0, "str", "")},
    "LidarScanStream": {"sensor_id": (0, "<u4", 0), "field_types": (1, "[ChannelField]", None)},
    "StreamingInfo": {"chunks": (0, "[ChunkInfo]", None)},
    "ChunkInfo": {"offset": (0, "<u8", 0), "stream_id": (1, "<u4", 0), "message_count": (2, "<u4", 0)},
    "Extrinsics": {"extrinsics": (0, "[<f8]", None), "ref_id": (1, "<u4", 0), "name": (2, "str", "")},
    "LidarScanMsg": {"channels": (0, "[ChannelData]", None), "field_types": (1, "[ChannelField]", None),
                     "header_timestamp": (2, "[<u8]", None), "header_measurement_id": (3, "[<u2]", None),
                     "header_status": (4, "[<u4]", None), "frame_id": (5, "<i4", 0), "pose": (6, "[<f8]", None),
                     "packet_timestamp": (7, "[<u8]", None), "custom_fields": (8, "[Field]", None),
                     "frame_status": (9, "<u8", 0), "shutdown_countdown": (10, "u1", 0),
                     "shot_limiting_countdown": (11, "u1", 0), "alert_flags": (12, "[u1]", None)},
    "ChannelData": {"buffer": (0, "[u1]", None)},
    "Field": {"name": (0, "str", ""), "tag": (1, "u1", 0), "shape": (2, "[<u8]", None),
              "field_class": (3, "<i8", 0), "data": (4, "[u1]", None), "bytes": (5, "<u8", 0)},
}
STRUCTS: dict[str, np.dtype] = {
    "ChunkOffset": np.dtype([("start_ts", "<u8"), ("end_ts", "<u8"), ("offset", "<u8")]),
    "ChannelField": np.dtype([("chan_field", "u1"), ("chan_field_type", "u1")]),
}
# file identifiers of the size-prefixed root buffers (bytes 8-12 of the block)
HEADER_ID, CHUNK_ID, METADATA_ID = b"OSF$", b"OSF!", b"OSF#"
# MetadataEntry.type of the entries read here
LIDAR_SENSOR = "ouster/v1/os_sensor/LidarSensor"
LIDAR_SCAN_STREAM = "ouster/v1/os_sensor/LidarScanStream"
STREAMING_INFO = "ouster/v1/streaming/StreamingInfo"
HEADER_STATUS_VALID = 2
OSF_VERSION_2_0 = 20  # OsfVersion::V_2_0; later versions are (major << 48 | minor << 32 | patch << 16)

# CHAN_FIELD (lidar_scan_stream.fbs): standard channel -> its name
CHAN_FIELDS: dict[int, str] = {
    1: "RANGE", 2: "RANGE2", 3: "SIGNAL", 4: "SIGNAL2", 5: "REFLECTIVITY", 6: "REFLECTIVITY2", 7: "NEAR_IR",
    8: "FLAGS", 9: "FLAGS2", 40: "RAW_HEADERS", **{44 + k: f"RAW32_WORD{k}" for k in range(5, 10)},
    **{50 + k: f"CUSTOM{k}" for k in range(10)}, **{59 + k: f"RAW32_WORD{k}" for k in range(1, 5)},
}
# ouster-sdk's ZoneState, packed (37 bytes), the element of the ZONE_STATES field
ZONE_STATE_DTYPE = np.dtype([
    ("live", "u1"), ("id", "u1"), ("error_flags", "u1"), ("trigger_type", "u1"), ("trigger_status", "u1"),
    ("triggered_frames", "<u4"), ("count", "<u4"), ("occlusion_count", "<u4"), ("invalid_count", "<u4"),
    ("max_count", "<u4"), ("min_range", "<u4"), ("max_range", "<u4"), ("mean_range", "<u4")])
# CHAN_FIELD_TYPE (common.fbs) -> element type
FIELD_TYPES: dict[int, np.dtype] = {
    1: np.dtype("u1"), 2: np.dtype("<u2"), 3: np.dtype("<u4"), 4: np.dtype("<u8"), 5: np.dtype("i1"),
    6: np.dtype("<i2"), 7: np.dtype("<i4"), 8: np.dtype("<i8"), 9: np.dtype("<f4"), 10: np.dtype("<f8"),
    11: np.dtype("S1"), 12: np.dtype("<f2"), 30: ZONE_STATE_DTYPE,
}
# Frame attribute of each standard channel, by return slot (the rest go to Frame.extra)
_FRAME_ATTRS = {"RANGE": ("range_mm", 0), "RANGE2": ("range_mm", 1), "REFLECTIVITY": ("reflectivity", 0),
                "REFLECTIVITY2": ("reflectivity", 1), "SIGNAL": ("signal", 0), "SIGNAL2": ("signal", 1),
                "FLAGS": ("flags", 0), "FLAGS2": ("flags", 1), "NEAR_IR": ("near_ir", None)}
_ATTR_DTYPES = {"range_mm": np.uint32, "reflectivity": np.uint8, "signal": np.uint16, "flags": np.uint8,
                "near_ir": np.uint16}

_MAX_ELEMENTS_PER_PIXEL = 64  # a decoded field holds at most this many values per pixel of the frame
_MAX_FRAME_BYTES_PER_PIXEL = 256  # the named fields of a frame decode to at most this (a dual frame's fields: 18 B)
_ZPNG_MAGIC = 0xFBF8
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class _Damaged(Exception):
    """Inside this module: what is wrong, before the file's name is put in front."""


# --------------------------------------------------------------------------- flatbuffers access


class _Table:
    """One table of a flatbuffer, read with the ``flatbuffers`` package after every position it uses
    is checked to lie inside the buffer (the package itself trusts the buffer)."""

    __slots__ = ("_t", "_buf", "_kind", "_fields", "_size")

    def __init__(self, buf: bytes, pos: int, kind: str) -> None:
        from flatbuffers.table import Table

        n = len(buf)
        if not 0 <= pos <= n - 4:
            raise _Damaged(f"a {kind} table lies outside its buffer")
        vtable = pos - struct.unpack_from("<i", buf, pos)[0]
        if not 0 <= vtable <= n - 4:
            raise _Damaged(f"the vtable of a {kind} table lies outside its buffer")
        vsize, tsize = struct.unpack_from("<HH", buf, vtable)
        if vsize < 4 or vsize % 2 or vtable + vsize > n or pos + tsize > n:
            raise _Damaged(f"a {kind} table has a vtable of {vsize} B for {tsize} B, beyond its buffer")
        self._t = Table(buf, pos)
        self._buf = buf
        self._kind = kind
        self._fields = TABLES[kind]
        self._size = tsize

    def _offset(self, name: str, width: int) -> int:
        slot = self._fields[name][0]
        off = self._t.Offset(4 + 2 * slot)
        if off and off + width > self._size:
            raise _Damaged(f"{self._kind}.{name} lies outside its table")
        return off

    def __getattr__(self, name: str) -> Any:
        try:
            _, kind, default = self._fields[name]
        except KeyError:
            raise AttributeError(name) from None
        if not kind.startswith("[") and kind != "str":
            dt = np.dtype(kind)
            off = self._offset(name, dt.itemsize)
            return default if not off else np.frombuffer(self._buf, dt, 1, self._t.Pos + off)[0].item()
        off = self._offset(name, 4)
        if not off:
            return default
        if kind == "str":
            return bytes(self._vector(off, 1)).decode("utf-8", errors="replace")
        inner = kind[1:-1]
        if inner in TABLES:
            return [_Table(self._buf, p, inner) for p in self._table_positions(off)]
        dt = STRUCTS.get(inner) or np.dtype(inner)
        return np.frombuffer(self._vector(off, dt.itemsize), dt)

    def _vector(self, off: int, item: int) -> bytes | memoryview:
        at = self._t.Pos + off
        start = at + struct.unpack_from("<I", self._buf, at)[0]
        if start > len(self._buf) - 4:
            raise _Damaged(f"a vector of {self._kind} lies outside its buffer")
        count = struct.unpack_from("<I", self._buf, start)[0]
        if count * item > len(self._buf) - start - 4:
            raise _Damaged(f"a vector of {self._kind} claims {count} items, more than its buffer holds")
        return memoryview(self._buf)[start + 4 : start + 4 + count * item]

    def _table_positions(self, off: int) -> list[int]:
        start = self._t.Pos + off
        start += struct.unpack_from("<I", self._buf, start)[0]
        offsets = np.frombuffer(self._vector(off, 4), "<u4").astype(np.int64)
        return (start + 4 + 4 * np.arange(offsets.size) + offsets).tolist()


def _root(buf: bytes, kind: str, identifier: bytes | None = None) -> _Table:
    """The root table of a size-prefixed flatbuffer ``buf`` (prefix included)."""
    if len(buf) < 8 or struct.unpack_from("<I", buf)[0] != len(buf) - 4:
        raise _Damaged(f"a {kind} buffer of {len(buf)} B does not hold the size it declares")
    if identifier is not None and buf[8:12] != identifier:
        raise _Damaged(f"a {kind} block has the identifier {bytes(buf[8:12])!r}, not {identifier!r}")
    return _Table(buf, 4 + struct.unpack_from("<I", buf, 4)[0], kind)


# --------------------------------------------------------------------------- field images


def _png_rows(data: bytes, rows: int, cols: int, depth: int, colour: int) -> np.ndarray:
    """The samples of a PNG image as ``uint8[rows, cols * bytes per pixel]``, big-endian samples as stored.

    Pillow decodes the 8-bit kinds and 16-bit grey exactly; it reduces 16-bit RGBA to 8 bits, so that
    one (64-bit fields) is inflated and unfiltered here.
    """
    if data[:8] != _PNG_SIGNATURE or len(data) < 33 or data[12:16] != b"IHDR":
        raise _Damaged("a field image is neither PNG nor ZPNG")
    width, height, bit_depth, colour_type = struct.unpack_from(">IIBB", data, 16)
    if (width, height, bit_depth, colour_type) != (cols, rows, depth, colour):
        raise _Damaged(f"a field image is {width}x{height} of {bit_depth}-bit samples (colour type {colour_type}); "
                       f"the field needs {cols}x{rows} of {depth}-bit (colour type {colour})")
    channels = {0: 1, 2: 3, 6: 4}[colour]
    pixel_bytes = channels * depth // 8
    if depth == 16 and channels == 4:
        return _png_inflate_unfilter(data, rows, cols * pixel_bytes, pixel_bytes)
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data), formats=["PNG"]) as img:
            img.load()
            arr = np.asarray(img)
    except Exception as exc:  # Pillow raises OSError, SyntaxError, ValueError, zlib.error ... on damaged data
        raise _Damaged(f"a PNG field image does not decode ({type(exc).__name__}: {exc})") from None
    if depth == 16:  # grey, values as numbers: back to the big-endian bytes of the other kinds
        return arr.astype(">u2").view(np.uint8).reshape(rows, cols * 2)
    return arr.reshape(rows, cols * pixel_bytes)


def _png_inflate_unfilter(data: bytes, rows: int, stride: int, bpp: int) -> np.ndarray:
    """PNG chunks → IDAT inflated into exactly ``rows`` filtered scanlines → unfiltered ``uint8[rows, stride]``."""
    idat = []
    pos = 8
    while pos + 8 <= len(data):
        length, kind = struct.unpack_from(">I4s", data, pos)
        if kind == b"IDAT":
            idat.append(data[pos + 8 : pos + 8 + length])
        elif kind == b"IEND":
            break
        pos += 12 + length
    want = rows * (stride + 1)
    d = zlib.decompressobj()
    try:
        raw = d.decompress(b"".join(idat), want)
    except zlib.error as exc:
        raise _Damaged(f"a PNG field image does not inflate: {exc}") from None
    if len(raw) != want:
        raise _Damaged(f"a PNG field image inflates to {len(raw)} B where its size needs {want}")
    lines = np.frombuffer(raw, np.uint8).reshape(rows, stride + 1)
    out = np.zeros((rows + 1, stride), np.uint8)  # row 0: the zero line above the image
    for r in range(rows):
        kind, line, above = lines[r, 0], lines[r, 1:], out[r]
        if kind == 0:
            out[r + 1] = line
        elif kind == 1:
            out[r + 1] = np.cumsum(line.reshape(-1, bpp), axis=0, dtype=np.uint8).ravel()
        elif kind == 2:
            out[r + 1] = line + above
        elif kind in (3, 4):  # Average, Paeth: each byte needs its left neighbour's result (Python ints: no
            # NumPy call per pixel; only 16-bit RGBA images, Pillow decodes the others)
            up, cur, filt = above.tolist(), [0] * stride, line.tolist()
            for x in range(stride):
                a = cur[x - bpp] if x >= bpp else 0
                b = up[x]
                if kind == 3:
                    cur[x] = (filt[x] + ((a + b) >> 1)) & 0xFF
                    continue
                c = up[x - bpp] if x >= bpp else 0
                pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                cur[x] = (filt[x] + (a if pa <= pb and pa <= pc else b if pb <= pc else c)) & 0xFF
            out[r + 1] = cur
        else:
            raise _Damaged(f"a PNG field image has the unknown filter type {kind}")
    return out[1:]


def _zpng_rows(data: bytes, rows: int, cols: int, pixel_bytes: int) -> np.ndarray:
    """A ZPNG image (8-byte header, zstd of per-row byte deltas, 3/4-byte pixels as colour planes) as
    ``uint8[rows, cols * pixel_bytes]``, little-endian samples."""
    import zstandard

    magic, width, height, channels, per_channel = struct.unpack_from("<HHHBB", data)
    if (width, height, channels * per_channel) != (cols % 65536, rows % 65536, pixel_bytes):
        raise _Damaged(f"a ZPNG field image is {width}x{height} of {channels * per_channel} B pixels; the field needs "
                       f"{cols}x{rows} of {pixel_bytes} B")
    want = rows * cols * pixel_bytes
    try:
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data[8:])) as reader:
            raw = reader.read(want + 1)  # one byte more than needed tells a stream that holds more
    except zstandard.ZstdError as exc:
        raise _Damaged(f"a ZPNG field image does not inflate: {exc}") from None
    if len(raw) != want:
        raise _Damaged(f"a ZPNG field image inflates to {len(raw)}{'+' if len(raw) > want else ''} B where its size "
                       f"needs {want}")
    packed = np.frombuffer(raw, np.uint8)
    if pixel_bytes in (3, 4):  # planes y = b', u = g' - b', v = g' - r' (and a') of the deltas r', g', b', a'
        planes = packed.reshape(pixel_bytes, rows, cols)
        b = planes[0]
        g = planes[1] + b
        deltas = [g - planes[2], g, b] + ([planes[3]] if pixel_bytes == 4 else [])
        packed = np.stack(deltas, axis=-1)
    else:
        packed = packed.reshape(rows, cols, pixel_bytes)
    return np.cumsum(packed, axis=1, dtype=np.uint8).reshape(rows, cols * pixel_bytes)


def _decode_image(data: bytes | memoryview, shape: tuple[int, ...], dtype: np.dtype, shift: np.ndarray | None) -> np.ndarray:
    """A field of ``shape`` (two or more dimensions) and ``dtype`` from its ZPNG or PNG image; a PNG of a
    standard channel is destaggered, so ``shift`` (``pixel_shift_by_row``) staggers it back."""
    data = bytes(data)
    rows = shape[0]
    cols = int(np.prod(shape[1:]))
    size = dtype.itemsize
    if size not in (1, 2, 4, 8):
        raise _Damaged(f"a field of {dtype} ({size} B) cannot be stored as an image")
    if len(data) >= 8 and struct.unpack_from("<H", data)[0] == _ZPNG_MAGIC:
        samples = _zpng_rows(data, rows, cols, size)
        values = samples.view(f"<u{size}")
        shift = None  # ZPNG keeps the field as it is in the frame
    else:
        depth, colour = {1: (8, 0), 2: (16, 0), 4: (8, 6), 8: (16, 6)}[size]
        samples = _png_rows(data, rows, cols, depth, colour)
        if size == 2:
            values = samples.view(">u2")
        elif size == 8:  # RGBA of 16-bit samples, each sample's bytes swapped back: bytes 0..7 low to high
            values = samples.reshape(rows, cols, 4, 2)[..., ::-1].reshape(rows, cols * 8).copy().view("<u8")
        else:
            values = samples.view(f"<u{size}")
    out = np.ascontiguousarray(values, dtype=f"<u{size}").view(dtype.newbyteorder("<") if size > 1 else dtype)
    out = out.reshape(shape)
    if shift is not None and len(shape) == 2:
        out = restagger(out, shift)
    return out


# --------------------------------------------------------------------------- the file


@dataclass
class OsfStream:
    """One sensor's frame stream: the metadata entry ids, its sensor's metadata and its chunks (file offsets)."""

    stream_id: int
    sensor_id: int
    metadata: Any  # OusterMetadata
    sensor: Any  # SensorInfo
    chunk_offsets: list[int]


class OsfFile:
    """The header, metadata and chunk index of one OSF file; frames from :meth:`frames`.

    Args:
        path: the ``.osf`` file.

    Raises:
        CaptureFormatError: not an OSF file, a version before 2.0, an unfinished file (header not
            marked valid), a header or metadata block that is damaged (CRC, sizes, offsets), no
            streaming index, sensor metadata that lidarpkt cannot read (the message says which).
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
        except _Damaged as exc:
            self.close()
            raise CaptureFormatError(f"{self.path}: damaged OSF file: {exc}") from None
        except (struct.error, ValueError, IndexError, OverflowError) as exc:
            self.close()
            raise CaptureFormatError(f"{self.path}: damaged OSF file ({type(exc).__name__}: {exc})") from None
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        self._fh.close()

    def _block(self, offset: int, end: int, what: str) -> bytes:
        """The size-prefixed flatbuffer at ``offset`` (prefix included), its CRC checked; it must end by ``end``."""
        if offset + 4 > end:
            raise _Damaged(f"the {what} at byte {offset} lies beyond the end of its region (byte {end})")
        self._fh.seek(offset)
        size = struct.unpack("<I", self._fh.read(4))[0]
        if offset + 4 + size + 4 > end:
            raise _Damaged(f"the {what} at byte {offset} declares {size} B, beyond the end of its region (byte {end}; "
                           f"the file has {self.size} B)")
        body = self._fh.read(size)
        (crc,) = struct.unpack("<I", self._fh.read(4))
        block = struct.pack("<I", size) + body
        if zlib.crc32(block) != crc:
            raise _Damaged(f"the {what} at byte {offset} fails its CRC-32")
        return block

    def _read_index(self) -> None:
        from .metadata import load_metadata

        header_block = self._block(0, self.size, "header")
        if header_block[8:12] != HEADER_ID:
            raise _Damaged("no OSF header (identifier 'OSF$')")
        header = _root(header_block, "Header", HEADER_ID)
        self.version = int(header.version)
        if self.version < OSF_VERSION_2_0:
            raise _Damaged(f"OSF version {self.version} predates 2.0, which lidarpkt (and ouster-sdk) read")
        if header.status != HEADER_STATUS_VALID:
            raise _Damaged("the header is not marked valid: the recording was not closed (its writer was stopped)")
        self.chunks_start = len(header_block) + 4
        self.metadata_offset = int(header.metadata_offset)
        if not self.chunks_start <= self.metadata_offset < self.size or header.file_length > self.size:
            raise _Damaged(f"the metadata is said to lie at bytes {self.metadata_offset}-{header.file_length}, outside "
                           f"the file's {self.size} B")
        meta = _root(self._block(self.metadata_offset, self.size, "metadata block"), "Metadata", METADATA_ID)
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
                sensors[entry_id] = _root(buf, "LidarSensor").metadata
            elif kind == LIDAR_SCAN_STREAM:
                streams[entry_id] = int(_root(buf, "LidarScanStream").sensor_id)
            elif kind == STREAMING_INFO:
                streaming = True
                for info in _root(buf, "StreamingInfo").chunks or []:
                    chunks.setdefault(int(info.stream_id), []).append(int(info.offset))
        if streams and not streaming:
            raise _Damaged("no streaming index (StreamingInfo): an OSF of the old standard layout, which ouster-sdk no "
                           "longer reads either")
        self.sensor_json = sensors
        self.streams: list[OsfStream] = []
        for stream_id, sensor_id in sorted(streams.items()):
            if sensor_id not in sensors:
                raise _Damaged(f"the frame stream {stream_id} names the sensor entry {sensor_id}, which is not there")
            try:
                md = load_metadata(sensors[sensor_id])
            except LidarpktError as exc:
                raise CaptureFormatError(f"{self.path}: the sensor metadata stored in the OSF file: {exc}") from None
            source = f"{self.path.name} (sensor {md.serial or sensor_id})"
            self.streams.append(OsfStream(stream_id, sensor_id, md, md.sensor_info(source),
                                          sorted(set(chunks.get(stream_id, [])))))  # a chunk listed twice: read once

    # ------------------------------------------------------------------ messages
    def _messages(self, stream: OsfStream) -> Iterator[tuple[int, int, bytes]]:
        """``(receive ts, stream id, LidarScanMsg buffer)`` of one stream, in file order."""
        for rel in stream.chunk_offsets:
            block = self._block(self.chunks_start + rel, self.metadata_offset, "chunk")
            chunk = _root(block, "Chunk", CHUNK_ID)
            seen: set[int] = set()
            for msg in chunk.messages or []:
                if msg.id == stream.stream_id:
                    buf = msg.buffer
                    if buf is None:
                        continue
                    # messages sharing one buffer would decode one frame's fields many times from few bytes
                    where = buf.ctypes.data  # its place in the chunk (a view of it)
                    if buf.size and where in seen:
                        raise _Damaged(f"two messages of the chunk at byte {self.chunks_start + rel} share one buffer")
                    seen.add(where)
                    yield int(msg.ts), stream.stream_id, bytes(buf)

    def frames(self) -> Iterator[Frame]:
        """Every frame of every sensor, by receive time (ties: stream order), as ouster-sdk gives them.

        Raises:
            CaptureFormatError: a chunk or a frame message is damaged (after the frames before it).
        """
        by_id = {s.stream_id: s for s in self.streams}
        order = {s.stream_id: i for i, s in enumerate(self.streams)}
        merged = heapq.merge(*(self._messages(s) for s in self.streams), key=lambda m: (m[0], order[m[1]]))
        while True:
            try:
                item = next(merged, None)
                if item is None:
                    return
                frame = decode_frame(item[2], by_id[item[1]])
            except _Damaged as exc:
                raise CaptureFormatError(f"{self.path}: damaged OSF file: {exc}") from None
            except (struct.error, ValueError, IndexError, OverflowError, UnicodeDecodeError) as exc:
                raise CaptureFormatError(f"{self.path}: damaged OSF file ({type(exc).__name__}: {exc})") from None
            yield frame

    @property
    def version_text(self) -> str:
        """The OSF version as ``"major.minor.patch"``."""
        if self.version < (1 << 16):  # the old enum: V_2_0 = 20, V_2_1 = 21
            return f"2.{self.version - OSF_VERSION_2_0}.0"
        return f"{self.version >> 48 & 0xFFFF}.{self.version >> 32 & 0xFFFF}.{self.version >> 16 & 0xFFFF}"

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary (``lidarpkt info``), read from the chunks without decoding a field: the OSF
        version and, per sensor, what it is and its frames (count, frame ids, receive times, ns).

        Raises:
            CaptureFormatError: a chunk or frame message is damaged.
        """
        sensors = []
        try:
            for stream in self.streams:
                ids, times, partial = [], [], 0
                window = stream.metadata.window_mask
                for ts, _, buf in self._messages(stream):
                    msg = _root(buf, "LidarScanMsg")
                    ids.append(int(msg.frame_id))
                    times.append(ts)
                    status = msg.header_status
                    partial += status is None or status.size != window.size or not (status[window] & 1).all()
                s = stream.sensor
                sensors.append({
                    "source": s.source, "model": s.model, "serial": s.serial, "firmware": s.firmware,
                    "profile": s.profile, "columns_per_frame": s.columns_per_frame, "rows": s.rows,
                    "frames": len(ids), "partial_frames": int(partial),
                    "frame_ids": [min(ids), max(ids)] if ids else None,
                    "first_timestamp_ns": min(times) if times else None,
                    "last_timestamp_ns": max(times) if times else None})
        except _Damaged as exc:
            raise CaptureFormatError(f"{self.path}: damaged OSF file: {exc}") from None
        except (struct.error, ValueError, IndexError, OverflowError) as exc:
            raise CaptureFormatError(f"{self.path}: damaged OSF file ({type(exc).__name__}: {exc})") from None
        return {"osf_version": self.version_text, "sensors": sensors}


def decode_frame(buf: bytes, stream: OsfStream) -> Frame:
    """One ``LidarScanMsg`` (size-prefixed) of ``stream`` as a :class:`~lidarpkt.core.frame.Frame` (see the module).

    Raises:
        _Damaged: the message or one of its fields is damaged.
    """
    md = stream.metadata
    h, w = md.pixels_per_column, md.columns_per_frame
    msg = _root(buf, "LidarScanMsg")

    def per_column(name: str, dtype) -> np.ndarray:
        values = getattr(msg, name)
        if values is None or values.size == 0:
            return np.zeros(w, dtype)
        if values.size != w:
            raise _Damaged(f"{name} of a frame has {values.size} columns, not the sensor's {w}")
        return values.astype(dtype)

    timestamp = per_column("header_timestamp", np.uint64)
    if (timestamp >> np.uint64(63)).any():
        raise _Damaged("a column timestamp is beyond 2**63 ns")
    status = per_column("header_status", np.uint32)
    # the packet header values the file keeps (one per packet, or per frame) as the frames decoded from
    # packets hold them: one per column, the value of the column's packet
    per_packet = max(1, md.columns_per_packet)
    n_packets = -(-w // per_packet)
    extra: dict[str, np.ndarray] = {}
    for stored, key, kind in (("packet_timestamp", "packet_timestamp_ns", np.uint64), ("alert_flags", "alert_flags", np.uint8)):
        values = getattr(msg, stored)
        if values is not None and values.size not in (0, n_packets):
            raise _Damaged(f"{stored} of a frame has {values.size} values, not one per packet ({n_packets})")
        values = values.astype(kind) if values is not None and values.size else np.zeros(n_packets, kind)
        extra[key] = np.repeat(values, per_packet)[:w]
    status_bits = int(msg.frame_status)  # ouster-sdk's frame_status: thermal shutdown bits 0-3, shot limiting 4-7
    for key, value in (("thermal_shutdown", status_bits & 0x0F), ("shot_limiting", status_bits >> 4 & 0x0F),
                       ("countdown_thermal_shutdown", msg.shutdown_countdown),
                       ("countdown_shot_limiting", msg.shot_limiting_countdown)):
        extra[key] = np.full(w, value, np.uint8)
    pose = msg.pose
    if pose is not None and pose.size:
        if pose.size != 16 * w:
            raise _Damaged(f"the pose of a frame has {pose.size} values, not 16 per column ({16 * w})")
        extra["pose"] = np.ascontiguousarray(pose.reshape(w, 4, 4).transpose(1, 2, 0))

    fields = {**_channel_fields(msg, md), **_custom_fields(msg, h, w)}

    # the standard channels become the frame's attributes, in the types frames decoded from packets have
    # (an older ouster-sdk stored REFLECTIVITY of RNG15_RFL8_NIR8 as uint16): a value that does not fit keeps
    # the type it was stored in
    planes: dict[str, dict[Any, np.ndarray]] = {}
    for name, (attr, slot) in _FRAME_ATTRS.items():
        if name in fields:
            values = fields.pop(name)
            target = np.dtype(_ATTR_DTYPES[attr])
            fits = values.dtype.kind == "u" and (values.size == 0 or int(values.max()) <= np.iinfo(target).max)
            planes.setdefault(attr, {})[slot] = values.astype(target, copy=False) if fits else values
    returns = 2 if any(1 in slots for slots in planes.values()) else 1
    frame_kw: dict[str, Any] = {"near_ir": planes.get("near_ir", {}).get(None)}
    for attr in ("range_mm", "reflectivity", "signal", "flags"):
        slots = planes.get(attr)
        if slots is None:  # absent: zeros for the two a frame always has (no return), else None
            frame_kw[attr] = np.zeros((returns, h, w), _ATTR_DTYPES[attr]) if attr in ("range_mm", "reflectivity") else None
            continue
        dtype = np.result_type(*slots.values())
        frame_kw[attr] = np.stack([slots[r].astype(dtype, copy=False) if r in slots else np.zeros((h, w), dtype)
                                   for r in range(returns)])
    for name, values in fields.items():
        extra[name.lower()] = values
    valid = (status & 1).astype(bool)
    labels = tuple(stream.sensor.return_labels[:returns])
    labels += tuple(f"return_{r + 1}" for r in range(len(labels), returns))
    return Frame(
        sensor=stream.sensor,
        frame_id=int(msg.frame_id),
        return_labels=labels,
        column_valid=valid,
        column_timestamp_ns=timestamp.astype(np.int64),
        azimuth_deg=np.mod(360.0 * (1.0 - np.arange(w) / w), 360.0),
        measurement_id=per_column("header_measurement_id", np.uint16),
        status=status,
        partial=not bool(valid[md.window_mask].all()),
        counters=FrameCounters(),
        extra=extra,
        **frame_kw,
    )


def _channel_fields(msg: _Table, md: Any) -> dict[str, np.ndarray]:
    """The standard channels of a frame message (RANGE, SIGNAL... ``[H, W]``), by name."""
    h, w = md.pixels_per_column, md.columns_per_frame
    out: dict[str, np.ndarray] = {}
    types, channels = msg.field_types, msg.channels
    if types is None or not types.size:
        return out
    if channels is None or len(channels) < types.size:
        raise _Damaged(f"a frame lists {types.size} fields but stores {0 if channels is None else len(channels)}")
    for (chan, tag), channel in zip(types.tolist(), channels):
        name = CHAN_FIELDS.get(chan)
        element = FIELD_TYPES.get(tag)
        if name is None or element is None or element.kind not in "ui":
            raise _Damaged(f"a frame stores the channel {chan} of type {tag}, which ouster-sdk does not define")
        if name in out:
            raise _Damaged(f"a frame stores the channel {name} twice")
        data = channel.buffer
        try:
            out[name] = _decode_image(data if data is not None else b"", (h, w), element, md.pixel_shift_by_row)
        except _Damaged as exc:
            raise _Damaged(f"frame {msg.frame_id}, field {name}: {exc}") from None
    return out


def _custom_fields(msg: _Table, h: int, w: int) -> dict[str, np.ndarray]:
    """The fields of a frame message stored by name (ZONE_MASK, ZONE_STATES...), in their shapes."""
    out: dict[str, np.ndarray] = {}
    budget = h * w * _MAX_FRAME_BYTES_PER_PIXEL
    for field in msg.custom_fields or []:
        name: str = field.name
        if name in out:
            raise _Damaged(f"a frame stores the field {name!r} twice")
        element = FIELD_TYPES.get(field.tag)
        stored = field.shape
        shape = tuple(int(n) for n in (stored.tolist() if stored is not None else ()))
        if element is None:
            raise _Damaged(f"the field {name!r} has the unknown type {field.tag}")
        most = h * w * _MAX_ELEMENTS_PER_PIXEL
        if not shape or any(n > most for n in shape) or int(np.prod(shape, dtype=object)) > most:
            raise _Damaged(f"the field {name!r} has the shape {shape}, beyond what a frame of {h}x{w} holds")
        data = field.data if field.data is not None else b""
        size = element.itemsize
        budget -= int(np.prod(shape)) * size
        if budget < 0:  # fields sharing their bytes could otherwise decode to any size
            raise _Damaged(f"the fields of frame {msg.frame_id} add up to more than {_MAX_FRAME_BYTES_PER_PIXEL} B a pixel")
        if len(shape) == 1:  # stored raw
            if len(data) != shape[0] * size:
                raise _Damaged(f"the field {name!r} holds {len(data)} B, not the {shape[0] * size} B of "
                               f"{shape[0]} {element}")
            out[name] = np.frombuffer(bytes(data), element).copy()
        elif int(np.prod(shape)) == 0:
            out[name] = np.zeros(shape, element)
        else:
            try:
                out[name] = _decode_image(data, shape, element, None)
            except _Damaged as exc:
                raise _Damaged(f"frame {msg.frame_id}, field {name}: {exc}") from None
    return out


class OsfReader(FrameIterator):
    """The frames of an OSF file (``lidarpkt.open("x.osf")``); ``file`` is its :class:`OsfFile`.

    ``stats`` counts the frames; ``decoders`` is empty (no packets are decoded). ``include_partial``:
    also the frames with a column of the column window not valid (left out by default, as from packets).

    Raises:
        CaptureFormatError: see :class:`OsfFile`; while iterating, a damaged chunk or frame.
    """

    def __init__(self, path: str | os.PathLike[str], *, include_partial: bool = False) -> None:
        from lidarpkt.pipeline.reader import SourceStats

        self.path = Path(path)
        self.file = OsfFile(path)
        self.stats = SourceStats()
        self.decoders: dict = {}
        self._include_partial = include_partial
        self._iter: Generator[Frame, None, None] = self._frames()

    def _frames(self) -> Generator[Frame, None, None]:
        try:
            for frame in self.file.frames():
                if frame.partial and not self._include_partial:
                    continue
                self.stats.frames += 1
                yield frame
        finally:
            self.file.close()

    def sensors(self) -> list:
        """The :class:`~lidarpkt.core.sensor.SensorInfo` of each sensor the file holds."""
        return [s.sensor for s in self.file.streams]

    def close(self) -> None:
        self._iter.close()
        self.file.close()


_PACKET_OPTIONS = ("ports", "src_addresses", "payload_sizes", "topics", "batch_packets", "source")


def open_osf(path: str | os.PathLike[str], options: Any) -> Any:
    """``lidarpkt.open`` of an OSF file, given its :class:`~lidarpkt.pipeline.options.OpenOptions`: an :class:`OsfReader`
    (``workers`` ≥ 2: decoded in a thread ahead of the caller, :class:`~lidarpkt.pipeline.parallel.PipelinedFrameReader`).

    The file carries its sensors' metadata: ``metadata`` is not used, nor are the options of packet decoding
    (``calibration``, ``verify_crc``...); ``include_partial`` applies.

    Raises:
        UnsupportedFilterError: a packet filter (``ports``, ``topics``, ``source``...): an OSF holds no packets.
        UnsupportedContainerError: a ``segment`` of a file cut in several: an OSF file is read whole.
        UsageError: ``workers`` is not a whole number >= 1.
        CaptureFormatError: see :class:`OsfFile`.
    """
    from lidarpkt.errors import UnsupportedContainerError, UnsupportedFilterError, UsageError

    given = [name for name in _PACKET_OPTIONS if getattr(options, name) is not None]
    if given:
        raise UnsupportedFilterError(f"{path}: {', '.join(n + '=' for n in given)} cannot filter an OSF file: it holds "
                                     "decoded frames, not packets")
    if options.segment is not None and options.segment.count != 1:
        raise UnsupportedContainerError(f"{path}: an OSF file is read whole (one segment)")
    workers = options.workers
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise UsageError(f"workers={workers!r}: not a whole number >= 1; give e.g. workers=2")
    reader = OsfReader(path, include_partial=options.include_partial)
    if workers == 1:
        return reader
    from lidarpkt.pipeline.parallel import PipelinedFrameReader

    return PipelinedFrameReader(reader)


def receive_span(path: str | os.PathLike[str]) -> tuple[int | None, int | None]:
    """First and last receive time (ns) of the frames of an OSF file; ``(None, None)`` when it has none."""
    f = OsfFile(path)
    try:
        sensors = f.describe()["sensors"]
    finally:
        f.close()
    firsts = [s["first_timestamp_ns"] for s in sensors if s["first_timestamp_ns"] is not None]
    lasts = [s["last_timestamp_ns"] for s in sensors if s["last_timestamp_ns"] is not None]
    return (min(firsts), max(lasts)) if firsts else (None, None)
