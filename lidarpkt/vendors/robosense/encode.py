"""The inverse of :func:`lidarpkt.vendors.robosense.decode_packets` and :func:`~lidarpkt.vendors.robosense.difop.decode_difop`:
RoboSense MSOP and DIFOP packets from their fields, through the same layouts
(:mod:`lidarpkt.vendors.robosense.packet`), for round-trip tests and generated captures. Header ids,
block flags, tails and the model fields that name the model follow from the model.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import PacketFormatError
from . import packet as P
from .decode import RANGE_RESOLUTION_UM
from .models import RobosenseModel


def _utc(stamp: np.ndarray, timestamp_ns: np.ndarray) -> None:
    ns = np.asarray(timestamp_ns, np.int64)
    seconds, rest = np.divmod(ns, 1_000_000_000)
    for k in range(6):
        stamp["seconds"][:, 5 - k] = (seconds >> (8 * k)) & 0xFF
    stamp["microseconds"] = rest // 1000


def _ymd(stamp: np.ndarray, timestamp_ns: np.ndarray) -> None:
    seconds, rest = np.divmod(np.asarray(timestamp_ns, np.int64), 1_000_000_000)
    t = seconds.astype("datetime64[s]")
    month_start = t.astype("datetime64[M]")
    year = t.astype("datetime64[Y]").astype(np.int64) + 1970
    if np.any((year < 2000) | (year > 2255)):
        raise PacketFormatError("timestamps outside the years 2000-2255 the year-month-day field holds")
    sod = seconds - t.astype("datetime64[D]").astype("datetime64[s]").astype(np.int64)
    stamp["year"], stamp["month"] = year - 2000, month_start.astype(np.int64) % 12 + 1
    stamp["day"] = (t.astype("datetime64[D]") - month_start.astype("datetime64[D]")).astype(np.int64) + 1
    stamp["hour"], stamp["minute"], stamp["second"] = sod // 3600, sod // 60 % 60, sod % 60
    stamp["millisecond"], stamp["microsecond"] = rest // 1_000_000, rest // 1000 % 1000


def set_time(stamp: np.ndarray, timestamp_ns: np.ndarray) -> None:
    """Write ``int64[N]`` ns since the epoch (to the µs) into UTC or year-month-day time fields."""
    if "seconds" in (stamp.dtype.names or ()):
        _utc(stamp, timestamp_ns)
    else:
        _ymd(stamp, timestamp_ns)


def encode_packets(model: RobosenseModel, *, azimuth_cdeg: np.ndarray, distance: np.ndarray,
                   reflectivity: np.ndarray, timestamp_ns: np.ndarray, ret_id: np.ndarray | None = None,
                   wave_mode: int | np.ndarray | None = None, distance_unit_um: int | None = None,
                   packet_count: np.ndarray | None = None, name_model: bool = True) -> np.ndarray:
    """``uint8[N, 1248]`` MSOP packets of ``model``.

    Args:
        azimuth_cdeg: ``[N, B]`` block azimuths, 0.01°; distance, reflectivity: ``[N, B, S]``.
        timestamp_ns: ``[N]`` packet times, ns since the epoch (to the µs).
        ret_id: RS-Ruby ``[N, B]`` which return each block holds (1 by default); wave_mode: RS-Ruby 1 or 3.
        distance_unit_um: the Helios family's unit (2500 or 5000; 2500 by default).
        packet_count: ``[N]`` the header's packet counter where the model has one (0, 1, 2 ... by default).
        name_model: write the model fields that name the model (False: zeros, as some units send).

    Raises :class:`~lidarpkt.errors.PacketFormatError` for shapes, units or times the model cannot carry.
    """
    az = np.asarray(azimuth_cdeg)
    n = az.shape[0]
    shape = (n, model.blocks, model.channels)
    if az.shape != shape[:2] or np.shape(distance) != shape or np.shape(reflectivity) != shape:
        raise PacketFormatError(f"an {model.name} packet has {model.blocks} blocks of {model.channels} channels")
    p = np.zeros(n, model.layout)
    h = p["header"]
    ident = P.MSOP_ID_V1 if model.family == "v1" else P.MSOP_ID_V2
    h["header_id"] = np.frombuffer(ident, np.uint8)
    set_time(h["timestamp"], timestamp_ns)
    if name_model:
        for field, value in model.codes[0] if model.codes else ():
            h[field] = value
        if model.family == "helios":
            h["lidar_type"] = 0x06
        if model.family == "ruby":
            h["lidar_type"] = dict(model.codes[0])["lidar_type"]
    if model.family == "helios":
        unit = 2500 if distance_unit_um is None else int(distance_unit_um)
        codes = {v: k for k, v in RANGE_RESOLUTION_UM.items()}
        if unit not in codes:
            raise PacketFormatError(f"the {model.name}'s distance unit is 2.5 or 5 mm, not {unit / 1000} mm")
        h["range_resolution"] = codes[unit]
        h["protocol_version"] = 1
    elif distance_unit_um is not None and distance_unit_um != model.distance_unit_um:
        raise PacketFormatError(f"the {model.name}'s distance unit is {(model.distance_unit_um or 0) / 1000} mm")
    if model.packet_counter is not None:
        h[model.packet_counter] = np.arange(n) if packet_count is None else packet_count
    blocks = p["blocks"]
    blocks["azimuth"] = az
    blocks["channels"]["distance"] = distance
    blocks["channels"]["reflectivity"] = reflectivity
    if model.family == "ruby":
        blocks["flag"] = P.RUBY_BLOCK_FLAG
        blocks["ret_id"] = 1 if ret_id is None else ret_id
        h["wave_mode"] = 1 if wave_mode is None else wave_mode
    else:
        blocks["flag"] = P.BLOCK_FLAG
        p["tail"]["tail"] = P.MSOP_TAIL
    return p.view(np.uint8).reshape(n, P.PACKET_SIZE).copy()


def encode_difop(model: RobosenseModel, *, return_mode: int, elevation_deg: np.ndarray,
                 azimuth_offset_deg: np.ndarray | None = None, motor_speed_rpm: int = 600, time_ns: int = 0,
                 serial_number: bytes = b"\x00" * 6, fov_deg: tuple[float, float] = (0.0, 360.0)) -> np.ndarray:
    """One ``uint8[1248]`` DIFOP packet of ``model``: its return-mode byte, rotation speed and calibration
    (degrees, rounded to the model's unit).

    Raises :class:`~lidarpkt.errors.PacketFormatError` for angles of another count or beyond the fields."""
    d = np.zeros(1, model.difop_layout)[0]
    d["header_id"] = np.frombuffer(P.DIFOP_ID, np.uint8)
    d["tail"] = P.DIFOP_TAIL
    d["motor_speed"] = motor_speed_rpm
    d["return_mode"] = return_mode
    d["fov_start"], d["fov_end"] = round(fov_deg[0] * 100), round(fov_deg[1] * 100)
    d["serial_number"] = np.frombuffer(serial_number, np.uint8)
    eth = d["ethernet"]
    eth["pc_msop_port"], eth["pc_difop_port"] = 6699, 7788
    eth["lidar_msop_port"], eth["lidar_difop_port"] = 6699, 7788
    if time_ns:  # 0: the field left zero, as a sensor that has no time yet sends it
        stamp = np.zeros(1, d["time"].dtype)
        set_time(stamp, np.array([time_ns]))
        d["time"] = stamp[0]
    el = np.asarray(elevation_deg, np.float64)
    az = np.zeros_like(el) if azimuth_offset_deg is None else np.asarray(azimuth_offset_deg, np.float64)
    if el.shape != (model.lasers,) or az.shape != el.shape:
        raise PacketFormatError(f"an {model.name} DIFOP holds {model.lasers} angles of each kind")
    unit = model.difop_angle_unit_mdeg / 1000.0
    names = model.difop_layout.names or ()
    if "pitch_calibration" in names:
        value = np.rint(np.abs(el) / unit).astype(np.int64)
        if np.any(value >= 1 << 24) or np.any((el < 0) != (np.arange(16) < 8)):
            raise PacketFormatError("an RS-LiDAR-16 DIFOP holds channels 1-8 pointing down, 9-16 up")
        for k in range(3):
            d["pitch_calibration"][:, 2 - k] = (value >> (8 * k)) & 0xFF
    else:
        for field, angles in (("vertical_angles", el), ("horizontal_angles", az)):
            value = np.rint(np.abs(angles) / unit).astype(np.int64)
            if np.any(value > 0xFFFF):
                raise PacketFormatError(f"{field}: an angle beyond the field's ±{0xFFFF * unit}°")
            d[field]["sign"][: model.lasers] = angles < 0
            d[field]["value"][: model.lasers] = value
    return np.frombuffer(d.tobytes(), np.uint8).copy()
