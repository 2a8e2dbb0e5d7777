"""Segments decoded in worker processes, their frames handed back through shared memory.

``lidarpkt.open(path, workers=N)`` cuts a large pcap/pcapng capture into segments
(:mod:`lidarpkt.pipeline.parallel`); with processes, N forked workers decode them (worker k takes
segments k, k + N, k + 2N …), so that the decoding holds no GIL the caller's thread wants. Each
worker writes the arrays of every frame it makes into a ring of shared memory of its own
(:data:`RING_BYTES`, mapped before the fork) and sends a small descriptor of the frame through a
pipe; the caller's frames are views of the ring, and their ring space is released when the last
view of a frame is dropped. So a frame crosses from one process to the other in one copy, made by
the worker, and memory stays bounded: a worker whose ring is full waits for the caller to drop
frames. When the caller is itself waiting for that worker (it keeps every frame it was given), the
worker sends the frame's bytes through the pipe instead, as a copy the caller owns.

What a worker sees is what the single-threaded reader of its segment sees: its warnings are sent
to the caller in their place among the frames and re-emitted there (same category and message),
its errors and counts come with the end of the segment. Workers are forked (POSIX ``fork``, so
nothing is imported again and the capture's metadata is parsed once); ``close()``, the end of the
frames or dropping the reader ends them (``SIGKILL`` when they are still busy) and reaps them.
"""

from __future__ import annotations

import dataclasses
import gc
import mmap
import os
import pickle
import signal
import threading
import time
import warnings
import weakref
from collections import deque
from multiprocessing.connection import Connection, Pipe
from typing import Any, Callable, Iterable

import numpy as np

from lidarpkt.core.frame import Frame
from lidarpkt.core.readahead import warn
from lidarpkt.errors import LidarpktError

__all__ = ["ProcessRunner", "RING_BYTES", "can_fork"]

#: Shared memory per worker for the frames it made that the caller has not dropped yet.
RING_BYTES = 32 << 20
_ALIGN = 64  # each array starts on a cache line
_PIPE_BYTES = 1 << 20  # the descriptors a worker may send ahead (F_SETPIPE_SZ; Linux's default maximum)
_WAIT_S = 0.0005  # a worker polls the ring this often while it is full
_FRAMES_PER_MESSAGE = 16  # frames described in one message at most (sooner when the caller waits for them)
# the control words of a ring, int64: bytes released by the caller (monotonic), and whether the caller
# is waiting for the worker's next message
_RELEASED, _WAITING = 0, 1


def can_fork() -> bool:
    """Whether this process can decode in forked workers: POSIX ``fork``, and not itself a daemonic
    ``multiprocessing`` worker (a Dask worker decoding an archive unit: it is the parallelism there)."""
    if not hasattr(os, "fork"):
        return False
    import multiprocessing

    return not multiprocessing.current_process().daemon


class _Ring:
    """A worker's shared memory: the ring of frame bytes and its control words, mapped before the fork."""

    def __init__(self, size: int) -> None:
        self.size = size
        # the pages made here, once (MAP_POPULATE where there is one): the worker and the caller then map them
        # without each faulting in zeroed pages of its own
        self.data = mmap.mmap(-1, size, flags=mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0))
        self._control_map = mmap.mmap(-1, mmap.PAGESIZE)
        self.control = np.frombuffer(self._control_map, np.int64, 2)


