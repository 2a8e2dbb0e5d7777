"""The C library's heap, asked to keep the memory a decoding process frees and takes again at once.

A capture is decoded in arrays of 0.1-16 MiB made many times a second and dropped a moment later (a batch's
payloads, a piece of columns, a frame's fields and points). glibc serves a block above its *mmap threshold*
with a new mapping and unmaps it when it is freed, and gives the free memory at the top of its heap back to
the system once that exceeds its *trim threshold*; either way the next array of the size has its pages
faulted in and zeroed again (a fault per 4 KiB). Both thresholds adjust themselves: when a mapped block is
freed, the mmap threshold rises to its size and the trim threshold to twice that (``mallopt(3)``, "dynamic
mmap threshold", up to 32 MiB on 64-bit systems), so a process that has freed a large array keeps the
smaller ones it makes after. :func:`keep_freed_arrays` frees one of 16 MiB, once per process.

Nothing else changes: where ``MALLOC_MMAP_THRESHOLD_``, ``MALLOC_TRIM_THRESHOLD_``, ``MALLOC_TOP_PAD_`` or
``MALLOC_MMAP_MAX_`` is set (glibc then leaves its thresholds alone), where the threshold is already higher,
and with another C library, the free changes nothing.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KEPT_BLOCK_BYTES", "keep_freed_arrays"]

#: the size of the block freed: blocks up to it come from the heap, and up to twice it stay there when freed
KEPT_BLOCK_BYTES = 16 << 20

_freed = False


def keep_freed_arrays() -> None:
    """Raise glibc's dynamic mmap threshold to :data:`KEPT_BLOCK_BYTES` (and its trim threshold to twice that)
    by freeing a block of that size, the first time it is called in a process (forked workers inherit it)."""
    global _freed
    if _freed:
        return
    _freed = True
    # mapped (above the threshold), never written, so never faulted in; unmapped as it is freed here
    np.empty(KEPT_BLOCK_BYTES, np.uint8)
