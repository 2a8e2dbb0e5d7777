"""LAS 1.4 / LAZ (laspy; lazrs compresses LAZ): the points of a capture with GPS time.

Point format 6 (LAS 1.4): X/Y/Z as int32 at a scale of 0.1 mm and offset 0 (the sensor's frame,
metres: every coordinate is within 0.05 mm of ``Frame.xyz()``, up to ±214 km); ``intensity`` = the
sensor's reflectivity byte; ``gps_time`` = the point's own firing time (column time + per-pixel
offset) as *adjusted standard GPS time* (GPS seconds − 10⁹, global encoding bit 0 set), converted
from UTC with the leap-second table below; ``point_source_id`` = the sensor's index in order of
appearance. Extra-bytes dimensions: ``frame_id`` (int64), ``row`` and ``column`` (uint16, as in
:class:`lidarpkt.Frame`).

Return number / number of returns have LAS's meaning: the returns of one pulse. A single-return
frame gives points 1 of 1. In a dual-return frame a pixel with two *different* returns (ranges
differ) gives two points, 1 of 2 the nearer and 2 of 2 the farther; a pixel whose two slots hold
the same return (equal range: the sensor repeats a lone return in both) or whose other slot is
empty gives one point, 1 of 1 (with the attributes of the first slot that holds it).

One file per capture (``out`` is the file), or with ``frames_per_file=N`` a folder of files
``STEM_SENSOR_FFFFFF[.PART].las`` each holding the frames with ``frame_id`` in
``[F, F + N)`` of one sensor (grouped by frame id, so the grouping does not depend on how the
capture was segmented).
"""

from __future__ import annotations

import calendar
import os
from pathlib import Path
from typing import Any

import numpy as np

from lidarpkt.errors import OutputError

from .base import BaseWriter

SCALE_M = 0.0001  # 0.1 mm
GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06T00:00:00Z
# (UTC date from which it holds, GPS − UTC seconds); IERS bulletin C, unchanged since 2017
LEAP_SECONDS = [(calendar.timegm((y, m, 1, 0, 0, 0)), n) for (y, m), n in (
    ((1981, 7), 1), ((1982, 7), 2), ((1983, 7), 3), ((1985, 7), 4), ((1988, 1), 5), ((1990, 1), 6),
    ((1991, 1), 7), ((1992, 7), 8), ((1993, 7), 9), ((1994, 7), 10), ((1996, 1), 11), ((1997, 7), 12),
    ((1999, 1), 13), ((2006, 1), 14), ((2009, 1), 15), ((2012, 7), 16), ((2015, 7), 17), ((2017, 1), 18))]


def adjusted_gps_time(unix_ns: np.ndarray) -> np.ndarray:
    """UTC ns since the Unix epoch → adjusted standard GPS time (s, float64: GPS seconds − 10⁹).

    Times before 1980 (sensor clocks counting from boot) give negative values, still exact to
    float64 precision (≈60 ns in the 2020s)."""
    unix_ns = np.asarray(unix_ns, np.int64)
    starts = np.array([s for s, _ in LEAP_SECONDS], np.int64) * 1_000_000_000
    leaps = np.concatenate([[0], [n for _, n in LEAP_SECONDS]]).astype(np.int64)
    leap = leaps[np.searchsorted(starts, unix_ns, side="right")]
    gps_ns = unix_ns - GPS_EPOCH_UNIX_S * 1_000_000_000 + leap * 1_000_000_000 - 10**18
    return gps_ns.astype(np.float64) * 1e-9


def las_points(frame) -> dict[str, np.ndarray]:
    """The points of one frame with LAS return numbering (see the module doc), as arrays: the rows
    of ``frame.points()``, in its order, less the second slot of a dual pixel that repeats the first.

    Keys: ``xyz`` float64 [N, 3], ``reflectivity``, ``return_number``, ``number_of_returns``,
    ``timestamp_ns``, ``row``, ``column``. Raises :class:`~lidarpkt.errors.CalibrationError` when
    the sensor has no calibration.
    """
    r = frame.shape[0]
    pts = frame.points()
    if r == 1:
        ones = np.ones(pts.size, np.uint8)
        return_number, number_of_returns = ones, ones
    elif r == 2:
        own = pts["range_mm"]
        # the other slot of the same pixel (its column is valid: the point is a return)
        other = frame.range_mm[1 - pts["return_slot"], pts["row"], pts["column"]]
        two = (other > 0) & (other != own)  # two different returns of one pulse
        keep = (pts["return_slot"] == 0) | (other == 0) | two  # slot 1 repeating slot 0 is not a pulse
        pts, own, two = pts[keep], own[keep], two[keep]
        return_number = np.where(two & (own > other[keep]), 2, 1).astype(np.uint8)  # 2 of 2: the farther
        number_of_returns = np.where(two, 2, 1).astype(np.uint8)
    else:
        raise OutputError(f"frame {frame.frame_id}: {r} return slots; LAS numbering is defined here for 1 or 2")
    return {"xyz": np.column_stack([pts["x"], pts["y"], pts["z"]]), "reflectivity": pts["reflectivity"],
            "return_number": return_number, "number_of_returns": number_of_returns,
            "timestamp_ns": pts["timestamp_ns"], "row": pts["row"], "column": pts["column"]}


