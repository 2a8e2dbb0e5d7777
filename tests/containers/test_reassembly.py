"""lidarpkt.containers.reassembly on its own: orders, duplicates, overlaps, timeouts, bounds (RFC 791 semantics)."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarpkt.containers.reassembly import Reassembler

PAYLOAD = bytes(range(256)) * 33  # 8448 bytes, like an Ouster RNG15 packet


def _pieces(data: bytes, size: int = 1480):
    return [(off, off + size < len(data), data[off : off + size]) for off in range(0, len(data), size)]


def test_in_order_and_reversed():
    for order in (lambda p: p, lambda p: p[::-1]):
        r = Reassembler()
        outs = [r.add("k", off, more, d, 0) for off, more, d in order(_pieces(PAYLOAD))]
        assert outs[:-1] == [None] * 5 and outs[-1] == PAYLOAD
        assert r.pending_datagrams == 0 and r.held_bytes == 0
        assert r.stats.reassembled == 1


@settings(max_examples=60, deadline=None)
@given(st.randoms(use_true_random=False), st.integers(1, 8).map(lambda k: 8 * k * 23))
def test_any_order_any_size(rnd, size):
    pieces = _pieces(PAYLOAD, size)
    rnd.shuffle(pieces)
    r = Reassembler()
    outs = [r.add(("a", 1), off, more, d, i) for i, (off, more, d) in enumerate(pieces)]
    assert [o for o in outs if o is not None] == [PAYLOAD]
    assert outs[-1] == PAYLOAD


def test_duplicates_and_overlaps():
    r = Reassembler()
    p = _pieces(PAYLOAD)
    assert r.add(1, *p[0], 0) is None
    assert r.add(1, *p[0], 0) is None  # exact duplicate
    # an overlapping piece with the same bytes (a sender that re-fragmented at another size)
    assert r.add(1, 1000, True, PAYLOAD[1000:3000], 0) is None
    for piece in p[1:]:
        out = r.add(1, *piece, 0)
    assert out == PAYLOAD
    # held pieces 0–1480, 1000–3000, 1480–2960, 2960–4440 …: the 2nd, 3rd and 4th overlap what precedes them
    assert r.stats.duplicate_fragments == 1 and r.stats.overlapping_fragments == 3


def test_different_bytes_at_a_held_offset_restart_the_datagram():
    """An IP ID reused by a new datagram while the old one is pending (its other fragments were lost)."""
    old = bytes(8448)
    r = Reassembler()
    pieces_old = _pieces(old)
    for piece in pieces_old[:2] + pieces_old[3:]:
        r.add(7, *piece, 0)
    outs = [r.add(7, *piece, 5) for piece in _pieces(PAYLOAD)]
    assert outs[-1] == PAYLOAD
    assert r.stats.reused_ids == 1 and r.stats.orphaned_fragments == 5


def test_timeout_drops_stale_fragments():
    r = Reassembler(timeout_ns=30 * 10**9)
    p = _pieces(PAYLOAD)
    r.add("id", *p[0], 0)
    # the same key 88.5 s later (duplicate_id.pcap): identical first bytes would be taken as a duplicate
    # without the timeout; with it, the stale fragment is gone first
    outs = [r.add("id", *piece, 88_500_000_000) for piece in p]
    assert outs[-1] == PAYLOAD
    assert r.stats.timed_out_datagrams == 1 and r.stats.orphaned_fragments == 1
    assert r.stats.duplicate_fragments == 0


def test_bounds_evict_oldest():
    r = Reassembler(max_datagrams=4, max_bytes=10**9)
    for k in range(10):
        r.add(k, 0, True, b"x" * 8, k)
    assert r.pending_datagrams == 4
    assert r.stats.evicted_datagrams == 6 and r.stats.orphaned_fragments == 6
    # the newest survive
    assert r.add(9, 8, False, b"y" * 8, 10) == b"x" * 8 + b"y" * 8
    r = Reassembler(max_datagrams=1000, max_bytes=3000)
    for k in range(10):
        r.add(k, 0, True, b"z" * 1480, k)
    assert r.held_bytes <= 3000
    big = Reassembler(max_bytes=1000)
    assert big.add("b", 0, True, b"q" * 1480, 0) is None  # larger than the whole budget: dropped at once
    assert big.pending_datagrams == 0 and big.stats.evicted_datagrams == 1


def test_malformed():
    r = Reassembler()
    assert r.add(1, 65528, False, b"x" * 16, 0) is None  # beyond 65535
    assert r.add(2, 0, True, b"", 0) is None  # empty non-last fragment
    r.add(3, 1480, False, b"a" * 100, 0)
    assert r.add(3, 2960, False, b"b" * 100, 0) is None  # two different ends
    assert r.stats.malformed_fragments == 3
    assert r.flush() == 0


def test_flush_counts_leftovers():
    r = Reassembler()
    pieces = _pieces(PAYLOAD)
    random.Random(3).shuffle(pieces)
    for piece in pieces[:-1]:
        r.add("x", *piece, 0)
    assert r.flush() == len(pieces) - 1
    assert r.pending_datagrams == 0 and r.held_bytes == 0


def test_bad_arguments():
    with pytest.raises(ValueError):
        Reassembler(timeout_ns=0)
