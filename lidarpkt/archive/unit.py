"""The pure unit of work of an archive job: one capture (or one segment of one) decoded and written.

:func:`run_unit` takes a :class:`UnitTask` and returns a :class:`UnitResult`; both are small,
frozen and picklable, and the unit keeps no state between calls, so any engine (a loop in this
process, a Dask worker anywhere) runs it. It is idempotent: outputs are written into a staging
folder of their own (``OUTDIR/.staging/KEY`` for a local OUTDIR, the worker's scratch for a
remote one), which is emptied first, and moved to their final names only when the writer has
closed them, so a unit killed at any point leaves nothing that looks complete.

Bad input (a damaged, unreadable or unknown capture, missing Ouster metadata) becomes the
result's ``error``, never an exception; frames decoded before the damage are kept. Programming
errors are not caught.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidarpkt.errors import LidarpktError, LidarpktWarning, OutputError

from .plan import is_remote, local_path

STAGING = ".staging"  # under a local OUTDIR: the unfinished units' files (hidden from Parquet readers)
DECODE_TOPICS = ("packets", "points")  # an MCAP unit writes what `lidarpkt decode IN -o OUT.mcap` writes


@dataclass(frozen=True)
class UnitTask:
    """What one unit does.

    Attributes:
        key: the unit's name in the manifest: the capture name, plus ``#PART`` for a segment.
        input: the capture (local path, ``file://`` or another fsspec URL).
        capture: the capture's unique name in the job (outputs are named after it).
        output: OUTDIR (local path or fsspec URL).
        format: a :func:`lidarpkt.writers.open_writer` format name.
        options: writer options as sorted ``(name, value)`` pairs (``layout``, ``frames_per_file``...).
        metadata: Ouster metadata JSONs (paths or URLs).
        open_options: other keyword options of ``lidarpkt.open``, as sorted ``(name, value)`` pairs.
        segment: a :class:`lidarpkt.containers.segments.Segment`, or None for the whole file.
        part: the segment's name (``seg0003``), None for the whole file.
        size_bytes: bytes this unit reads (for progress), the capture's size when whole.
        ordinals: a segment's :class:`~lidarpkt.archive.ordinals.Ordinals` (where its VLP-16
            ``frame_id`` and ``packet_index`` start in the whole file); None: from 0. (A task the
            job holds back carries here, instead, why its ordinals are unknown; it is not run.)
    """

    key: str
    input: str
    capture: str
    output: str
    format: str
    options: tuple[tuple[str, Any], ...] = ()
    metadata: tuple[str, ...] = ()
    segment: Any = None
    part: str | None = None
    size_bytes: int = 0
    ordinals: Any = None
    open_options: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class UnitResult:
    """What one unit did.

    Attributes:
        key, input, part: as in the task.
        outputs: the complete files written, relative to OUTDIR (``/``-separated), sorted.
        frames: frames written; points: returns written (points of every slot).
        lost_packets: packets missing inside frames (sum of the frames' counters).
        skipped_packets: packets of streams that are no supported sensor (counted, not decoded).
        malformed_packets: records and packets skipped as malformed (reader and decoders).
        warnings: the texts of the warnings the decode emitted (truncation, skips), at most 20.
        seconds: wall time of the unit; cpu_seconds: CPU time of its process meanwhile (on a loaded
            machine the honest measure of its cost).
        error: None when the unit completed; else what was wrong with the input, in one line.
    """

    key: str
    input: str
    part: str | None
    outputs: tuple[str, ...] = ()
    frames: int = 0
    points: int = 0
    lost_packets: int = 0
    skipped_packets: int = 0
    malformed_packets: int = 0
    warnings: tuple[str, ...] = ()
    seconds: float = 0.0
    error: str | None = None
    size_bytes: int = 0
    cpu_seconds: float = 0.0

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass
class _Counts:
    frames: int = 0
    points: int = 0
    lost: int = 0
    malformed: int = 0
    messages: list[str] = field(default_factory=list)


def writer_target(fmt: str, stage: Path, capture: str, options: dict[str, Any]) -> Path:
    """Where a unit's writer writes, inside its staging folder: the staging root for Parquet (a
    dataset partitioned by capture: OUTDIR is the dataset); ``CAPTURE_STEM.SUFFIX`` for one-file
    formats (npz, mcap, las/laz, csv, rrd, bag; and the rosbag2 folder, one output as well); a
    folder ``CAPTURE_STEM/`` for the formats that write a folder (ply, pcd, kitti, las/laz/csv with
    ``frames_per_file``)."""
    from lidarpkt.writers import FORMATS

    stem = Path(capture).stem
    if fmt == "parquet":
        return stage
    if fmt == "pcap":  # the raw packets, not frames: no frame writer (.packets)
        return stage / f"{stem}.pcap"
    spec = FORMATS.get(fmt)
    if spec is not None and not spec.directory and not options.get("frames_per_file"):
        return stage / f"{stem}{spec.suffixes[0]}"  # .mcap, .npz, .las, .bag, .rosbag2 ...
    return stage / stem


def _stage_dir(task: UnitTask) -> tuple[Path, bool]:
    """(staging folder, is it a scratch folder of this worker)."""
    if is_remote(task.output):
        return Path(tempfile.mkdtemp(prefix="lidarpkt-unit-")), True
    safe = "".join(c if c.isalnum() or c in "._-" else "_" for c in task.key)
    return Path(local_path(task.output)) / STAGING / safe, False


def _fetch_input(url: str, scratch: list[str]) -> str:
    """A local path of ``url``: itself when local, else a copy in this worker's scratch folder."""
    if not is_remote(url):
        return local_path(url)
    import fsspec

    folder = tempfile.mkdtemp(prefix="lidarpkt-in-")
    scratch.append(folder)
    fs, path = fsspec.core.url_to_fs(url)
    dest = os.path.join(folder, os.path.basename(path.rstrip("/")))
    fs.get(path, dest, recursive=fs.isdir(path))
    return dest


