"""NPZ: the frames of each sensor put on their fixed azimuth grid and stacked, one ``.npz`` file.

Arrays (``K`` frames): ``range_mm [K, R, H, W]``, ``reflectivity``, and for Ouster ``signal``,
``near_ir``, ``flags``; per column ``column_valid [K, W]``, ``column_timestamp_ns``,
``azimuth_deg``, ``measurement_id``, ``status``; per frame ``frame_id [K]``, ``partial``,
``lost_packets``; and ``return_labels``, ``sensor_json`` (the sensor description). The first
sensor's keys are bare, whatever the input holds; further sensors' keys are prefixed ``s1_``,
``s2_`` …; ``sensor_prefixes`` lists the prefixes (``["", "s1_"]``). Frames are spooled through
temporary files beside the output (memory stays bounded however long the capture) and streamed
into the zip at close.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from lidarpkt.errors import OutputError

from .base import BaseWriter

_PER_FRAME_FIELDS = ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "azimuth_deg",
                     "signal", "near_ir", "flags", "measurement_id", "status")


class _Spool:
    """The frames of one sensor, each field appended to its own temporary file as raw bytes, so
    that memory stays bounded however long the input; :meth:`write_into` streams them into the
    ``.npz`` (a zip of ``.npy`` files) as ``[K, ...]`` arrays."""

    def __init__(self, tmpdir: Path, index: int, first) -> None:
        self.tmpdir = tmpdir
        self.index = index
        self.files: dict[str, tuple[BinaryIO, np.dtype, tuple[int, ...]]] = {}
        self.scalars: dict[str, list] = {"frame_id": [], "partial": [], "lost_packets": []}
        self.constants = {"return_labels": np.array(first.return_labels),
                          "sensor_json": np.array(json.dumps(first.sensor.describe(), default=str))}
        self.count = 0

    def append(self, frame) -> None:
        for name in _PER_FRAME_FIELDS:
            arr = getattr(frame, name)
            if arr is None:
                continue
            arr = np.ascontiguousarray(arr)
            entry = self.files.get(name)
            if entry is None:
                raw = open(self.tmpdir / f"s{self.index}_{name}.raw", "w+b")
                entry = self.files[name] = (raw, arr.dtype, arr.shape)
            fh, dtype, shape = entry
            if arr.dtype != dtype or arr.shape != shape:
                raise OutputError(f"frame {frame.frame_id}: {name} is {arr.dtype}{list(arr.shape)}, unlike the "
                                  f"frames before it ({dtype}{list(shape)}); cannot stack them")
            fh.write(arr.tobytes())
        self.scalars["frame_id"].append(frame.frame_id)
        self.scalars["partial"].append(frame.partial)
        self.scalars["lost_packets"].append(frame.counters.lost_packets)
        self.count += 1

    def write_into(self, zf, prefix: str) -> None:
        for name, (fh, dtype, shape) in self.files.items():
            fh.flush()
            fh.seek(0)
            with zf.open(prefix + name + ".npy", "w", force_zip64=True) as out:
                np.lib.format.write_array_header_2_0(out, {
                    "descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                    "shape": (self.count,) + tuple(shape)})
                shutil.copyfileobj(fh, out, 16 << 20)
        arrays = {"frame_id": np.array(self.scalars["frame_id"], np.int64),
                  "partial": np.array(self.scalars["partial"], bool),
                  "lost_packets": np.array(self.scalars["lost_packets"], np.int64), **self.constants}
        for name, arr in arrays.items():
            with zf.open(prefix + name + ".npy", "w", force_zip64=True) as out:
                np.lib.format.write_array(out, arr, allow_pickle=False)

    def close(self) -> None:
        for fh, _, _ in self.files.values():
            fh.close()


def _prefix(index: int) -> str:
    """NPZ key prefix of the ``index``-th sensor: none for the first, ``s1_``, ``s2_`` … after."""
    return "" if index == 0 else f"s{index}_"


class NpzWriter(BaseWriter):
    """One ``.npz`` of the capture's frames on the azimuth grid (see the module doc).

    Args:
        out: the ``.npz`` file (its folder must exist).
        capture, part: see :func:`lidarpkt.writers.open_writer`.
        grid: azimuth grid resolution in degrees (``None``: the sensor's default).
        compress: deflate the arrays (slower).

    ``close()`` writes nothing and returns ``[]`` when no frame was written.
    Raises :class:`~lidarpkt.errors.OutputError` when frames of one sensor differ in shape or
    the file cannot be written.
    """

    suffix = ".npz"

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 grid: float | None = None, compress: bool = False) -> None:
        super().__init__(out, capture=capture, part=part)
        self.grid = grid
        self.compress = compress
        self.path = self.single_file()
        if not self.path.parent.is_dir():
            raise OutputError(f"-o {self.path}: the folder {self.path.parent} does not exist")
        self._tmpdir = tempfile.TemporaryDirectory(prefix=".lidarpkt-npz-", dir=self.path.parent)
        self._spools: dict[tuple, _Spool] = {}

    @property
    def sensors(self) -> int:
        """Sensors (spools) seen so far."""
        return len(self._spools)

    def _write(self, frame) -> None:
        key = (frame.sensor.vendor, frame.sensor.model, frame.sensor.source, frame.shape[0], frame.shape[1])
        gridded = frame.on_grid(self.grid)
        spool = self._spools.get(key)
        if spool is None:
            spool = self._spools[key] = _Spool(Path(self._tmpdir.name), len(self._spools), gridded)
        spool.append(gridded)

    def _finish(self) -> None:
        if self._spools:
            tmp = self.files.temporary(self.path)
            try:
                with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED if self.compress else zipfile.ZIP_STORED,
                                     allowZip64=True) as zf:
                    # one rule whatever the input holds: the first sensor's keys are bare (range_mm ...),
                    # the others' prefixed s1_, s2_ ...; "sensor_prefixes" lists them
                    for spool in self._spools.values():
                        spool.write_into(zf, _prefix(spool.index))
                    with zf.open("sensor_prefixes.npy", "w") as fh:
                        np.lib.format.write_array(fh, np.array([_prefix(s.index) for s in self._spools.values()]),
                                                  allow_pickle=False)
            except OSError as exc:
                raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from None
            self.files.commit(tmp)
        self._release()

    def _release(self) -> None:
        for spool in self._spools.values():
            spool.close()
        self._tmpdir.cleanup()
