"""Rerun recordings (``.rrd``, rerun-sdk: the ``rerun`` extra): each frame's points, coloured, and its images.

``lidarpkt decode drive.pcap -o drive.rrd``, ``export --format rrd``, or from Python::

    with open_writer("rrd", "drive.rrd", capture="drive.pcap", color="reflectivity") as w:
        for frame in lidarpkt.open("drive.pcap"):
            w.write(frame)

then ``rerun drive.rrd`` (the viewer rerun-sdk installs). ``lidarpkt view --rerun`` shows a capture or
a live sensor in the viewer with the same entities (:mod:`lidarpkt.view.rerun`).

Entities, per sensor ``NAME`` (its vendor, then ``NAME_2`` … for further sensors of that vendor) and
return slot ``LABEL`` (``strongest``, ``last``, ``second_strongest`` …, as ``Frame.return_labels``):

=================================  ==============  ==================================================
entity                             archetype       content
=================================  ==============  ==================================================
``/NAME/points/LABEL``             ``Points3D``    the slot's rows of ``Frame.points()``: x, y, z in
                                                   metres (float32), coloured by range or reflectivity
``/NAME/range_image/LABEL``        ``DepthImage``  ``range_mm`` (uint32, ``meter`` = 1000), turbo
                                                   colour map; Ouster images destaggered
``/NAME/reflectivity_image/LABEL`` ``Image``       the reflectivity byte (grey, ``L``)
=================================  ==============  ==================================================

Timelines: ``frame`` (the frame id) and ``sensor_time`` (the frame's first valid column, ns since
the Unix epoch): each frame is one entry of each entity on both. The root ``/`` says x forward, y
left, z up (``ViewCoordinates.FLU``), and a default layout (:func:`default_blueprint`, sent again
when a sensor appears) shows the points in 3D over the images.

Colours (``color``): ``"range"`` (default) maps the range from 0 to a scale fixed per sensor on its
first frame (the 95th percentile of its ranges, so a few far returns do not wash it out) onto a
blue–cyan–green–yellow–red ramp; ``"reflectivity"`` maps the reflectivity byte from 0 to 100 (the
diffuse targets of the sensors' calibrated reflectivity; retro-reflectors above 100 are red) onto
the same ramp.

The file is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import errno
import os
import re
from typing import Any

import numpy as np

from lidarpkt.errors import OutputError

from .base import BaseWriter

COLORINGS = ("range", "reflectivity")
REFLECTIVITY_FULL_SCALE = 100.0  # diffuse targets: 0-100 % in the calibrated reflectivity byte
RANGE_SCALE_PERCENTILE = 95.0
APPLICATION_ID = "lidarpkt"
# the colour ramp's anchors, evenly spaced from 0 to 1: dark blue, cyan, green, yellow, red
_RAMP_ANCHORS = np.array([[30, 40, 160], [0, 200, 230], [40, 210, 60], [250, 220, 0], [220, 30, 20]], np.float64)
_RAMP = np.stack([np.interp(np.linspace(0, 1, 256), np.linspace(0, 1, len(_RAMP_ANCHORS)), _RAMP_ANCHORS[:, c])
                  for c in range(3)], axis=1).round().astype(np.uint8)  # uint8[256, 3]


def ramp_colors(values: np.ndarray, full_scale: float) -> np.ndarray:
    """``uint8[N, 3]`` colours of ``values`` from 0 (blue) to ``full_scale`` and above (red)."""
    index = np.clip(np.asarray(values, np.float64) / max(float(full_scale), 1e-9), 0.0, 1.0) * 255.0
    return _RAMP[index.astype(np.intp)]


POINT_RADIUS_UI = 1.5  # points drawn this many UI points wide, whatever the distance


def default_blueprint(sensors: list[str]) -> Any:
    """The viewer's layout for the sensors named: their points in 3D (black background, x forward, z
    up) over their range and reflectivity images."""
    import rerun.blueprint as rrb

    def contents(kind: str) -> list[str]:
        return [f"+ /{name}/{kind}/**" for name in sensors]

    return rrb.Blueprint(rrb.Vertical(
        rrb.Spatial3DView(name="points", origin="/", contents=contents("points"), background=[0, 0, 0]),
        rrb.Horizontal(rrb.Spatial2DView(name="range", origin="/", contents=contents("range_image")),
                       rrb.Spatial2DView(name="reflectivity", origin="/", contents=contents("reflectivity_image"))),
        row_shares=[3, 1]))


class RerunFrames:
    """Logs frames to a ``rerun.RecordingStream`` as the entities and timelines of the module doc.

    Args:
        recording: the stream (a file, a viewer or a server, as its caller set it up).
        color: ``"range"`` or ``"reflectivity"``.
        images: also log the range and reflectivity images.

    Raises OutputError: another ``color``.
    """

    def __init__(self, recording: Any, color: str = "range", images: bool = True) -> None:
        if color not in COLORINGS:
            raise OutputError(f"--color {color}: choose range or reflectivity")
        self.recording = recording
        self.color = color
        self.images = images
        self._names: dict[tuple, str] = {}
        self._labels: dict[tuple, list[str]] = {}
        self._range_scale_m: dict[tuple, float] = {}
        import rerun as rr

        recording.log("/", rr.ViewCoordinates.FLU, static=True)  # x forward, y left, z up: the points' frame

    @staticmethod
    def _key(frame) -> tuple:
        return (frame.sensor.vendor, frame.sensor.source, frame.sensor.serial)

    def sensor_name(self, frame) -> str:
        """The entity name of ``frame``'s sensor (its vendor, ``_2`` … for further sensors of that vendor)."""
        key = self._key(frame)
        name = self._names.get(key)
        if name is None:
            base = re.sub(r"[^A-Za-z0-9_]", "_", frame.sensor.vendor) or "sensor"
            taken = set(self._names.values())
            name, k = base, 2
            while name in taken:
                name, k = f"{base}_{k}", k + 1
            self._names[key] = name
            labels: list[str] = []
            for slot, label in enumerate(frame.return_labels):
                label = re.sub(r"[^A-Za-z0-9_]", "_", label) or f"return{slot}"
                labels.append(label if label not in labels else f"{label}_{slot}")
            self._labels[key] = labels
            self.recording.send_blueprint(default_blueprint(list(self._names.values())))  # with the new sensor
        return name

    def colors(self, frame, points: np.ndarray) -> np.ndarray:
        """``uint8[N, 3]``: the colour of each row of ``points`` (``frame.points()``; see the module doc)."""
        if self.color == "reflectivity":
            return ramp_colors(points["reflectivity"], REFLECTIVITY_FULL_SCALE)
        key = self._key(frame)
        if key not in self._range_scale_m:
            ranges = points["range_mm"]
            self._range_scale_m[key] = float(np.percentile(ranges, RANGE_SCALE_PERCENTILE)) / 1000.0 \
                if ranges.size else 1.0
        return ramp_colors(points["range_mm"] / 1000.0, self._range_scale_m[key])

    def log(self, frame, points: np.ndarray | None = None) -> None:
        """Log one frame (``points``: ``frame.points()`` when already computed). Raises
        :class:`~lidarpkt.errors.CalibrationError` when the sensor has no calibration."""
        import rerun as rr

        name = self.sensor_name(frame)
        labels = self._labels[self._key(frame)]
        if points is None:
            points = frame.points()
        rec = self.recording
        rec.set_time("frame", sequence=int(frame.frame_id))
        rec.set_time("sensor_time", timestamp=np.datetime64(int(frame.timestamp_ns), "ns"))
        colors = self.colors(frame, points)
        xyz = np.column_stack([points["x"], points["y"], points["z"]]).astype(np.float32)
        for slot, label in enumerate(labels):
            mine = points["return_slot"] == slot
            rec.log(f"/{name}/points/{label}", rr.Points3D(xyz[mine], colors=colors[mine],
                                                           radii=rr.Radius.ui_points(POINT_RADIUS_UI)))
        if not self.images:
            return
        rng = frame.destaggered(frame.range_mm)
        refl = frame.destaggered(frame.reflectivity)
        for slot, label in enumerate(labels):
            rec.log(f"/{name}/range_image/{label}",
                    rr.DepthImage(np.ascontiguousarray(rng[slot], np.uint32), meter=1000.0, colormap="turbo"))
            rec.log(f"/{name}/reflectivity_image/{label}",
                    rr.Image(np.ascontiguousarray(refl[slot], np.uint8), color_model="L"))