class LasWriter(BaseWriter):
    """LAS 1.4 point format 6 (see the module doc).

    Args:
        out: the ``.las`` file, or with ``frames_per_file`` a folder (created if missing).
        capture, part: see :func:`lidarpkt.writers.open_writer`.
        frames_per_file: ``None`` for one file, else N frames (by frame id) per file and sensor.
    """

    suffix = ".las"
    compress = False

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 frames_per_file: int | None = None) -> None:
        super().__init__(out, capture=capture, part=part)
        self.frames_per_file = self.one_file_or_groups(frames_per_file)
        self._open: dict[Any, tuple[Any, Path]] = {}  # group key -> (laspy writer, temporary path)
        self._sensors: dict[tuple, int] = {}

    def _header(self):
        import laspy

        header = laspy.LasHeader(point_format=6, version="1.4")
        header.scales = np.array([SCALE_M] * 3)
        header.offsets = np.zeros(3)
        header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
        header.global_encoding.wkt = True  # LAS 1.4: required for point formats 6-10 (no CRS is given)
        header.add_extra_dims([laspy.ExtraBytesParams("frame_id", np.int64, description="lidarpkt frame id"),
                               laspy.ExtraBytesParams("row", np.uint16, description="beam, 0 = top"),
                               laspy.ExtraBytesParams("column", np.uint16, description="frame column")])
        header.generating_software = "lidarpkt"
        return header

    def _writer_for(self, frame):
        import laspy

        if self.frames_per_file is None:
            key, final = None, self.path
        else:
            key, final = self.group_file(frame, self.frames_per_file, self.suffix)
        entry = self._open.get(key)
        if entry is None:
            tmp = self.files.temporary(final)
            fh = open(tmp, "wb")
            backend = laspy.LazBackend.Lazrs if self.compress else None
            writer = laspy.LasWriter(fh, self._header(), do_compress=self.compress, laz_backend=backend)
            entry = self._open[key] = (writer, tmp)
        return entry[0]

    def _write(self, frame) -> None:
        import laspy

        skey = (frame.sensor.vendor, frame.sensor.source, frame.sensor.serial)
        sensor_index = self._sensors.setdefault(skey, len(self._sensors))
        pts = las_points(frame)
        writer = self._writer_for(frame)
        n = pts["row"].size
        if n == 0:
            return
        record = laspy.ScaleAwarePointRecord.zeros(n, header=writer.header)
        record.x, record.y, record.z = pts["xyz"][:, 0], pts["xyz"][:, 1], pts["xyz"][:, 2]
        record.intensity = pts["reflectivity"]
        record.return_number = pts["return_number"]
        record.number_of_returns = pts["number_of_returns"]
        record.gps_time = adjusted_gps_time(pts["timestamp_ns"])
        record.point_source_id = np.full(n, sensor_index, np.uint16)
        record["frame_id"] = np.full(n, frame.frame_id, np.int64)
        record["row"] = pts["row"].astype(np.uint16)
        record["column"] = pts["column"].astype(np.uint16)
        writer.write_points(record)
        self.points_written += n

    def _finish(self) -> None:
        for key in list(self._open):
            writer, tmp = self._open.pop(key)
            writer.close()
            self.files.commit(tmp)

    def _release(self) -> None:
        for writer, _ in self._open.values():
            try:
                writer.close()
            except Exception:  # noqa: BLE001 - abandoning the file; it is removed next
                pass
        self._open.clear()


class LazWriter(LasWriter):
    """The same points LAZ-compressed (lazrs)."""

    suffix = ".laz"
    compress = True
