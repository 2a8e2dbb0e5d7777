"""Ouster sensor metadata (the JSON from the sensor's ``get_metadata``) in both layouts.

Two layouts exist in the wild:

* the old flat one (firmware ≤ 2.x): top-level ``beam_altitude_angles``, ``lidar_mode``,
  ``data_format`` {...}, ``prod_sn``, ``build_rev`` ...; "reduced" files hold only the beam
  angles and ``lidar_mode``;
* the nested one (firmware ≥ 2.4 / SDK ≥ 0.7): ``sensor_info``, ``config_params``,
  ``lidar_data_format``, ``beam_intrinsics``, ``lidar_intrinsics``, ``imu_intrinsics`` ...

Defaults where a field is absent (those of ouster-sdk for an OS1-64 gen 1, the sensor the
reduced files come from):

========================================  ============================================================
field                                     default
========================================  ============================================================
udp_profile_lidar                         ``LEGACY``
pixels_per_column                         number of beam altitude angles
columns_per_packet                        16
columns_per_frame                         first number of ``lidar_mode`` (``1024x10`` → 1024)
column_window                             ``[0, columns_per_frame - 1]``
pixel_shift_by_row                        ``[3s, 2s, s, 0]`` repeated, s = 6 · columns_per_frame / 1024
lidar_origin_to_beam_origin_mm            12.163
beam_to_lidar_transform                   identity with x translation = lidar_origin_to_beam_origin_mm
lidar_to_sensor_transform                 diag(−1, −1, 1) with z translation 36.18 mm
imu_to_sensor_transform                   identity with translation (6.253, −11.775, 7.645) mm
udp_port_lidar / udp_port_imu             7502 / 7503 (udp_port_lidar 0: the lidar stream is off)
udp_port_zm                               none (zone monitoring off)
udp_profile_imu                           ``LEGACY``
imu_measurements_per_packet               8 (ACCEL32_GYRO32_NMEA)
header_type                               ``FUSA`` for FUSA_RNG15_RFL8_NIR8_DUAL, else ``STANDARD``
return_order                              ``STRONGEST_TO_WEAKEST``
timestamp_mode, azimuth_window            none (as the sensor was set; not needed to decode)
initialization_id, prod_sn                0 / ``None`` (not checked: legacy packets carry neither)
========================================  ============================================================
"""

from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lidarpkt.errors import MetadataError
from .profiles import (
    HEADER_TYPES,
    IMU_PACKET_SIZE,
    ZONE_PACKET_SIZE,
    Profile,
    get_profile,
    imu_packet_dtype,
    with_header,
)

DEFAULT_LIDAR_ORIGIN_TO_BEAM_ORIGIN_MM = 12.163
DEFAULT_LIDAR_TO_SENSOR = np.array([[-1, 0, 0, 0], [0, -1, 0, 0], [0, 0, 1, 36.18], [0, 0, 0, 1]], dtype=np.float64)
DEFAULT_IMU_TO_SENSOR = np.array(
    [[1, 0, 0, 6.253], [0, 1, 0, -11.775], [0, 0, 1, 7.645], [0, 0, 0, 1]], dtype=np.float64
)
DEFAULT_LIDAR_PORT = 7502
DEFAULT_IMU_PORT = 7503
_MODES = re.compile(r"^(\d+)x(\d+)$")
_VERSION = re.compile(r"v(\d+)\.(\d+)\.(\d+)")
_MAX_COLUMNS = 1 << 16  # measurement_id is a u16
_MAX_UDP_PAYLOAD = 65535 - 8  # one UDP datagram (IPv6 without jumbograms; IPv4 allows 65507)


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
        for text in (self.firmware, _get(self.raw, ("sensor_info", "image_rev"), ("image_rev",))):
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


# --------------------------------------------------------------------------- parsing


def _get(doc: dict, *paths: tuple[str, ...]) -> Any:
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


def _where(paths: tuple[tuple[str, ...], ...]) -> str:
    return " or ".join(".".join(p) for p in paths)


