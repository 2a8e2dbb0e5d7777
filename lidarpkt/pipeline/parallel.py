"""Both cores: ``lidarpkt.open(path, workers=N)`` decodes with N workers beside the caller's thread.

- **Segments** (:class:`ParallelFrameReader`, pcap/pcapng of at least 2 x :data:`MIN_SEGMENT_BYTES`):
  the capture is cut into record-aligned segments (:func:`lidarpkt.containers.segments.plan_segments`,
  cuts found by re-synchronising on record headers near each cut, so that planning reads almost
  nothing); each segment is read by its own :class:`~lidarpkt.pipeline.reader.FrameReader`
  (``segment=``), which yields exactly the frames the segment owns. The workers are forked processes
  (:mod:`lidarpkt.pipeline.processes`: no GIL shared with the caller, frames handed back through shared
  memory in one copy), or threads where this process cannot fork (a daemonic worker of its own, a
  platform without ``fork``; then only for N >= 3). The frames of segment k are handed out only after
  those of segment k-1, so the order is that of ``workers=1``; the VLP-16 ordinals a segment reader
  counts from its own start (``frame_id``, ``extra["packet_index"]``) are renumbered to the whole
  file's. The reader of each segment checks the cut after it (its walk of the records must meet it)
  and stops the capture where damage stops the single-threaded reader. Memory stays flat in the
  capture's length: each worker holds at most its ring of frames (processes) or its segment
  (threads), each segment at most :data:`MAX_SEGMENT_BYTES` of packets and about
  :data:`MAX_SEGMENT_FRAME_BYTES` of frames.
- **A pipeline** (:class:`PipelinedFrameReader`, the containers that cannot be cut: MCAP, bags, OSF,
  and small captures): one thread reads the packets (the read-ahead of ``workers=1``) and a second
  decodes them into frames, up to :data:`DECODE_AHEAD_BYTES` of frames ahead of the caller, whose own
  work on each frame then overlaps the decoding of the next ones. The frames are those of the
  single-threaded reader itself (same object code, same order), and its warnings reach the caller's
  thread at the point of the stream where they arose.

``workers=None`` (the default) is :func:`default_workers`: several processes for a large pcap/pcapng,
one thread otherwise.
"""

from __future__ import annotations

import os
import queue
import threading
import weakref
from collections import deque
import dataclasses
from dataclasses import fields
from typing import TYPE_CHECKING, Any, Callable, Generator

import numpy as np

from lidarpkt.errors import CaptureFormatError, UnknownSensorError
from lidarpkt.core.frame import Frame
from lidarpkt.core.sequence import FrameIterator
from lidarpkt.vendors import registry
from .options import OpenOptions

if TYPE_CHECKING:
    from concurrent.futures import ThreadPoolExecutor

__all__ = ["ParallelFrameReader", "PipelinedFrameReader", "Renumber", "check_workers", "open_parallel", "plan",
           "default_workers", "PARALLEL_MIN_BYTES", "MIN_SEGMENT_BYTES", "MAX_SEGMENT_BYTES", "MAX_SEGMENT_FRAME_BYTES",
           "DECODE_AHEAD_BYTES"]

# Each segment boundary costs about two frames of decoding (the segment after it discards the frame it
# starts in; the one before reads on to complete its last frame) plus a reader's set-up (callgrind: ~17M
# instructions for VLP-16 dual, where 1 MB of capture costs ~27M; ~20M for OS-2-128, 6M per MB). So
# segments hold many frames, but no more than MAX_SEGMENT_FRAME_BYTES of decoded frames each.

PARALLEL_MIN_BYTES = 64 << 20  # workers=None: captures at least this large are decoded by several processes
MAX_DEFAULT_WORKERS = 4
MIN_DEFAULT_WORKERS = 3  # workers=None forks no fewer: two on two cores were slower than one
MIN_SEGMENT_BYTES = 8 << 20
MAX_SEGMENT_BYTES = 64 << 20
MAX_SEGMENT_FRAME_BYTES = 56 << 20
_SEGMENTS_PER_WORKER = 2  # a capture gives at least this many segments per worker when it is large enough
_END = object()  # marks the end of a segment's frames on its queue
DECODE_AHEAD_BYTES = 16 << 20  # frames decoded ahead of the caller (~10 OS-128 frames, ~70 VLP-16 dual ones)
DECODE_THREAD_NAME = "lidarpkt-decode"


