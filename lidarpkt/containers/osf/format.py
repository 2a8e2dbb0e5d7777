"""The OSF file format (ouster-sdk's recording of decoded frames), declared once: its flatbuffers tables and
structs, the identifiers of its blocks, the entry types read, the field types and standard channels; and
bounds-checked access to its tables.

The layout (ouster-sdk's ``ouster_osf/fb/*.fbs`` and its reader) is a sequence of flatbuffers blocks,
each a 4-byte little-endian size, the buffer and a CRC-32 (zlib's) of both::

    Header (identifier HEADER_ID: version, status, metadata_offset, file_length)
    Chunk (CHUNK_ID: StampedMessage[] of one stream), Chunk, ...
    Metadata (METADATA_ID, at metadata_offset: the entries, each a buffer of its own type)
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from ..magic import OSF_IDENTIFIER

FORMAT = "OSF"  # the format's name, in messages

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
HEADER_ID, CHUNK_ID, METADATA_ID = OSF_IDENTIFIER, b"OSF!", b"OSF#"
# MetadataEntry.type of the entries read here
LIDAR_SENSOR = "ouster/v1/os_sensor/LidarSensor"
LIDAR_SCAN_STREAM = "ouster/v1/os_sensor/LidarScanStream"
STREAMING_INFO = "ouster/v1/streaming/StreamingInfo"
HEADER_STATUS_VALID = 2
VERSION_2_0 = 20  # OsfVersion::V_2_0; later versions are (major << 48 | minor << 32 | patch << 16)

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


class Damaged(Exception):
    """Inside the reader: what is wrong, before the file's name is put in front."""


class FlatTable:
    """One table of a flatbuffer, read with the ``flatbuffers`` package after every position it uses
    is checked to lie inside the buffer (the package itself trusts the buffer)."""

    __slots__ = ("_t", "_buf", "_kind", "_fields", "_size")

    def __init__(self, buf: bytes, pos: int, kind: str) -> None:
        from flatbuffers.table import Table

        n = len(buf)
        if not 0 <= pos <= n - 4:
            raise Damaged(f"a {kind} table lies outside its buffer")
        vtable = pos - struct.unpack_from("<i", buf, pos)[0]
        if not 0 <= vtable <= n - 4:
            raise Damaged(f"the vtable of a {kind} table lies outside its buffer")
        vsize, tsize = struct.unpack_from("<HH", buf, vtable)
        if vsize < 4 or vsize % 2 or vtable + vsize > n or pos + tsize > n:
            raise Damaged(f"a {kind} table has a vtable of {vsize} B for {tsize} B, beyond its buffer")
        self._t = Table(buf, pos)
        self._buf = buf
        self._kind = kind
        self._fields = TABLES[kind]
        self._size = tsize

    def _offset(self, name: str, width: int) -> int:
        slot = self._fields[name][0]
        off = self._t.Offset(4 + 2 * slot)
        if off and off + width > self._size:
            raise Damaged(f"{self._kind}.{name} lies outside its table")
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
            return [FlatTable(self._buf, p, inner) for p in self._table_positions(off)]
        dt = STRUCTS.get(inner) or np.dtype(inner)
        return np.frombuffer(self._vector(off, dt.itemsize), dt)

    def _vector(self, off: int, item: int) -> bytes | memoryview:
        at = self._t.Pos + off
        start = at + struct.unpack_from("<I", self._buf, at)[0]
        if start > len(self._buf) - 4:
            raise Damaged(f"a vector of {self._kind} lies outside its buffer")
        count = struct.unpack_from("<I", self._buf, start)[0]
        if count * item > len(self._buf) - start - 4:
            raise Damaged(f"a vector of {self._kind} claims {count} items, more than its buffer holds")
        return memoryview(self._buf)[start + 4 : start + 4 + count * item]

    def _table_positions(self, off: int) -> list[int]:
        start = self._t.Pos + off
        start += struct.unpack_from("<I", self._buf, start)[0]
        offsets = np.frombuffer(self._vector(off, 4), "<u4").astype(np.int64)
        return (start + 4 + 4 * np.arange(offsets.size) + offsets).tolist()


def root_table(buf: bytes, kind: str, identifier: bytes | None = None) -> FlatTable:
    """The root table of a size-prefixed flatbuffer ``buf`` (prefix included)."""
    if len(buf) < 8 or struct.unpack_from("<I", buf)[0] != len(buf) - 4:
        raise Damaged(f"a {kind} buffer of {len(buf)} B does not hold the size it declares")
    if identifier is not None and buf[8:12] != identifier:
        raise Damaged(f"a {kind} block has the identifier {bytes(buf[8:12])!r}, not {identifier!r}")
    return FlatTable(buf, 4 + struct.unpack_from("<I", buf, 4)[0], kind)
