"""The compiled kernels, when the optional extension ``lidarpkt._native`` was built.

These loops do not vectorise well in NumPy, and run in C when they can
(``lidarpkt/native/*.c``, one file per concern: ``walk.c`` the packet walk, ``xyz.c``,
``velodyne.c``, ``ouster.c``; ``module.c`` the method table):

- the walk over classic-pcap record headers when record sizes are mixed, and over pcapng's
  enhanced packet blocks (each record's offset depends on the one before it);
- gathering rows of bytes at offsets (header fields of 1-8 bytes, where NumPy's fancy index
  costs more per row than the bytes it moves);
- Ouster XYZ, ``range · direction + offset`` in one pass instead of thirteen NumPy passes;
- VLP-16 packets into range-image columns (``velodyne.decode.column_pixels``): one pass in chunks
  of 64 packets, row by row, where NumPy makes two;
- VLP-16 XYZ, the table lookups and products of ``VelodyneGeometry._points`` fused in one pass;
- the VLP-16 dual-return mark (``core.dual.second_strongest_mark``): one pass over a frame's two slots in
  exact double products, where NumPy gathers the differing pairs and widens them to int64.
- Ouster frame assembly (``ouster_scatter``, ``native/ouster.c``): each packet's pixels straight
  into the frame's ``[H, W]`` field arrays at their (row, column) place, in blocks of 16 rows copied
  to an L1 scratch and then extracted field by field with SSE2; no word planes, no transposing copy
  (the packets are column-major: reading each field straight from them loads a column apart).
  ``benchmarks/bench_ouster_scatter.py`` measures it; the figures are in the documentation's
  performance history.

The two XYZ loops have an AVX2 clone beside the baseline one (``target_clones``: the loader picks
it on a machine that has AVX2, as NumPy's own dispatch does), with no FMA, so the bytes are the same.

Each has a pure-NumPy twin in the module that calls it, used when the extension is absent (a
machine without a C compiler at install time) or disabled with ``LIDARPKT_NATIVE=0``; the
tests run both and compare them byte for byte.

Attributes:
    native: the extension module, or ``None``.
"""

from __future__ import annotations

import os
from types import ModuleType


def _load() -> ModuleType | None:
    if os.environ.get("LIDARPKT_NATIVE", "1") == "0":
        return None
    try:
        from lidarpkt import _native
    except ImportError:
        return None
    return _native


native: ModuleType | None = _load()


def describe() -> str:
    """One line for reports: which implementation runs."""
    if native is not None:
        return f"compiled kernels ({native.__name__})"
    why = "disabled by LIDARPKT_NATIVE=0" if os.environ.get("LIDARPKT_NATIVE") == "0" else "extension not built"
    return f"pure NumPy ({why})"