def _int(doc: dict, what: str, *paths: tuple[str, ...], default: int | None = None) -> int | None:
    value = _get(doc, *paths)
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise MetadataError(f"metadata field {_where(paths)} ({what}) must be an integer, got {value!r}")
    try:
        number = int(value)
    except ValueError:
        raise MetadataError(f"metadata field {_where(paths)} ({what}) must be an integer, got {value!r}") from None
    if isinstance(value, float) and number != value:
        raise MetadataError(f"metadata field {_where(paths)} ({what}) must be an integer, got {value!r}")
    return number


def _floats(doc: dict, what: str, paths: tuple[tuple[str, ...], ...], shape: tuple[int, ...] | None) -> np.ndarray | None:
    value = _get(doc, *paths)
    if value is None:
        return None
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise MetadataError(f"metadata field {_where(paths)} ({what}) must be a list of numbers") from None
    if shape is not None:
        if arr.size != int(np.prod(shape)):
            raise MetadataError(
                f"metadata field {_where(paths)} ({what}) must hold {int(np.prod(shape))} numbers, got {arr.size}"
            )
        arr = arr.reshape(shape)
    if not np.all(np.isfinite(arr)):
        raise MetadataError(f"metadata field {_where(paths)} ({what}) holds non-finite numbers")
    return arr


_DF = ("lidar_data_format",), ("data_format",)

#: Return-slot labels by ``return_order`` (ouster-sdk's ReturnOrder names, the last two of older firmware).
RETURN_LABELS: dict[str, tuple[str, str]] = {
    "STRONGEST_TO_WEAKEST": ("strongest", "second_strongest"),
    "FARTHEST_TO_NEAREST": ("farthest", "second_farthest"),
    "NEAREST_TO_FARTHEST": ("nearest", "second_nearest"),
    "STRONGEST_RETURN_FIRST": ("strongest", "second_strongest"),
    "LAST_RETURN_FIRST": ("last", "second_last"),
}


def _df(key: str) -> tuple[tuple[str, ...], ...]:
    return tuple(p + (key,) for p in _DF)


def load_metadata(source: str | os.PathLike | dict) -> OusterMetadata:
    """Parse an Ouster metadata JSON (path, JSON text or already-parsed dict), either layout.

    Returns:
        :class:`OusterMetadata`; absent fields get the defaults listed in this module's docstring
        (their names are in ``.defaulted``).

    Raises:
        MetadataError: the file cannot be read or is not JSON, or a field is missing or wrong;
            the message names the field.
    """
    path: str | None = None
    if isinstance(source, dict):
        doc = source
    else:
        text: str
        if isinstance(source, str) and source.lstrip().startswith("{"):
            text = source
        else:
            path = os.fspath(source)
            try:
                text = Path(path).read_text(encoding="utf-8")
            except (OSError, ValueError) as exc:  # ValueError: undecodable bytes, a NUL in the path
                raise MetadataError(f"cannot read Ouster metadata file {path!r}: {exc}") from None
        try:
            doc = json.loads(text)
        except (ValueError, RecursionError) as exc:  # bad JSON, a number of thousands of digits, deep nesting
            raise MetadataError(f"Ouster metadata {path or '(text)'} is not valid JSON: {exc}") from None
    if not isinstance(doc, dict):
        raise MetadataError(f"Ouster metadata {path or ''} must be a JSON object, got {type(doc).__name__}")
    try:
        return _parse(doc, path)
    except MetadataError as exc:
        if path:
            raise MetadataError(f"{path}: {exc}") from None
        raise


