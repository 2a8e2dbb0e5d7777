"""``catalog(paths)``: one row per (capture file, sensor stream) of an archive, computed in parallel.

Each capture is described by :func:`lidarpkt.pipeline.describe.describe_capture` (what ``lidarpkt info``
prints: streams, their kind, mode, times and packet counts) and decoded once with
:func:`lidarpkt.open` to count frames and lost packets per sensor. An unreadable capture still
gets a row, with its error.
"""

from __future__ import annotations

import os
import warnings
from typing import Any, Mapping, Sequence

from lidarpkt.errors import LidarpktError, LidarpktWarning

from .engine import EngineOptions, ProgressCallback, run_rows
from .plan import Capture, plan_captures

# column -> pyarrow type name; the order of the table and of the JSON objects
CATALOG_COLUMNS: dict[str, str] = {
    "path": "string", "size_bytes": "int64", "container": "string", "stream": "string", "source": "string",
    "kind": "string", "vendor": "string", "model": "string", "mode": "string", "payload_size": "int64",
    "start_ns": "int64", "end_ns": "int64", "packets": "int64", "frames": "int64", "partial_frames": "int64",
    "lost_packets": "int64", "skipped_packets": "int64", "malformed_records": "int64", "error": "string",
}


def _mode(details: dict[str, Any]) -> str | None:
    if details.get("profile_source") == "guess" and len(details.get("candidates") or ()) > 1:
        return None  # packets of that size fit several profiles: only the sensor's metadata can say which
    if "profile" in details:
        return str(details["profile"])
    mode = details.get("return_mode")
    if mode is None:
        return None
    return mode if isinstance(mode, str) else "/".join(mode)


def _count_frames(path: str, metadata: Sequence[Any], open_options: dict[str, Any]) -> tuple[dict[str, dict[str, Any]], str | None]:
    """Frames, partial frames, lost and skipped packets and model per source, and the decode error."""
    from lidarpkt.pipeline.reader import open_frames

    per: dict[str, dict[str, Any]] = {}
    error = None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LidarpktWarning)  # counted by the reader; the row says them
            with open_frames(path, metadata=list(metadata) or None, **open_options) as reader:
                for frame in reader:
                    s = per.setdefault(frame.sensor.source or "unknown source", {
                        "frames": 0, "partial_frames": 0, "lost_packets": 0, "skipped_packets": 0,
                        "model": frame.sensor.model, "mode": frame.sensor.profile or frame.sensor.return_mode})
                    s["frames"] += 1
                    s["partial_frames"] += int(frame.partial)
                    s["lost_packets"] += frame.counters.lost_packets
                    s["skipped_packets"] += frame.counters.malformed_packets + frame.counters.late_packets
    except (LidarpktError, OSError) as exc:
        error = str(exc) if isinstance(exc, LidarpktError) else f"{path}: cannot read ({exc.strerror or exc})"
    return per, error


def _take(per_source: dict[str, dict[str, Any]], source: str) -> dict[str, Any] | None:
    """The decoded counts of a lidar stream: those of the sensor named after it, else of a sensor
    at the same address (a decoder is named after its first packet, which may be its IMU's)."""
    if source in per_source:
        return per_source.pop(source)
    host = source.rsplit(":", 1)[0]
    for name in list(per_source):
        if name.rsplit(":", 1)[0] == host:
            return per_source.pop(name)
    return None


