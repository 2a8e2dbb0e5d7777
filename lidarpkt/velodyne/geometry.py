"""VLP-16 points from a frame, in the ROS driver / velodyne_decoder convention (x forward, y left, z up).

For a firing of laser l at azimuth α (0.01° from the packet, interpolated per firing) and
raw distance r::

    d = r · distance_resolution + dist_correction[l]
    a = α − rot_correction[l]
    x = d · cos ω_l · cos a + h_l · sin a,   y = −d · cos ω_l · sin a + h_l · cos a,
    z = d · sin ω_l + vert_offset[l]

with h = horiz_offset_correction (the beam origin's sideways offset, the HDL-64E S3
manual's formulas), which is velodyne_decoder 3.1.0's model for VLP-16 calibrations (it
agrees with it within float32 rounding, far below 1 mm). The two-point distance correction
(dist_correction_x/y) is not modelled: :func:`load_calibration` refuses it.
"""

from __future__ import annotations

import functools

import numpy as np

from .. import kernels
from ..errors import CalibrationError
from .calibration import VelodyneCalibration, load_calibration


@functools.lru_cache(maxsize=8)
def _trig_tables(rot: tuple[float, ...] | None) -> tuple[np.ndarray, np.ndarray]:
    """cos and −sin of (azimuth − rot_correction) for every 0.01° azimuth: ``[36000]`` (no rotation
    corrections) or ``[16, 36000]`` per row (y = −d·cos ω·sin a: the table holds −sin so that no pass
    is spent on the sign). Read-only and shared by every geometry of the same corrections: 0.6 MB
    (9 MB per row) per decoder made a capture with thousands of source addresses use gigabytes."""
    az = np.radians(np.arange(36000) / 100.0)
    if rot is None:
        cos, neg_sin = np.cos(az), -np.sin(az)
    else:
        r = np.asarray(rot)[:, None]
        cos, neg_sin = np.cos(az[None, :] - r), -np.sin(az[None, :] - r)
    cos.flags.writeable = False
    neg_sin.flags.writeable = False
    return cos, neg_sin