class PipelinedFrameReader(FrameIterator):
    """Iterator of :class:`~lidarpkt.core.frame.Frame`: a single-threaded reader's frames, decoded in a thread
    of their own ahead of the caller (``lidarpkt.open(path, workers=2)``; see the module docstring).

    ``reader`` is that :class:`~lidarpkt.pipeline.reader.FrameReader` (its packets read ahead as ``workers=1``
    reads them; in a pass with packets, :func:`lidarpkt.pipeline.passes.open_pass`, its batches come through
    in order with the frames); ``stats`` is its :class:`~lidarpkt.core.streams.SourceStats`, complete once
    the iteration has ended. ``close()`` (or ``with``) stops both threads. Raises while iterating what the
    single-threaded reader raises, after the frames before it.
    """

    def __init__(self, reader: Any, max_bytes: int = DECODE_AHEAD_BYTES) -> None:
        from lidarpkt.core.readahead import ReadAhead

        self.reader = reader
        self.stats = reader.stats
        self.workers = 2
        self._ahead = self._iter = ReadAhead(lambda: reader, max_bytes=max_bytes, nbytes=_frame_nbytes,
                                             name=DECODE_THREAD_NAME)

    def close(self) -> None:
        """Stop decoding (the thread finishes the frame in hand and closes the reader). Idempotent."""
        self._ahead.close()

    def __del__(self) -> None:
        ahead = getattr(self, "_ahead", None)
        if ahead is not None:
            ahead.close(timeout=0)


def _frame_nbytes(frame: Frame) -> int:
    """Bytes of a frame's arrays (what it counts against :data:`DECODE_AHEAD_BYTES`); of a pass's packet batch
    (:class:`~lidarpkt.pipeline.reader.Packets`), its payload."""
    batch = getattr(frame, "batch", None)
    if batch is not None:
        return int(batch.payload.nbytes)
    total = sum(v.nbytes for v in vars(frame).values() if isinstance(v, np.ndarray))
    return total + sum(v.nbytes for v in frame.extra.values() if isinstance(v, np.ndarray))


