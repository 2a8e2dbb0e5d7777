"""Frames as ROS 2 messages: organised ``sensor_msgs/PointCloud2`` and ``sensor_msgs/Image``.

One point cloud per return slot. The cloud is organised: ``height`` = H rows (row 0 = the
top beam, as in :class:`lidarpkt.core.frame.Frame`), ``width`` = W columns; clouds and images of
staggered frames are destaggered (as ouster-ros publishes them), the others keep the firing order.
Pixels without a return (range 0, or a column no packet delivered) have NaN x, y, z, and the
cloud's ``is_dense`` is false (the ROS convention for an organised cloud: viewers skip them
instead of drawing them on the sensor's origin); their other fields say what the image says of
the pixel (its row, its column's time, the sensor's reflectivity). The returns are the rows of
``Frame.points()``, the same as every other point output. The ``header.frame_id`` is the sensor's
(:class:`lidarpkt.writers.mcap.frames.SensorFrames`; by default its vendor's driver's, ``velodyne`` / ``os_sensor``).

Point fields (the layout is :data:`POINT_DTYPE`; the PointField list derives from it):

=================  =========  ==================================================================
field              type       meaning
=================  =========  ==================================================================
x, y, z            float32    metres, the reference tools' frame (``Frame.points()``); NaN: no return
intensity          float32    VLP-16: calibrated reflectivity (as the ROS driver); Ouster: signal
reflectivity       uint16     the sensor's reflectivity byte
ring               uint16     VLP-16: ring as the ROS driver (0 = lowest beam, = 15 − row);
                              Ouster: beam index (= row)
time               float32    seconds after ``header.stamp`` (the frame's first column)
range              uint32     millimetres (0 = no return)
=================  =========  ==================================================================
"""

from __future__ import annotations

import dataclasses
import struct

import numpy as np

from lidarpkt.core.ros import Topic
from lidarpkt.core.vendor import FrameTopics
from lidarpkt.containers import rosmsgs
from . import schemas

POINT_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("reflectivity", "<u2"),
     ("ring", "<u2"), ("time", "<f4"), ("range", "<u4")]
)

# sensor_msgs/PointField datatype codes
_DATATYPE = {np.dtype("<f4"): 7, np.dtype("<u2"): 4, np.dtype("<u4"): 6, np.dtype("<f8"): 8, np.dtype("u1"): 2}


def _frame_topics(frame) -> FrameTopics:
    from lidarpkt.vendors import registry

    return registry.vendor(frame.sensor.vendor).ros.frames


def default_frame_id(vendor: str) -> str:
    """The default coordinate frame of a ``vendor`` sensor: its ROS driver's (``velodyne``, ``os_sensor``)."""
    from lidarpkt.vendors import registry

    return registry.vendor(vendor).ros.frames.frame_id


def point_fields() -> list:
    """The ``sensor_msgs/msg/PointField`` list of :data:`POINT_DTYPE`."""
    pf = rosmsgs.typestore().types["sensor_msgs/msg/PointField"]
    from lidarpkt.containers.layouts import field_info, field_names

    return [pf(name=name, offset=field_info(POINT_DTYPE, name)[1], datatype=_DATATYPE[POINT_DTYPE[name]],
               count=1) for name in field_names(POINT_DTYPE)]


def _display(frame, image: np.ndarray) -> np.ndarray:
    """``[..., H, W]`` image in display order: destaggered for a staggered frame, unchanged otherwise."""
    return frame.destaggered(image)


def cloud_fields(frame, points: np.ndarray) -> np.ndarray:
    """``POINT_DTYPE[N]``: rows of ``frame.points()`` as the ROS drivers name and type their fields
    (see the module doc), in the same order."""
    out = np.empty(points.size, POINT_DTYPE)
    out["x"], out["y"], out["z"] = points["x"], points["y"], points["z"]
    out["reflectivity"] = points["reflectivity"]
    ros = _frame_topics(frame)
    intensity = ros.intensity if ros.intensity in (points.dtype.names or ()) else "reflectivity"
    out["intensity"] = points[intensity]
    out["ring"] = (frame.shape[1] - 1 - points["row"]) if ros.ring_from_bottom else points["row"]
    out["time"] = (points["timestamp_ns"] - frame.timestamp_ns).astype(np.float64) * 1e-9
    out["range"] = points["range_mm"]
    return out


