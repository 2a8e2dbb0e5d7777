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

import functools

import numpy as np

from lidarpkt.errors import CalibrationError
from .calibration import RobosenseCalibration


@functools.lru_cache(maxsize=1)
def trig_tables() -> tuple[np.ndarray, np.ndarray]:
    """cos and sin of every azimuth in whole 0.01°: ``float64[36000]`` each, read-only, shared."""
    az = np.radians(np.arange(36000) / 100.0)
    cos, sin = np.cos(az), np.sin(az)
    cos.flags.writeable = False
    sin.flags.writeable = False
    return cos, sin


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
        self._sin_el = np.sin(el)[:, None]
        offset = np.radians(calibration.azimuth_offset_deg[self.row_laser])
        # x and −y of a unit range: cos ε·cos(α + δ) = A·cos α − B·sin α, cos ε·sin(α + δ) = A·sin α + B·cos α
        self._a = (np.cos(el) * np.cos(offset))[:, None]
        self._b = (np.cos(el) * np.sin(offset))[:, None]

    def distance_m(self, range_mm: np.ndarray) -> np.ndarray:
        """``float64[...]`` exact distance, metres, of ``range_mm`` (the frame's rounded millimetres)."""
        if self.unit_um % 1000 == 0:  # whole millimetres: range_mm is exact
            return np.asarray(range_mm) * 1e-3
        raw = (np.asarray(range_mm, np.int64) * 1000) // self.unit_um
        return raw * (self.unit_um * 1e-6)

    def xyz(self, frame, dtype=np.float64) -> np.ndarray:
        """``[R, H, W, 3]`` metres of ``dtype``, zeros where there is no return.

        Raises :class:`~lidarpkt.errors.CalibrationError` for a frame without per-firing azimuths."""
        try:
            alpha_cdeg = frame.extra["azimuth_cdeg"]
        except KeyError:
            raise CalibrationError("RoboSense frame without per-firing azimuths (extra['azimuth_cdeg'])") from None
        cos_table, sin_table = trig_tables()
        index = np.asarray(alpha_cdeg, np.intp)
        cos_a, sin_a = cos_table[index], sin_table[index]  # [H, W]
        kx = np.multiply(cos_a, self._a)
        tmp = np.multiply(sin_a, self._b)
        kx -= tmp
        ky = np.multiply(sin_a, self._a)
        np.multiply(cos_a, self._b, out=tmp)
        ky += tmp
        np.negative(ky, out=ky)
        d = self.distance_m(frame.range_mm)  # [R, H, W]
        out = np.empty(frame.range_mm.shape + (3,), dtype)
        np.multiply(d, kx, out=out[..., 0], casting="same_kind")
        np.multiply(d, ky, out=out[..., 1], casting="same_kind")
        np.multiply(d, self._sin_el, out=out[..., 2], casting="same_kind")
        if self.lens_rx_m or self.lens_rz_m:  # the beam starts at the lens centre; no return stays zeros
            hit = frame.range_mm > 0
            if self.lens_rx_m:
                np.multiply(cos_a, self.lens_rx_m, out=cos_a)
                np.multiply(sin_a, -self.lens_rx_m, out=sin_a)
                np.add(out[..., 0], cos_a, out=out[..., 0], where=hit, casting="same_kind")
                np.add(out[..., 1], sin_a, out=out[..., 1], where=hit, casting="same_kind")
            if self.lens_rz_m:
                np.add(out[..., 2], self.lens_rz_m, out=out[..., 2], where=hit, casting="same_kind")
        return out
