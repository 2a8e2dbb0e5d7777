"""A small OSF writer for the tests (the ``flatbuffers`` package's Builder, the layout of ouster-sdk's
``ouster_osf/fb/*.fbs``): files ouster-sdk's reader can read too, and hostile variants no writer makes
(messages sharing one buffer, fields sharing their bytes)."""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

import flatbuffers
import numpy as np

LIDAR_SENSOR = "ouster/v1/os_sensor/LidarSensor"
LIDAR_SCAN_STREAM = "ouster/v1/os_sensor/LidarScanStream"
STREAMING_INFO = "ouster/v1/streaming/StreamingInfo"
VERSION_2_1 = 21


@dataclass
class Custom:
    """A named field of a frame message: ``data`` is stored as given (raw bytes or an image)."""

    name: str
    tag: int  # CHAN_FIELD_TYPE
    shape: tuple[int, ...]
    data: bytes
    field_class: int = 1  # PIXEL_FIELD


@dataclass
class Message:
    """One LidarScanMsg: standard channels ``(CHAN_FIELD, CHAN_FIELD_TYPE, image bytes)`` and per-column arrays."""

    frame_id: int
    timestamp: np.ndarray
    measurement_id: np.ndarray
    status: np.ndarray
    channels: list[tuple[int, int, bytes]] = field(default_factory=list)
    custom: list[Custom] = field(default_factory=list)
    share_custom_data: bool = False  # every custom field points at the first one's bytes


def _u8(b: flatbuffers.Builder, data: bytes) -> int:
    return b.CreateByteVector(bytes(data))


def _scalars(b: flatbuffers.Builder, values, width: int, prepend) -> int:
    values = list(values)
    b.StartVector(width, len(values), width)
    for v in reversed(values):
        prepend(int(v))
    return b.EndVector()


def _offsets(b: flatbuffers.Builder, offs: list[int]) -> int:
    b.StartVector(4, len(offs), 4)
    for off in reversed(offs):
        b.PrependUOffsetTRelative(off)
    return b.EndVector()


def _finish(b: flatbuffers.Builder, root: int, ident: bytes | None = None) -> bytes:
    b.FinishSizePrefixed(root, file_identifier=ident)
    return bytes(b.Output())


def lidar_scan_msg(m: Message) -> bytes:
    b = flatbuffers.Builder(1024)
    b.ForceDefaults(True)
    chans = []
    for _, _, data in m.channels:
        d = _u8(b, data)
        b.StartObject(1)
        b.PrependUOffsetTRelativeSlot(0, d, 0)
        chans.append(b.EndObject())
    channels = _offsets(b, chans)
    b.StartVector(2, len(m.channels), 1)
    for chan, tag, _ in reversed(m.channels):
        b.PrependUint8(tag)
        b.PrependUint8(chan)
    types = b.EndVector()
    customs = []
    shared = None
    for c in m.custom:
        name = b.CreateString(c.name)
        shape = _scalars(b, c.shape, 8, b.PrependUint64)
        if shared is None or not m.share_custom_data:
            shared = _u8(b, c.data)
        b.StartObject(6)
        b.PrependUOffsetTRelativeSlot(0, name, 0)
        b.PrependUint8Slot(1, c.tag, 0)
        b.PrependUOffsetTRelativeSlot(2, shape, 0)
        b.PrependInt64Slot(3, c.field_class, 0)
        b.PrependUOffsetTRelativeSlot(4, shared, 0)
        b.PrependUint64Slot(5, int(np.prod(c.shape)) * 8, 0)
        customs.append(b.EndObject())
    custom = _offsets(b, customs) if customs else 0
    ts = _scalars(b, m.timestamp, 8, b.PrependUint64)
    mid = _scalars(b, m.measurement_id, 2, b.PrependUint16)
    st = _scalars(b, m.status, 4, b.PrependUint32)
    b.StartObject(14)
    b.PrependUOffsetTRelativeSlot(0, channels, 0)
    b.PrependUOffsetTRelativeSlot(1, types, 0)
    b.PrependUOffsetTRelativeSlot(2, ts, 0)
    b.PrependUOffsetTRelativeSlot(3, mid, 0)
    b.PrependUOffsetTRelativeSlot(4, st, 0)
    b.PrependInt32Slot(5, m.frame_id, 0)
    if custom:
        b.PrependUOffsetTRelativeSlot(8, custom, 0)
    return _finish(b, b.EndObject())


def chunk(messages: list[tuple[int, int, bytes]], share_buffers: bool = False) -> bytes:
    """A Chunk of ``(ts, stream id, message buffer)``; ``share_buffers``: every message points at the first's."""
    b = flatbuffers.Builder(1024)
    b.ForceDefaults(True)
    offs = []
    shared = None
    for ts, stream, buf in messages:
        if shared is None or not share_buffers:
            shared = _u8(b, buf)
        b.StartObject(4)
        b.PrependUint64Slot(0, ts, 0)
        b.PrependUint32Slot(1, stream, 0)
        b.PrependUOffsetTRelativeSlot(2, shared, 0)
        b.PrependUint64Slot(3, ts, 0)
        offs.append(b.EndObject())
    msgs = _offsets(b, offs)
    b.StartObject(2)
    b.PrependUOffsetTRelativeSlot(0, msgs, 0)
    return _finish(b, b.EndObject(), b"OSF!")


