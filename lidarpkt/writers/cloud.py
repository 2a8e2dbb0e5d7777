"""PLY (plyfile) and PCD (pypcd4): one binary point cloud file per frame, for PCL and ROS users.

``out`` is a folder; each frame is ``STEM_SENSOR_FRAMEID.ply`` / ``.pcd`` (named by capture stem,
sensor and frame id, so the names do not depend on how the capture was segmented). One point per
return slot that holds a return, *as the sensor sent it* (a dual-return pixel whose two slots
repeat one return is two points, told apart by ``return``); pixels with no return are left out.
Points are the rows of ``Frame.points()``, in its order (slot, then row, then column; Ouster
columns staggered, as sent). Fields, as the ROS drivers name them (the MCAP ``PointCloud2`` values):

=========  =======  ===============================================================================
field      type     meaning
=========  =======  ===============================================================================
x, y, z    float32  metres, ``Frame.xyz()``
intensity  float32  VLP-16: the reflectivity byte; Ouster: signal (as the ROS drivers publish)
ring       uint16   VLP-16: 0 = the lowest beam (= 15 − row); Ouster: beam index (= row)
time       float32  seconds after the frame's first column (the frame's timestamp)
return     uint8    the return slot (index in ``Frame.return_labels``); dual-return frames only
=========  =======  ===============================================================================
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from lidarpkt.containers.layouts import field_names
from .base import BaseWriter

FIELDS = ("x", "y", "z", "intensity", "ring", "time")


def cloud_points(frame) -> np.ndarray:
    """The points of one frame as a structured array with the fields of the module doc: the rows of
    ``frame.points()``, in its order, as the ``PointCloud2`` writer names them.

    Raises :class:`~lidarpkt.errors.CalibrationError` when the sensor has no calibration."""
    from .mcap.pointcloud import cloud_fields

    pts = frame.points()
    fields = cloud_fields(frame, pts)
    dual = frame.shape[0] > 1
    dtype = np.dtype([(n, fields.dtype[n]) for n in FIELDS] + ([("return", "u1")] if dual else []))
    out = np.empty(pts.size, dtype)
    for n in FIELDS:
        out[n] = fields[n]
    if dual:
        out["return"] = pts["return_slot"]
    return out


class _PerFrameWriter(BaseWriter):
    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None) -> None:
        super().__init__(out, capture=capture, part=part)
        self.out_dir()

    def _write(self, frame) -> None:
        pts = cloud_points(frame)
        final = self.out / self.frame_file_name(frame, self.suffix)
        tmp = self.files.temporary(final)
        with open(tmp, "wb") as fh:
            self._dump(pts, fh)
        self.files.commit(tmp)
        self.points_written += pts.size

    def _finish(self) -> None:
        pass  # every file was renamed into place when its frame was written

    def _dump(self, pts: np.ndarray, fh) -> None:  # pragma: no cover - abstract
        raise NotImplementedError


class PlyWriter(_PerFrameWriter):
    """Binary little-endian PLY, one ``vertex`` element per frame (plyfile)."""

    suffix = ".ply"

    def _dump(self, pts: np.ndarray, fh) -> None:
        from plyfile import PlyData, PlyElement

        PlyData([PlyElement.describe(pts, "vertex")], text=False, byte_order="<",
                comments=["lidarpkt"]).write(fh)


class PcdWriter(_PerFrameWriter):
    """Binary PCD v0.7 (pypcd4), unorganised (``HEIGHT 1``)."""

    suffix = ".pcd"

    def _dump(self, pts: np.ndarray, fh) -> None:
        from pypcd4 import PointCloud

        names = field_names(pts.dtype)
        cloud = PointCloud.from_points([pts[n] for n in names], names, [pts.dtype[n] for n in names])
        cloud.save(fh)
