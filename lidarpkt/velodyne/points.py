"""VLP-16 frames as flat point lists, one point per return, in firing order.

The layout follows velodyne_decoder's point records so that clouds can be compared
point for point or handed to PCL-style consumers: ``x, y, z`` (metres, float64),
``intensity`` (reflectivity), ``ring`` (0 = lowest laser, −15°; ``ring = 15 − row``),
``column`` (the frame column: one firing sequence), ``time_ns`` (firing time, ns since the
epoch) and ``return_type``: 1 strongest, 2 last, 3 both (dual mode, the two slots at the same
distance: one point), as velodyne_decoder labels them. Firing order inside a column is laser id
order (laser 0 first).
"""

from __future__ import annotations

import numpy as np

from ..errors import UsageError
from ..frame import Frame
from .geometry import VelodyneGeometry

POINT_DTYPE = np.dtype([
    ("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "u1"), ("ring", "<u2"),
    ("column", "<i8"), ("time_ns", "<i8"), ("return_type", "u1"),
])
STRONGEST, LAST, BOTH = 1, 2, 3
_LABEL_CODE = {"strongest": STRONGEST, "last": LAST}


def frame_points(frame: Frame, *, min_range_m: float | None = None, max_range_m: float | None = None) -> np.ndarray:
    """``POINT_DTYPE[P]`` points of a VLP-16 frame, ordered by column, then laser id, then slot.

    Dual frames give one point with ``return_type`` 3 where both slots hold the same range
    (with slot 1's reflectivity, as velodyne_decoder does), else one point per non-empty
    slot (2 for slot 0 = last, 1 for slot 1).
    ``min_range_m`` / ``max_range_m`` drop points outside that distance (velodyne_decoder
    drops outside 0.1–200 m by default). Raises ``CalibrationError`` without a calibration.
    """
    xyz = frame.xyz()  # [R, 16, W, 3]
    geometry = frame.sensor.geometry
    if not isinstance(geometry, VelodyneGeometry):
        raise UsageError(f"frame_points(frame): a {frame.sensor.vendor} frame; give a Velodyne one")
    r, h, w = frame.shape
    rng = frame.range_mm
    keep = rng > 0
    codes = np.array([_LABEL_CODE.get(lbl, 0) for lbl in frame.return_labels], np.uint8)
    label = np.broadcast_to(codes[:, None, None], rng.shape).copy()
    if r == 2:
        # velodyne_decoder's rule: equal distances are one return, reported with slot 1's
        # (the strongest block's) reflectivity, whatever slot 0's says
        same = (rng[0] == rng[1]) & keep[0]
        label[1][same] = BOTH
        keep[0] &= ~same
    if min_range_m is not None or max_range_m is not None:
        d = geometry.distance_m(frame)
        if min_range_m is not None:
            keep &= d >= min_range_m
        if max_range_m is not None:
            keep &= d <= max_range_m
    # order: column, laser id (firing order), slot
    row_of_laser = np.argsort(geometry.row_laser)
    k = keep[:, row_of_laser, :].transpose(2, 1, 0)  # [W, laser, R]
    cidx, lidx, sidx = np.nonzero(k)
    rows = row_of_laser[lidx]
    out = np.empty(cidx.size, POINT_DTYPE)
    p = xyz[sidx, rows, cidx]
    out["x"], out["y"], out["z"] = p[:, 0], p[:, 1], p[:, 2]
    out["intensity"] = frame.reflectivity[sidx, rows, cidx]
    out["ring"] = h - 1 - rows
    out["column"] = cidx
    toff = frame.pixel_time_offset_ns
    out["time_ns"] = frame.column_timestamp_ns[cidx] + (toff[rows, cidx] if toff is not None else 0)
    out["return_type"] = label[sidx, rows, cidx]
    return out
