"""``export(paths, out, format=...)``: every capture of an archive written in one format, in parallel.

Plan (:mod:`.plan`) → one :class:`~.unit.UnitTask` per capture or segment → the engine
(:mod:`.engine`) runs :func:`~.unit.run_unit` on each → the manifest (:mod:`.manifest`) records
each as it finishes. A re-run of the same job skips the units already done; a damaged input is
recorded with its error and the job goes on.
"""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterator, Mapping, Sequence

from lidarpkt.errors import LidarpktError
from lidarpkt.writers import FORMATS as WRITER_FORMATS, accepted_options

from .engine import EngineOptions, Progress, ProgressCallback, dask_client, run_all
from .ordinals import CountTask, SegmentCount, count_segment, start_ordinals
from .manifest import Manifest, OutdirLock, job_fingerprint, make_row
from lidarpkt.containers.segments import DEFAULT_SEGMENT_BYTES

from .plan import PlanError, is_remote, local_path, plan_captures, plan_segments
from .unit import STAGING, UnitResult, UnitTask, run_unit

# the writers' formats (lidarpkt.writers.FORMATS), and pcap: the capture's raw packets (:mod:`.packets`)
FORMATS = (*WRITER_FORMATS, "pcap")
# MCAP is ``lidarpkt decode IN -o OUT.mcap``'s output: one recording of the capture (raw packets,
# clouds, log times, one summary and index), which a reader opens as one file; segments would
# split one recording into several, so it runs whole files, as the other formats that say so
# (ROS bags, Rerun recordings, KITTI sequences: ``Format.whole_capture``). pcap is one file per
# capture too. Every other format runs segments (PLY/PCD: one file per frame, named by the
# whole-file frame id a segment knows: .ordinals).
WHOLE_FILE_FORMATS = (*(name for name, spec in WRITER_FORMATS.items() if spec.whole_capture), "pcap")


