"""The layouts of the Ouster packets beside the lidar ones, each declared once: IMU packets (the LEGACY
48-byte packet and ACCEL32_GYRO32_NMEA of firmware 3.x) and zone-monitoring packets. The packet header
and footer are the lidar packets' (:mod:`.profiles`)."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .bitfield import BitField, check_cover, reserved_bits
from .profiles import FOOTER_BYTES, HEADER_BYTES


# --------------------------------------------------------------------------- IMU

#: LEGACY IMU packet (48 bytes): three timestamps (ns), acceleration (g), angular velocity (deg/s).
IMU_DTYPE = np.dtype(
    [
        ("sys_timestamp_ns", "<u8"),
        ("accel_timestamp_ns", "<u8"),
        ("gyro_timestamp_ns", "<u8"),
        ("accel_x_g", "<f4"),
        ("accel_y_g", "<f4"),
        ("accel_z_g", "<f4"),
        ("gyro_x_deg_per_s", "<f4"),
        ("gyro_y_deg_per_s", "<f4"),
        ("gyro_z_deg_per_s", "<f4"),
    ]
)
IMU_PACKET_SIZE = IMU_DTYPE.itemsize

#: IMU profiles of the metadata's ``udp_profile_imu``.
IMU_PROFILES = ("LEGACY", "ACCEL32_GYRO32_NMEA")

#: ACCEL32_GYRO32_NMEA (firmware 3.x): the 32-byte packet header of the lidar packets, this NMEA block,
#: ``imu_measurements_per_packet`` measurements of :data:`IMU_MEASUREMENT_DTYPE`, the 32-byte footer.
#: The sentence is NUL-padded ASCII (the last NMEA sentence the sensor received, empty without one).
IMU_NMEA_BLOCK_DTYPE = np.dtype(
    {"names": ["nmea_timestamp_ns", "nmea_sentence"], "formats": ["<u8", "S85"], "offsets": [0, 8], "itemsize": 100}
)
#: One ACCEL32_GYRO32_NMEA measurement: a column-like header (status bit 0 = valid), acceleration in m/s²
#: and angular velocity in rad/s (float32; the LEGACY packet's are in g and deg/s).
IMU_MEASUREMENT_DTYPE = np.dtype(
    [
        ("timestamp_ns", "<u8"),
        ("measurement_id", "<u2"),
        ("status", "<u2"),
        ("accel_x_mps2", "<f4"),
        ("accel_y_mps2", "<f4"),
        ("accel_z_mps2", "<f4"),
        ("gyro_x_radps", "<f4"),
        ("gyro_y_radps", "<f4"),
        ("gyro_z_radps", "<f4"),
    ]
)


def imu_packet_dtype(measurements: int) -> np.dtype:
    """Structured dtype of one ACCEL32_GYRO32_NMEA packet holding ``measurements`` measurements."""
    return _imu_packet_dtype(int(measurements))


@lru_cache(maxsize=16)
def _imu_packet_dtype(m: int) -> np.dtype:
    nmea_at = HEADER_BYTES
    meas_at = nmea_at + IMU_NMEA_BLOCK_DTYPE.itemsize
    footer_at = meas_at + m * IMU_MEASUREMENT_DTYPE.itemsize
    return np.dtype(
        {
            "names": ["header", "nmea", "measurements", "footer"],
            "formats": [("u1", (HEADER_BYTES,)), IMU_NMEA_BLOCK_DTYPE, (IMU_MEASUREMENT_DTYPE, (m,)), ("u1", (FOOTER_BYTES,))],
            "offsets": [0, nmea_at, meas_at, footer_at],
            "itemsize": footer_at + FOOTER_BYTES,
        }
    )


# --------------------------------------------------------------------------- zone monitoring

ZONES_PER_PACKET = 16
ZONESET_HASH_BYTES = 32
#: One zone's state in a zone-monitoring packet (36 bytes); the ranges are in mm like RANGE.
ZONE_STATE_FIELDS: tuple[BitField, ...] = (
    BitField("live", 0, 1),
    *reserved_bits(1, 7),
    BitField("id", 8, 8),
    BitField("error_flags", 16, 8),
    *reserved_bits(24, 2),
    BitField("trigger_type", 26, 2),
    *reserved_bits(28, 3),
    BitField("trigger_status", 31, 1),
    BitField("triggered_frames", 32, 32),
    BitField("count", 64, 32),
    BitField("occlusion_count", 96, 32),
    BitField("invalid_count", 128, 32),
    BitField("max_count", 160, 32),
    BitField("min_range_mm", 192, 19),
    *reserved_bits(211, 13),
    BitField("max_range_mm", 224, 19),
    *reserved_bits(243, 13),
    BitField("mean_range_mm", 256, 19),
    *reserved_bits(275, 13),
)
ZONE_STATE_BYTES = 36
check_cover(ZONE_STATE_FIELDS, ZONE_STATE_BYTES * 8, "zone state")
#: Zone-monitoring packet: packet header, timestamp (ns), SHA-256 of the live zone set, 16 zone states, footer.
ZONE_PACKET_DTYPE = np.dtype(
    {
        "names": ["header", "timestamp_ns", "live_zoneset_hash", "zones", "footer"],
        "formats": [("u1", (HEADER_BYTES,)), "<u8", ("u1", (ZONESET_HASH_BYTES,)),
                    ("u1", (ZONES_PER_PACKET, ZONE_STATE_BYTES)), ("u1", (FOOTER_BYTES,))],
        "offsets": [0, HEADER_BYTES, HEADER_BYTES + 8, HEADER_BYTES + 8 + ZONESET_HASH_BYTES,
                    HEADER_BYTES + 8 + ZONESET_HASH_BYTES + ZONES_PER_PACKET * ZONE_STATE_BYTES],
        "itemsize": HEADER_BYTES + 8 + ZONESET_HASH_BYTES + ZONES_PER_PACKET * ZONE_STATE_BYTES + FOOTER_BYTES,
    }
)
ZONE_PACKET_SIZE = ZONE_PACKET_DTYPE.itemsize
