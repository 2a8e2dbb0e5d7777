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

from lidarpkt.errors import UsageError
from lidarpkt.core.frame import Frame
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
    drops outside 0.1–200 m by default). The points are rows of ``frame.points()`` in
    velodyne_decoder's layout and order. Raises ``CalibrationError`` without a calibration.
    """
    pts = frame.points()
    geometry = frame.sensor.geometry
    if not isinstance(geometry, VelodyneGeometry):
        raise UsageError(f"frame_points(frame): a {frame.sensor.vendor} frame; give a Velodyne one")
    slot, row, col = pts["return_slot"], pts["row"], pts["column"]
    codes = np.array([_LABEL_CODE.get(lbl, 0) for lbl in frame.return_labels], np.uint8)
    label = codes[slot]
    keep = np.ones(pts.size, bool)
    if frame.shape[0] == 2:
        # velodyne_decoder's rule: equal distances are one return, reported with slot 1's
        # (the strongest block's) reflectivity, whatever slot 0's says
        same = frame.range_mm[1 - slot, row, col] == pts["range_mm"]
        label = np.where(same & (slot == 1), BOTH, label).astype(np.uint8)
        keep &= ~(same & (slot == 0))
    if min_range_m is not None or max_range_m is not None:
        d = geometry.distance_m(frame)[slot, row, col]
        if min_range_m is not None:
            keep &= d >= min_range_m
        if max_range_m is not None:
            keep &= d <= max_range_m
    laser = np.asarray(geometry.row_laser)[row]
    order = np.flatnonzero(keep)
    order = order[np.lexsort((slot[order], laser[order], col[order]))]  # column, laser id (firing order), slot
    pts, label = pts[order], label[order]
    out = np.empty(pts.size, POINT_DTYPE)
    out["x"], out["y"], out["z"] = pts["x"], pts["y"], pts["z"]
    out["intensity"] = pts["reflectivity"]
    out["ring"] = frame.shape[1] - 1 - pts["row"].astype(np.int64)
    out["column"] = pts["column"]
    out["time_ns"] = pts["timestamp_ns"]
    out["return_type"] = label
    return out