@dataclass
class ExportReport:
    """What :func:`export_job` did: the manifest rows of this job's units (done now or before)."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    skipped: int = 0  # units already done by an earlier run

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] != "done"]

    def summary(self) -> str:
        """A few lines: counts, then one line per failed unit (its error)."""
        done = len(self.rows) - len(self.failed)
        frames = sum(r["frames"] or 0 for r in self.rows)
        lines = [f"{done} of {len(self.rows)} units done ({self.skipped} already done before), {frames} frames, "
                 f"{len(self.failed)} failed"]
        lines += [f"  failed: {r['key']}: {r['error']}" for r in self.failed]
        return "\n".join(lines)


def writer_options(fmt: str, *, layout: str | None = None, frames_per_file: int | None = None,
                   storage: str | None = None, **extra: Any) -> tuple[tuple[str, Any], ...]:
    """The writer options of a job as sorted pairs (only the ones given), checked against the format.

    Raises:
        PlanError: an unknown format, or an option the format does not take.
    """
    if fmt not in FORMATS:
        raise PlanError(f"--format {fmt}: choose one of {', '.join(FORMATS)}")
    opts: dict[str, Any] = dict(extra)
    if fmt == "parquet" and layout is None:
        layout = "points"  # the writer's default, named so that a job with --layout points is the same job
    if layout is not None:
        if fmt != "parquet":
            raise PlanError(f"--layout {layout}: only --format parquet has layouts (points, frames)")
        opts["layout"] = layout
    if frames_per_file is not None:
        if fmt == "pcap" or "frames_per_file" not in accepted_options(fmt):
            raise PlanError(f"--frames-per-file {frames_per_file}: only --format las/laz/csv split files by frames")
        if frames_per_file < 1:
            raise PlanError(f"--frames-per-file {frames_per_file}: give 1 or more frames")
        opts["frames_per_file"] = int(frames_per_file)
    if storage is not None:
        if fmt == "pcap" or "storage" not in accepted_options(fmt):
            raise PlanError(f"--storage {storage}: only --format rosbag2 has storages (sqlite3, mcap)")
        if storage not in ("sqlite3", "mcap"):
            raise PlanError(f"--storage {storage}: choose sqlite3 or mcap")
        opts["storage"] = storage
    return tuple(sorted(opts.items()))


def plan_units(paths: Sequence[str | os.PathLike[str]], out: str, fmt: str, options: tuple, *,
               glob: str | None = None, metadata: Sequence[str] = (), segment_bytes: int = DEFAULT_SEGMENT_BYTES,
               open_options: Mapping[str, Any] | None = None) -> tuple[list[UnitTask], dict[str, int], list[tuple[UnitTask, str]]]:
    """(tasks, capture mtime by key, tasks that failed while planning with their error)."""
    tasks, mtimes, failed = [], {}, []
    for cap in plan_captures(paths, glob=glob, metadata=metadata, open_options=open_options):
        base: dict[str, Any] = dict(input=cap.url, capture=cap.name, output=out, format=fmt, options=options,
                                    metadata=cap.metadata, open_options=cap.open_options)
        try:
            segments = [None] if fmt in WHOLE_FILE_FORMATS else plan_segments(cap, segment_bytes)
        except LidarpktError as exc:  # cannot be indexed: recorded as this input's failure
            task = UnitTask(key=cap.name, size_bytes=cap.size_bytes, **base)
            failed.append((task, str(exc)))
            mtimes[task.key] = cap.mtime_ns
            continue
        for seg in segments:
            if seg is None:
                task = UnitTask(key=cap.name, size_bytes=cap.size_bytes, **base)
            else:
                part = f"seg{seg.index:04d}"
                task = UnitTask(key=f"{cap.name}#{part}", segment=seg, part=part, size_bytes=seg.size_bytes, **base)
            tasks.append(task)
            mtimes[task.key] = cap.mtime_ns
    return tasks, mtimes, failed


def _prepare_outdir(out: str) -> None:
    if is_remote(out):
        return
    root = Path(local_path(out))
    if root.exists() and not root.is_dir():
        raise PlanError(f"-o {out}: a file has this name; export writes a folder")
    if not root.parent.is_dir():
        raise PlanError(f"-o {out}: the folder {root.parent} does not exist; create it first")
    root.mkdir(exist_ok=True)


def export_job(
    paths: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    *,
    format: str = "parquet",  # noqa: A002 - the verb's flag name
    layout: str | None = None,
    frames_per_file: int | None = None,
    storage: str | None = None,
    metadata: Sequence[str | os.PathLike[str]] = (),
    glob: str | None = None,
    segment_bytes: int | str = DEFAULT_SEGMENT_BYTES,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    retries: int | None = None,
    progress: ProgressCallback | None = None,
    open_options: Mapping[str, Any] | None = None,
) -> ExportReport:
    """Export every capture under ``paths`` to ``out`` (a folder, local or fsspec URL) in ``format``.

    See :func:`lidarpkt.archive.export` for the arguments. Returns the :class:`ExportReport`.

    Raises:
        PlanError: bad PATHS, format or options; ExportBusyError: another job writes ``out``;
        EngineError: the engine cannot start.
    """
    out = os.fspath(out)
    options = writer_options(format, layout=layout, frames_per_file=frames_per_file, storage=storage)
    seg_bytes = parse_size_arg(segment_bytes)
    _prepare_outdir(out)
    engine = EngineOptions(workers=workers, scheduler=scheduler, client=client,
                           **({} if retries is None else {"retries": retries}))
    with OutdirLock(out):
        if not is_remote(out):  # what unfinished units of a killed job left: redone below
            shutil.rmtree(Path(local_path(out)) / STAGING, ignore_errors=True)
        manifest = Manifest(out)
        job = job_fingerprint(format, options)
        tasks, mtimes, failed = plan_units(paths, out, format, options, glob=glob,
                                           metadata=[os.fspath(m) for m in metadata], segment_bytes=seg_bytes,
                                           open_options=open_options)
        report = ExportReport()
        todo = _not_done(manifest, tasks, mtimes, job, report)
        for task, error in failed:
            result = UnitResult(key=task.key, input=task.input, part=None, error=error, size_bytes=task.size_bytes)
            row = make_row(task, result, capture_mtime_ns=mtimes[task.key], job=job)
            manifest.append(row)
            report.rows.append(row)
        todo.sort(key=lambda t: -t.size_bytes)  # the largest first: the job ends sooner
        bar = None
        try:
            with _one_client(engine, todo) as engine:  # one cluster for both passes
                todo, unknown = _with_ordinals(todo, tasks, engine, progress=progress)
                bar = Progress(sum(t.size_bytes for t in todo + unknown), len(todo) + len(unknown), callback=progress,
                               label=f"export {format}")
                record = _Recorder(manifest, report, bar, mtimes, job)
                for task in unknown:
                    record(task, UnitResult(key=task.key, input=task.input, part=task.part, error=task.ordinals,
                                            size_bytes=task.size_bytes))
                run_all(run_unit, todo, engine, record, lost=_lost_unit)
        finally:
            if bar is not None:
                bar.close()
            manifest.flush()
            if not is_remote(out):
                try:
                    (Path(local_path(out)) / STAGING).rmdir()  # empty once every unit has finished
                except OSError:
                    pass
    order = {t.key: i for i, t in enumerate(tasks)}
    report.rows.sort(key=lambda r: order.get(r["key"], -1))
    return report


@contextmanager
def _one_client(engine: EngineOptions, todo: list[UnitTask]) -> Iterator[EngineOptions]:
    """``engine``, with the Dask client it starts shared by the count pass and the units."""
    if engine.in_process() or engine.client is not None or not todo:
        yield engine
        return
    with dask_client(engine) as client:
        yield replace(engine, client=client)


def _with_ordinals(todo: list[UnitTask], tasks: list[UnitTask], engine: EngineOptions, *,
                   progress: ProgressCallback | None = None) -> tuple[list[UnitTask], list[UnitTask]]:
    """(tasks to run, tasks that cannot run): each segment after a capture's first gets its whole-file
    ordinals, counted in the segments before it (:mod:`.ordinals`); a segment whose ordinals cannot
    be known (an earlier segment is damaged: the whole-file reader stops there too) is returned
    apart, with the reason in its ``ordinals``."""
    need: dict[str, int] = {}  # capture → the last segment that must be counted
    for t in todo:
        if t.segment is not None and t.segment.index > 0:
            need[t.input] = max(need.get(t.input, 0), t.segment.index - 1)
    if not need:
        return todo, []
    counts: dict[tuple[str, int], SegmentCount] = {}
    jobs = [CountTask(t.key, t.input, t.segment, t.open_options) for t in tasks
            if t.segment is not None and t.segment.index <= need.get(t.input, -1)]
    bar = Progress(sum(j.segment.size_bytes for j in jobs), len(jobs), callback=progress, label="count frames")

    def got(job: CountTask, count: SegmentCount) -> None:
        counts[(job.input, job.segment.index)] = count
        bar.advance(job.segment.size_bytes, failed=count.error is not None)

    try:
        run_all(count_segment, jobs, engine, got,
                lost=lambda job, why: SegmentCount(job.key, error=f"{job.input}: counting its frames: {why}"))
    finally:
        bar.close()
    ready: list[UnitTask] = []
    unknown: list[UnitTask] = []
    for t in todo:
        if t.segment is None or t.segment.index == 0:
            ready.append(t)
            continue
        start = start_ordinals([counts[(t.input, i)] for i in range(t.segment.index)])[-1]
        (unknown if isinstance(start, str) else ready).append(replace(t, ordinals=start))
    return ready, unknown


def _not_done(manifest: Manifest, tasks: list[UnitTask], mtimes: dict[str, int], job: str,
              report: ExportReport) -> list[UnitTask]:
    """The tasks an earlier run has not finished; the finished ones' rows go into ``report``."""
    latest = manifest.latest()
    todo = []
    for task in tasks:
        if manifest.is_done(task, mtime_ns=mtimes[task.key], job=job):
            report.rows.append(latest[task.key])
            report.skipped += 1
        else:
            todo.append(task)
    return todo