class ParallelFrameReader(FrameIterator):
    """Iterator of :class:`~lidarpkt.core.frame.Frame` decoded by ``workers`` processes (or threads) over segments
    of a capture.

    Made by ``lidarpkt.open(path, workers=N)`` with N > 1; yields the frames of ``workers=1``, in the
    same order, with the same arrays, ``frame_id`` and ``extra``. ``stats`` sums the segment readers'
    :class:`~lidarpkt.core.streams.SourceStats` (its packet counters include the packets each segment reader
    read past its end to complete its last frame; ``stats.frames`` is exact). ``close()`` (or ``with``)
    stops the workers (processes are ended, threads finish the segment in hand). Warnings of the segment
    readers are re-emitted in the caller's thread (processes) or emitted from the worker threads.

    Raises (while iterating): what ``lidarpkt.open`` raises, at the point of the stream where the
    single-threaded reader would (the frames of the segments before it are yielded first).
    """

    _iter: Generator[Frame, None, None]  # closed by close()

    def __init__(self, path: str | os.PathLike[str], segments: list, options: OpenOptions,
                 open_segment: Callable[[str | os.PathLike[str], OpenOptions], Any], stats: Any,
                 processes: bool = False) -> None:
        """``options`` are ``lidarpkt.open``'s; ``open_segment(path, options)`` makes the single-threaded reader
        of ``options.segment`` (a :class:`~lidarpkt.pipeline.reader.FrameReader`); ``stats`` is an empty
        :class:`~lidarpkt.core.streams.SourceStats` that sums theirs; ``processes``: the segments are
        decoded by forked processes (:mod:`lidarpkt.pipeline.processes`) instead of threads."""
        self.path = path
        self.segments = segments
        self.workers = int(options.workers or 1)
        self.processes = bool(processes)
        self._include_partial = options.include_partial
        # the workers are the threads; the sensor files are read once, not per segment
        self._options = dataclasses.replace(options, workers=1, include_partial=True, read_ahead=False,
                                            metadata=registry.load_sensor_files(options.metadata) or None)
        self._open_segment = open_segment
        self.stats = stats
        self._stop = threading.Event()
        self._pool: ThreadPoolExecutor | None = None
        self._runner = None
        if self.processes:
            from .processes import ProcessRunner

            self._runner = ProcessRunner(segments, self.workers, self._read_segment)
        else:
            from concurrent.futures import ThreadPoolExecutor  # imported when used: logging, its start-up cost

            self._pool = ThreadPoolExecutor(self.workers, thread_name_prefix="lidarpkt-segment")
        # the generator holds a weak proxy: dropping the reader finalises it (__del__ stops the workers)
        self._iter = ParallelFrameReader._frames(weakref.proxy(self))

    def close(self) -> None:
        """Stop: pending segments are cancelled, running ones stop at their next frame (worker processes
        are ended). Idempotent."""
        self._stop.set()
        self._iter.close()
        self._end(wait=True)

    def __del__(self) -> None:
        stop = getattr(self, "_stop", None)
        if stop is not None:
            stop.set()
            self._end(wait=False)

    def _end(self, wait: bool) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=wait, cancel_futures=True)
        if self._runner is not None:
            self._runner.close()

    # ------------------------------------------------------------------ work
    def _read_segment(self, segment, out: queue.SimpleQueue) -> None:
        """Put one segment's frames on ``out`` as they come, then ``(_END, stats, split_ordinal, unknown,
        error, split_offset, truncated)``: its stats, the ordinal of its first packet past its end, the
        message of an UnknownSensorError (a segment of foreign traffic is no error while another segment
        holds a sensor), any other exception (raised by the consumer when it gets there), where its walk
        crossed its end (see :meth:`_check_cut`) and whether it stopped at damage."""
        reader = None
        unknown = error = None
        try:
            reader = self._open_segment(self.path, dataclasses.replace(self._options, segment=segment))
            for frame in reader:
                if self._stop.is_set():
                    break
                out.put(frame)
        except UnknownSensorError as exc:
            unknown = str(exc)
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer's thread, raised there
            error = exc
        finally:
            if reader is not None:
                reader.close()
        stats = reader.stats if reader is not None else None
        pcap = getattr(reader, "reader", None)
        read_stats = getattr(pcap, "stats", None)
        out.put((_END, stats, getattr(pcap, "split_ordinal", None), unknown, error, getattr(pcap, "split_offset", None),
                 bool(getattr(read_stats, "truncated", False))))

    def _frames(self) -> Generator[Frame, None, None]:
        pending: deque[tuple[Any, Any]] = deque()  # (segment, its items' get()): a queue or a process channel
        todo = iter(self.segments)
        renumber = Renumber()
        unknown: list[str] = []
        segments_read = 0

        def submit() -> None:
            seg = next(todo, None)
            if seg is None:
                return
            if self._runner is not None:  # the worker processes have their segments already
                pending.append((seg, self._runner.start(seg)))
                return
            q: queue.SimpleQueue = queue.SimpleQueue()
            assert self._pool is not None
            self._pool.submit(self._read_segment, seg, q)
            pending.append((seg, q))

        try:
            for _ in range(self.workers):
                submit()
            while pending:
                seg, q = pending[0]
                while True:
                    item = q.get()
                    if not isinstance(item, Frame):  # the end of the segment
                        break
                    frame = renumber.frame(item)
                    if frame.partial and not self._include_partial:
                        continue
                    self.stats.frames += 1
                    yield frame
                _, stats, split, no_sensor, error, split_offset, truncated = item
                if error is not None:
                    raise error
                pending.popleft()
                segments_read += 1
                renumber.end_segment(split)
                if stats is not None:
                    _add_stats(self.stats, stats)
                if no_sensor is not None:
                    unknown.append(no_sensor)
                if not self._check_cut(seg, split_offset, truncated):
                    break  # the whole-file reader stops at the same damage: no later segment counts
                submit()
        finally:
            try:
                self._stop.set()
                self._end(wait=False)
            except ReferenceError:  # the reader was dropped, and its __del__ has stopped the workers
                pass
        if unknown and len(unknown) == segments_read:
            raise UnknownSensorError(unknown[0])

    def _check_cut(self, segment, split_offset: int | None, truncated: bool) -> bool:
        """Whether the segments after ``segment`` continue the capture: False when its reader stopped at
        damage before its end (the single-threaded reader stops there too).

        Raises:
            CaptureFormatError: its walk crossed its end elsewhere than at the start of a record (the
                cut, found by re-synchronising on record headers, is no record boundary).
        """
        if segment.index == segment.count - 1 or split_offset is None:
            return segment.index == segment.count - 1 or not truncated
        if split_offset != segment.end_offset:
            raise CaptureFormatError(
                f"{self.path}: workers={self.workers} cut the capture at byte {segment.end_offset}, which the records "
                f"walked from byte {segment.start_offset} do not start at; read it with workers=1")
        return True


