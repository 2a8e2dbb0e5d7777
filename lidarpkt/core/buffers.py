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

import sys

import numpy as np

__all__ = ["BufferPool"]

_ALIGN = 64  # bytes: requests are rounded up to whole cache lines, so slightly different sizes share buffers


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
        self._buffers: list[np.ndarray] = []  # uint8[capacity], each the base of the arrays made from it
        self._bytes = 0

    @property
    def nbytes(self) -> int:
        """Bytes of the buffers kept (at most :attr:`max_bytes`)."""
        return self._bytes

    def empty(self, shape: int | tuple[int, ...], dtype: np.typing.DTypeLike) -> np.ndarray:
        """An array of ``shape`` and ``dtype`` (uninitialised, C order, writeable, aligned as ``numpy.empty``'s)."""
        dt = np.dtype(dtype)
        shape = (shape,) if isinstance(shape, int) else tuple(shape)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dt.itemsize
        buf = self._free(nbytes)
        if buf is None:
            buf = np.empty(-(-max(nbytes, 1) // _ALIGN) * _ALIGN, np.uint8)
            self._keep(buf)
            self.made += 1
        else:
            self.reused += 1
        return buf[:nbytes].view(dt).reshape(shape)

    def _free(self, nbytes: int) -> np.ndarray | None:
        best = None
        for buf in self._buffers:
            # 3 references: the list's, the loop variable's and getrefcount's argument; any array made from
            # the buffer adds one (NumPy views refer to the array that owns the memory)
            if buf.shape[0] >= nbytes and sys.getrefcount(buf) == 3 and (best is None or buf.shape[0] < best.shape[0]):
                best = buf
        return best

    def _keep(self, buf: np.ndarray) -> None:
        size = buf.shape[0]
        if self._bytes + size > self.max_bytes:
            # make room by dropping free buffers (too small for this request, or it would have been taken)
            kept = []
            for old in self._buffers:
                if self._bytes + size > self.max_bytes and sys.getrefcount(old) == 3:
                    self._bytes -= old.shape[0]
                else:
                    kept.append(old)
            self._buffers = kept
        if self._bytes + size <= self.max_bytes:
            self._buffers.append(buf)
            self._bytes += size
