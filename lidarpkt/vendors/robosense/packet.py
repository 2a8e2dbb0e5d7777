"""The RoboSense MSOP and DIFOP packet layouts, declared once as NumPy structured dtypes.

Every other module of :mod:`lidarpkt.vendors.robosense` views payloads through these dtypes; none
hard-codes a byte offset. Multi-byte fields are big-endian ("big-endian mode, with the high byte in
the front", every RoboSense user manual). Field names follow the manuals. All packets are 1248 bytes.

MSOP (main data stream, port 6699) has three header layouts:

* ``HEADER_V1`` (42 B; RS-LiDAR-16, RS-LiDAR-32, RS-Bpearl): ``header_id`` 55 AA 05 0A 5A A5 50 A0,
  ``packet_count`` (RS-Bpearl; reserved on the others), ``timestamp`` (year-month-day form, or the
  UTC form on the RS-Bpearl V4), ``lidar_model_flag`` (the RS-LiDAR-16 manual's "LiDAR model":
  1 RS-LiDAR-16, 2 RS-LiDAR-32, 3 RS-Bpearl), ``lidar_type`` and ``lidar_model`` (RS-Bpearl V4:
  3 and 4), ``temperature``.
* ``HEADER_HELIOS`` (42 B; RS-Helios, RS-Helios-16P): ``header_id`` 55 AA 05 5A,
  ``protocol_version``, ``top_board_packet_count`` (bytes stepping by 3), ``bottom_board_packet_count``
  (+1 a packet), ``range_resolution`` (1: 0.25 cm, 0: 0.5 cm), ``angle_pulse_interval_count`` (µs),
  ``timestamp`` (UTC form), ``lidar_type`` (6: RS-Helios), ``lidar_model``, ``temperature``.
  The manuals' tables put the type one byte later than units send it (byte 31); the capture in
  ``fixtures/external/nebula/robosense`` and rs_driver have it at byte 30 (pinned in a test).
* ``HEADER_V2`` (80 B; RS-Ruby, RS-Ruby Plus): ``header_id`` 55 AA 05 5A, ``protocol_version``,
  ``wave_mode`` (1 single return, 3 dual), ``temperature``, ``timestamp`` (UTC form), ``lidar_type``
  (4 RS-Ruby, 5 RS-Ruby Plus), ``lidar_model``.

then blocks (12 of 32 channels, flag FF EE; or 3 of 128 channels, flag FE with a ``ret_id``), each
an ``azimuth`` (0.01°) and ``channels`` of ``distance`` (the model's unit) and ``reflectivity``
(0-255), and a tail (``reserved`` 4 bytes, ``tail`` 00 FF; RS-Ruby: 4 reserved bytes).

DIFOP (device information, port 7788): ``header_id`` A5 FF 00 5A 11 11 55 55, ``motor_speed``
(rpm), ``ethernet`` (addresses, MAC, ports), ``fov_start``/``fov_end`` (0.01°), ``phase_lock``,
firmware versions, ``serial_number``, ``zero_angle_offset``, ``return_mode`` (byte 300),
``time``, ``gprmc``, the corrected vertical and horizontal angle of each channel (a sign byte, 0
positive / 1 negative, and a magnitude; RS-LiDAR-16: 16 unsigned 24-bit pitches), ``tail`` 0F F0.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError

PACKET_SIZE = 1248
MSOP_ID_V1 = bytes((0x55, 0xAA, 0x05, 0x0A, 0x5A, 0xA5, 0x50, 0xA0))
MSOP_ID_V2 = bytes((0x55, 0xAA, 0x05, 0x5A))  # RS-Helios and RS-Ruby families
DIFOP_ID = bytes((0xA5, 0xFF, 0x00, 0x5A, 0x11, 0x11, 0x55, 0x55))
BLOCK_FLAG = 0xFFEE  # bytes FF EE
RUBY_BLOCK_FLAG = 0xFE
MSOP_TAIL = 0x00FF  # bytes 00 FF
DIFOP_TAIL = 0x0FF0  # bytes 0F F0

CHANNEL = np.dtype([("distance", ">u2"), ("reflectivity", "u1")])
# seconds since the epoch in 6 bytes, then microseconds
TIME_UTC = np.dtype([("seconds", "u1", (6,)), ("microseconds", ">u4")])
# year (from 2000), month, day, hour, minute, second, millisecond, microsecond
TIME_YMD = np.dtype([("year", "u1"), ("month", "u1"), ("day", "u1"), ("hour", "u1"), ("minute", "u1"),
                     ("second", "u1"), ("millisecond", ">u2"), ("microsecond", ">u2")])


def header_v1(time: np.dtype) -> np.dtype:
    """The 42-byte MSOP header of the RS-LiDAR-16/32 and RS-Bpearl, with ``time`` (:data:`TIME_YMD` or
    :data:`TIME_UTC`)."""
    return np.dtype([
        ("header_id", "u1", (8,)), ("reserved1", "u1", (4,)), ("packet_count", ">u4"), ("reserved2", "u1", (4,)),
        ("timestamp", time), ("lidar_model_flag", "u1"), ("lidar_type", "u1"), ("lidar_model", "u1"),
        ("reserved3", "u1", (5,)), ("temperature", "u1", (2,)), ("reserved4", "u1", (2,)),
    ])


HEADER_HELIOS = np.dtype([
    ("header_id", "u1", (4,)), ("protocol_version", ">u2"), ("reserved1", "u1", (2,)),
    ("top_board_packet_count", ">u4"), ("bottom_board_packet_count", ">u4"), ("reserved2", "u1"),
    ("range_resolution", "u1"), ("angle_pulse_interval_count", ">u2"), ("timestamp", TIME_UTC),
    ("lidar_type", "u1"), ("lidar_model", "u1"), ("reserved3", "u1", (6,)), ("temperature", "u1", (2,)),
    ("reserved4", "u1", (2,)),
])
HEADER_V2 = np.dtype([
    ("header_id", "u1", (4,)), ("protocol_version", ">u2"), ("reserved1", "u1"), ("wave_mode", "u1"),
    ("temperature", "u1", (2,)), ("timestamp", TIME_UTC), ("reserved2", "u1", (10,)), ("lidar_type", "u1"),
    ("lidar_model", "u1"), ("reserved3", "u1", (48,)),
])

BLOCK_32 = np.dtype([("flag", ">u2"), ("azimuth", ">u2"), ("channels", CHANNEL, (32,))])
BLOCK_128 = np.dtype([("flag", "u1"), ("ret_id", "u1"), ("azimuth", ">u2"), ("channels", CHANNEL, (128,))])
TAIL_12 = np.dtype([("reserved", ">u4"), ("tail", ">u2")])
TAIL_RUBY = np.dtype([("reserved", "u1", (4,))])


def msop_dtype(header: np.dtype, block: np.dtype, blocks: int, tail: np.dtype) -> np.dtype:
    """A whole MSOP packet; checked to be :data:`PACKET_SIZE` bytes."""
    dtype = np.dtype([("header", header), ("blocks", block, (blocks,)), ("tail", tail)])
    if dtype.itemsize != PACKET_SIZE:
        raise ImportError(f"RoboSense MSOP layout of {dtype.itemsize} B, not {PACKET_SIZE}")
    return dtype


MSOP_V1_YMD = msop_dtype(header_v1(TIME_YMD), BLOCK_32, 12, TAIL_12)
MSOP_V1_UTC = msop_dtype(header_v1(TIME_UTC), BLOCK_32, 12, TAIL_12)
MSOP_HELIOS = msop_dtype(HEADER_HELIOS, BLOCK_32, 12, TAIL_12)
MSOP_RUBY = msop_dtype(HEADER_V2, BLOCK_128, 3, TAIL_RUBY)

# ------------------------------------------------------------------------------------------ DIFOP
ANGLE = np.dtype([("sign", "u1"), ("value", ">u2")])  # sign 0 positive, 1 negative
ETHERNET = np.dtype([
    ("lidar_ip", "u1", (4,)), ("dest_pc_ip", "u1", (4,)), ("mac_addr", "u1", (6,)), ("lidar_msop_port", ">u2"),
    ("pc_msop_port", ">u2"), ("lidar_difop_port", ">u2"), ("pc_difop_port", ">u2"),
])
_DIFOP_HEAD = [
    ("header_id", "u1", (8,)), ("motor_speed", ">u2"), ("ethernet", ETHERNET), ("fov_start", ">u2"),
    ("fov_end", ">u2"), ("reserved1", "u1", (2,)), ("phase_lock", ">u2"), ("top_firmware_version", "u1", (5,)),
    ("bottom_firmware_version", "u1", (5,)),
]
_DIFOP_V1_MIDDLE = [
    ("reserved2", "u1", (242,)), ("serial_number", "u1", (6,)), ("zero_angle_offset", ">u2"), ("return_mode", "u1"),
    ("software_version", ">u2"), ("time", TIME_YMD), ("operating_status", "u1", (24,)), ("reserved3", "u1", (5,)),
    ("fault_diagnosis", "u1", (40,)), ("gprmc", "u1", (86,)),
]
_DIFOP_V2_MIDDLE = [
    ("bottom_software_version", "u1", (5,)), ("motor_firmware_version", "u1", (5,)), ("hardware_version", "u1", (3,)),
    ("web_page_version", "u1", (4,)), ("backup_crc", "u1", (16,)), ("ethernet_gateway", "u1", (4,)),
    ("subnet_mask", "u1", (4,)), ("reserved2", "u1", (201,)), ("serial_number", "u1", (6,)),
    ("zero_angle_offset", ">u2"), ("return_mode", "u1"), ("time_sync_mode", "u1"), ("sync_status", "u1"),
    ("time", TIME_UTC), ("operating_status", "u1", (24,)), ("reserved3", "u1", (5,)), ("fault_diagnosis", "u1", (40,)),
    ("gprmc", "u1", (86,)),
]


def _difop(middle: list, angles: list) -> np.dtype:
    fields = _DIFOP_HEAD + middle + angles
    used = np.dtype(fields).itemsize
    dtype = np.dtype(fields + [("reserved_end", "u1", (PACKET_SIZE - 2 - used,)), ("tail", ">u2")])
    if dtype.itemsize != PACKET_SIZE:
        raise ImportError(f"RoboSense DIFOP layout of {dtype.itemsize} B, not {PACKET_SIZE}")
    return dtype


# RS-LiDAR-16: sixteen unsigned 24-bit pitches in 0.0001°, channels 1-8 downwards (RS-LiDAR-16 manual B.6)
DIFOP_RS16 = _difop(_DIFOP_V1_MIDDLE, [("reserved4", "u1", (697,)), ("pitch_calibration", "u1", (16, 3))])
# RS-LiDAR-32 (0.001°) and RS-Bpearl (0.01°): 32 vertical and 32 horizontal angles
DIFOP_V1_32 = _difop(_DIFOP_V1_MIDDLE, [("vertical_angles", ANGLE, (32,)), ("horizontal_angles", ANGLE, (32,))])
DIFOP_HELIOS = _difop(_DIFOP_V2_MIDDLE, [("vertical_angles", ANGLE, (32,)), ("horizontal_angles", ANGLE, (32,))])
DIFOP_RUBY = _difop(_DIFOP_V2_MIDDLE, [("vertical_angles", ANGLE, (128,)), ("horizontal_angles", ANGLE, (128,))])
# every DIFOP layout has the return mode at byte 300 and the angles from byte 468


def offset(dtype: np.dtype, name: str) -> int:
    """Byte offset of the field ``name`` of ``dtype``."""
    fields = dtype.fields
    assert fields is not None
    return int(fields[name][1])


if not all(offset(d, "return_mode") == 300 for d in (DIFOP_RS16, DIFOP_V1_32, DIFOP_HELIOS, DIFOP_RUBY)):
    raise ImportError("RoboSense DIFOP layouts: the return mode is not at byte 300")
if not all(offset(d, "vertical_angles") == 468 for d in (DIFOP_V1_32, DIFOP_HELIOS, DIFOP_RUBY)):
    raise ImportError("RoboSense DIFOP layouts: the vertical angles do not start at byte 468")


def be_uint(fields: np.ndarray) -> np.ndarray:
    """``int64[...]`` of big-endian unsigned integers stored as ``uint8[..., k]`` byte fields (the UTC
    seconds' 6 bytes, the RS-LiDAR-16's 24-bit pitches)."""
    b = np.asarray(fields, np.int64)
    out = np.zeros(b.shape[:-1], np.int64)
    for k in range(b.shape[-1]):
        out = (out << 8) | b[..., k]
    return out


def as_packets(payload: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """View ``uint8[N, 1248]`` payloads as ``dtype[N]`` (no copy when C-contiguous).

    Raises :class:`~lidarpkt.errors.PacketFormatError` for payloads of another shape.
    """
    payload = np.ascontiguousarray(payload, dtype=np.uint8)
    if payload.ndim != 2 or payload.shape[1] != dtype.itemsize:
        raise PacketFormatError(f"RoboSense payloads must be uint8[N, {dtype.itemsize}], got shape {payload.shape}")
    return payload.view(dtype)[:, 0]