# ------------------------------------------------------------------------------------------ worker side
class _Sender:
    """The worker's end: frames packed into the ring (or pickled whole when it must not wait), warnings
    and the end of each segment pickled, all through the pipe in the order they happen."""

    def __init__(self, ring: _Ring, conn: Connection) -> None:
        self.ring = ring
        self.conn = conn
        self.head = 0  # bytes allocated since the start (monotonic); position head % size
        self.sensors: dict[int, Any] = {}  # id → SensorInfo sent (kept alive: the id stays unique)
        self._last: Frame | None = None
        self._images: dict[int, tuple[np.ndarray, bool]] = {}  # id → (read-only image, whether its rows are constant)
        self._pending: list[tuple] = []  # frames described but not sent: one message for several

    def put(self, item: Any) -> None:
        """A frame, or the end-of-segment tuple of :meth:`ParallelFrameReader._read_segment`."""
        if isinstance(item, Frame):
            self._frame(item)
            # kept until the next frame is made: freed first, its arrays at the top of the heap would be handed
            # back to the system and faulted in again for the next frame
            self._last = item
            if len(self._pending) >= _FRAMES_PER_MESSAGE or self.ring.control[_WAITING]:
                self._flush()
        else:
            self._send(("end", _picklable_end(item)))

    def warnings(self, caught: list) -> None:
        for w in caught:
            self._send(("warning", (w.category, str(w.message))))
        caught.clear()

    def _send(self, message: Any) -> None:
        self._flush()  # the frames before it first
        self.conn.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))

    def _flush(self) -> None:
        if self._pending:
            frames, self._pending = self._pending, []
            self.conn.send_bytes(pickle.dumps(("frames", frames), protocol=pickle.HIGHEST_PROTOCOL))

    def _frame(self, frame: Frame) -> None:
        sensor = frame.sensor
        if id(sensor) not in self.sensors:
            self.sensors[id(sensor)] = sensor
            self._send(("sensor", (id(sensor), sensor)))
        arrays: list[np.ndarray] = []
        fields, extra = _describe(frame, arrays, self._constant_rows)
        total = sum(_padded(a.nbytes) for a in arrays)
        start = self._allocate(total)
        if start is None:  # the caller waits for this frame and holds the ring: the bytes themselves
            self._pending.append(("copy", id(sensor), fields, extra, [np.ascontiguousarray(a) for a in arrays]))
            self._flush()
            return
        base, pos, places = start % self.ring.size, 0, []
        for a in arrays:
            dst = np.frombuffer(self.ring.data, a.dtype, a.size, base + pos).reshape(a.shape)
            np.copyto(dst, a)
            places.append((pos, a.dtype.str, a.shape))
            pos += _padded(a.nbytes)
        self._pending.append(("frame", id(sensor), fields, extra, places, start, self.head))

    def _constant_rows(self, v: np.ndarray) -> bool:
        """Whether ``v`` is a read-only 2-D view of a read-only image whose every row holds one value (checked once
        per image)."""
        base = v.base
        if v.flags.writeable or v.ndim != 2 or not isinstance(base, np.ndarray) or base.flags.writeable or base.ndim != 2:
            return False
        known = self._images.get(id(base))
        if known is None:
            known = (base, bool(base.size) and bool((base == base[:, :1]).all()))
            self._images[id(base)] = known
        return known[1]

    def _allocate(self, nbytes: int) -> int | None:
        """The monotonic offset of ``nbytes`` of ring (contiguous: a block that would wrap starts over at 0, the
        bytes skipped counted with it); ``None`` when the ring is full and the caller waits for this worker."""
        size, control = self.ring.size, self.ring.control
        if nbytes > size:
            return None
        skip = size - self.head % size if self.head % size + nbytes > size else 0
        need = skip + nbytes
        while self.head + need - int(control[_RELEASED]) > size:
            if self._pending:  # the caller cannot drop frames it has not been sent
                self._flush()
                continue
            if control[_WAITING]:
                return None
            time.sleep(_WAIT_S)
        start = self.head + skip
        self.head += need
        return start


def _describe(frame: Frame, arrays: list[np.ndarray], constant_rows: Callable[[np.ndarray], bool]) -> tuple[dict, dict]:
    """(fields, extra) of ``frame`` for the caller: every array replaced by its index in ``arrays`` (a
    broadcast array by its compact form and shape), the other values as they are; the sensor left out."""

    def place(v: Any) -> Any:
        if not isinstance(v, np.ndarray):
            return v
        if 0 in v.strides and v.size:  # a read-only broadcast: its compact form
            compact = v[tuple(slice(0, 1) if s == 0 else slice(None) for s in v.strides)]
            arrays.append(np.ascontiguousarray(compact))
            return _Array(len(arrays) - 1, v.shape, False)
        if constant_rows(v):  # a view of a read-only image of constant rows (Velodyne pixel time offsets)
            return _Rows(tuple(v[:, 0].tolist()), v.dtype.str, v.shape[1])
        arrays.append(v)
        return _Array(len(arrays) - 1, None, bool(v.flags.writeable))

    fields = {f.name: place(getattr(frame, f.name)) for f in dataclasses.fields(frame) if f.name not in ("sensor", "extra")}
    extra = {k: place(v) for k, v in frame.extra.items()}
    return fields, extra


