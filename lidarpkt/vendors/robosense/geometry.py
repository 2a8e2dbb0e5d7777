"""XYZ of RoboSense frames, in the frame of RoboSense's own drivers (rs_driver, nebula): x forward at
azimuth 0, y left, z up; azimuths grow clockwise seen from above.

A laser of elevation ε and azimuth offset δ (the DIFOP's or the angle CSV's), fired at azimuth α
(``frame.extra["azimuth_cdeg"]``, 0.01°), with distance d::

    θ = α + δ
    x = d · cos ε · cos θ + RX · cos α      y = −d · cos ε · sin θ − RX · sin α      z = d · sin ε + RZ

(RX, RZ: the model's lens centre; :attr:`RobosenseModel.lens_rx_m`). d is the exact distance, the
raw value times the model's unit (a 2.5 mm unit does not fit the frame's whole millimetres; the raw
value is recovered from them exactly). Pixels without a return are zeros.
"""

from __future__ import annotations

import numpy as np

from lidarpkt.errors import CalibrationError
from .calibration import RobosenseCalibration


class RobosenseGeometry:
    """Points of RoboSense frames from a calibration (a :class:`lidarpkt.core.frame.Geometry`).

    Args:
        calibration: the sensor's angles, one per laser.
        row_laser: ``int[H]`` laser of each frame row.
        unit_um: µm per raw distance unit.
        lens_rx_m, lens_rz_m: the model's lens centre.
    """

    def __init__(self, calibration: RobosenseCalibration, row_laser: np.ndarray, unit_um: int, lens_rx_m: float,
                 lens_rz_m: float) -> None:
        self.calibration = calibration
        self.row_laser = np.asarray(row_laser)
        self.unit_um = int(unit_um)
        self.lens_rx_m = float(lens_rx_m)
        self.lens_rz_m = float(lens_rz_m)
        el = np.radians(calibration.elevation_deg[self.row_laser])
        self._cos_el = np.cos(el)[:, None]
        self._sin_el = np.sin(el)[:, None]
        self._offset_deg = calibration.azimuth_offset_deg[self.row_laser][:, None]

    def distance_m(self, range_mm: np.ndarray) -> np.ndarray:
        """``float64[...]`` exact distance, metres, of ``range_mm`` (the frame's rounded millimetres)."""
        raw = (np.asarray(range_mm, np.int64) * 1000) // self.unit_um
        return raw * (self.unit_um * 1e-6)

    def xyz(self, frame, dtype=np.float64) -> np.ndarray:
        """``[R, H, W, 3]`` metres of ``dtype``, zeros where there is no return.

        Raises :class:`~lidarpkt.errors.CalibrationError` for a frame without per-firing azimuths."""
        try:
            alpha_cdeg = frame.extra["azimuth_cdeg"]
        except KeyError:
            raise CalibrationError("RoboSense frame without per-firing azimuths (extra['azimuth_cdeg'])") from None
        alpha = np.radians(np.asarray(alpha_cdeg, np.float64) / 100.0)  # [H, W]
        theta = alpha + np.radians(self._offset_deg)
        d = self.distance_m(frame.range_mm)  # [R, H, W]
        hit = frame.range_mm > 0
        out = np.empty(frame.range_mm.shape + (3,), dtype)
        horizontal = d * self._cos_el
        rx = self.lens_rx_m
        np.multiply(horizontal, np.cos(theta), out=out[..., 0], casting="same_kind")
        np.multiply(horizontal, -np.sin(theta), out=out[..., 1], casting="same_kind")
        np.multiply(d, self._sin_el, out=out[..., 2], casting="same_kind")
        if rx:
            out[..., 0] += np.where(hit, rx * np.cos(alpha), 0.0)
            out[..., 1] -= np.where(hit, rx * np.sin(alpha), 0.0)
        if self.lens_rz_m:
            out[..., 2] += np.where(hit, self.lens_rz_m, 0.0)
        return out
