"""The ``catalog`` and ``export`` verbs, and ``multireturn`` over an archive: wiring of
:func:`lidarpkt.archive.catalog`, :func:`lidarpkt.archive.export` and :func:`lidarpkt.archive.multireturn_maps`
to the command line.

``lidarpkt catalog PATHS... -o catalog.parquet|catalog.json [--json] [--glob G] [--workers N | --scheduler ADDR]``
``lidarpkt export PATHS... -o OUTDIR --format parquet|las|laz|ply|pcd|npz|mcap|csv|kitti|rrd|rosbag1|rosbag2|pcap
[--layout points|frames] [--frames-per-file N] [--storage sqlite3|mcap] [--segment-size S] [--metadata FILE]...
[--model NAME] [--workers N | --scheduler ADDR] [-q]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from lidarpkt.archive.export import FORMATS
from lidarpkt.containers.segments import DEFAULT_SEGMENT_BYTES
from lidarpkt.errors import LidarpktError
from lidarpkt.writers.base import write_atomic

from . import args as cliargs
from .console import JobBars, count


def _add_engine(p: argparse.ArgumentParser) -> None:
    p.add_argument("--glob", metavar="PATTERN", help="in folders, only files whose name matches (e.g. '*.pcap')")
    cliargs.add_sensor_options(p, "a sensor's description file for every input, of any vendor, told apart by its "
                                  "content (by default the JSON beside each capture with the same stem); repeat, one "
                                  "per sensor")
    p.add_argument("--workers", type=cliargs.number("--workers"), metavar="N",
                   help="use N CPU cores (default: every core): N processes of a local Dask cluster, a capture or "
                        "segment each; 1 runs in this process, without Dask")
    p.add_argument("--scheduler", metavar="ADDR",
                   help="run on an existing Dask cluster (tcp://HOST:8786; default $DASK_SCHEDULER_ADDRESS)")
    cliargs.add_quiet(p, "no progress bar or summary")


def add_catalog_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``lidarpkt catalog``."""
    p.add_argument("paths", nargs="+", metavar="PATH", help="captures, folders (walked recursively) or fsspec URLs")
    p.add_argument("-o", "--output", metavar="CATALOG.parquet",
                   help="write the catalog to this file: Parquet (.parquet) or a JSON list of rows (.json)")
    cliargs.add_json(p, "the catalog as a JSON list of rows", file_flag=None)
    _add_engine(p)


def add_export_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``lidarpkt export``."""
    p.add_argument("paths", nargs="+", metavar="PATH", help="captures, folders (walked recursively) or fsspec URLs")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR",
                   help="output folder (local or fsspec URL); holds the outputs and _manifest.jsonl")
    p.add_argument("--format", required=True, choices=FORMATS, help="output format (pcap: the capture's raw "
                   "packets, from pcapng, MCAP and ROS bags too; a bag's keep the vendor's default ports)")
    p.add_argument("--layout", choices=("points", "frames"), help="Parquet: one row per return (points, the "
                   "default) or per frame")
    p.add_argument("--frames-per-file", type=cliargs.number("--frames-per-file"), metavar="N",
                   help="LAS/LAZ/CSV: one file per N frames")
    p.add_argument("--storage", choices=("sqlite3", "mcap"),
                   help="rosbag2: the storage of the bag's messages (sqlite3, as ros2 bag records by default)")
    p.add_argument("--segment-size", metavar="S", help="captures larger than this are cut into segments run in "
                   "parallel: bytes, or 256MB, 1GB, 512MiB (default 256MiB)")
    _add_engine(p)


def _check_engine(args: argparse.Namespace) -> dict[str, Any]:
    """The engine flags checked, and the sensor options as the job's keywords (``metadata``, ``open_options``)."""
    if args.workers is not None and args.scheduler:
        raise LidarpktError("--workers and --scheduler: give one (--scheduler runs on the cluster's workers)")
    options = cliargs.sensor_options(args)  # URLs: read by the units
    return {"metadata": options.pop("metadata", ()), "open_options": options}