def _publish(files: list[Path], stage: Path, task: UnitTask) -> tuple[str, ...]:
    """Move complete files from the staging folder to their place under OUTDIR (a folder output, a
    rosbag2, file by file)."""
    files = [p for f in files for p in (sorted(x for x in Path(f).rglob("*") if x.is_file()) if Path(f).is_dir()
                                        else [Path(f)])]
    rels = []
    remote = is_remote(task.output)
    if remote:
        import fsspec

        fs, root = fsspec.core.url_to_fs(task.output)
    for f in files:
        rel = Path(f).resolve().relative_to(stage.resolve()).as_posix()
        try:
            if remote:
                fs.put_file(str(f), f"{root.rstrip('/')}/{rel}")
            else:
                dest = Path(local_path(task.output)) / rel
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(f, dest)
        except OSError as exc:
            raise OutputError(f"{task.output}/{rel}: cannot put the output in place ({exc.strerror or exc}); "
                              "check the output folder's space and permissions") from None
        rels.append(rel)
    return tuple(sorted(rels))


def _write_capture(path: str, task: UnitTask, metadata: list[str], writer: Any, feed: Any) -> None:
    """The task's capture (its segment, when it has one) into ``writer``, in one pass (``metadata``: local
    paths); a segment's frames get the whole file's ordinals."""
    options: dict[str, Any] = dict(task.open_options)
    if task.segment is not None:
        options["segment"] = task.segment
    feed.write(path, [writer], metadata=metadata or None, **options)


def _write_pcap(path: str, target: Path, metadata: list[str]) -> list[Path]:
    """The capture's raw packets as a pcap (:func:`.packets.write_packets_pcap`); frames are not counted."""
    from .packets import write_packets_pcap

    write_packets_pcap(path, target, metadata=metadata)
    return [target]


def _feed(task: UnitTask) -> Any:
    """The :class:`lidarpkt.writers.feed.Feed` of the task: a segment's frames renumbered to the whole file's."""
    from lidarpkt.writers.feed import Feed

    from .ordinals import renumber_from

    renumber = renumber_from(task.ordinals) if task.segment is not None else None
    return Feed(map_frame=None if renumber is None else renumber.frame)


