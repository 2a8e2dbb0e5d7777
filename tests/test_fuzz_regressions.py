"""Inputs that the fuzzers (benchmarks/fuzz.py) and the hostile-input tests found, kept as regressions.

Each test names the input and what went wrong before the fix.
"""

from __future__ import annotations

import tracemalloc

from lidarpkt.reassembly import FRAGMENT_OVERHEAD, Reassembler


# --------------------------------------------------------------------------- fragment reassembly
def test_tiny_orphan_fragments_are_charged_their_memory():
    """Orphan 1-byte fragments at every 8-byte offset of 1024 datagrams: before, held_bytes counted only
    the data (8 MB of 64 MB allowed) while Python held ~70 bytes per fragment (~580 MB). Now each
    fragment is charged FRAGMENT_OVERHEAD too, and the traced memory stays near max_bytes."""
    budget = 4 * 1024 * 1024
    r = Reassembler(max_bytes=budget)
    tracemalloc.start()
    try:
        n = 0
        for k in range(12):
            for off in range(0, 8192 * 8, 8):
                r.add(k, off, True, b"x", n)
                n += 1
        current, _peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert r.held_bytes <= budget
    held = sum(len(p) + FRAGMENT_OVERHEAD for e in r._pending.values() for p in e.pieces.values())
    assert held == r.held_bytes
    assert r.stats.evicted_datagrams > 0 and r.stats.orphaned_fragments > 0
    assert current < 2 * budget, f"{current} bytes traced for a {budget}-byte budget"