def _entry_buffer(kind: str, sensor_json: str = "", n_messages: int = 0) -> bytes:
    b = flatbuffers.Builder(1024)
    b.ForceDefaults(True)
    if kind == LIDAR_SENSOR:
        text = b.CreateString(sensor_json)
        b.StartObject(1)
        b.PrependUOffsetTRelativeSlot(0, text, 0)
    elif kind == LIDAR_SCAN_STREAM:
        b.StartObject(2)
        b.PrependUint32Slot(0, 1, 0)  # the LidarSensor entry's id
    else:
        b.StartObject(3)
        b.PrependUint64Slot(0, 0, 0)  # the chunk's offset from the end of the header
        b.PrependUint32Slot(1, 2, 0)  # the LidarScanStream entry's id
        b.PrependUint32Slot(2, n_messages, 0)
        info = b.EndObject()
        infos = _offsets(b, [info])
        times = [1_000 + i for i in range(n_messages)]
        receive = _scalars(b, times, 8, b.PrependUint64)
        sensor = _scalars(b, times, 8, b.PrependUint64)
        b.StartObject(7)  # StreamStats of the stream: ouster-sdk indexes frames by them
        b.PrependUint32Slot(0, 2, 0)
        b.PrependUint64Slot(1, times[0] if times else 0, 0)
        b.PrependUint64Slot(2, times[-1] if times else 0, 0)
        b.PrependUint64Slot(3, n_messages, 0)
        b.PrependUint32Slot(4, 0, 0)
        b.PrependUOffsetTRelativeSlot(5, receive, 0)
        b.PrependUOffsetTRelativeSlot(6, sensor, 0)
        stats = _offsets(b, [b.EndObject()])
        b.StartObject(2)
        b.PrependUOffsetTRelativeSlot(0, infos, 0)
        b.PrependUOffsetTRelativeSlot(1, stats, 0)
    return _finish(b, b.EndObject())


def metadata(sensor_json: str, n_messages: int) -> bytes:
    b = flatbuffers.Builder(1024)
    b.ForceDefaults(True)
    entries = []
    for i, kind in enumerate((LIDAR_SENSOR, LIDAR_SCAN_STREAM, STREAMING_INFO), start=1):
        typ = b.CreateString(kind)
        buf = _u8(b, _entry_buffer(kind, sensor_json, n_messages))
        b.StartObject(3)
        b.PrependUint32Slot(0, i, 0)
        b.PrependUOffsetTRelativeSlot(1, typ, 0)
        b.PrependUOffsetTRelativeSlot(2, buf, 0)
        entries.append(b.EndObject())
    vec = _offsets(b, entries)
    b.StartVector(24, 1, 8)  # the one chunk: ChunkOffset(start_ts, end_ts, offset)
    b.Prep(8, 24)
    b.PrependUint64(0)
    b.PrependUint64(1_000 + max(0, n_messages - 1))
    b.PrependUint64(1_000)
    chunks = b.EndVector()
    ident = b.CreateString("lidarpkt-test")
    b.StartObject(5)
    b.PrependUOffsetTRelativeSlot(0, ident, 0)
    b.PrependUint64Slot(1, 1_000, 0)
    b.PrependUint64Slot(2, 1_000 + max(0, n_messages - 1), 0)
    b.PrependUOffsetTRelativeSlot(3, chunks, 0)
    b.PrependUOffsetTRelativeSlot(4, vec, 0)
    return _finish(b, b.EndObject(), b"OSF#")


def header(metadata_offset: int, file_length: int) -> bytes:
    b = flatbuffers.Builder(128)
    b.ForceDefaults(True)
    b.StartObject(4)
    b.PrependUint64Slot(0, VERSION_2_1, 0)
    b.PrependUint8Slot(1, 2, 0)  # VALID
    b.PrependUint64Slot(2, metadata_offset, 0)
    b.PrependUint64Slot(3, file_length, 0)
    return _finish(b, b.EndObject(), b"OSF$")


def _block(buf: bytes) -> bytes:
    return buf + struct.pack("<I", zlib.crc32(buf))


def osf_file(sensor_json: str, messages: list[Message], share_buffers: bool = False) -> bytes:
    """A whole OSF file: header, one chunk of the frame messages (stream 2), metadata."""
    body = _block(chunk([(1_000 + i, 2, lidar_scan_msg(m)) for i, m in enumerate(messages)], share_buffers))
    meta = _block(metadata(sensor_json, len(messages)))
    head_len = len(_block(header(0, 0)))
    head = _block(header(head_len + len(body), head_len + len(body) + len(meta)))
    assert len(head) == head_len
    return head + body + meta


def png_rgba(values: np.ndarray) -> bytes:
    """``uint32[H, W]`` as the 8-bit RGBA PNG ouster-sdk writes (R the low byte)."""
    import io

    from PIL import Image

    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(values.astype("<u4")).view(np.uint8).reshape(*values.shape, 4), "RGBA").save(
        out, "PNG")
    return out.getvalue()


def zpng(values: np.ndarray) -> bytes:
    """``uint{8,16,64}[H, W]`` as a ZPNG image: byte deltas along each row, zstd (pixels of 1, 2 or 8 bytes)."""
    import zstandard

    h, w = values.shape
    size = values.dtype.itemsize
    raw = np.ascontiguousarray(values.astype(f"<u{size}")).view(np.uint8).reshape(h, w, size)
    deltas = np.diff(raw, axis=1, prepend=np.zeros((h, 1, size), np.uint8))
    return struct.pack("<HHHBB", 0xFBF8, w, h, 1 if size < 8 else 4, size if size < 8 else 2) + \
        zstandard.ZstdCompressor().compress(deltas.tobytes())