class RrdWriter(BaseWriter):
    """A Rerun recording file (see the module doc).

    Args:
        out: the ``.rrd`` file (its folder must exist).
        capture, part: see :func:`lidarpkt.writers.open_writer`; the recording is named after ``capture``.
        color: ``"range"`` (default) or ``"reflectivity"``.
        images: also log the range and reflectivity images (default True).

    Raises:
        OutputError: another ``color``; the folder does not exist.
    """

    suffix = ".rrd"

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 color: str = "range", images: bool = True) -> None:
        import rerun as rr

        super().__init__(out, capture=capture, part=part)
        if color not in COLORINGS:
            raise OutputError(f"--color {color}: choose range or reflectivity")
        self.path = self.single_file()
        self._tmp = self.files.temporary(self.path)
        self.recording: Any = rr.RecordingStream(APPLICATION_ID)
        self.recording.save(self._tmp)
        if self.capture:
            self.recording.send_recording_name(self.capture + (f" {self.part}" if self.part else ""))
        self.frames = RerunFrames(self.recording, color=color, images=images)

    def _write(self, frame) -> None:
        points = frame.points()
        self.frames.log(frame, points)
        self.points_written += points.size

    def _finish(self) -> None:
        try:
            self.recording.flush()
            self.recording.disconnect()  # the file sink writes its end and closes
        except RuntimeError as exc:  # its file-writer thread stopped: the write failed (a full disk, most often)
            raise OSError(errno.EIO, f"the Rerun file writer stopped ({exc}): is there space left on the disk?") from exc
        self.files.commit(self._tmp)

    def _release(self) -> None:
        self.recording.disconnect()
