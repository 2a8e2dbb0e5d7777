"""``to_dask(paths)``: the points (or frames) of an archive as a ``dask.dataframe`` decoded
lazily, one partition per capture or segment of a large one, built with ``dask.dataframe.from_delayed``.

``layout="points"``: the columns of the Parquet points layout
(:func:`lidarpkt.writers.parquet.points_schema`) plus ``capture``, with ``sensor``,
``return_label`` and ``capture`` as plain strings so that partitions of different captures
concatenate without category juggling. ``layout="frames"``: the frames layout's columns
(:func:`~lidarpkt.writers.parquet.frames_schema`: one row per frame, range images as lists)
plus ``capture``. A partition is what ``lidarpkt export --format parquet`` writes for that unit,
row for row. The segments of a capture start from the whole file's VLP-16 ordinals: their count
pass (:mod:`.ordinals`) is part of the graph, so nothing is decoded before ``compute``.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

from lidarpkt.errors import LidarpktWarning

from lidarpkt.containers.segments import DEFAULT_SEGMENT_BYTES

from .plan import PlanError, parse_size, plan_captures, plan_segments


@dataclass(frozen=True)
class _Part:
    """What one partition decodes (picklable)."""

    input: str
    capture: str
    metadata: tuple[str, ...]
    segment: Any = None
    layout: str = "points"
    open_options: tuple[tuple[str, Any], ...] = ()


def points_arrow_schema():
    """The schema of :func:`to_dask`'s partitions (as a pyarrow schema)."""
    import pyarrow as pa

    from lidarpkt.writers.parquet import points_schema

    fields = [pa.field("capture", pa.string())]
    for f in points_schema():
        typ = pa.string() if pa.types.is_dictionary(f.type) else f.type
        fields.append(pa.field(f.name, typ))
    return pa.schema(fields)


def _frame_table(frame: Any, capture: str, schema):
    import numpy as np
    import pyarrow as pa

    from lidarpkt.writers.base import sensor_name
    from lidarpkt.writers.parquet import frame_points

    cols = frame_points(frame)
    n = cols["frame_id"].size
    labels = np.array(frame.return_labels, dtype=object)
    cols = {**cols, "capture": np.full(n, capture, dtype=object),
            "sensor": np.full(n, sensor_name(frame.sensor), dtype=object),
            "return_label": labels[cols["return_slot"]] if n else np.zeros(0, dtype=object)}
    arrays = [pa.array(cols[f.name], f.type) if f.name in cols else pa.nulls(n, f.type) for f in schema]
    return pa.Table.from_arrays(arrays, schema=schema)


def frames_arrow_schema():
    """The schema of :func:`to_dask`'s ``layout="frames"`` partitions (as a pyarrow schema)."""
    import pyarrow as pa

    from lidarpkt.writers.parquet import frames_schema

    return pa.schema([pa.field("capture", pa.string()), *frames_schema()])


class _FramesRows:
    """A partition's frames-layout rows, built by the writer's own ``frame_record_batch``: the
    very rows the export writes."""

    def __init__(self) -> None:
        from lidarpkt.writers.parquet import frames_schema

        self.schema = frames_schema()

    def table(self, frame: Any, capture: str):
        import pyarrow as pa

        from lidarpkt.writers.parquet import frame_record_batch

        batch = frame_record_batch(frame, self.schema)
        return pa.Table.from_batches([batch]).add_column(0, "capture", pa.array([capture], pa.string()))


def decode_partition(part: _Part, start: Any = None):
    """The points (or frames) of one capture or segment as a pandas DataFrame (a partition).

    Args:
        start: a segment's :class:`~.ordinals.Ordinals` (or the error that made them unknown).

    Raises:
        lidarpkt.errors.LidarpktError: the capture cannot be decoded (Dask reports it on compute).
    """
    import pyarrow as pa

    from lidarpkt.pipeline.reader import open_frames

    from .ordinals import renumber_from
    from .plan import local_path

    if isinstance(start, str):
        raise PlanError(start)
    frames_rows = _FramesRows() if part.layout == "frames" else None
    schema = points_arrow_schema() if frames_rows is None else frames_arrow_schema()
    renumber = renumber_from(start) if part.segment is not None else None
    tables = []
    options = dict(part.open_options) if part.segment is None else {**dict(part.open_options), "segment": part.segment}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LidarpktWarning)  # counted by the readers; export's manifest lists them
        with open_frames(local_path(part.input), metadata=list(part.metadata) or None, **options) as reader:
            for frame in reader:
                if renumber is not None:
                    frame = renumber.frame(frame)
                tables.append(_frame_table(frame, part.capture, schema) if frames_rows is None
                              else frames_rows.table(frame, part.capture))
    table = pa.concat_tables(tables) if tables else schema.empty_table()
    return _to_pandas(table)


def _to_pandas(table):
    """Arrow-backed pandas columns: exact types, and nulls (``signal`` of a VLP-16) stay nulls."""
    import pandas as pd

    return table.to_pandas(types_mapper=pd.ArrowDtype)


def to_dask(paths: Sequence[str | os.PathLike[str]], *, layout: str = "points", glob: str | None = None,
            metadata: Sequence[str | os.PathLike[str]] = (), segment_bytes: int | str = DEFAULT_SEGMENT_BYTES,
            open_options: Mapping[str, Any] | None = None):
    """A lazy ``dask.dataframe.DataFrame`` of every return (``layout="points"``) or every frame
    (``layout="frames"``) in the captures under ``paths``; see the module doc for the columns.

    Args:
        paths: files or folders of captures (local paths or ``file://``; remote URLs: export first).
        layout: ``"points"`` or ``"frames"``.
        glob, metadata, segment_bytes, open_options: as for :func:`lidarpkt.archive.export`.

    Raises:
        PlanError: an unknown layout, bad paths, a remote URL; EngineError: Dask is not installed.
    """
    if layout not in ("points", "frames"):
        raise PlanError(f"layout={layout!r}: choose points or frames")
    from .engine import EngineError

    try:
        import dask
        import dask.dataframe as dd
    except ImportError:
        raise EngineError("to_dask needs Dask: pip install 'lidarpkt[dask]'") from None
    from .ordinals import CountTask, count_segment, start_ordinals

    parts = []
    for cap in plan_captures(paths, glob=glob, metadata=metadata, open_options=open_options):
        if "://" in cap.url and not cap.url.startswith("file://"):
            raise PlanError(f"{cap.url}: to_dask reads local captures; export remote ones to Parquet first")
        segments = plan_segments(cap, parse_size(segment_bytes))
        counts = [dask.delayed(count_segment, pure=True)(CountTask(f"{cap.name}#{i}", cap.url, s, cap.open_options))
                  for i, s in enumerate(segments[:-1]) if s is not None]
        starts = dask.delayed(start_ordinals, pure=True)(counts) if counts else None
        for i, seg in enumerate(segments):
            start = starts[i] if starts is not None and i > 0 else None
            parts.append(dask.delayed(decode_partition, pure=True)(_Part(cap.url, cap.name, cap.metadata, seg, layout, cap.open_options),
                                                                   start))
    schema = points_arrow_schema() if layout == "points" else frames_arrow_schema()
    meta = _to_pandas(schema.empty_table())
    return dd.from_delayed(parts, meta=meta, verify_meta=True)