def catalog_capture(capture: Capture) -> list[dict[str, Any]]:
    """The catalog rows of one capture (a pure function: picklable in and out, for any engine).

    Never raises on bad input: an unreadable capture gives one row whose ``error`` says why.
    """
    from lidarpkt.pipeline.describe import describe_capture

    base: dict[str, Any] = {c: None for c in CATALOG_COLUMNS}
    base.update(path=capture.url, size_bytes=capture.size_bytes)
    scratch: list[str] = []
    try:
        from lidarpkt.vendors import registry

        from .unit import _fetch_input

        try:
            path = _fetch_input(capture.url, scratch)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", LidarpktWarning)
                md = registry.load_sensor_files([_fetch_input(m, scratch) for m in capture.metadata])
                doc = describe_capture(path, md)
        except (LidarpktError, OSError) as exc:
            msg = str(exc) if isinstance(exc, LidarpktError) else f"{capture.url}: cannot read ({exc.strerror or exc})"
            return [{**base, "error": msg}]
        # the loaded sensor files: a remote one is no local path. The frames of a file of decoded
        # frames are counted by describe_capture.
        per_source, error = _count_frames(path, md, dict(capture.open_options)) if "sensors" not in doc else ({}, None)
    finally:
        if scratch:
            import shutil

            for folder in scratch:
                shutil.rmtree(folder, ignore_errors=True)
    truncated = f"{capture.url}: truncated: {doc.get('truncated_reason')}" if doc.get("truncated") else None
    base.update(container=doc["format"], malformed_records=doc.get("malformed", 0), error=error or truncated)
    rows = []
    for s in doc.get("sensors", ()):  # a file of decoded frames: the frames of each sensor, no packets
        rows.append({**base, "stream": s["source"], "source": s["source"], "kind": s["kind"],
                     "vendor": s["vendor"], "model": s["model"], "mode": s["profile"], "start_ns": s["first_timestamp_ns"],
                     "end_ns": s["last_timestamp_ns"], "packets": 0, "frames": s["frames"],
                     "partial_frames": s["partial_frames"], "lost_packets": 0, "skipped_packets": 0})
    # the streams the decode's error names, if it names any: the rows of the others do not carry it
    named = {f"{s['src']} → {s['dst']}" for s in doc["streams"] if error and f"{s['src']} → {s['dst']}" in error}
    for s in doc["streams"]:
        details = s.get("details") or {}
        source = s["src"] or "unknown source"
        # a decoder is per source address (its frames name the port of its first packet, which may be
        # the IMU's): the frames go to the first lidar stream of that address
        decoded = _take(per_source, source) if _is_lidar(s["stream_kind"]) else None
        row = dict(base)
        if error and named and f"{s['src']} → {s['dst']}" not in named:
            row["error"] = truncated  # the error is another stream's (it names it)
        row.update(stream=f"{s['src'] or '?'} -> {s['dst'] or '?'}", source=source, kind=s["kind"],
                   vendor=s["vendor"], model=(decoded or {}).get("model") or details.get("product_name") or details.get("model"),
                   mode=_mode(details), payload_size=s["payload_size"], start_ns=s["first_timestamp_ns"],
                   end_ns=s["last_timestamp_ns"], packets=s["packets"])
        if decoded is not None:
            row.update({k: decoded[k] for k in ("frames", "partial_frames", "lost_packets", "skipped_packets")})
        elif s["details"] is None:  # no sensor module knows it
            row.update(frames=0, partial_frames=0, lost_packets=0, skipped_packets=s["packets"])
        rows.append(row)
    if not rows:
        rows.append({**base, "packets": 0, "frames": 0})
    return rows


def _is_lidar(stream_kind: str) -> bool:
    """Whether ``info``'s ``stream_kind`` text names a stream frames are made of."""
    from lidarpkt.core.streams import StreamKind
    from lidarpkt.vendors import registry

    kind = StreamKind.parse(stream_kind)
    try:
        return registry.vendor(kind.vendor).stream(kind.name).lidar
    except KeyError:  # "other"
        return False


def catalog_rows(
    paths: Sequence[str | os.PathLike[str]],
    *,
    glob: str | None = None,
    metadata: Sequence[str | os.PathLike[str]] = (),
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    progress: ProgressCallback | None = None,
    open_options: Mapping[str, Any] | None = None,
) -> list[dict[str, Any]]:
    """The catalog as a list of row dicts (columns :data:`CATALOG_COLUMNS`), in the order of the inputs."""
    captures = plan_captures(paths, glob=glob, metadata=metadata, open_options=open_options)
    return run_rows(catalog_capture, captures, [c.size_bytes for c in captures],
                    EngineOptions(workers=workers, scheduler=scheduler, client=client), label="catalog",
                    progress=progress, lost=_lost_capture)


def _lost_capture(capture: Capture, why: str) -> list[dict[str, Any]]:
    return [{**{c: None for c in CATALOG_COLUMNS}, "path": capture.url, "size_bytes": capture.size_bytes,
             "error": f"{capture.url}: {why}"}]


def rows_to_table(rows: Sequence[dict[str, Any]], columns: dict[str, str]):
    """A ``pyarrow.Table`` of ``rows`` with the given column types."""
    pa = _pyarrow()
    schema = pa.schema([(name, getattr(pa, kind)()) for name, kind in columns.items()])
    return pa.Table.from_pylist([{c: r.get(c) for c in columns} for r in rows], schema=schema)


def _pyarrow():
    try:
        import pyarrow
    except ImportError:
        raise LidarpktError("catalog and export tables need pyarrow: pip install 'lidarpkt[dask]'") from None
    return pyarrow
