"""The VLP-16 packet layouts, declared once as NumPy structured dtypes.

Everything else in :mod:`lidarpkt.vendors.velodyne` (decoding, encoding, classification) views
payloads through these dtypes; no other module hard-codes a byte offset.

Data packet (VLP-16 user manual, "Data Packet Format"), 1206 bytes::

    12 × data block (100 B):  flag u16 LE (0xEEFF: bytes FF EE), azimuth u16 LE (0.01°),
                               32 × (distance u16 LE in 2 mm, reflectivity u8)
    timestamp   u32 LE         µs past the top of the hour
    return mode u8             0x37 strongest, 0x38 last, 0x39 dual
    product id  u8             0x22 VLP-16 (early units: 0x21)

Position packet ("Position Packet Format"), 512 bytes::

    0–197    unused (zero on the VLP-16; the HDL-32E puts gyro/temperature/accel here)
    198–201  timestamp u32 LE, µs past the hour
    202      PPS status: 0 absent, 1 synchronizing, 2 locked, 3 error
    203–205  thermal status, last shutdown temperature, power-up temperature (newer firmware)
    206–333  NMEA sentence ($GPRMC or $GPGGA), NUL-padded
    334–511  unused
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError
from .models import RETURN_MODES, VLP16

DATA_PACKET_SIZE = 1206
POSITION_PACKET_SIZE = 512
BLOCKS_PER_PACKET = 12
CHANNELS_PER_BLOCK = 32
BLOCK_FLAG = 0xEEFF  # bytes FF EE read as u16 little-endian

RETURN_MODE_CODES = {name: code for code, name in RETURN_MODES.items()}


def known_return_mode(return_mode: np.ndarray) -> np.ndarray:
    """``bool[N]``: which of the packets' return-mode bytes (``uint8[N]``) is one of :data:`RETURN_MODES` (a table
    lookup, where ``np.isin`` sorts)."""
    return _KNOWN_RETURN_MODE[return_mode]


_KNOWN_RETURN_MODE = np.zeros(256, bool)
_KNOWN_RETURN_MODE[list(RETURN_MODES)] = True
PRODUCT_VLP16 = VLP16.product_ids[0]
PRODUCT_HDL32E = 0x21  # also written by early (2014) VLP-16 firmware

PPS_STATUS = {0: "absent", 1: "synchronizing", 2: "locked", 3: "error"}

CHANNEL_DTYPE = np.dtype([("distance_2mm", "<u2"), ("reflectivity", "u1")])  # 3 B, packed
BLOCK_DTYPE = np.dtype([("flag", "<u2"), ("azimuth_cdeg", "<u2"), ("channels", CHANNEL_DTYPE, (CHANNELS_PER_BLOCK,))])
DATA_PACKET_DTYPE = np.dtype(
    [
        ("blocks", BLOCK_DTYPE, (BLOCKS_PER_PACKET,)),
        ("timestamp_us", "<u4"),
        ("return_mode", "u1"),
        ("product_id", "u1"),
    ]
)

NMEA_OFFSET = 206
NMEA_SIZE = 128
POSITION_PACKET_DTYPE = np.dtype(
    {
        "names": [
            "unused_head", "timestamp_us", "pps_status", "thermal_status",
            "last_shutdown_temperature", "powerup_temperature", "nmea", "unused_tail",
        ],
        "formats": [
            ("u1", (198,)), "<u4", "u1", "u1", "u1", "u1", ("u1", (NMEA_SIZE,)),
            ("u1", (POSITION_PACKET_SIZE - NMEA_OFFSET - NMEA_SIZE,)),
        ],
        "offsets": [0, 198, 202, 203, 204, 205, NMEA_OFFSET, NMEA_OFFSET + NMEA_SIZE],
        "itemsize": POSITION_PACKET_SIZE,
    }
)

if DATA_PACKET_DTYPE.itemsize != DATA_PACKET_SIZE or BLOCK_DTYPE.itemsize != 100:  # a layout typo, caught at import
    raise PacketFormatError(f"VLP-16 layout declares {DATA_PACKET_DTYPE.itemsize} B packets of "
                            f"{BLOCK_DTYPE.itemsize} B blocks; the manual says {DATA_PACKET_SIZE} and 100")

# Laser elevation by laser id (manual, "Laser Angles"), degrees.
LASER_ELEVATION_DEG = np.array(VLP16.elevation_deg, dtype=np.float64)
# Laser id of each frame row: row 0 = highest elevation (laser 15), row 15 = laser 0.
ROW_TO_LASER = np.argsort(-LASER_ELEVATION_DEG, kind="stable")

# Packet periods (manual, "Timing"), µs.
SINGLE_PACKET_PERIOD_US = VLP16.packet_period_us("strongest")  # 1327.104


# HDL-32E position packets (HDL-32E manual, appendix B, "Positioning Packet"): bytes 14–37 hold three
# gyro/temperature/accelerometer sensors, each four u16 LE words whose low 12 bits are a two's-complement
# reading (the high 4 bits are status): gyro (0.09766 °/s per count), temperature (0.1453 °C per count
# + 25 °C), accelerometer X and Y (0.001221 g per count). Offsets inside the packet.
HDL32E_INERTIAL_OFFSET = 14
HDL32E_SENSOR_DTYPE = np.dtype([("gyro", "<u2"), ("temperature", "<u2"), ("accel_x", "<u2"), ("accel_y", "<u2")])
HDL32E_INERTIAL_DTYPE = np.dtype([("sensors", HDL32E_SENSOR_DTYPE, (3,))])
HDL32E_GYRO_DEG_S = 0.09766
HDL32E_TEMPERATURE_C = 0.1453
HDL32E_TEMPERATURE_OFFSET_C = 25.0
HDL32E_ACCEL_G = 0.001221


def as_data_packets(payload: np.ndarray) -> np.ndarray:
    """View ``uint8[N, 1206]`` payloads as ``DATA_PACKET_DTYPE[N]`` (no copy when C-contiguous).

    Raises :class:`~lidarpkt.errors.PacketFormatError` if the array is not ``[N, 1206]``.
    """
    payload = np.ascontiguousarray(payload, dtype=np.uint8)
    if payload.ndim != 2 or payload.shape[1] != DATA_PACKET_SIZE:
        raise PacketFormatError(f"VLP-16 data payloads must be uint8[N, {DATA_PACKET_SIZE}], got shape {payload.shape}")
    return payload.view(DATA_PACKET_DTYPE)[:, 0]


def as_position_packets(payload: np.ndarray) -> np.ndarray:
    """View ``uint8[N, 512]`` payloads as ``POSITION_PACKET_DTYPE[N]``. Raises ``PacketFormatError`` on another size."""
    payload = np.ascontiguousarray(payload, dtype=np.uint8)
    if payload.ndim != 2 or payload.shape[1] != POSITION_PACKET_SIZE:
        raise PacketFormatError(
            f"VLP-16 position payloads must be uint8[N, {POSITION_PACKET_SIZE}], got shape {payload.shape}"
        )
    return payload.view(POSITION_PACKET_DTYPE)[:, 0]