def frame_points(frame, points: np.ndarray | None = None) -> np.ndarray:
    """``POINT_DTYPE[R, H, W]`` organised points of ``frame`` in display order (see module doc).

    Every pixel is a point, filled field by field from the frame's images in whole-array passes: the
    returns (:meth:`Frame.has_return`) with the values of :func:`cloud_fields` of their ``frame.points()``
    row, the other pixels with NaN x, y, z, range 0 and what the image says of the pixel (its
    reflectivity and signal, its row, its firing time: the column's, or the frame's where no packet
    delivered the column). x, y, z are ``frame.xyz()`` rounded to float32, or taken from ``points``
    (``frame.points()``) when given.
    Raises :class:`lidarpkt.errors.CalibrationError` when the sensor has no calibration.
    """
    r, h, w = frame.shape
    hit = frame.has_return()
    grid = np.empty((r, h, w), POINT_DTYPE)
    if points is None:
        xyz = frame.xyz()
        for i, name in enumerate(("x", "y", "z")):
            grid[name] = xyz[..., i]
            np.copyto(grid[name], np.float32(np.nan), where=~hit)
    else:  # the rows of points() are hit's pixels in C order
        flat = np.flatnonzero(hit)
        for name in ("x", "y", "z"):
            grid[name] = np.nan
            grid[name].reshape(-1)[flat] = points[name]
    t0 = frame.timestamp_ns
    t = np.where(np.asarray(frame.column_valid, bool), frame.column_timestamp_ns, t0)
    t = t + frame.pixel_time_offset_ns if frame.pixel_time_offset_ns is not None else np.broadcast_to(t, (h, w))
    grid["time"] = (t - t0).astype(np.float64) * 1e-9  # one [H, W] image for every slot
    grid["reflectivity"] = frame.reflectivity
    ros = _frame_topics(frame)
    intensity = getattr(frame, ros.intensity, None)  # the image the vendor's driver names, where the frame has it
    grid["intensity"] = frame.reflectivity if intensity is None else intensity
    row = np.arange(h, dtype=np.uint16)[:, None]
    grid["ring"] = (h - 1 - row) if ros.ring_from_bottom else row
    grid["range"] = frame.range_mm
    np.copyto(grid["range"], 0, where=~hit)
    return _display(frame, grid)


def pointcloud_messages(frame, points: np.ndarray | None = None, *,
                        frame_id: str | None = None) -> list[tuple[Topic, object]]:
    """``(topic, PointCloud2)`` for each return slot of ``frame``; ``header.stamp`` = sensor time,
    ``header.frame_id`` = ``frame_id`` (default: the vendor's, :func:`default_frame_id`); ``points`` is
    ``frame.points()`` when already computed."""
    pts = frame_points(frame, points)
    store = rosmsgs.typestore()
    pc2 = store.types[schemas.POINTCLOUD2]
    r, h, w = pts.shape
    fields = point_fields()
    hdr = rosmsgs.header(frame.timestamp_ns, frame_id or default_frame_id(frame.sensor.vendor))
    out = []
    for slot in range(r):
        data = np.ascontiguousarray(pts[slot]).view(np.uint8).reshape(-1)
        dense = not np.isnan(pts["x"][slot]).any()
        msg = pc2(header=hdr, height=h, width=w, fields=fields, is_bigendian=False,
                  point_step=POINT_DTYPE.itemsize, row_step=POINT_DTYPE.itemsize * w, data=data, is_dense=dense)
        out.append((schemas.points_topic(frame.sensor.vendor, slot), msg))
    return out


def pointcloud_cdr(msg) -> tuple[bytes, np.ndarray, bytes]:
    """The CDR of a ``sensor_msgs/PointCloud2`` message (the bytes :func:`lidarpkt.containers.rosmsgs.encode`
    gives, encapsulation included) in three pieces: what comes before the points (header, fields, steps, the
    data's length), ``msg.data`` itself (``uint8[N]``, not copied) and what follows it (``is_dense``).

    Raises ValueError when ``msg.data`` is not a contiguous ``uint8`` array."""
    data = msg.data
    if not (isinstance(data, np.ndarray) and data.dtype == np.uint8 and data.ndim == 1 and data.flags.c_contiguous):
        raise ValueError("PointCloud2 data must be a contiguous uint8[N] array")
    cdr = rosmsgs.encode(schemas.POINTCLOUD2, dataclasses.replace(msg, data=_NO_POINTS))
    # uint8[] data: its uint32 length (here 0, 4-aligned), no bytes; then the bool is_dense, the last field
    return cdr[:-5] + struct.pack("<I", data.size), data, cdr[-1:]


_NO_POINTS = np.zeros(0, np.uint8)


def image_messages(frame, *, frame_id: str | None = None) -> list[tuple[Topic, object]]:
    """Range (``32FC1``, metres) and reflectivity (``mono8``) images of each return slot."""
    store = rosmsgs.typestore()
    img = store.types[schemas.IMAGE]
    r, h, w = frame.shape
    hdr = rosmsgs.header(frame.timestamp_ns, frame_id or default_frame_id(frame.sensor.vendor))
    rng_m = _display(frame, frame.range_mm).astype("<f4") * np.float32(1e-3)
    refl = _display(frame, frame.reflectivity).astype(np.uint8)
    out = []
    for slot in range(r):
        out.append((schemas.image_topic(frame.sensor.vendor, "range", slot),
                    img(header=hdr, height=h, width=w, encoding="32FC1", is_bigendian=0, step=4 * w,
                        data=np.ascontiguousarray(rng_m[slot]).view(np.uint8).reshape(-1))))
        out.append((schemas.image_topic(frame.sensor.vendor, "reflectivity", slot),
                    img(header=hdr, height=h, width=w, encoding="mono8", is_bigendian=0, step=w,
                        data=np.ascontiguousarray(refl[slot]).reshape(-1))))
    return out
