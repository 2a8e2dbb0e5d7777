"""Frames as Foxglove messages: ``foxglove.PointCloud``, ``foxglove.RawImage``, ``foxglove.FrameTransform``.

Pure functions, no server: the schema classes are foxglove-sdk's own (``foxglove.messages``).

Point cloud of one return slot (one message per slot): the rows of ``Frame.points()`` of that
slot (only the pixels with a return, row-major over ``[H, W]``, Ouster columns staggered as on
the wire), so no point sits on the sensor's origin. Each point is :data:`POINT_DTYPE` (24 bytes,
little-endian):

=============  =======  =================================================================
field          type     meaning
=============  =======  =================================================================
x, y, z        float32  metres, ``Frame.points()`` rounded (the reference tools' sensor frame)
range          uint32   millimetres, ``Frame.range_mm``
reflectivity   uint16   the sensor's reflectivity
row            uint16   image row (0 = top beam)
return         uint8    return slot (index into ``Frame.return_labels``)
=============  =======  =================================================================

Images (one pair per slot): range as ``32FC1`` in metres (0 = no return) and reflectivity as
``mono8`` (VLP-16) or ``mono16``; Ouster images are destaggered for display.
"""

from __future__ import annotations

import numpy as np

POINT_DTYPE = np.dtype({
    "names": ["x", "y", "z", "range", "reflectivity", "row", "return"],
    "formats": ["<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "u1"],
    "offsets": [0, 4, 8, 12, 16, 18, 20],
    "itemsize": 24,
})

BASE_FRAME = "base_link"  # parent of every sensor frame in the view's transforms


def _numeric_types() -> dict:
    from foxglove.messages import PackedElementFieldNumericType as T

    return {np.dtype("<f4"): T.Float32, np.dtype("<u4"): T.Uint32, np.dtype("<u2"): T.Uint16,
            np.dtype("u1"): T.Uint8}


def point_fields() -> list:
    """The ``PackedElementField`` list of :data:`POINT_DTYPE`."""
    from foxglove.messages import PackedElementField

    from lidarpkt.containers.layouts import field_info, field_names

    types = _numeric_types()
    return [PackedElementField(name=name, offset=field_info(POINT_DTYPE, name)[1], type=types[POINT_DTYPE[name]])
            for name in field_names(POINT_DTYPE)]


def timestamp(ns: int):
    """``foxglove.messages.Timestamp`` of an int64 ns time since the epoch."""
    from foxglove.messages import Timestamp

    return Timestamp(int(ns) // 1_000_000_000, int(ns) % 1_000_000_000)


def slot_points(points: np.ndarray, slot: int) -> np.ndarray:
    """The rows of ``points`` (``Frame.points()``, slot-major) of return slot ``slot``: a view."""
    lo, hi = np.searchsorted(points["return_slot"], [slot, slot + 1])
    return points[lo:hi]


def frame_points(frame, slot: int, points: np.ndarray | None = None) -> np.ndarray:
    """``POINT_DTYPE[N]``: the returns of ``frame``'s slot ``slot`` (see the module doc), from
    ``points`` (``frame.points()``, computed here when not given).

    Raises :class:`lidarpkt.errors.CalibrationError` when the sensor has no geometry.
    """
    src = slot_points(frame.points() if points is None else points, slot)
    pts = np.empty(src.size, POINT_DTYPE)
    for name in ("x", "y", "z", "reflectivity", "row"):
        pts[name] = src[name]
    pts["range"] = src["range_mm"]
    pts["return"] = src["return_slot"]
    return pts


def point_cloud(frame, slot: int, frame_id: str, points: np.ndarray | None = None):
    """``foxglove.PointCloud`` of one return slot, stamped with the frame's sensor time; ``points``
    is ``frame.points()`` when already computed."""
    from foxglove.messages import PointCloud, Pose, Quaternion, Vector3

    pts = frame_points(frame, slot, points)
    origin = Pose(position=Vector3(x=0.0, y=0.0, z=0.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    return PointCloud(timestamp=timestamp(frame.timestamp_ns), frame_id=frame_id, pose=origin,
                      point_stride=POINT_DTYPE.itemsize, fields=point_fields(), data=pts.tobytes())


def _display(frame, image: np.ndarray) -> np.ndarray:
    return frame.destaggered(image)  # unchanged for a frame without a stagger


def images(frame, slot: int, frame_id: str) -> tuple:
    """``(range, reflectivity)`` ``foxglove.RawImage`` of one return slot (see the module doc)."""
    from foxglove.messages import RawImage

    h, w = frame.shape[1:]
    stamp = timestamp(frame.timestamp_ns)
    range_m = np.ascontiguousarray(_display(frame, frame.range_mm[slot]).astype("<f4") * np.float32(1e-3))
    refl = _display(frame, frame.reflectivity[slot])
    if refl.dtype.itemsize == 1:
        refl, encoding = np.ascontiguousarray(refl, np.uint8), "mono8"
    else:
        refl, encoding = np.ascontiguousarray(refl, "<u2"), "mono16"
    return (RawImage(timestamp=stamp, frame_id=frame_id, width=w, height=h, encoding="32FC1", step=4 * w,
                     data=range_m.tobytes()),
            RawImage(timestamp=stamp, frame_id=frame_id, width=w, height=h, encoding=encoding,
                     step=refl.itemsize * w, data=refl.tobytes()))


def transform(frame, frame_id: str, parent: str = BASE_FRAME):
    """``foxglove.FrameTransform`` placing the sensor frame at the origin of ``parent`` (identity)."""
    from foxglove.messages import FrameTransform, Quaternion, Vector3

    return FrameTransform(timestamp=timestamp(frame.timestamp_ns), parent_frame_id=parent, child_frame_id=frame_id,
                          translation=Vector3(x=0.0, y=0.0, z=0.0), rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
