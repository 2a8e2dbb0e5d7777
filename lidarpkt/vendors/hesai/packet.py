"""The Hesai Pandar packet layouts, declared once as NumPy structured dtypes.

Every other module of :mod:`lidarpkt.vendors.hesai` views payloads through these dtypes; none hard-codes a
byte offset. All multi-byte fields are little-endian. Field names follow the Hesai user manuals
("Point Cloud Data Packet"); every layout has the same field names, so that decoding is one code path:

* ``header`` (absent on the Pandar40P): ``sop`` (start of packet, bytes EE FF), and on the 12-byte
  header of the QT and XT families ``protocol_major``/``protocol_minor``; then ``laser_num``,
  ``block_num``, ``dis_unit`` (mm per distance unit), on the 12-byte header ``return_num`` and
  ``flags``.
* ``blocks[B]``: (Pandar40P: ``sob``, bytes FF EE) ``azimuth`` (0.01°) and ``units[C]`` of
  ``distance`` (``dis_unit`` mm; 4 mm on the 40P, which has no header) and ``reflectivity``
  (0-255), and on the 4-byte units of the QT and XT families ``confidence`` (reserved on most).
* ``tail``: ``return_mode`` (0x33-0x3E, :data:`lidarpkt.vendors.hesai.models.RETURN_MODES`),
  ``motor_speed`` (rpm), ``utc`` (year, month, day, hour, minute, second; the year counted from
  the model's ``year_offset``), ``timestamp_us`` (µs past the UTC second), ``factory_information``
  (0x42 on the units here), and ``udp_sequence`` where the protocol has one. The PandarQT128 adds a
  body CRC, 17 bytes of functional safety, ``mode_flag`` (which of its two firing loops a
  dual-return packet holds) and a tail CRC; its last 32 bytes (a signature, zeros here) are not read.

Sizes: Pandar40P 1262 B (1266 with the UDP sequence), Pandar64 1194 B (1198), PandarQT64 1072 B,
PandarQT128 1127 B, PandarXT16 568 B, PandarXT32 1080 B, PandarXT32M 820 B.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError

SOP = 0xFFEE  # header start: bytes EE FF read as u16 little-endian
SOB = 0xEEFF  # Pandar40P block start: bytes FF EE

HEADER_12B = np.dtype([
    ("sop", "<u2"), ("protocol_major", "u1"), ("protocol_minor", "u1"), ("reserved1", "u1", (2,)),
    ("laser_num", "u1"), ("block_num", "u1"), ("reserved2", "u1"), ("dis_unit", "u1"), ("return_num", "u1"),
    ("flags", "u1"),
])
HEADER_8B = np.dtype([
    ("sop", "<u2"), ("laser_num", "u1"), ("block_num", "u1"), ("reserved1", "u1"), ("dis_unit", "u1"),
    ("reserved2", "u1", (2,)),
])
UNIT_3B = np.dtype([("distance", "<u2"), ("reflectivity", "u1")])
UNIT_4B = np.dtype([("distance", "<u2"), ("reflectivity", "u1"), ("confidence", "u1")])

UTC = ("utc", "u1", (6,))  # year, month, day, hour, minute, second

# Pandar40P and Pandar64 ("Tail" of their manuals)
TAIL_40P = np.dtype([
    ("reserved1", "u1", (5,)), ("high_temperature_shutdown_flag", "u1"), ("reserved2", "u1", (2,)),
    ("motor_speed", "<u2"), ("timestamp_us", "<u4"), ("return_mode", "u1"), ("factory_information", "u1"), UTC,
])
# PandarXT16, XT32, XT32M
TAIL_XT = np.dtype([
    ("reserved1", "u1", (10,)), ("return_mode", "u1"), ("motor_speed", "<u2"), UTC, ("timestamp_us", "<u4"),
    ("factory_information", "u1"), ("udp_sequence", "<u4"),
])
# PandarQT64
TAIL_QT64 = np.dtype([
    ("reserved1", "u1", (10,)), ("motor_speed", "<u2"), ("timestamp_us", "<u4"), ("return_mode", "u1"),
    ("factory_information", "u1"), UTC, ("udp_sequence", "<u4"),
])
# PandarQT128 (protocol 3.2): functional safety, then the tail
FUNCTIONAL_SAFETY_QT128 = np.dtype([
    ("fs_version", "u1"), ("state", "u1"), ("fault_codes", "u1"), ("fault_code", "<u2"), ("reserved", "u1", (8,)),
    ("crc_fs", "<u4"),
])
TAIL_QT128 = np.dtype([
    ("reserved1", "u1", (5,)), ("mode_flag", "u1"), ("reserved2", "u1", (6,)), ("return_mode", "u1"),
    ("motor_speed", "<u2"), UTC, ("timestamp_us", "<u4"), ("factory_information", "u1"), ("udp_sequence", "<u4"),
    ("crc_tail", "<u4"),
])


def block_dtype(unit: np.dtype, channels: int, *, sob: bool = False) -> np.dtype:
    """One data block: (``sob``) ``azimuth`` u16 in 0.01° and ``channels`` units."""
    head = [("sob", "<u2")] if sob else []
    return np.dtype(head + [("azimuth", "<u2"), ("units", unit, (channels,))])


def packet_dtype(*, header: np.dtype | None, unit: np.dtype, channels: int, blocks: int, tail: np.dtype,
                 sob: bool = False, body_crc: bool = False, safety: np.dtype | None = None,
                 trailing_bytes: int = 0) -> np.dtype:
    """A whole packet: header, ``blocks`` blocks, (body CRC, functional safety), tail, ``trailing_bytes``
    more (optional fields lidarpkt does not read)."""
    fields: list = []
    if header is not None:
        fields.append(("header", header))
    fields.append(("blocks", block_dtype(unit, channels, sob=sob), (blocks,)))
    if body_crc:
        fields.append(("crc_body", "<u4"))
    if safety is not None:
        fields.append(("functional_safety", safety))
    fields.append(("tail", tail))
    if trailing_bytes:
        fields.append(("trailing", "u1", (trailing_bytes,)))
    return np.dtype(fields)


def as_packets(payload: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """View ``uint8[N, L]`` payloads as ``dtype[N]`` (no copy when C-contiguous); bytes past
    ``dtype.itemsize`` (optional fields) are not read.

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the payloads are shorter than the layout.
    """
    payload = np.ascontiguousarray(payload, dtype=np.uint8)
    if payload.ndim != 2 or payload.shape[1] < dtype.itemsize:
        raise PacketFormatError(f"Hesai payloads must be uint8[N, >= {dtype.itemsize}], got shape {payload.shape}")
    if payload.shape[1] != dtype.itemsize:
        payload = np.ascontiguousarray(payload[:, : dtype.itemsize])
    return payload.view(dtype)[:, 0]