def run_catalog(args: argparse.Namespace) -> int:
    """Write the catalog (every row, errors too); exit status as export's (:func:`job_status`): 1 when a file
    failed, its row saying why."""
    from lidarpkt.archive import CATALOG_COLUMNS
    from lidarpkt.archive.catalog import catalog_rows, rows_to_table

    if not args.output and not args.json:
        raise LidarpktError("-o/--output: give -o CATALOG.parquet (or CATALOG.json), or --json to print the catalog")
    sensor = _check_engine(args)
    # checked before the work: a typo must not cost a pass over an archive
    out = cliargs.check_output(args.output, "-o", (".parquet", ".json")) if args.output else None
    if out is not None and out.suffix.lower() == ".json":  # -o's suffix picks the format
        args.json_file, out = args.output, None
    cliargs.check_json(args)
    bars = JobBars(args.quiet)
    try:
        rows = catalog_rows(args.paths, glob=args.glob, workers=args.workers, scheduler=args.scheduler, progress=bars,
                            **sensor)
    finally:
        bars.close()
    if out is not None:
        import pyarrow.parquet as pq

        table = rows_to_table(rows, CATALOG_COLUMNS)
        write_atomic(out, lambda tmp: pq.write_table(table, tmp, compression="zstd"))
    if cliargs.wants_json(args):
        cliargs.emit_json(args, json.dumps(rows, indent=1, default=str))
    files = len({r["path"] for r in rows})
    bad = len({r["path"] for r in rows if r["error"]})
    if not args.quiet or bad:
        print(f"lidarpkt catalog: {count(len(rows), 'stream')} in {count(files, 'file')} ({bad} with errors)"
              + (f" in {out or cliargs.json_file(args)}" if out or cliargs.json_file(args) else ""), file=sys.stderr)
    return job_status(bad)


def run_export(args: argparse.Namespace) -> int:
    """Run the export job; exit status 1 when any input failed (the summary says which and why)."""
    from lidarpkt.archive.export import export_job

    sensor = _check_engine(args)
    if "://" not in args.output:  # a local OUTDIR is checked (and made) before the work, removed on an error
        cliargs.check_folder(args.output, "-o")
    bars = JobBars(args.quiet)
    try:
        report = export_job(args.paths, args.output, format=args.format, layout=args.layout,
                            frames_per_file=args.frames_per_file, storage=args.storage, glob=args.glob,
                            segment_bytes=args.segment_size or DEFAULT_SEGMENT_BYTES, workers=args.workers,
                            scheduler=args.scheduler, progress=bars, **sensor)
    finally:
        bars.close()
    if not args.quiet or report.failed:
        print("lidarpkt export: " + report.summary(), file=sys.stderr)
    return job_status(len(report.failed))


def job_status(failed_files: int) -> int:
    """The exit status of the archive verbs (catalog, export, multireturn over several captures): 0 when every
    file was read, 1 when some file failed (the output holds the others; the summary says which failed)."""
    return 1 if failed_files else 0



def run_multireturn_archive(args: argparse.Namespace) -> int:
    """The ``lidarpkt multireturn PATHS... -o OUTDIR`` form (several captures, a folder, or an engine
    flag); exit status 1 when a capture could not be analysed."""
    from lidarpkt.analysis.stack import parse_frame_range
    from lidarpkt.archive.multireturn import multireturn_maps
    from lidarpkt.archive.plan import PlanError

    if args.plot:
        raise PlanError(f"--plot {args.plot}: figures are drawn for one capture (-o MAP.npz); "
                        "the folder form writes maps and summary.csv only")
    sensor = _check_engine(args)
    if "://" not in args.output:  # a local OUTDIR is checked (and made) before the work, removed on an error
        cliargs.check_folder(args.output, "-o")
    options: dict[str, Any] = {"neighbourhood": args.neighbourhood, "monitor_frame": args.monitor_frame,
                               "threshold_m": args.threshold, "method": args.method}
    if args.gap is not None:
        options["gap_m"] = args.gap
    bars = JobBars(getattr(args, "quiet", False))
    try:
        rows = multireturn_maps(args.input, args.output, glob=getattr(args, "glob", None),
                                frames=parse_frame_range(args.frames) if args.frames else None, grid_deg=args.grid,
                                workers=args.workers, scheduler=args.scheduler, progress=bars, **sensor, **options)
    finally:
        bars.close()
    failed = [r for r in rows if r["error"]]
    for r in rows:
        if not r["error"]:
            print(f"{r['capture']} slot {r['slot']} ({r['return_label']}): {count(r['frames_used'], 'frame')}, "
                  f"multi-return {_fraction(r['multi_return_fraction'])}, non-return {_fraction(r['nonreturn_fraction'])}")
    for r in failed:
        print(f"lidarpkt multireturn: failed: {r['capture']}: {r['error']}", file=sys.stderr)
    print(f"wrote {count(len({r['map'] for r in rows if r['map']}), 'map')} and {Path(args.output) / 'summary.csv'}")
    return job_status(len({r["capture"] for r in failed}))


def _fraction(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.4f}"