class _Recorder:
    """Called in the driver as each unit finishes: its manifest row, the report, the progress."""

    def __init__(self, manifest: Manifest, report: ExportReport, bar: Progress, mtimes: dict[str, int],
                 job: str) -> None:
        self.manifest, self.report, self.bar, self.mtimes, self.job = manifest, report, bar, mtimes, job
        self.claimed = {rel: r["key"] for r in report.rows for rel in r["outputs"] or ()}

    def __call__(self, task: UnitTask, result: UnitResult) -> None:
        row = make_row(task, result, capture_mtime_ns=self.mtimes[task.key], job=self.job)
        clash = [(rel, self.claimed[rel]) for rel in row["outputs"]
                 if self.claimed.setdefault(rel, task.key) != task.key]
        if clash:  # a safety net: names are made distinct per capture and segment
            row.update(status="failed", error=f"{clash[0][0]}: written by {task.key} and by {clash[0][1]}; "
                       "export these captures to separate folders")
        self.manifest.append(row)
        self.report.rows.append(row)
        self.bar.advance(task.size_bytes, failed=row["status"] != "done")


def _lost_unit(task: UnitTask, why: str) -> UnitResult:
    return UnitResult(key=task.key, input=task.input, part=task.part, error=f"{task.input}: {why}",
                      size_bytes=task.size_bytes)


def parse_size_arg(value: int | str) -> int:
    from .plan import parse_size

    return parse_size(value)
