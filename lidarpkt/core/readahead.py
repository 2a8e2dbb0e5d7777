"""Read-ahead: packet batches read by a background thread while the caller decodes.

The pcap reader spends most of its time in ``readinto`` and NumPy copies, which release the
GIL, so reading the next batches on a second core overlaps with decoding the current ones.
:class:`ReadAhead` runs a reader's ``batches()`` in a daemon thread and hands the batches over
through a queue bounded in bytes (memory stays bounded whatever the capture's length).

What the reader raises or warns reaches the caller at the same point of the stream as without
the thread: an exception is queued after the batches read before it and raised again (the same
object) by :meth:`ReadAhead.__next__`; a warning the reader emits through :func:`warn` while it
runs in the thread is queued in its place and re-emitted (same category and message) in the
caller's thread, so that the caller's warning filters and ``catch_warnings`` see it.

Abandoning the iteration (``close()``, or the last reference dropped) stops the thread: it
notices within one batch and closes the file.
"""

from __future__ import annotations

import threading
import warnings
from collections import deque
from typing import Any, Callable, Generic, Iterator, TypeVar

_local = threading.local()
T = TypeVar("T")  # what the reader yields (packet batches, frames)

THREAD_NAME = "lidarpkt-read-ahead"
DEFAULT_MAX_BYTES = 8 << 20  # queued batches (payload bytes; one read block); one batch is always allowed


def warn(message: Warning, stacklevel: int = 1) -> None:
    """``warnings.warn(message, stacklevel=...)``, or queued for the caller when run by a read-ahead thread."""
    sink = getattr(_local, "sink", None)
    if sink is not None:
        sink(message)
        return
    warnings.warn(message, stacklevel=stacklevel + 1)


class ReadAhead(Generic[T]):
    """Iterator over the items of ``make_batches()`` (called in the thread), read ahead.

    ``nbytes(item)`` is what an item counts against ``max_bytes`` (packet batches: their payload);
    ``name`` names the thread. Read-aheads nest: one run by another's thread re-emits its warnings
    through :func:`warn`, so they travel on to the outermost caller.
    """

    def __init__(self, make_batches: Callable[[], Iterator[T]], *, max_bytes: int = DEFAULT_MAX_BYTES,
                 nbytes: Callable[[T], int] | None = None, name: str = THREAD_NAME) -> None:
        self._make = make_batches
        self._nbytes: Callable[[T], int] = nbytes or _nbytes
        self._max_bytes = max(1, int(max_bytes))
        self._cond = threading.Condition()
        self._items: deque = deque()  # (kind, value, nbytes): kind "batch" | "warning" | "error" | "end"
        self._bytes = 0
        self._stop = False
        self._done = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ reader thread
    def _put(self, kind: str, value, nbytes: int = 0) -> bool:
        with self._cond:
            while not self._stop and self._items and self._bytes + nbytes > self._max_bytes:
                self._cond.wait()
            if self._stop:
                return False
            self._items.append((kind, value, nbytes))
            self._bytes += nbytes
            self._cond.notify_all()
            return True

    def _run(self) -> None:
        _local.sink = lambda w: self._put("warning", w)
        it = None
        try:
            it = self._make()
            for batch in it:
                if not self._put("batch", batch, self._nbytes(batch)):
                    return
            self._put("end", None)
        except BaseException as exc:  # handed to the caller, raised there
            self._put("error", exc)
        finally:
            if it is not None and hasattr(it, "close"):
                try:
                    it.close()  # the reader's file is closed in this thread, where it was opened
                except BaseException:
                    pass
            _local.sink = None

    # ------------------------------------------------------------------ caller
    def __iter__(self) -> ReadAhead[T]:
        return self

    def __next__(self) -> T:
        while True:
            if self._done:
                raise StopIteration
            with self._cond:
                while not self._items:
                    if not self._thread.is_alive() and not self._items:
                        self._done = True  # the thread ended without a word (it cannot, but never hang)
                        raise StopIteration
                    self._cond.wait(0.5)
                kind, value, nbytes = self._items.popleft()
                self._bytes -= nbytes
                self._cond.notify_all()
            if kind == "batch":
                return value
            if kind == "warning":
                warn(value, stacklevel=2)  # attributed to the caller of next(); on to an outer read-ahead
                continue
            self._done = True
            self._thread.join()
            if kind == "error":
                raise value
            raise StopIteration

    def close(self, timeout: float = 10.0) -> None:
        """Stop the thread (it finishes the batch in hand and closes the file) and drop what was read ahead."""
        with self._cond:
            self._stop = True
            self._done = True
            self._items.clear()
            self._bytes = 0
            self._cond.notify_all()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()


def _nbytes(batch: Any) -> int:
    payload = getattr(batch, "payload", None)
    return int(getattr(payload, "nbytes", 0)) + 16 * len(batch)