@dataclasses.dataclass(frozen=True)
class _Rows:
    """A read-only ``[len(values), width]`` array whose row r holds ``values[r]``."""

    values: tuple
    dtype: str
    width: int


@dataclasses.dataclass(frozen=True)
class _Array:
    """Where a frame's array went: its index in the frame's arrays; ``shape`` when it is a broadcast of that
    compact array; whether it is writeable."""

    index: int
    shape: tuple | None
    writeable: bool


def _padded(n: int) -> int:
    return (n + _ALIGN - 1) // _ALIGN * _ALIGN


def _picklable_end(item: tuple) -> tuple:
    """The end-of-segment tuple with its exception replaced by one that pickles, when it does not."""
    error = item[4]
    if error is not None:
        try:
            pickle.loads(pickle.dumps(error))
        except Exception:  # noqa: BLE001 - any failure to round-trip: the caller gets its text
            item = (*item[:4], RuntimeError(f"{type(error).__name__}: {error}"), *item[5:])
    return item


def _serve(read_segment: Callable[[Any, Any], None], segments: list, sender: _Sender) -> None:
    """The worker's life: each of its segments read in turn (``read_segment(segment, out)`` puts its frames
    and end on ``out``), what it warns caught and sent in place."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")  # every warning goes to the caller, whose filters decide

        class Out:
            @staticmethod
            def put(item: Any) -> None:
                sender.warnings(caught)
                sender.put(item)

        for segment in segments:
            read_segment(segment, Out)


# ------------------------------------------------------------------------------------------ caller side
class _Channel:
    """The caller's end of one worker: its messages, frames made views of the ring."""

    def __init__(self, ring: _Ring, conn: Connection, pid: int) -> None:
        self.ring = ring
        self.conn = conn
        self.pid = pid
        self.sensors: dict[int, Any] = {}
        self.live: deque[list] = deque()  # [start, end, released] of the frames in the ring, in ring order
        self.lock = threading.Lock()  # releases come from whichever thread drops a frame
        self.queued: deque[tuple] = deque()  # frames received, not asked for yet

    def get(self) -> Any:
        """The next frame or end-of-segment tuple; warnings on the way are re-emitted here."""
        while True:
            if self.queued:
                item = self.queued.popleft()
                if item[0] == "frame":
                    return self._frame(*item[1:])
                _, sensor, fields, extra, arrays = item  # "copy"
                return _build(self.sensors[sensor], fields, extra, arrays)
            control = self.ring.control
            control[_WAITING] = 1
            try:
                data = self.conn.recv_bytes()
            except EOFError:
                raise LidarpktError(f"a decoding worker (process {self.pid}) ended before its segments did; "
                                    "read the capture with workers=1") from None
            finally:
                control[_WAITING] = 0
            kind, body = pickle.loads(data)
            if kind == "frames":
                self.queued.extend(body)
            elif kind == "sensor":
                self.sensors[body[0]] = body[1]
            elif kind == "warning":
                warn(body[0](body[1]), stacklevel=2)
            else:  # "end"
                return body

    def _frame(self, sensor: int, fields: dict, extra: dict, places: list, start: int, end: int) -> Frame:
        size = self.ring.size
        block = np.frombuffer(self.ring.data, np.uint8, end - start if places else 0, start % size if places else 0)
        arrays = [np.ndarray(shape, dt, block, p) for p, dt, shape in places]
        entry = [start, end, False]
        with self.lock:
            self.live.append(entry)
        weakref.finalize(block, self._release, entry)  # every array of the frame is a view of block
        return _build(self.sensors[sensor], fields, extra, arrays)

    def _release(self, entry: list) -> None:
        with self.lock:
            entry[2] = True
            tail = None
            while self.live and self.live[0][2]:
                tail = self.live.popleft()[1]
            if tail is not None:
                self.ring.control[_RELEASED] = tail


