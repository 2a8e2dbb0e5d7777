"""Ouster sensor metadata read from its JSON (the sensor's ``get_metadata``), in both layouts: :func:`load_metadata`.

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
from pathlib import Path

import numpy as np

from lidarpkt.errors import MetadataError
from .profiles import HEADER_TYPES, get_profile, with_header
from .metadata import (DEFAULT_IMU_PORT, DEFAULT_IMU_TO_SENSOR, DEFAULT_LIDAR_ORIGIN_TO_BEAM_ORIGIN_MM,
                       DEFAULT_LIDAR_PORT, DEFAULT_LIDAR_TO_SENSOR, RETURN_LABELS, OusterMetadata, json_get)

_MODES = re.compile(r"^(\d+)x(\d+)$")
_MAX_COLUMNS = 1 << 16  # measurement_id is a u16
_MAX_UDP_PAYLOAD = 65535 - 8  # one UDP datagram (IPv6 without jumbograms; IPv4 allows 65507)


def _where(paths: tuple[tuple[str, ...], ...]) -> str:
    return " or ".join(".".join(p) for p in paths)


def _int(doc: dict, what: str, *paths: tuple[str, ...], default: int | None = None) -> int | None:
    value = json_get(doc, *paths)
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
    value = json_get(doc, *paths)
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

    profile_name = json_get(doc, *_df("udp_profile_lidar"), ("config_params", "udp_profile_lidar"))
    if profile_name is None:
        profile_name = "LEGACY"
        defaulted.append("udp_profile_lidar")
    if not isinstance(profile_name, str):
        raise MetadataError(f"metadata field lidar_data_format.udp_profile_lidar must be text, got {profile_name!r}")
    profile = get_profile(profile_name)
    header_type = json_get(doc, *_df("header_type"), ("config_params", "header_type"))  # firmware 3.2+
    if header_type is None:
        header_type = "FUSA" if profile.header_type == "FUSA" else "STANDARD"
        if not profile.legacy:
            defaulted.append("header_type")
    if not isinstance(header_type, str) or header_type not in HEADER_TYPES:
        raise MetadataError(f"metadata field lidar_data_format.header_type {header_type!r}: expected one of {', '.join(HEADER_TYPES)}")
    profile = with_header(profile, header_type)

    lidar_mode = json_get(doc, ("config_params", "lidar_mode"), ("lidar_mode",))
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

    window = json_get(doc, *_df("column_window"))
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
    serial = json_get(doc, ("sensor_info", "prod_sn"), ("prod_sn",))
    if isinstance(serial, (int, str)) and not isinstance(serial, bool) and re.fullmatch(r"\s*[+-]?[0-9]+\s*", str(serial)):
        if len(str(serial).strip()) > 16 or not 0 <= int(serial) < 1 << 40:
            raise MetadataError(f"metadata field sensor_info.prod_sn {serial!r} does not fit the packet's 40-bit serial")
    firmware = json_get(doc, ("sensor_info", "build_rev"), ("build_rev",))
    prod_line = json_get(doc, ("sensor_info", "prod_line"), ("prod_line",))
    imu_profile = json_get(doc, *_df("udp_profile_imu"), ("config_params", "udp_profile_imu"))
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
    lidar_off = json_get(doc, ("config_params", "udp_port_lidar"), ("udp_port_lidar",)) == 0
    return_order = json_get(doc, ("config_params", "return_order"), ("return_order",))
    if return_order is None:
        return_order = "STRONGEST_TO_WEAKEST"
        defaulted.append("return_order")
    if not isinstance(return_order, str) or return_order not in RETURN_LABELS:
        raise MetadataError(f"metadata field config_params.return_order {return_order!r}: expected one of {', '.join(RETURN_LABELS)}")
    timestamp_mode = json_get(doc, ("config_params", "timestamp_mode"), ("timestamp_mode",))
    azimuth_window = json_get(doc, ("config_params", "azimuth_window"), ("azimuth_window",))
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