class Renumber:
    """A segment reader's frames with the whole file's VLP-16 ordinals (``frame_id``,
    ``extra["packet_index"]``) and one SensorInfo object per sensor and mode (changed in place).

    ``lidarpkt.open(workers=N)`` reads the segments in order and starts from nothing: each segment
    carries the counts on (:meth:`end_segment`), and the first SensorInfo of a sensor, as the
    single-threaded reader's first frame's, serves the whole capture. An archive unit reads one
    segment alone and is given where it starts: ``frame_ids`` (per VLP-16 source, the whole file's
    id of the segment's first frame), ``packet_base`` (ordinal of its first packet) and ``rates``
    (per source, the whole file's ``(frequency_hz, columns_per_frame)``: a segment's decoder measures
    the rate from its own first packets).
    """

    def __init__(self, frame_ids: dict[str, int] | None = None, packet_base: int = 0,
                 rates: dict[str, tuple] | None = None) -> None:
        self.packet_base = int(packet_base)  # ordinal, in the whole file, of the current segment's first packet
        self.next_frame_id: dict[str, int] = dict(frame_ids or {})  # per VLP-16 stream: frame_id of its next frame
        self.rates = dict(rates or {})
        self.sensors: dict[int, Any] = {}  # id(segment's SensorInfo) → the whole file's
        self.canonical: dict[tuple, Any] = {}
        self._held: list = []  # keeps the SensorInfo objects whose id() is a key alive

    def frame(self, frame: Frame) -> Frame:
        """``frame`` of the current segment with the whole file's ordinals and SensorInfo."""
        frame.sensor = self._sensor(frame.sensor)
        if registry.vendor(frame.sensor.vendor).frame_ids_counted:  # frame ids counted from the stream's start
            key = str(frame.sensor.source)
            frame.frame_id = self.next_frame_id.get(key, 0)
            self.next_frame_id[key] = frame.frame_id + 1
        index = frame.extra.get("packet_index")
        if index is not None and self.packet_base:
            frame.extra["packet_index"] = np.where(index >= 0, index + self.packet_base, index)
        return frame

    def end_segment(self, split_ordinal: int | None) -> None:
        """The current segment is done; the next one's packets start ``split_ordinal`` packets later."""
        if split_ordinal is not None:
            self.packet_base += int(split_ordinal)

    def _sensor(self, info):
        got = self.sensors.get(id(info))
        if got is None:
            rate = self.rates.get(str(info.source))
            if rate is not None and tuple(rate) != (info.frequency_hz, info.columns_per_frame):
                info_whole = dataclasses.replace(info, frequency_hz=rate[0], columns_per_frame=rate[1])
            else:
                info_whole = info
            # not the rate in the key: the first SensorInfo of a sensor and mode is the whole file's
            key = (info.vendor, str(info.source), info.model, info.return_mode, info.profile, info.serial,
                   info.init_id)
            got = self.canonical.setdefault(key, info_whole)
            self.sensors[id(info)] = got
            self._held.append(info)
        return got


def _add_stats(total, part) -> None:
    for f in fields(total):
        a, b = getattr(total, f.name), getattr(part, f.name)
        if isinstance(a, dict):
            for k, v in b.items():
                a[k] = a.get(k, 0) + v
        elif f.name != "frames":
            setattr(total, f.name, a + b)


def open_parallel(path: str | os.PathLike[str], options: OpenOptions,
                  open_segment: Callable[[str | os.PathLike[str], OpenOptions], Any], stats: Any
                  ) -> "ParallelFrameReader | PipelinedFrameReader | None":
    """``lidarpkt.open(path, **options)`` when ``options.workers`` > 1: segments for 3 workers or more on a
    capture that can be cut, the pipeline otherwise; ``None`` when a segment was asked for (it is read in
    one thread). ``open_segment`` and ``stats``: see :class:`ParallelFrameReader` (this module does not
    import :mod:`lidarpkt.pipeline.reader`, which calls it).

    Raises:
        lidarpkt.errors.UsageError: ``workers`` is not a positive integer.
    """
    workers = check_workers(options.workers)
    if workers is None:
        workers = default_workers(path)
        options = dataclasses.replace(options, workers=workers)
    if workers == 1 or options.segment is not None:
        return None
    from .processes import can_fork  # imported when used: multiprocessing's start-up cost

    processes = can_fork()
    if processes:
        from .processes import RING_BYTES

        segments = plan(path, workers, RING_BYTES)
    else:
        segments = plan(path, workers) if workers >= 3 else []
    if segments:
        return ParallelFrameReader(path, segments, options, open_segment, stats, processes=processes)
    return PipelinedFrameReader(open_segment(path, dataclasses.replace(options, workers=1)))


