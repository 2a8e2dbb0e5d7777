"""``to_dask(paths)``: the points of an archive as a ``dask.dataframe`` decoded lazily, one
partition per capture (or segment of a large one), built with ``dask.dataframe.from_map``.

The columns are the Parquet points layout's (:func:`lidarpkt.writers.parquet.points_schema`)
plus ``capture``, with ``sensor``, ``return_label`` and ``capture`` as plain strings so that
partitions of different captures concatenate without category juggling. A partition is what
``lidarpkt export --format parquet`` writes for that unit, row for row.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from typing import Any, Sequence

from lidarpkt.errors import LidarpktWarning

from .plan import DEFAULT_SEGMENT_BYTES, PlanError, parse_size, plan_captures, plan_segments


@dataclass(frozen=True)
class _Part:
    """What one partition decodes (picklable)."""

    input: str
    capture: str
    metadata: tuple[str, ...]
    segment: Any = None


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


def decode_partition(part: _Part):
    """The points of one capture or segment as a pandas DataFrame (a ``from_map`` partition).

    Raises:
        lidarpkt.errors.LidarpktError: the capture cannot be decoded (Dask reports it on compute).
    """
    import pyarrow as pa

    import lidarpkt

    from .plan import local_path

    schema = points_arrow_schema()
    tables = []
    options = {} if part.segment is None else {"segment": part.segment}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LidarpktWarning)  # counted by the readers; export's manifest lists them
        with lidarpkt.open(local_path(part.input), metadata=list(part.metadata) or None, **options) as reader:
            for frame in reader:
                tables.append(_frame_table(frame, part.capture, schema))
    table = pa.concat_tables(tables) if tables else schema.empty_table()
    return _to_pandas(table)


def _to_pandas(table):
    """Arrow-backed pandas columns: exact types, and nulls (``signal`` of a VLP-16) stay nulls."""
    import pandas as pd

    return table.to_pandas(types_mapper=pd.ArrowDtype)


def to_dask(paths: Sequence[str | os.PathLike[str]], *, layout: str = "points", glob: str | None = None,
            metadata: Sequence[str | os.PathLike[str]] = (), segment_bytes: int | str = DEFAULT_SEGMENT_BYTES):
    """A lazy ``dask.dataframe.DataFrame`` of every return in the captures under ``paths``.

    Args:
        paths: files or folders of captures (local paths or ``file://``; remote URLs: export first).
        layout: ``"points"`` (one row per return); the frames layout is read with
            ``dask.dataframe.read_parquet`` from an ``export --layout frames`` folder instead.
        glob, metadata, segment_bytes: as for :func:`lidarpkt.archive.export`.

    Raises:
        PlanError: an unknown layout, bad paths, a remote URL; EngineError: Dask is not installed.
    """
    if layout != "points":
        raise PlanError(f"layout={layout!r}: to_dask gives the points layout; for frames, export with "
                        "--format parquet --layout frames and read it with dask.dataframe.read_parquet")
    from .engine import EngineError

    try:
        import dask.dataframe as dd
    except ImportError:
        raise EngineError("to_dask needs Dask: pip install 'lidarpkt[dask]'") from None
    parts = []
    for cap in plan_captures(paths, glob=glob, metadata=metadata):
        if "://" in cap.url and not cap.url.startswith("file://"):
            raise PlanError(f"{cap.url}: to_dask reads local captures; export remote ones to Parquet first")
        for seg in plan_segments(cap, parse_size(segment_bytes)):
            parts.append(_Part(cap.url, cap.name, cap.metadata, seg))
    meta = _to_pandas(points_arrow_schema().empty_table())
    return dd.from_map(decode_partition, parts, meta=meta, enforce_metadata=True)