def _reader_counts(reader: Any) -> tuple[int, int]:
    """(skipped, malformed) packets the readers counted: unrouted streams; malformed records."""
    if reader is None:
        return 0, 0
    skipped = int(getattr(reader.stats, "unrouted_packets", 0))
    pstats = getattr(getattr(reader, "reader", None), "stats", None)
    malformed = int(getattr(pstats, "malformed", 0) or 0) if pstats is not None and not isinstance(pstats, dict) else 0
    return skipped, malformed


def run_unit(task: UnitTask) -> UnitResult:
    """Decode one capture or segment into the task's format under OUTDIR; see the module doc.

    Returns:
        a :class:`UnitResult`; ``error`` says what was wrong with the input or the output, and
        ``outputs`` are then the files of the frames decoded before the damage (possibly none).
    """
    from lidarpkt.writers import open_writer, takes_packets

    start, cpu_start = time.perf_counter(), time.process_time()
    counts = _Counts()
    scratch: list[str] = []
    stage, _ = _stage_dir(task)
    shutil.rmtree(stage, ignore_errors=True)  # an earlier, killed attempt's files
    try:
        stage.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        return UnitResult(key=task.key, input=task.input, part=task.part, size_bytes=task.size_bytes,
                          error=f"{stage.parent}: cannot create the staging folder ({exc.strerror or exc}); "
                                "check the output folder's space and permissions")
    options = dict(task.options)
    error: str | None = None
    outputs: tuple[str, ...] = ()
    writer = None
    feed = _feed(task)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", LidarpktWarning)
            try:
                local = _fetch_input(task.input, scratch)
                target = writer_target(task.format, stage, task.capture, options)
                metadata = [_fetch_input(m, scratch) for m in task.metadata]
                if task.format == "pcap":  # the raw packets back in a pcap
                    outputs = _publish(_write_pcap(local, target, metadata), stage, task)
                else:
                    if takes_packets(task.format):  # decode's output: the capture's raw packets (of the one pass), clouds
                        from lidarpkt.writers.mcap.frames import calibration_file

                        options = {"topics": DECODE_TOPICS, "capture": local, **options,
                                   "calibration": calibration_file(metadata)}
                    else:
                        options = {"capture": task.capture, **options}
                    writer = open_writer(task.format, target, part=task.part, **options)
                    _write_capture(local, task, metadata, writer, feed)
            except OutputError as exc:  # nothing of this unit can be trusted
                error = str(exc)
                feed.frames = 0
            except (LidarpktError, OSError) as exc:  # damaged input: keep the frames before the damage
                error = _input_error(task, exc)
        counts.frames, counts.lost, counts.malformed = feed.frames, feed.lost_packets, feed.malformed_packets
        counts.messages = [str(w.message) for w in caught if issubclass(w.category, LidarpktWarning)][:20]
        if writer is not None and counts.frames:
            counts.points = int(getattr(writer, "points_written", 0))
            try:
                outputs = _publish(writer.close(), stage, task)
            except LidarpktError as exc:
                error, outputs = error or str(exc), ()
    finally:
        if feed.last is not None:
            feed.last.close()
        if writer is not None and not outputs:
            writer.abort()
        shutil.rmtree(stage, ignore_errors=True)
        for folder in scratch:
            shutil.rmtree(folder, ignore_errors=True)
    skipped, malformed = _reader_counts(feed.last.reader if feed.last is not None else None)
    return UnitResult(
        key=task.key, input=task.input, part=task.part, outputs=outputs, frames=counts.frames if outputs else 0,
        points=counts.points if outputs else 0, lost_packets=counts.lost, skipped_packets=skipped,
        malformed_packets=malformed + counts.malformed, warnings=tuple(counts.messages),
        seconds=time.perf_counter() - start, error=error, size_bytes=task.size_bytes,
        cpu_seconds=time.process_time() - cpu_start,
    )


def _input_error(task: UnitTask, exc: BaseException) -> str:
    """One line naming the input: the library's message (which names the file), or the OS error."""
    if isinstance(exc, OSError):
        return f"{task.input}: cannot read ({exc.strerror or exc})"
    text = str(exc)
    name = os.path.basename(local_path(task.input))
    return text if name in text else f"{task.input}: {text}"
