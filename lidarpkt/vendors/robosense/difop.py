"""DIFOP packets: what a RoboSense sensor says of itself once a second (device information output).

:func:`decode_difop` reads one DIFOP through the model's layout (:mod:`lidarpkt.vendors.robosense.packet`)
into a :class:`DeviceInfo`: motor speed, field of view, return mode, firmware, serial number,
network settings, the sensor's time, and its own calibration, the corrected vertical and horizontal
angle of each laser (a sign byte, 0 positive and 1 negative, and a magnitude in the model's unit:
0.01°, 0.001° on the RS-LiDAR-32; the RS-LiDAR-16 sends unsigned 24-bit pitches in 0.0001°, its
channels 1-8 pointing down). A DIFOP whose identifier, tail, return mode or angles are impossible
(a sign byte other than 0 or 1, an elevation beyond ±90°, an azimuth offset beyond ±180°) is
refused: :func:`decode_difop` returns ``None`` and the decoder counts it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from . import packet as P
from .decode import time_ns
from .models import RobosenseModel


@dataclass(frozen=True, eq=False)
class DeviceInfo:
    """One DIFOP's contents.

    Attributes:
        motor_speed_rpm: the set rotation speed (300, 600, 1200).
        return_mode: the return-mode byte (:attr:`RobosenseModel.return_modes`).
        fov_start_deg, fov_end_deg: the azimuth window with valid data, degrees.
        elevation_deg, azimuth_offset_deg: ``float64[lasers]`` the sensor's own calibration.
        time_ns: the sensor's time, ns since the epoch (0 where the field is impossible).
        serial_number: hex text; firmware: the version fields as hex text, by name.
        ethernet: addresses and ports as sent.
    """

    motor_speed_rpm: int
    return_mode: int
    fov_start_deg: float
    fov_end_deg: float
    elevation_deg: np.ndarray
    azimuth_offset_deg: np.ndarray
    time_ns: int
    serial_number: str
    firmware: dict[str, str] = field(default_factory=dict)
    ethernet: dict[str, Any] = field(default_factory=dict)

    def describe(self) -> dict[str, Any]:
        """A JSON-ready summary for ``lidarpkt info``."""
        return {"motor_speed_rpm": self.motor_speed_rpm, "return_mode_byte": self.return_mode,
                "fov_deg": [self.fov_start_deg, self.fov_end_deg], "serial_number": self.serial_number,
                "firmware": dict(self.firmware), **self.ethernet}


def angles_deg(angles: np.ndarray, unit_mdeg: float) -> tuple[np.ndarray, bool]:
    """``(float64[K] degrees, possible)`` of ``[K]`` :data:`~lidarpkt.vendors.robosense.packet.ANGLE` fields."""
    sign = angles["sign"]
    value = angles["value"].astype(np.float64) * unit_mdeg / 1000.0
    return np.where(sign == 1, -value, value), bool(np.all(sign <= 1))


def _hex(raw: np.ndarray) -> str:
    return bytes(np.asarray(raw, np.uint8)).hex()


def decode_difop(row: np.ndarray, model: RobosenseModel) -> DeviceInfo | None:
    """The :class:`DeviceInfo` of one DIFOP payload (``uint8[1248]``) of ``model``, ``None`` when its
    identifier, tail, return mode or angles are impossible."""
    row = np.asarray(row, np.uint8).reshape(1, -1)
    if row.shape[1] != P.PACKET_SIZE:
        return None
    d = P.as_packets(row, model.difop_layout)[0]
    if bytes(d["header_id"]) != P.DIFOP_ID or int(d["tail"]) != P.DIFOP_TAIL:
        return None
    mode = int(d["return_mode"])
    if mode not in model.return_modes:
        return None
    lasers = model.lasers
    names = model.difop_layout.names or ()
    if "pitch_calibration" in names:
        pitch = P.be_uint(d["pitch_calibration"]).astype(np.float64) * model.difop_angle_unit_mdeg / 1000.0
        elevation = np.where(np.arange(16) < 8, -pitch, pitch)
        azimuth = np.zeros(16)
        ok = True
    else:
        elevation, ok_v = angles_deg(d["vertical_angles"][:lasers], model.difop_angle_unit_mdeg)
        azimuth, ok_h = angles_deg(d["horizontal_angles"][:lasers], model.difop_angle_unit_mdeg)
        ok = ok_v and ok_h
    if not (ok and np.all(np.abs(elevation) <= 90.0) and np.all(np.abs(azimuth) < 180.0)):
        return None
    stamp, stamp_ok = time_ns(np.asarray(d["time"]).reshape(1))
    eth = d["ethernet"]
    firmware = {"top_firmware_version": _hex(d["top_firmware_version"]),
                "bottom_firmware_version": _hex(d["bottom_firmware_version"])}
    for name in ("bottom_software_version", "motor_firmware_version", "hardware_version", "software_version"):
        if name in names:
            firmware[name] = _hex(np.asarray(d[name]).reshape(-1).view(np.uint8))
    return DeviceInfo(
        motor_speed_rpm=int(d["motor_speed"]), return_mode=mode, fov_start_deg=int(d["fov_start"]) / 100.0,
        fov_end_deg=int(d["fov_end"]) / 100.0, elevation_deg=elevation, azimuth_offset_deg=azimuth,
        time_ns=int(stamp[0]) if stamp_ok[0] else 0, serial_number=_hex(d["serial_number"]), firmware=firmware,
        ethernet={"lidar_ip": ".".join(str(int(v)) for v in eth["lidar_ip"]),
                  "msop_port": int(eth["pc_msop_port"]), "difop_port": int(eth["pc_difop_port"])},
    )
