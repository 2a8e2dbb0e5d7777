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

from lidarpkt.core import kernels
from lidarpkt.errors import CalibrationError
from .calibration import VelodyneCalibration, load_calibration
from .models import VLP16, VelodyneModel


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
    """XYZ of VLP-16 frames for one calibration (the ``Geometry`` of :class:`~lidarpkt.core.frame.Frame`).

    Raises :class:`CalibrationError` for a frame without per-firing azimuths.
    """

    def __init__(self, calibration: VelodyneCalibration | str | None = None, model: VelodyneModel = VLP16) -> None:
        self.model = model
        self.calibration = load_calibration(calibration, model)
        cal = self.calibration
        if cal.lasers != model.lasers:
            raise CalibrationError(f"{cal.source}: a calibration of {cal.lasers} lasers for a {model.name}, "
                                   f"which has {model.lasers}; pass the sensor's own calibration")
        # VelodyneCalibration.__post_init__ fills every per-laser table (None: zeros)
        assert cal.dist_correction_m is not None and cal.vert_offset_m is not None
        assert cal.horiz_offset_m is not None and cal.rot_correction_rad is not None
        order = cal.rows_to_laser  # laser id of each row
        self.row_laser = order
        omega = cal.vert_correction_rad[order]
        # metres per millimetre of range_mm (range_mm = raw × the model's unit; the file's resolution scales raw)
        unit_mm = round(model.distance_resolution_m * 1000)
        mm = cal.distance_resolution_m / unit_mm
        if model is not VLP16 and model.sequences_per_block != 2:
            # the manual's unit, whatever the file says: nebula's VLS128.yaml says 0.007 m for the VLS-128's 4 mm
            mm = model.distance_resolution_m / unit_mm
        lasers = model.lasers
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
        # a table per row up to 32 rows (9 MB each... of 16 for a VLP-16); beyond, cos/sin of the azimuth
        # combined with each row's correction per pixel
        self._cos, self._neg_sin = _trig_tables(tuple(rot.tolist()) if self._per_row and lasers <= 16 else None)
        self._rows = np.arange(lasers)[:, None]
        self._rot = rot[:, None]
        self._two_point = bool(np.any(cal.two_point))
        # the compiled kernel's per-row coefficients (k_xy, k_z, dc_xy, dc_z, vert_offset) and switches
        self._coef = np.ascontiguousarray(np.stack([self._k_xy[:, 0], self._k_z[:, 0], self._dc_xy[:, 0],
                                                    self._dc_z[:, 0], self._vert_offset[:, 0]]), np.float64)
        self._coef_rot = np.ascontiguousarray(np.concatenate([self._coef, np.cos(self._rot).T, np.sin(self._rot).T]))
        self._has_dist = bool(np.any(self._dist_correction))
        self._has_voff = bool(np.any(self._vert_offset))
        # the kernel has no horizontal-offset or two-point term: a calibration with one takes the NumPy path
        self._kernel_coef = (None if np.any(self._horiz_offset) or self._two_point
                             else self._coef_rot if self._per_row and self._cos.ndim == 1 else self._coef)

    def distance_m(self, frame) -> np.ndarray:
        """``float64[R, L, W]`` corrected distance, metres (0 stays 0)."""
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
        coef = self._kernel_coef  # with one table, each row's correction is combined per pixel (_coef_rot)
        # one fused pass (the same operations as _points, in C): 2-3x fewer passes over [R, 16, W]
        if (native is not None and coef is not None and rng.ndim == 3 and rng.shape[1] == len(self.row_laser)
                and np.shape(az_cdeg) == rng.shape[1:]):
            out = np.empty(rng.shape + (3,), dtype=np.float64)
            native.velodyne_xyz(_rows_contiguous(rng, np.uint32), _rows_contiguous(az_cdeg, np.uint16),
                                self._cos, self._neg_sin, coef, self._has_dist, self._has_voff, out)
            return out
        idx = np.asarray(az_cdeg, dtype=np.intp)
        if self._cos.ndim == 2:
            cos_a, neg_sin_a = self._cos[self._rows, idx], self._neg_sin[self._rows, idx]  # [16, W]
        else:
            cos_a, neg_sin_a = self._cos[idx], self._neg_sin[idx]
            if self._per_row:  # cos(a − r) = cos a cos r + sin a sin r; −sin(a − r) = −sin a cos r + cos a sin r
                cr, sr = np.cos(self._rot), np.sin(self._rot)
                cos_a, neg_sin_a = cos_a * cr - neg_sin_a * sr, neg_sin_a * cr + cos_a * sr
        out = np.empty(rng.shape + (3,), dtype=np.float64)
        self._points(rng, cos_a, neg_sin_a, out)
        return out

    def _points(self, rng: np.ndarray, cos_a: np.ndarray, neg_sin_a: np.ndarray, out: np.ndarray) -> None:
        """XYZ of ``rng`` (``[R, 16, W]``, slots sharing the ``[16, W]`` azimuths) into ``out[..., 3]``.

        Computing both dual slots outright is as fast as reusing slot 0 where they agree (measured).
        """
        if self._two_point:
            self._points_two_point(rng, cos_a, neg_sin_a, out)
            return
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

    def _points_two_point(self, rng: np.ndarray, cos_a: np.ndarray, neg_sin_a: np.ndarray, out: np.ndarray) -> None:
        """XYZ with the HDL-64E S3 manual's two-point distance correction: below 25.04 m the correction of each
        axis is interpolated between the near-point one (dist_correction_x at 2.40 m sideways, _y at 1.93 m
        forward) and the far one (dist_correction), z taking the mean of the two (as velodyne_decoder and the
        ROS driver do; the manual's z uses y's, taken for a slip)."""
        cal = self.calibration
        order = self.row_laser
        two = cal.two_point[order][:, None]
        dc = self._dist_correction
        assert cal.dist_correction_x_m is not None and cal.dist_correction_y_m is not None  # filled (zeros)
        dcx = cal.dist_correction_x_m[order][:, None]
        dcy = cal.dist_correction_y_m[order][:, None]
        omega = cal.vert_correction_rad[order][:, None]
        cos_w, sin_w = np.cos(omega), np.sin(omega)
        hit = rng > 0
        d = rng * self._metres_per_mm  # measured distance, m
        sin_a = -neg_sin_a
        xy = (d + dc) * cos_w
        near = two & (d < 25.04)
        x_coeff = (np.abs(xy * sin_a) - 2.40) / (25.04 - 2.40)
        y_coeff = (np.abs(xy * cos_a) - 1.93) / (25.04 - 1.93)
        cx = np.where(near, x_coeff * dc + (1 - x_coeff) * dcx, dc)
        cy = np.where(near, y_coeff * dc + (1 - y_coeff) * dcy, dc)
        cz = np.where(near, (cx + cy) / 2, dc)
        h = self._horiz_offset
        out[..., 0] = ((d + cy) * cos_w * cos_a + h * sin_a) * hit
        out[..., 1] = (-(d + cx) * cos_w * sin_a + h * cos_a) * hit
        out[..., 2] = ((d + cz) * sin_w + self._vert_offset) * hit


def _rows_contiguous(a: np.ndarray, dtype: type) -> np.ndarray:
    """``a`` as ``dtype`` with contiguous rows (its last axis), as the compiled kernel takes it: a frame's
    views of its columns as they are, anything else copied."""
    a = np.asarray(a)
    if a.dtype == dtype and a.strides[-1] == a.itemsize:
        return a
    return np.ascontiguousarray(a, dtype)