def _build(sensor: Any, fields: dict, extra: dict, arrays: list[np.ndarray]) -> Frame:
    def value(v: Any) -> Any:
        if isinstance(v, _Rows):
            return _rows_image(v)
        if not isinstance(v, _Array):
            return v
        a = arrays[v.index]
        if v.shape is not None:  # a broadcast of its compact form (read-only, as broadcasts are)
            return np.broadcast_to(a, v.shape)
        if not v.writeable:
            a.flags.writeable = False
        return a

    return Frame(sensor=sensor, extra={k: value(v) for k, v in extra.items()},
                 **{k: value(v) for k, v in fields.items()})


_IMAGES: dict[tuple, np.ndarray] = {}  # (values, dtype) → a read-only image of those rows, the widest asked for


def _rows_image(rows: _Rows) -> np.ndarray:
    """A read-only view of a kept image of constant rows (as the decoder's own frames share one)."""
    key = (rows.values, rows.dtype)
    image = _IMAGES.get(key)
    if image is None or image.shape[1] < rows.width:
        if len(_IMAGES) > 64:
            _IMAGES.clear()
        image = np.empty((len(rows.values), max(rows.width, 4096)), rows.dtype)
        image[...] = np.asarray(rows.values, rows.dtype)[:, None]
        image.flags.writeable = False
        _IMAGES[key] = image
    return image[:, :rows.width]


class ProcessRunner:
    """``workers`` forked processes decoding ``segments`` (worker k: segments k, k + workers, …) with
    ``read_segment(segment, out)``; :meth:`start` gives the stream of a segment's items (``get()``: its frames
    in order, then its end-of-segment tuple), which are to be asked for in segment order."""

    def __init__(self, segments: list, workers: int, read_segment: Callable[[Any, Any], None],
                 ring_bytes: int | None = None) -> None:
        ring_bytes = RING_BYTES if ring_bytes is None else ring_bytes
        self.workers = max(1, min(int(workers), len(segments)))
        self.pids: list[int] = []
        self._channels: list[_Channel] = []
        # the objects alive now are moved out of the collector's reach while forking: a worker's collections
        # would otherwise write to every object's header, copying each page of this process's heap
        gc.freeze()
        try:
            for k in range(self.workers):
                ring = _Ring(ring_bytes)
                recv, send = Pipe(duplex=False)
                _widen(send)
                pid = os.fork()
                if pid == 0:  # the worker
                    _worker(read_segment, segments[k::self.workers], ring, recv, send)
                send.close()
                self._channels.append(_Channel(ring, recv, pid))
                self.pids.append(pid)
        finally:
            gc.unfreeze()
        self._finalizer = weakref.finalize(self, _end_workers, [c.pid for c in self._channels])

    def start(self, segment: Any) -> _Channel:
        return self._channels[segment.index % self.workers]

    def close(self) -> None:
        """End the workers (killed when still busy) and reap them. Idempotent."""
        self._finalizer()


def _widen(conn: Connection) -> None:
    try:
        import fcntl

        fcntl.fcntl(conn.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), _PIPE_BYTES)
    except (ImportError, OSError):
        pass  # not Linux, or a lower limit: descriptors wait for the caller sooner


def _worker(read_segment: Callable[[Any, Any], None], segments: list, ring: _Ring, recv: Connection,
            send: Connection) -> None:
    """The body of a forked worker; never returns."""
    status = 1
    try:
        recv.close()
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # the caller decides when to stop (close() kills)
        _serve(read_segment, segments, _Sender(ring, send))
        send.close()
        status = 0
    except BaseException:  # noqa: BLE001 - the caller sees the pipe close early
        pass
    finally:
        os._exit(status)


def _end_workers(pids: Iterable[int]) -> None:
    for pid in pids:
        try:
            done, _ = os.waitpid(pid, os.WNOHANG)
            if done == 0:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
        except ChildProcessError:
            pass
