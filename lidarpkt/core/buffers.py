"""Arrays whose memory is used again once nothing refers to them: :class:`BufferPool`.

A decoder that writes each run of packets into new arrays gets new pages from the system (a page fault
and a zeroed page per 4 KiB) whenever the C library has handed the freed memory back in between, and
the first writes to them miss every cache. A pool keeps the buffers of the arrays it made and makes the
next ones from a buffer no array refers to any more. CPython counts the references: a NumPy view keeps
the array it was made from alive, so a frame, any array of it or any slice of one that the caller still
holds keeps its buffer out of the pool, and the caller never sees its numbers change.

One pool belongs to one decoder, which takes from it in one thread at a time.
"""

from __future__ import annotations

import math
import sys

import numpy as np

__all__ = ["BufferPool"]


def size_class(nbytes: int) -> int:
    """The capacity of the buffer made for ``nbytes``: rounded up to a multiple of a quarter of the power of
    two below it (at most 25 % more) and to whole cache lines, so that nearly equal requests share buffers."""
    step = max(64, 1 << max(0, nbytes.bit_length() - 3))
    return -(-max(nbytes, 1) // step) * step


class BufferPool:
    """Uninitialised arrays made from recycled buffers.

    ``max_bytes`` bounds the memory of the buffers the pool keeps (in use or free); past it, arrays are
    made as ``numpy.empty`` makes them and not kept. :attr:`reused` and :attr:`made` count the arrays made
    from a kept buffer and from a new one.
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = int(max_bytes)
        self.reused = 0
        self.made = 0
        self._classes: dict[int, list[np.ndarray]] = {}  # capacity → uint8 buffers, each the base of its arrays
        self._bytes = 0

    @property
    def nbytes(self) -> int:
        """Bytes of the buffers kept (at most :attr:`max_bytes`)."""
        return self._bytes

    def empty(self, shape: int | tuple[int, ...], dtype: np.typing.DTypeLike) -> np.ndarray:
        """An array of ``shape`` and ``dtype`` (uninitialised, C order, writeable, aligned as ``numpy.empty``'s)."""
        dt = np.dtype(dtype)
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        capacity = size_class(math.prod(shape) * dt.itemsize)
        kept = self._classes.setdefault(capacity, [])
        for buf in kept:
            # 3 references: the list's, the loop variable's and getrefcount's argument; any array made from
            # the buffer adds one (it is their base, and NumPy views refer to the array that owns the memory)
            if sys.getrefcount(buf) == 3:
                self.reused += 1
                return np.ndarray(shape, dt, buffer=buf)
        buf = np.empty(capacity, np.uint8)
        self.made += 1
        if self._bytes + capacity > self.max_bytes:
            self._drop_free(self._bytes + capacity - self.max_bytes)
        if self._bytes + capacity <= self.max_bytes:
            kept.append(buf)
            self._bytes += capacity
        return np.ndarray(shape, dt, buffer=buf)

    def _drop_free(self, nbytes: int) -> None:
        """Forget free buffers (of other sizes: none of this one was free) until ``nbytes`` are dropped."""
        for capacity, kept in self._classes.items():
            keep = []
            for buf in kept:
                if nbytes > 0 and sys.getrefcount(buf) == 3:
                    nbytes -= capacity
                    self._bytes -= capacity
                else:
                    keep.append(buf)
            kept[:] = keep
