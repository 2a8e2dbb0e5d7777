"""XYZ of Hesai frames, in nebula's frame (the one of Hesai's own SDK).

A pixel of row h (channel ``row_channel[h]``) in a column of block azimuth α lies at azimuth
θ = α + the channel's azimuth offset and elevation ε (the angle-correction CSV), range r::

    x = r · cos ε · sin θ      y = r · cos ε · cos θ      z = r · sin ε

so azimuth is measured clockwise from +y seen from above (x right, y forward, z up), as nebula's
``HesaiDecoder`` writes its points. The beams start at the sensor's origin (no beam offsets).
"""

from __future__ import annotations

import numpy as np

from .calibration import HesaiCalibration


class HesaiGeometry:
    """Points of Hesai frames from their calibration (a :class:`lidarpkt.core.sensor.Geometry`).

    Args:
        calibration: the sensor's angles.
        row_channel: ``int[H]`` channel (0-based) of each frame row.
    """

    def __init__(self, calibration: HesaiCalibration, row_channel: np.ndarray) -> None:
        self.calibration = calibration
        self.row_channel = np.asarray(row_channel)
        el = np.radians(calibration.elevation_deg[self.row_channel])
        self._cos_el, self._sin_el = np.cos(el), np.sin(el)
        self._az_offset_deg = calibration.azimuth_offset_deg[self.row_channel]

    def xyz(self, frame, dtype=np.float64) -> np.ndarray:
        """``[R, H, W, 3]`` metres of ``dtype``, zeros where there is no return."""
        theta = np.radians(frame.azimuth_deg[None, :] + self._az_offset_deg[:, None])  # [H, W]
        unit = np.empty((3,) + theta.shape, np.float64)  # the direction of each pixel's beam
        np.multiply(self._cos_el[:, None], np.sin(theta), out=unit[0])
        np.multiply(self._cos_el[:, None], np.cos(theta), out=unit[1])
        unit[2] = self._sin_el[:, None]
        r_m = frame.range_mm * 1e-3  # [R, H, W] float64
        out = np.empty(frame.range_mm.shape + (3,), dtype)
        for k in range(3):  # one pass per coordinate (a trailing axis of 3 in a broadcast is slower)
            np.multiply(r_m, unit[k], out=out[..., k], casting="same_kind")
        return out
