"""CSV points (pyarrow's CSV writer): the rows and columns of the Parquet ``points`` layout, as text.

``lidarpkt decode drive.pcap -o drive.csv`` writes one file for the capture;
``--frames-per-file N`` (``frames_per_file=N``) makes ``drive.csv`` a folder of files
``STEM_SENSOR_FFFFFF[.PART].csv``, each holding the frames with ``frame_id`` in ``[F, F + N)`` of one
sensor (``N = 1``: one file per frame). ``export --format csv`` writes the same per capture (a capture
cut into segments gives one file per segment, ``STEM.segNNNN.csv``).

One header line, then one line per row of :meth:`lidarpkt.Frame.points` (every return slot that holds
a return), comma-separated, text quoted. The columns are those of :mod:`lidarpkt.writers.parquet`'s
``points`` layout, in its order, with ``capture`` (its partition there) first:

``capture, sensor, frame_id, frame_timestamp_ns, timestamp_ns, row, column, azimuth_deg, return_slot,
return_label, range_m, x, y, z, reflectivity, signal, near_ir``

Numbers are written in the shortest form that reads back to the same value in the column's type
(:func:`lidarpkt.writers.parquet.points_schema`: x, y, z are float32, range_m and azimuth_deg
float64, times int64 ns since the Unix epoch); ``signal`` and ``near_ir`` are empty where the sensor
has none (Velodyne, Hesai). DuckDB reads a file back to the Parquet rows with
``read_csv('drive.csv', types={'x': 'FLOAT', 'y': 'FLOAT', 'z': 'FLOAT'})`` (its detection would
read x, y, z as DOUBLE); pandas with ``dtype={'x': 'float32', ...}``.

Files are written under a temporary name and renamed when complete (at the end, or when the
frames of the next group of their sensor arrive).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from .base import BaseWriter


def csv_schema():
    """The pyarrow schema of the CSV files: ``capture``, then :func:`~lidarpkt.writers.parquet.points_schema`."""
    import pyarrow as pa

    from .parquet import points_schema

    return pa.schema([pa.field("capture", pa.string()), *points_schema()])


class CsvWriter(BaseWriter):
    """CSV points, one file per capture or per N frames (see the module doc).

    Args:
        out: the ``.csv`` file, or with ``frames_per_file`` a folder (created if missing).
        capture, part: see :func:`lidarpkt.writers.open_writer`; ``capture`` fills the ``capture`` column.
        frames_per_file: ``None`` for one file, else N frames (by frame id) per file and sensor.

    Raises:
        OutputError: ``frames_per_file`` below 1; the output's folder does not exist.
    """

    suffix = ".csv"

    def __init__(self, out: str | os.PathLike[str], *, capture: Any = None, part: str | None = None,
                 frames_per_file: int | None = None) -> None:
        super().__init__(out, capture=capture, part=part)
        self.frames_per_file = self.one_file_or_groups(frames_per_file)
        self.schema = csv_schema()
        self._points_schema = self.schema.remove(0)
        self._open: dict[Any, tuple[Any, Any, Path, Any]] = {}  # sensor -> (group key, CSV writer, temporary, file)

    def _writer_for(self, frame) -> Any:
        import pyarrow.csv as pcsv

        sensor: Any = None
        if self.frames_per_file is None:
            key, final = None, self.path
        else:
            key, final = self.group_file(frame, self.frames_per_file, self.suffix)
            sensor = key[0]
        entry = self._open.get(sensor)
        if entry is not None and entry[0] != key:  # the sensor's frames moved on to the next group
            self._commit(sensor)
            entry = None
        if entry is None:
            tmp = self.files.temporary(final)
            fh = open(tmp, "wb")
            writer = pcsv.CSVWriter(fh, self.schema, write_options=pcsv.WriteOptions(quoting_style="needed"))
            entry = self._open[sensor] = (key, writer, tmp, fh)
        return entry[1]

    def _commit(self, sensor: Any) -> None:
        _, writer, tmp, fh = self._open.pop(sensor)
        writer.close()
        fh.close()
        self.files.commit(tmp)

    def _write(self, frame) -> None:
        import pyarrow as pa

        from .parquet import points_record_batch

        batch = points_record_batch(frame, self._points_schema)
        capture = pa.DictionaryArray.from_arrays(pa.array([0] * batch.num_rows, pa.int32()),
                                                 pa.array([self.capture or ""])).cast(pa.string())
        batch = pa.RecordBatch.from_arrays([capture, *batch.columns], schema=self.schema)
        self._writer_for(frame).write_batch(batch)
        self.points_written += batch.num_rows

    def _finish(self) -> None:
        for sensor in list(self._open):  # no frame, no file (as the other point formats)
            self._commit(sensor)

    def _release(self) -> None:
        for _, writer, _, fh in self._open.values():
            try:
                writer.close()
            except Exception:  # noqa: BLE001 - abandoning the file; it is removed next
                pass
            fh.close()
        self._open.clear()
