"""Frames as ROS 2 messages: organised ``sensor_msgs/PointCloud2`` and ``sensor_msgs/Image``.

One point cloud per return slot. The cloud is organised: ``height`` = H rows (row 0 = the
top beam, as in :class:`lidarpkt.frame.Frame`), ``width`` = W columns; Ouster clouds and
images are destaggered (as ouster-ros publishes them), VLP-16 ones keep the firing order.
Pixels without a return (range 0, or a column no packet delivered) have NaN x, y, z, and the
cloud's ``is_dense`` is false (the ROS convention for an organised cloud: viewers skip them
instead of drawing them on the sensor's origin). The ``header.frame_id`` is the sensor's
(:class:`lidarpkt.writers.mcap.frames.SensorFrames`; by default ``velodyne`` / ``os_sensor``).

Point fields (the layout is :data:`POINT_DTYPE`; the PointField list derives from it):

=================  =========  ==================================================================
field              type       meaning
=================  =========  ==================================================================
x, y, z            float32    metres, the reference tools' frame (``Frame.xyz()``); NaN: no return
intensity          float32    VLP-16: calibrated reflectivity (as the ROS driver); Ouster: signal
reflectivity       uint16     the sensor's reflectivity byte
ring               uint16     VLP-16: ring as the ROS driver (0 = lowest beam, = 15 − row);
                              Ouster: beam index (= row)
time               float32    seconds after ``header.stamp`` (the frame's first column)
range              uint32     millimetres (0 = no return)
=================  =========  ==================================================================
"""

from __future__ import annotations

import numpy as np

from . import schemas

POINT_DTYPE = np.dtype(
    [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("reflectivity", "<u2"),
     ("ring", "<u2"), ("time", "<f4"), ("range", "<u4")]
)

# sensor_msgs/PointField datatype codes
_DATATYPE = {np.dtype("<f4"): 7, np.dtype("<u2"): 4, np.dtype("<u4"): 6, np.dtype("<f8"): 8, np.dtype("u1"): 2}

FRAME_IDS = {"velodyne": "velodyne", "ouster": "os_sensor"}


def point_fields() -> list:
    """The ``sensor_msgs/msg/PointField`` list of :data:`POINT_DTYPE`."""
    pf = schemas.typestore().types["sensor_msgs/msg/PointField"]
    from lidarpkt.sources.layouts import field_info, field_names

    return [pf(name=name, offset=field_info(POINT_DTYPE, name)[1], datatype=_DATATYPE[POINT_DTYPE[name]],
               count=1) for name in field_names(POINT_DTYPE)]


def _display(frame, image: np.ndarray) -> np.ndarray:
    """``[..., H, W]`` image in display order: destaggered for Ouster, unchanged otherwise."""
    return frame.destaggered(image) if frame.sensor.vendor == "ouster" else image


def frame_points(frame, xyz: np.ndarray | None = None) -> np.ndarray:
    """``POINT_DTYPE[R, H, W]`` points of ``frame`` in display order (see module doc).

    ``xyz`` defaults to ``frame.xyz()`` (raises :class:`lidarpkt.errors.CalibrationError`
    when the sensor has no calibration).
    """
    r, h, w = frame.shape
    if xyz is None:
        xyz = frame.xyz()
    pts = np.zeros((r, h, w), POINT_DTYPE)
    xyz = _display(frame, np.moveaxis(xyz, -1, 0))  # [3, R, H, W] so the last two axes are (H, W)
    no_return = _display(frame, (frame.range_mm == 0) | ~frame.column_valid)
    pts["x"], pts["y"], pts["z"] = (np.where(no_return, np.float32(np.nan), c) for c in xyz)
    refl = _display(frame, frame.reflectivity)
    pts["reflectivity"] = refl
    if frame.sensor.vendor == "ouster" and frame.signal is not None:
        pts["intensity"] = _display(frame, frame.signal)
    else:
        pts["intensity"] = refl
    rows = np.arange(h, dtype=np.uint16)[:, None]
    pts["ring"] = (h - 1 - rows) if frame.sensor.vendor == "velodyne" else rows
    t_ns = np.where(frame.column_valid, frame.column_timestamp_ns - frame.timestamp_ns, 0)[None, :]
    if frame.pixel_time_offset_ns is not None:
        t_ns = t_ns + frame.pixel_time_offset_ns
    pts["time"] = _display(frame, np.broadcast_to(t_ns, (h, w)).astype(np.float64) * 1e-9)
    pts["range"] = _display(frame, frame.range_mm)
    return pts


def pointcloud_messages(frame, xyz: np.ndarray | None = None, *,
                        frame_id: str | None = None) -> list[tuple[schemas.Topic, object]]:
    """``(topic, PointCloud2)`` for each return slot of ``frame``; ``header.stamp`` = sensor time,
    ``header.frame_id`` = ``frame_id`` (default: the vendor's, :data:`FRAME_IDS`)."""
    pts = frame_points(frame, xyz)
    store = schemas.typestore()
    pc2 = store.types[schemas.POINTCLOUD2]
    r, h, w = pts.shape
    fields = point_fields()
    hdr = schemas.header(frame.timestamp_ns, frame_id or FRAME_IDS.get(frame.sensor.vendor, frame.sensor.vendor))
    out = []
    for slot in range(r):
        data = np.ascontiguousarray(pts[slot]).view(np.uint8).reshape(-1)
        dense = not np.isnan(pts["x"][slot]).any()
        msg = pc2(header=hdr, height=h, width=w, fields=fields, is_bigendian=False,
                  point_step=POINT_DTYPE.itemsize, row_step=POINT_DTYPE.itemsize * w, data=data, is_dense=dense)
        out.append((schemas.points_topic(frame.sensor.vendor, slot), msg))
    return out


def image_messages(frame, *, frame_id: str | None = None) -> list[tuple[schemas.Topic, object]]:
    """Range (``32FC1``, metres) and reflectivity (``mono8``) images of each return slot."""
    store = schemas.typestore()
    img = store.types[schemas.IMAGE]
    r, h, w = frame.shape
    hdr = schemas.header(frame.timestamp_ns, frame_id or FRAME_IDS.get(frame.sensor.vendor, frame.sensor.vendor))
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