def check_workers(workers: Any) -> int | None:
    """``workers`` when it is ``None`` (the default: :func:`default_workers` decides) or a whole number >= 1.

    Raises:
        lidarpkt.errors.UsageError: it is neither.
    """
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        from lidarpkt.errors import UsageError

        raise UsageError(f"workers={workers!r}: not a whole number >= 1; give e.g. workers=2")
    return workers


def default_workers(path: str | os.PathLike[str]) -> int:
    """``lidarpkt.open``'s ``workers=None``: for a pcap/pcapng of at least :data:`PARALLEL_MIN_BYTES`, the CPUs this
    process may use that are idle now (the CPUs less the load average, at most :data:`MAX_DEFAULT_WORKERS`) when
    workers can be forked and at least :data:`MIN_DEFAULT_WORKERS` are idle, else 1. A smaller capture decodes in
    about the time it takes to set workers up, bags and OSF cannot be cut, on cores other processes keep busy the
    workers only add their copies and segment boundaries, and two workers on two cores measured slower than one
    (the documentation's performance page)."""
    from lidarpkt.containers.magic import container_kind
    from lidarpkt.errors import LidarpktError

    try:
        big = os.path.isfile(path) and os.path.getsize(path) >= PARALLEL_MIN_BYTES
        cuttable = big and container_kind(path) == "pcap"  # pcap or pcapng
    except (OSError, LidarpktError):  # the reader opened next says what is wrong with the file
        return 1
    if not cuttable:
        return 1
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    idle = min(cpus, MAX_DEFAULT_WORKERS, int(cpus - _load_average() + 0.5))
    if idle < MIN_DEFAULT_WORKERS:
        return 1
    from .processes import can_fork  # multiprocessing's modules, imported only when workers may be forked

    return idle if can_fork() else 1


def _load_average() -> float:
    try:
        return os.getloadavg()[0]
    except OSError:  # not available: assume the machine is idle
        return 0.0


def plan(path: str | os.PathLike[str], workers: int, frame_bytes: int | None = None) -> list:
    """The segments ``workers`` decode; one segment when the capture is no pcap/pcapng or too small.
    ``frame_bytes``: the frames a worker may hold at once (a process's ring; default
    :data:`MAX_SEGMENT_FRAME_BYTES`), which bounds a segment's frames."""
    from lidarpkt.containers.segments import plan_segments

    try:
        size = os.path.getsize(path)
    except OSError:
        return []
    if workers < 2 or os.path.isdir(path) or size < 2 * MIN_SEGMENT_BYTES:
        return []
    most = max(MIN_SEGMENT_BYTES, min(MAX_SEGMENT_BYTES, int((frame_bytes or MAX_SEGMENT_FRAME_BYTES) / _expansion(path))))
    seg_bytes = min(most, max(MIN_SEGMENT_BYTES, size // (workers * _SEGMENTS_PER_WORKER)))
    segments = plan_segments(path, seg_bytes, walk=False)  # each cut is checked by the segment before it
    return segments if len(segments) > 1 else []


def _expansion(path) -> float:
    """Frame bytes per capture byte, from a classic pcap's first record: 2.5 for datagrams that fit a record (a
    Velodyne packet: 7 bytes of frame for each 3-byte return, its columns' arrays besides), 1.0 for an IPv4
    fragment or a large record (an Ouster packet: its pixels as they come, field by field); 2.5 when unknown."""
    from lidarpkt.containers.magic import PCAP_MAGIC_MODIFIED, PCAP_MAGIC_NS, PCAP_MAGIC_US

    with open(path, "rb") as fh:
        head = fh.read(24 + 16 + 22)
    if len(head) < 62:
        return 2.5
    for order in ("little", "big"):
        if int.from_bytes(head[:4], order) in (PCAP_MAGIC_US, PCAP_MAGIC_NS, PCAP_MAGIC_MODIFIED):
            caplen = int.from_bytes(head[32:36], order)
            ethernet = int.from_bytes(head[20:24], order) == 1 and head[52:54] == b"\x08\x00"  # link type, IPv4
            fragment = ethernet and int.from_bytes(head[60:62], "big") & 0x3FFF != 0  # more fragments, or an offset
            return 1.0 if fragment or caplen >= 2000 else 2.5
    return 2.5  # pcapng, damage