def _parse(doc: dict, path: str | None) -> OusterMetadata:
    defaulted: list[str] = []

    alt_paths = (("beam_intrinsics", "beam_altitude_angles"), ("beam_altitude_angles",))
    az_paths = (("beam_intrinsics", "beam_azimuth_angles"), ("beam_azimuth_angles",))
    altitude = _floats(doc, "beam elevation angles, degrees", alt_paths, None)
    azimuth = _floats(doc, "beam azimuth offsets, degrees", az_paths, None)
    if altitude is None:
        raise MetadataError(f"missing field {_where(alt_paths)}: not an Ouster sensor metadata file?")
    if azimuth is None:
        raise MetadataError(f"missing field {_where(az_paths)}")
    altitude = altitude.ravel()
    azimuth = azimuth.ravel()

    profile_name = _get(doc, *_df("udp_profile_lidar"), ("config_params", "udp_profile_lidar"))
    if profile_name is None:
        profile_name = "LEGACY"
        defaulted.append("udp_profile_lidar")
    if not isinstance(profile_name, str):
        raise MetadataError(f"metadata field lidar_data_format.udp_profile_lidar must be text, got {profile_name!r}")
    profile = get_profile(profile_name)
    header_type = _get(doc, *_df("header_type"), ("config_params", "header_type"))  # firmware 3.2+
    if header_type is None:
        header_type = "FUSA" if profile.header_type == "FUSA" else "STANDARD"
        if not profile.legacy:
            defaulted.append("header_type")
    if not isinstance(header_type, str) or header_type not in HEADER_TYPES:
        raise MetadataError(f"metadata field lidar_data_format.header_type {header_type!r}: expected one of {', '.join(HEADER_TYPES)}")
    profile = with_header(profile, header_type)

    lidar_mode = _get(doc, ("config_params", "lidar_mode"), ("lidar_mode",))
    mode_w = mode_hz = None
    if lidar_mode is not None:
        m = _MODES.match(str(lidar_mode))
        if not m:
            raise MetadataError(f"metadata field lidar_mode must look like '1024x10', got {lidar_mode!r}")
        mode_w, mode_hz = int(m.group(1)), int(m.group(2))

    h = _int(doc, "beams", *_df("pixels_per_column"))
    if h is None:
        h = altitude.size
        defaulted.append("pixels_per_column")
    if h <= 0:
        raise MetadataError(f"metadata field lidar_data_format.pixels_per_column must be positive, got {h}")
    if altitude.size != h or azimuth.size != h:
        raise MetadataError(
            f"beam_altitude_angles ({altitude.size}) and beam_azimuth_angles ({azimuth.size}) must have "
            f"pixels_per_column = {h} entries"
        )
    c = _int(doc, "columns per packet", *_df("columns_per_packet"), ("config_params", "columns_per_packet"))
    if c is None:
        c = 16
        defaulted.append("columns_per_packet")
    if c <= 0:
        raise MetadataError(f"metadata field columns_per_packet must be positive, got {c}")
    w = _int(doc, "columns per frame", *_df("columns_per_frame"))
    if w is None:
        if mode_w is None:
            raise MetadataError("missing field lidar_data_format.columns_per_frame (and no lidar_mode to infer it from)")
        w = mode_w
        defaulted.append("columns_per_frame")
    if w <= 0 or w % c:
        raise MetadataError(f"columns_per_frame {w} must be a positive multiple of columns_per_packet {c}")
    if w > _MAX_COLUMNS:  # measurement_id is a u16 on the wire
        raise MetadataError(f"columns_per_frame {w} is more than a packet's 16-bit measurement_id can count ({_MAX_COLUMNS})")
    if profile.packet_size(h, c) > _MAX_UDP_PAYLOAD:
        raise MetadataError(
            f"{profile.name} packets of {c} columns x {h} beams would be {profile.packet_size(h, c)} B, more than a UDP "
            f"datagram holds ({_MAX_UDP_PAYLOAD} B): check pixels_per_column and columns_per_packet"
        )

    window = _get(doc, *_df("column_window"))
    if window is None:
        window = (0, w - 1)
        defaulted.append("column_window")
    if not (isinstance(window, (list, tuple)) and len(window) == 2 and all(isinstance(x, int) for x in window)):
        raise MetadataError(f"metadata field lidar_data_format.column_window must be [first, last], got {window!r}")
    if not all(0 <= x < w for x in window):
        raise MetadataError(f"metadata field lidar_data_format.column_window {window} outside 0..{w - 1}")

    shift = _floats(doc, "stagger in columns", _df("pixel_shift_by_row"), (h,))
    if shift is None:
        s = 6 * w // 1024
        shift = np.resize(np.array([3 * s, 2 * s, s, 0], np.float64), h)
        defaulted.append("pixel_shift_by_row")
    if np.any(shift != np.round(shift)):
        raise MetadataError("metadata field lidar_data_format.pixel_shift_by_row must hold integers")
    if np.any(np.abs(shift) >= w):
        raise MetadataError(f"metadata field lidar_data_format.pixel_shift_by_row must lie within ±{w - 1} columns")

    origin_paths = (("beam_intrinsics", "lidar_origin_to_beam_origin_mm"), ("lidar_origin_to_beam_origin_mm",))
    origin = _floats(doc, "mm", origin_paths, (1,))
    if origin is None:
        origin_mm = DEFAULT_LIDAR_ORIGIN_TO_BEAM_ORIGIN_MM
        defaulted.append("lidar_origin_to_beam_origin_mm")
    else:
        origin_mm = float(origin[0])
    b2l = _floats(doc, "4x4, mm", (("beam_intrinsics", "beam_to_lidar_transform"), ("beam_to_lidar_transform",)), (4, 4))
    if b2l is None:
        b2l = np.eye(4)
        b2l[0, 3] = origin_mm
        defaulted.append("beam_to_lidar_transform")
    l2s = _floats(doc, "4x4, mm", (("lidar_intrinsics", "lidar_to_sensor_transform"), ("lidar_to_sensor_transform",)), (4, 4))
    if l2s is None:
        l2s = DEFAULT_LIDAR_TO_SENSOR.copy()
        defaulted.append("lidar_to_sensor_transform")
    i2s = _floats(doc, "4x4, mm", (("imu_intrinsics", "imu_to_sensor_transform"), ("imu_to_sensor_transform",)), (4, 4))
    if i2s is None:
        i2s = DEFAULT_IMU_TO_SENSOR.copy()
        defaulted.append("imu_to_sensor_transform")

    lidar_port = _int(doc, "UDP port", ("config_params", "udp_port_lidar"), ("udp_port_lidar",))
    imu_port = _int(doc, "UDP port", ("config_params", "udp_port_imu"), ("udp_port_imu",))
    if lidar_port is None:
        lidar_port = DEFAULT_LIDAR_PORT
        defaulted.append("udp_port_lidar")
    if imu_port is None:
        imu_port = DEFAULT_IMU_PORT
        defaulted.append("udp_port_imu")
    init_id = _int(doc, "initialization id", ("sensor_info", "initialization_id"), ("initialization_id",))
    if init_id is None:
        init_id = 0
        defaulted.append("initialization_id")
    if not 0 <= init_id < 1 << 24:
        raise MetadataError(f"metadata field sensor_info.initialization_id {init_id} does not fit the packet's 24 bits")
    for name, port in (("udp_port_lidar", lidar_port), ("udp_port_imu", imu_port)):
        if not 0 <= port <= 65535:
            raise MetadataError(f"metadata field config_params.{name} {port} is not a UDP port (0-65535)")
    serial = _get(doc, ("sensor_info", "prod_sn"), ("prod_sn",))
    if isinstance(serial, (int, str)) and not isinstance(serial, bool) and re.fullmatch(r"\s*[+-]?[0-9]+\s*", str(serial)):
        if len(str(serial).strip()) > 16 or not 0 <= int(serial) < 1 << 40:
            raise MetadataError(f"metadata field sensor_info.prod_sn {serial!r} does not fit the packet's 40-bit serial")
    firmware = _get(doc, ("sensor_info", "build_rev"), ("build_rev",))
    prod_line = _get(doc, ("sensor_info", "prod_line"), ("prod_line",))
    imu_profile = _get(doc, *_df("udp_profile_imu"), ("config_params", "udp_profile_imu"))
    if imu_profile is None:
        imu_profile = "LEGACY"
        defaulted.append("udp_profile_imu")
    # an IMU profile lidarpkt does not know never keeps the lidar data from being decoded: kept by name
    imu_profile = str(imu_profile)
    imu_m = _int(doc, "IMU measurements per packet", ("imu_data_format", "imu_measurements_per_packet"))
    if imu_m is None:
        imu_m = 8
        if imu_profile == "ACCEL32_GYRO32_NMEA":
            defaulted.append("imu_measurements_per_packet")
    # only ACCEL32_GYRO32_NMEA packets are sized by it; firmware writes 0 beside a LEGACY IMU (OSF files of fw 3.x)
    least = 1 if imu_profile == "ACCEL32_GYRO32_NMEA" else 0
    if not least <= imu_m <= 1024:
        raise MetadataError(f"metadata field imu_data_format.imu_measurements_per_packet {imu_m} outside {least}..1024"
                            f" (udp_profile_imu {imu_profile})")
    zm_port = _int(doc, "UDP port", ("config_params", "udp_port_zm"), ("udp_port_zm",))
    if zm_port is not None and not 0 <= zm_port <= 65535:
        raise MetadataError(f"metadata field config_params.udp_port_zm {zm_port} is not a UDP port (0-65535)")
    lidar_off = _get(doc, ("config_params", "udp_port_lidar"), ("udp_port_lidar",)) == 0
    return_order = _get(doc, ("config_params", "return_order"), ("return_order",))
    if return_order is None:
        return_order = "STRONGEST_TO_WEAKEST"
        defaulted.append("return_order")
    if return_order not in RETURN_LABELS:
        raise MetadataError(f"metadata field config_params.return_order {return_order!r}: expected one of {', '.join(RETURN_LABELS)}")
    timestamp_mode = _get(doc, ("config_params", "timestamp_mode"), ("timestamp_mode",))
    azimuth_window = _get(doc, ("config_params", "azimuth_window"), ("azimuth_window",))
    if azimuth_window is not None:
        if not (isinstance(azimuth_window, (list, tuple)) and len(azimuth_window) == 2
                and all(isinstance(x, int) and 0 <= x <= 360000 for x in azimuth_window)):
            raise MetadataError(f"metadata field config_params.azimuth_window must be [first, last] millidegrees in 0..360000, got {azimuth_window!r}")
        azimuth_window = (int(azimuth_window[0]), int(azimuth_window[1]))

    return OusterMetadata(
        profile=profile,
        pixels_per_column=h,
        columns_per_packet=c,
        columns_per_frame=w,
        column_window=(int(window[0]), int(window[1])),
        lidar_mode=str(lidar_mode) if lidar_mode is not None else None,
        frequency_hz=float(mode_hz) if mode_hz else None,
        beam_altitude_deg=altitude,
        beam_azimuth_deg=azimuth,
        pixel_shift_by_row=shift.astype(np.int64),
        beam_to_lidar_transform=b2l,
        lidar_to_sensor_transform=l2s,
        imu_to_sensor_transform=i2s,
        lidar_origin_to_beam_origin_mm=origin_mm,
        lidar_port=lidar_port,
        imu_port=imu_port,
        init_id=init_id,
        serial=str(serial) if serial not in (None, "") else None,
        firmware=str(firmware) if firmware else None,
        prod_line=str(prod_line) if prod_line else None,
        raw=doc,
        defaulted=tuple(defaulted),
        path=path,
        imu_profile=imu_profile,
        imu_measurements_per_packet=imu_m,
        zm_port=zm_port or None,
        lidar_enabled=not lidar_off,
        return_order=str(return_order),
        timestamp_mode=str(timestamp_mode) if timestamp_mode is not None else None,
        azimuth_window=azimuth_window,
    )
