"""KITTI point clouds: one ``.bin`` per frame and the timestamp files, as KITTI's raw data lays them out.

``lidarpkt decode drive.pcap -o drive.kitti`` (or ``export --format kitti``, or
``open_writer("kitti", OUT, capture=...)``) writes, for each sensor of the capture, one sequence
folder in ``OUT``::

    OUT/STEM_SENSOR/velodyne_points/
        data/0000000000.bin           one per frame, named by its frame id (10 digits)
        timestamps.txt                one line per .bin file, in the files' order
        timestamps_start.txt
        timestamps_end.txt

``STEM`` is the capture's file name without its suffix, ``SENSOR`` the sensor's serial or source
address (``STEM_SENSOR.PART`` for a segment given ``part``: each segment is a sequence of its own).
The folder is named ``velodyne_points`` whatever the sensor, as KITTI's loaders (pykitti, the devkit)
expect.

**Points.** Each ``.bin`` is the frame's points as KITTI stores them: ``float32[N, 4]``, little
endian, no header, one row ``x, y, z, intensity`` per row of :meth:`lidarpkt.Frame.points` in its
order (every return slot that holds a return; a dual-return pixel gives two rows). ``x, y, z`` are
metres in the sensor's frame (x forward, y left, z up, as KITTI's Velodyne frame), the float64
values of ``points()`` rounded to float32 (the same numbers as the Parquet and CSV outputs).

**Intensity** is KITTI's *reflectance*, a number in [0, 1]: here the sensor's calibrated
reflectivity byte divided by 255 (``points()["reflectivity"] / 255`` rounded to float32). KITTI's own
values are the HDL-64E's 8-bit intensity scaled the same way, and the tools that convert other
datasets to KITTI (nuScenes' devkit, Livox's) divide the 8-bit value by 255 too, so a model trained
on KITTI sees the byte on the scale it learned. The mapping is the same for every vendor (a
reflectivity byte is 0–100 for diffuse targets and above 100 for retro-reflectors on Velodyne and
Ouster sensors, 0–255 % on Hesai), and ``intensity * 255`` gives the byte back exactly.

**Times** (UTC, ``YYYY-MM-DD HH:MM:SS.fffffffff``, nanoseconds): ``timestamps_start.txt`` is the
frame's first valid column, ``timestamps_end.txt`` its last, and ``timestamps.txt`` when the sensor
faced forward (the return nearest the +x axis, as KITTI stamps the moment its scanner faced the
cameras; the frame's first column when it has no return).

Every file is written under a temporary name and all are renamed into place at the end, when the
timestamp files are complete: a sequence is there whole or not at all. The archives write a
capture whole (they do not cut it into segments), so that a sequence lists every frame of it.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any

import numpy as np

from .base import BaseWriter, _safe, sensor_tag

REFLECTIVITY_FULL_SCALE = 255.0  # the reflectivity byte's largest value: KITTI reflectance = byte / 255
FOLDER = "velodyne_points"


def kitti_points(points: np.ndarray) -> np.ndarray:
    """``float32[N, 4]``: x, y, z (metres) and intensity (reflectivity / 255) of each row of
    ``points`` (a frame's :meth:`~lidarpkt.Frame.points`), in its order (see the module doc)."""
    out = np.empty((points.size, 4), np.float32)
    out[:, 0], out[:, 1], out[:, 2] = points["x"], points["y"], points["z"]
    out[:, 3] = points["reflectivity"] / REFLECTIVITY_FULL_SCALE  # in float64, then rounded to float32
    return out


def kitti_time(ns: int) -> str:
    """``YYYY-MM-DD HH:MM:SS.fffffffff`` (UTC) of ``ns`` nanoseconds since the Unix epoch."""
    seconds, nanos = divmod(int(ns), 1_000_000_000)
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(seconds)) + f".{nanos:09d}"


def frame_times_ns(frame, points: np.ndarray) -> tuple[int, int, int]:
    """(start, forward, end) of a frame, ns: its first and last valid column, and the firing time of
    the return nearest the +x axis (``points``: the frame's :meth:`~lidarpkt.Frame.points`)."""
    valid = frame.column_timestamp_ns[frame.column_valid]
    start = int(valid.min()) if valid.size else int(frame.timestamp_ns)
    end = int(valid.max()) if valid.size else int(frame.timestamp_ns)
    if not points.size:
        return start, start, end
    nearest = int(np.argmin(np.abs(np.arctan2(points["y"], points["x"]))))
    return start, int(points["timestamp_ns"][nearest]), end


class KittiWriter(BaseWriter):
    """KITTI raw-data layout (see the module doc).

    Args:
        out: the output folder (created if missing; its parent must exist).
        capture: the input's name (the sequence folders are named by it).
        part: a segment name, added to the sequence folders' names.

    Raises:
        OutputError: the folder cannot be made, or a file has its name.
    """

    suffix = ".bin"

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None) -> None:
        super().__init__(out, capture=capture, part=part)
        self.out_dir()
        # sequence folder -> frame id -> (start, forward, end): a frame id met again replaces its file and line
        self._times: dict[Path, dict[int, tuple[int, int, int]]] = {}
        self._bins: dict[Path, Path] = {}  # final .bin -> its temporary, renamed at the end
        self._folders: set[Path] = set()  # the sequence folders made

    def sequence_dir(self, frame) -> Path:
        """``OUT/STEM_SENSOR/velodyne_points`` of ``frame``'s sensor (created)."""
        stem = _safe(Path(self.capture).stem) if self.capture else "frames"
        part = f".{_safe(self.part)}" if self.part else ""
        folder = self.out / f"{stem}_{sensor_tag(frame.sensor)}{part}" / FOLDER
        if folder not in self._folders:
            (folder / "data").mkdir(parents=True, exist_ok=True)
            self._folders.add(folder)
        return folder

    def _write(self, frame) -> None:
        points = frame.points()
        folder = self.sequence_dir(frame)
        final = folder / "data" / f"{frame.frame_id:010d}.bin"
        tmp = self._bins.get(final) or self._bins.setdefault(final, self.files.temporary(final))
        kitti_points(points).astype("<f4", copy=False).tofile(tmp)
        self._times.setdefault(folder, {})[int(frame.frame_id)] = frame_times_ns(frame, points)
        self.points_written += points.size

    def _finish(self) -> None:
        done = list(self._bins.values())
        for folder, by_id in self._times.items():
            times = [by_id[k] for k in sorted(by_id)]  # the order of the file names
            for index, name in ((1, "timestamps.txt"), (0, "timestamps_start.txt"), (2, "timestamps_end.txt")):
                tmp = self.files.temporary(folder / name)
                tmp.write_text("".join(kitti_time(t[index]) + "\n" for t in times), encoding="ascii")
                done.append(tmp)
        for tmp in done:  # every file complete: renamed into place together
            self.files.commit(tmp)

    def abort(self) -> None:
        super().abort()
        for folder in self._folders:  # the folders made for a sequence that is not there
            for empty in (folder / "data", folder, folder.parent):
                try:
                    empty.rmdir()
                except OSError:  # not empty: an earlier run's sequence
                    break
