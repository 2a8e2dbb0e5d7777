"""Archives at scale: catalog and export whole directories of captures, in parallel on Dask.

>>> from lidarpkt import archive
>>> table = archive.catalog(["/data/drive"])                       # doctest: +SKIP
>>> manifest = archive.export(["/data/drive"], "/data/out", format="parquet", workers=8)  # doctest: +SKIP
>>> ddf = archive.to_dask(["/data/drive"])                         # doctest: +SKIP

Every job is one pure unit of work (:func:`lidarpkt.archive.unit.run_unit`) per capture or
segment, run in this process (``workers=1``, without Dask), on a local Dask cluster of processes
(``workers=N``, default the CPU count) or on an existing cluster (``scheduler="tcp://..."``,
``DASK_SCHEDULER_ADDRESS`` or ``client=``). Dask is the optional extra ``lidarpkt[dask]``.
"""

from __future__ import annotations

import os
from typing import Any, Mapping, Sequence

from .catalog import CATALOG_COLUMNS, catalog_rows, rows_to_table
from .export import FORMATS, ExportReport, export_job
from .manifest import COLUMNS as MANIFEST_COLUMNS
from lidarpkt.containers.segments import DEFAULT_SEGMENT_BYTES

from .engine import JobProgress, ProgressCallback
from .plan import parse_size
from .unit import UnitResult, UnitTask, run_unit

__all__ = ["catalog", "export", "to_dask", "multireturn_maps", "run_unit", "UnitTask", "UnitResult",
           "FORMATS", "DEFAULT_SEGMENT_BYTES", "parse_size", "ExportReport", "JobProgress"]

_MANIFEST_TYPES = {"key": "string", "input": "string", "capture": "string", "part": "string", "status": "string",
                   "frames": "int64", "points": "int64", "lost_packets": "int64", "skipped_packets": "int64",
                   "malformed_packets": "int64", "seconds": "float64", "cpu_seconds": "float64", "error": "string",
                   "size_bytes": "int64", "mtime_ns": "int64", "job": "string", "finished_at": "string"}


def catalog(paths: Sequence[str | os.PathLike[str]], *, glob: str | None = None,
            metadata: Sequence[str | os.PathLike[str]] = (), workers: int | None = None,
            scheduler: str | None = None, client: Any = None, open_options: Mapping[str, Any] | None = None):
    """One row per (capture file, sensor stream) under ``paths``, as a ``pyarrow.Table``.

    Columns (:data:`CATALOG_COLUMNS`): ``path``, ``size_bytes``, ``container``, ``stream``,
    ``source``, ``kind``, ``vendor``, ``model``, ``mode`` (return mode or Ouster profile),
    ``payload_size``, ``start_ns``/``end_ns`` (host capture time, ns since the epoch), ``packets``,
    ``frames`` (of them ``partial_frames``), ``lost_packets``, ``skipped_packets``,
    ``malformed_records``, ``error`` (null when the file read cleanly).

    Args:
        paths: files, folders (walked recursively) or fsspec URLs.
        glob: in folders, only file names matching this pattern.
        metadata: Ouster metadata JSONs for every input (else the JSON beside each capture).
        workers, scheduler, client: the engine, as for :func:`export` (default: a local cluster of
            the CPU count; ``workers=1`` runs in this process).
        open_options: as for :func:`export`.

    Raises:
        lidarpkt.archive.plan.PlanError: a PATH does not exist or holds no capture.
    """
    rows = catalog_rows(paths, glob=glob, metadata=metadata, workers=workers, scheduler=scheduler, client=client,
                        open_options=open_options)
    return rows_to_table(rows, CATALOG_COLUMNS)


def export(paths: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], *, format: str = "parquet",  # noqa: A002
           layout: str | None = None, frames_per_file: int | None = None, storage: str | None = None,
           metadata: Sequence[str | os.PathLike[str]] = (), glob: str | None = None,
           segment_bytes: int | str = DEFAULT_SEGMENT_BYTES, workers: int | None = None,
           scheduler: str | None = None, client: Any = None, progress: ProgressCallback | None = None,
           open_options: Mapping[str, Any] | None = None):
    """Export every capture under ``paths`` to the folder ``out`` in ``format``; returns the manifest.

    Args:
        paths: files, folders (walked recursively) or fsspec URLs of captures.
        out: the output folder (local path or fsspec URL); it holds the outputs and ``_manifest.jsonl``.
        format: one of :data:`FORMATS`.
        layout: Parquet: ``"points"`` (one row per return, the default) or ``"frames"``.
        frames_per_file: LAS/LAZ/CSV: one file per N frames instead of one per capture.
        storage: rosbag2: ``"sqlite3"`` (the default) or ``"mcap"``.
        metadata: Ouster metadata JSONs for every input (else the JSON beside each capture, same stem).
        glob: in folders, only file names matching this pattern.
        segment_bytes: captures above this size (bytes, or ``"256MB"``; default 256 MiB) are cut
            into segments, record-aligned byte ranges decoded in parallel (pcap/pcapng).
        workers: processes of a local Dask cluster (default: the CPU count); 1 runs here without Dask.
        scheduler: address of an existing Dask scheduler (``tcp://host:8786``), or ``DASK_SCHEDULER_ADDRESS``.
        client: a ``distributed.Client`` to run on (wins over the two above).
        progress: called with a :class:`~lidarpkt.archive.engine.JobProgress` as the job advances (after
            each unit, and at the end of each pass), e.g. to draw a progress bar.
        open_options: further keyword options of ``lidarpkt.open`` for every capture (``model``, ...).

    Returns:
        a ``pyarrow.Table`` of this job's manifest rows (one per input and segment): ``status``
        (``done``/``failed``), ``outputs`` (relative to ``out``), counts, ``error``.

    Raises:
        PlanError, ExportBusyError, EngineError (all :class:`lidarpkt.errors.LidarpktError`); a
        damaged input is not an exception but a ``failed`` row.
    """
    report = export_job(paths, out, format=format, layout=layout, frames_per_file=frames_per_file, storage=storage,
                        metadata=metadata, glob=glob, segment_bytes=segment_bytes, workers=workers,
                        scheduler=scheduler, client=client, progress=progress, open_options=open_options)
    return manifest_table(report.rows)


def manifest_table(rows: Sequence[dict[str, Any]]):
    """Manifest rows as a ``pyarrow.Table`` (``outputs`` and ``warnings`` are lists of strings)."""
    from .catalog import _pyarrow

    pa = _pyarrow()
    types = {c: getattr(pa, _MANIFEST_TYPES[c])() if c in _MANIFEST_TYPES else pa.list_(pa.string())
             for c in MANIFEST_COLUMNS}
    schema = pa.schema(list(types.items()))
    return pa.Table.from_pylist([{c: r.get(c) for c in MANIFEST_COLUMNS} for r in rows], schema=schema)


def to_dask(paths: Sequence[str | os.PathLike[str]], *, layout: str = "points", **options: Any):
    """A ``dask.dataframe`` of the captures' points (``layout="points"``) or frames (``layout="frames"``),
    each partition (a capture or segment) decoded lazily; see :mod:`.lazy`."""
    from .lazy import to_dask as _to_dask

    return _to_dask(paths, layout=layout, **options)


def multireturn_maps(paths: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], **options: Any):
    """One multi-return map per capture and a summary table; see :mod:`.multireturn`."""
    from .multireturn import multireturn_maps as _maps

    return _maps(paths, out, **options)
