"""Gathers over the records of a chunk: header fields at many offsets, payload rows, stream groups.

The compiled kernel ``gather_rows`` copies rows when the extension is built; the NumPy twins
(a sliding-window view indexed once) are used otherwise and give the same bytes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.core import kernels
from .layouts import ByteOrder, field_info

__all__ = ["Chunk", "gather", "copy_rows", "field", "few_groups"]


@dataclass
class Chunk:
    """Records of one chunk: where their link-layer bytes are in the file buffer."""

    data_off: np.ndarray  # int64[n] offset of the first captured byte
    caplen: np.ndarray  # int64[n]
    ts_ns: np.ndarray  # int64[n]
    linktype: np.ndarray  # int64[n]


def gather(buf: np.ndarray, idx: np.ndarray, dtype) -> np.ndarray:
    """Values of ``dtype`` at byte offsets ``idx`` of ``buf`` (offsets must be in range)."""
    size = np.dtype(dtype).itemsize
    if size == 1:
        return buf[idx]
    return copy_rows(buf, idx, size).view(dtype).reshape(-1)


def field(buf: np.ndarray, base: np.ndarray, layout: np.dtype, name: str, endian: ByteOrder | None = None) -> np.ndarray:
    """int64 values of one header field at each ``base`` offset (offsets clipped into the buffer)."""
    dt, off = field_info(layout, name)
    if endian is not None and dt.itemsize > 1:
        dt = dt.newbyteorder(endian)
    idx = np.minimum(base + off, buf.shape[0] - dt.itemsize)
    return gather(buf, idx, dt).astype(np.int64)


def few_groups(k1: np.ndarray, k2: np.ndarray, limit: int = 8) -> list[np.ndarray] | None:
    """Row indices of each distinct ``(k1, k2)`` pair, in order of first appearance, or ``None``
    when there are more than ``limit`` pairs.

    A chunk usually holds one to a few streams (a VLP-16's data and position packets); one
    comparison pass per stream is far cheaper than the sorts of ``np.unique``.
    """
    left = np.arange(k1.shape[0])
    groups: list[np.ndarray] = []
    while left.size:
        if len(groups) == limit:
            return None
        first = left[0]
        mine = (k1[left] == k1[first]) & (k2[left] == k2[first])
        if mine.all():
            groups.append(left)
            break
        groups.append(left[mine])
        left = left[~mine]
    return groups


def copy_rows(buf: np.ndarray, offs: np.ndarray, length: int) -> np.ndarray:
    """``uint8[n, length]`` copy of the bytes at each offset of ``buf``.

    Row k of a (read-only, zero-copy) sliding-window view is ``buf[k:k+length]``, so one
    fancy index on its first axis copies every payload as a contiguous row (memcpy-speed),
    far faster than gathering an ``n × length`` index array.
    """
    n = offs.shape[0]
    if n == 0 or length == 0:
        return np.zeros((n, length), np.uint8)
    native = kernels.native
    if native is not None:
        out = np.empty((n, length), np.uint8)
        native.gather_rows(buf, np.ascontiguousarray(offs, np.int64), out)
        return out
    windows = np.ndarray((buf.shape[0] - length + 1, length), np.uint8, buf, 0, (1, 1))
    return windows[offs]