class VelodyneGeometry:
    """XYZ of VLP-16 frames for one calibration (the ``Geometry`` of :class:`~lidarpkt.frame.Frame`).

    Raises :class:`CalibrationError` for a frame without per-firing azimuths.
    """

    def __init__(self, calibration: VelodyneCalibration | str | None = None) -> None:
        self.calibration = load_calibration(calibration)
        cal = self.calibration
        # VelodyneCalibration.__post_init__ fills every per-laser table (None: zeros)
        assert cal.dist_correction_m is not None and cal.vert_offset_m is not None
        assert cal.horiz_offset_m is not None and cal.rot_correction_rad is not None
        order = cal.rows_to_laser  # laser id of each row
        self.row_laser = order
        omega = cal.vert_correction_rad[order]
        mm = cal.distance_resolution_m / 2.0  # metres per millimetre of range_mm (range_mm = raw × 2)
        self._metres_per_mm = mm
        self._k_xy = (mm * np.cos(omega))[:, None]  # [16, 1]: range_mm → horizontal distance
        self._k_z = (mm * np.sin(omega))[:, None]
        self._dist_correction = cal.dist_correction_m[order][:, None]
        self._dc_xy = self._dist_correction * np.cos(omega)[:, None]
        self._dc_z = self._dist_correction * np.sin(omega)[:, None]
        self._vert_offset = cal.vert_offset_m[order][:, None]
        self._horiz_offset = cal.horiz_offset_m[order][:, None]
        rot = cal.rot_correction_rad[order]
        self._per_row = bool(np.any(rot != 0))
        self._cos, self._neg_sin = _trig_tables(tuple(rot.tolist()) if self._per_row else None)
        self._rows = np.arange(16)[:, None]
        # the compiled kernel's per-row coefficients (k_xy, k_z, dc_xy, dc_z, vert_offset) and switches
        self._coef = np.ascontiguousarray(np.stack([self._k_xy[:, 0], self._k_z[:, 0], self._dc_xy[:, 0],
                                                    self._dc_z[:, 0], self._vert_offset[:, 0]]), np.float64)
        self._has_dist = bool(np.any(self._dist_correction))
        self._has_voff = bool(np.any(self._vert_offset))

    def distance_m(self, frame) -> np.ndarray:
        """``float64[R, 16, W]`` corrected distance, metres (0 stays 0)."""
        rng = frame.range_mm
        return np.where(rng > 0, rng * self._metres_per_mm + self._dist_correction, 0.0)

    def xyz(self, frame, dtype: "np.typing.DTypeLike" = np.float64) -> np.ndarray:
        """``[R, 16, W, 3]`` metres of ``dtype`` (float32: the float64 points rounded); zeros where the
        range is 0 (no return or no sample).

        Uses ``frame.extra["azimuth_cdeg"]`` (``uint16[16, W]``, per-firing azimuth).
        """
        out = self._xyz64(frame)
        return out if np.dtype(dtype) == np.float64 else out.astype(dtype)

    def _xyz64(self, frame) -> np.ndarray:
        try:
            az_cdeg = frame.extra["azimuth_cdeg"]
        except KeyError:
            raise CalibrationError("VLP-16 frame without per-firing azimuths (extra['azimuth_cdeg'])") from None
        rng = frame.range_mm
        native = kernels.native
        # one fused pass (the same operations as _points, in C): 2-3x fewer passes over [R, 16, W]; the
        # kernel has no horizontal-offset term, so a calibration with one takes the NumPy path
        if (native is not None and rng.ndim == 3 and rng.shape[1] == 16 and np.shape(az_cdeg) == rng.shape[1:]
                and not np.any(self._horiz_offset)):
            out = np.empty(rng.shape + (3,), dtype=np.float64)
            native.velodyne_xyz(np.ascontiguousarray(rng, np.uint32), np.ascontiguousarray(az_cdeg, np.uint16),
                                self._cos, self._neg_sin, self._coef, self._has_dist, self._has_voff, out)
            return out
        idx = np.asarray(az_cdeg, dtype=np.intp)
        if self._per_row:
            cos_a, neg_sin_a = self._cos[self._rows, idx], self._neg_sin[self._rows, idx]  # [16, W]
        else:
            cos_a, neg_sin_a = self._cos[idx], self._neg_sin[idx]
        out = np.empty(rng.shape + (3,), dtype=np.float64)
        self._points(rng, cos_a, neg_sin_a, out)
        return out

    def _points(self, rng: np.ndarray, cos_a: np.ndarray, neg_sin_a: np.ndarray, out: np.ndarray) -> None:
        """XYZ of ``rng`` (``[R, 16, W]``, slots sharing the ``[16, W]`` azimuths) into ``out[..., 3]``.

        Computing both dual slots outright is as fast as reusing slot 0 where they agree (measured).
        """
        k_xy, k_z, dc_xy, dc_z, voff = self._k_xy, self._k_z, self._dc_xy, self._dc_z, self._vert_offset
        hit = rng > 0
        dxy = rng * k_xy  # horizontal distance, metres
        dz = rng * k_z
        if np.any(self._dist_correction):
            dxy += hit * dc_xy
            dz += hit * dc_z
        np.multiply(dxy, cos_a, out=out[..., 0])
        np.multiply(dxy, neg_sin_a, out=out[..., 1])
        if np.any(self._horiz_offset):
            h = hit * self._horiz_offset  # the offset is perpendicular to the beam: (sin a, cos a)
            out[..., 0] -= h * neg_sin_a
            out[..., 1] += h * cos_a
        if np.any(self._vert_offset):
            dz += voff
            dz *= hit
        out[..., 2] = dz
