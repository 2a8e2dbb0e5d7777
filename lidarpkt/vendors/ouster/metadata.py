"""Ouster sensor metadata, parsed (:class:`OusterMetadata`): everything needed to decode one sensor's
packets, from the JSON the sensor's ``get_metadata`` returns (read by :mod:`.metadata_json`, which
documents the two layouts and the defaults of absent fields)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .auxiliary import IMU_PACKET_SIZE, ZONE_PACKET_SIZE, imu_packet_dtype
from .profiles import Profile

DEFAULT_LIDAR_ORIGIN_TO_BEAM_ORIGIN_MM = 12.163
DEFAULT_LIDAR_TO_SENSOR = np.array([[-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 1, 36.18], [0, 0, 0, 1]], dtype=np.float64)
DEFAULT_IMU_TO_SENSOR = np.array(
    [[1, 0, 0, 6.253], [0, 1, 0, -11.775], [0, 0, 1, 7.645], [0, 0, 0, 1]], dtype=np.float64
)
DEFAULT_LIDAR_PORT = 7502
DEFAULT_IMU_PORT = 7503
_VERSION = re.compile(r"v(\d+)\.(\d+)\.(\d+)")


#: Return-slot labels by ``return_order`` (ouster-sdk's ReturnOrder names, the last two of older firmware).
RETURN_LABELS: dict[str, tuple[str, str]] = {
    "STRONGEST_TO_WEAKEST": ("strongest", "second_strongest"),
    "FARTHEST_TO_NEAREST": ("farthest", "second_farthest"),
    "NEAREST_TO_FARTHEST": ("nearest", "second_nearest"),
    "STRONGEST_RETURN_FIRST": ("strongest", "second_strongest"),
    "LAST_RETURN_FIRST": ("last", "second_last"),
}



@dataclass(eq=False)
class OusterMetadata:
    """Everything needed to decode one Ouster sensor's packets, parsed from its metadata JSON.

    Attributes:
        profile: the lidar :class:`~lidarpkt.vendors.ouster.profiles.Profile`.
        pixels_per_column: H (beams); columns_per_packet: 16 usually; columns_per_frame: W.
        column_window: ``(first, last)`` measurement ids the sensor sends, inclusive
            (``first > last`` when the window wraps through 0).
        lidar_mode: e.g. ``"1024x10"``; frequency_hz: 10 or 20 (``None`` if unknown).
        beam_altitude_deg, beam_azimuth_deg: ``float64[H]``, degrees, row order.
        pixel_shift_by_row: ``int64[H]`` stagger shifts in columns.
        beam_to_lidar_transform, lidar_to_sensor_transform, imu_to_sensor_transform:
            ``float64[4, 4]`` homogeneous transforms, translations in mm.
        lidar_origin_to_beam_origin_mm: as in the JSON (or the default).
        lidar_port, imu_port: UDP destination ports.
        init_id: ``initialization_id`` (0 if absent); serial: ``prod_sn`` as text (``None`` if absent).
        firmware: ``build_rev`` (or ``image_rev``), ``None`` if absent; prod_line: e.g. ``"OS-1-64"``.
        imu_profile: ``udp_profile_imu`` (``LEGACY``, ``ACCEL32_GYRO32_NMEA``; another name is kept, its
            packets are not decoded); imu_measurements_per_packet: of ACCEL32_GYRO32_NMEA packets.
        zm_port: UDP port of the zone-monitoring packets, ``None`` when zone monitoring is off.
        lidar_enabled: False when the metadata turns the lidar stream off (``udp_port_lidar`` 0).
        return_order: which return goes in which slot (``STRONGEST_TO_WEAKEST``,
            ``FARTHEST_TO_NEAREST``, ``NEAREST_TO_FARTHEST``); it names the return slots.
        timestamp_mode: e.g. ``TIME_FROM_PTP_1588`` (``None`` if absent): what the column timestamps count.
        azimuth_window: ``(first, last)`` millidegrees the sensor sends (``None`` if absent); the
            columns it covers are ``column_window``.
        raw: the JSON document as a dict.
        defaulted: names of the fields that were absent and took their documented default.
    """

    profile: Profile
    pixels_per_column: int
    columns_per_packet: int
    columns_per_frame: int
    column_window: tuple[int, int]
    lidar_mode: str | None
    frequency_hz: float | None
    beam_altitude_deg: np.ndarray
    beam_azimuth_deg: np.ndarray
    pixel_shift_by_row: np.ndarray
    beam_to_lidar_transform: np.ndarray
    lidar_to_sensor_transform: np.ndarray
    imu_to_sensor_transform: np.ndarray
    lidar_origin_to_beam_origin_mm: float
    lidar_port: int
    imu_port: int
    init_id: int
    serial: str | None
    firmware: str | None
    prod_line: str | None
    raw: dict[str, Any] = field(repr=False, default_factory=dict)
    defaulted: tuple[str, ...] = ()
    path: str | None = None
    imu_profile: str = "LEGACY"
    imu_measurements_per_packet: int = 8
    zm_port: int | None = None
    lidar_enabled: bool = True
    return_order: str = "STRONGEST_TO_WEAKEST"
    timestamp_mode: str | None = None
    azimuth_window: tuple[int, int] | None = None

    # ------------------------------------------------------------------ derived
    @property
    def packet_size(self) -> int:
        """Bytes of one lidar packet (UDP payload) in this profile."""
        return self.profile.packet_size(self.pixels_per_column, self.columns_per_packet)

    @property
    def imu_packet_size(self) -> int | None:
        """Bytes of one IMU packet of ``imu_profile``; ``None`` for a profile lidarpkt does not know."""
        if self.imu_profile == "LEGACY":
            return IMU_PACKET_SIZE
        if self.imu_profile == "ACCEL32_GYRO32_NMEA":
            return imu_packet_dtype(self.imu_measurements_per_packet).itemsize
        return None

    @property
    def zone_packet_size(self) -> int:
        return ZONE_PACKET_SIZE

    @property
    def header_type(self) -> str | None:
        """Packet-header layout: ``"STANDARD"``, ``"FUSA"``, ``None`` for LEGACY lidar packets."""
        return self.profile.header_type

    @property
    def return_labels(self) -> tuple[str, ...]:
        """The label of each return slot of the profile, by ``return_order``."""
        return RETURN_LABELS.get(self.return_order, RETURN_LABELS["STRONGEST_TO_WEAKEST"])[: self.profile.returns]

    @property
    def profile_name(self) -> str:
        return self.profile.name

    @property
    def serial_int(self) -> int | None:
        """``prod_sn`` as the integer the packet header carries, ``None`` if unknown."""
        try:
            return int(self.serial) if self.serial else None
        except ValueError:
            return None

    @property
    def firmware_version(self) -> tuple[int, int, int] | None:
        """(major, minor, patch) from ``build_rev`` or ``image_rev``; ``None`` if neither says."""
        for text in (self.firmware, json_get(self.raw, ("sensor_info", "image_rev"), ("image_rev",))):
            if isinstance(text, str):
                m = _VERSION.search(text)
                if m:
                    return int(m.group(1)), int(m.group(2)), int(m.group(3))
        return None

    @property
    def footer_kind(self) -> str:
        """What the last 8 footer bytes hold: ``"crc"`` (CRC-64/XZ, firmware ≥ 2.5),
        ``"zero"`` (2.2 and earlier), ``"opaque"`` (2.3–2.4: non-zero, not a CRC),
        ``"unknown"`` (firmware not in the metadata), ``"none"`` (LEGACY: no footer)."""
        if self.profile.legacy:
            return "none"
        if self.profile.header_type == "FUSA":  # no CRC in FUSA footers (ouster-sdk: none to check)
            return "zero"
        v = self.firmware_version
        if v is None:
            return "unknown"
        if v >= (2, 5, 0):
            return "crc"
        if v >= (2, 3, 0):
            return "opaque"
        return "zero"

    @property
    def window_mask(self) -> np.ndarray:
        """``bool[W]``: the measurement ids inside ``column_window``."""
        w = self.columns_per_frame
        first, last = self.column_window
        ids = np.arange(w)
        if first <= last:
            return (ids >= first) & (ids <= last)
        return (ids >= first) | (ids <= last)

    def sensor_info(self, source: str | None = None):
        """A :class:`~lidarpkt.core.sensor.SensorInfo` for frames of this sensor, with its XYZ geometry."""
        from lidarpkt.core.sensor import SensorInfo
        from .geometry import OusterGeometry

        mode = {1: "single", 2: "dual"}[self.profile.returns]
        if self.profile.name == "RNG15_RFL8_NIR8":
            mode = "low_data_rate"
        return SensorInfo(
            vendor="ouster",
            model=self.prod_line or f"OS-?-{self.pixels_per_column}",
            rows=self.pixels_per_column,
            columns_per_frame=self.columns_per_frame,
            return_mode=mode,
            return_labels=self.return_labels,
            return_order=self.return_order,
            beam_altitude_deg=self.beam_altitude_deg,
            beam_azimuth_deg=self.beam_azimuth_deg,
            frequency_hz=self.frequency_hz,
            grid_resolution_deg=360.0 / self.columns_per_frame,
            geometry=OusterGeometry(self),
            serial=self.serial,
            firmware=self.firmware,
            profile=self.profile.name,
            init_id=self.init_id,
            pixel_shift_by_row=self.pixel_shift_by_row,
            source=source,
            metadata=self.raw,
        )


def json_get(doc: dict, *paths: tuple[str, ...]) -> Any:
    """First value found along the key paths, else ``None``."""
    for path in paths:
        node: Any = doc
        for key in path:
            if not isinstance(node, dict) or key not in node:
                node = None
                break
            node = node[key]
        if node is not None:
            return node
    return None
