"""VLP-16 points from a frame, in the ROS driver / velodyne_decoder convention (x forward, y left, z up).

For a firing of laser l at azimuth α (0.01° from the packet, interpolated per firing) and
raw distance r::

    d = r · distance_resolution + dist_correction[l]
    a = α − rot_correction[l]
    x = d · cos ω_l · cos a,   y = −d · cos ω_l · sin a,   z = d · sin ω_l + vert_offset[l]

which is velodyne_decoder 3.1.0's model for VLP-16 calibrations (it agrees with it
within float32 rounding, far below 1 mm).
"""

from __future__ import annotations

import numpy as np

from ..errors import CalibrationError
from .calibration import VelodyneCalibration, load_calibration


class VelodyneGeometry:
    """XYZ of VLP-16 frames for one calibration (the ``Geometry`` of :class:`~lidarpkt.frame.Frame`).

    Raises :class:`CalibrationError` for a calibration with horizontal offsets (a model
    only multi-bank Velodynes use; not implemented here).
    """

    def __init__(self, calibration: VelodyneCalibration | str | None = None) -> None:
        self.calibration = load_calibration(calibration)
        cal = self.calibration
        if np.any(cal.horiz_offset_m != 0):
            raise CalibrationError(
                f"{cal.source}: horiz_offset_correction is set; lidarpkt's VLP-16 geometry does not model "
                "horizontal beam offsets (set them to 0 or use the stock calibration)"
            )
        order = cal.rows_to_laser  # laser id of each row
        self.row_laser = order
        omega = cal.vert_correction_rad[order]
        self._cos_omega = np.cos(omega)[:, None]  # [16, 1]
        self._sin_omega = np.sin(omega)[:, None]
        self._rot = cal.rot_correction_rad[order][:, None]
        self._vert_offset = cal.vert_offset_m[order][:, None]
        self._dist_correction = cal.dist_correction_m[order][:, None]
        self._metres_per_mm = cal.distance_resolution_m / 2.0  # range_mm = raw × 2

    def distance_m(self, frame) -> np.ndarray:
        """``float64[R, 16, W]`` corrected distance, metres (0 stays 0)."""
        rng = frame.range_mm
        return np.where(rng > 0, rng * self._metres_per_mm + self._dist_correction, 0.0)

    def xyz(self, frame) -> np.ndarray:
        """``float64[R, 16, W, 3]`` metres; zeros where the range is 0 (no return or no sample).

        Uses ``frame.extra["azimuth_cdeg"]`` (``uint16[16, W]``, per-firing azimuth).
        """
        try:
            az_cdeg = frame.extra["azimuth_cdeg"]
        except KeyError:
            raise CalibrationError("VLP-16 frame without per-firing azimuths (extra['azimuth_cdeg'])") from None
        rng = frame.range_mm
        d = rng * self._metres_per_mm + self._dist_correction  # [R, 16, W]
        a = np.radians(az_cdeg / 100.0) - self._rot  # [16, W]
        cos_a, sin_a = np.cos(a), np.sin(a)
        out = np.empty(rng.shape + (3,), dtype=np.float64)
        dxy = d * self._cos_omega
        out[..., 0] = dxy * cos_a
        out[..., 1] = -dxy * sin_a
        out[..., 2] = d * self._sin_omega + self._vert_offset
        out[rng == 0] = 0.0
        return out
