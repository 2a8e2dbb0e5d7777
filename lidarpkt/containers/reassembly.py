"""IP fragment reassembly with bounded memory and a host-time timeout.

dpkt does not reassemble fragments, yet Ouster packets larger than the MTU reach a
capture as IPv4 fragments (8448 B → 6 fragments at MTU 1500). A :class:`Reassembler`
collects the fragments of each datagram under a caller-chosen key (for IPv4:
version, source, destination, protocol, IP ID) and returns the datagram's IP payload
once every byte from 0 to the end given by the last fragment has arrived.

Why the timeout: an IP ID is only 16 bits and a sender reuses it. An orphan first
fragment left over from a lost datagram must never be merged with a later datagram
that happens to reuse its ID (``ouster-sdk/duplicate_id.pcap``: the reuse comes
88.5 s later). Pending datagrams older than ``timeout_ns`` of capture (host) time are
dropped, like the Linux kernel does after ``ipfrag_time`` (30 s).

Why the bounds: a capture full of lost fragments must not grow memory without
limit. At most ``max_datagrams`` datagrams and ``max_bytes`` bytes are held, each fragment
charged its bytes plus :data:`FRAGMENT_OVERHEAD` (the memory Python spends to hold it, like the
kernel's skb truesize: without it, a flood of 1-byte fragments held ~70 times ``max_bytes``);
beyond that the oldest pending datagram is evicted. Every dropped fragment is counted.
"""

from __future__ import annotations

import bisect
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Hashable

__all__ = ["Reassembler", "ReassemblyStats", "IPV4_MAX_DATAGRAM", "FRAGMENT_OVERHEAD"]

IPV4_MAX_DATAGRAM = 65535  # bytes of IP payload a fragment offset (13 bits × 8) plus length may reach
FRAGMENT_OVERHEAD = 80  # bytes charged per held fragment beyond its data (bytes object + dict slot, measured ~70)


@dataclass
class ReassemblyStats:
    """Counters of a :class:`Reassembler` (all counts of fragments unless the name says datagrams)."""

    fragments: int = 0  # fragments offered to add()
    reassembled: int = 0  # datagrams completed
    duplicate_fragments: int = 0  # a fragment whose bytes were all already held (dropped)
    overlapping_fragments: int = 0  # partial overlap with held bytes (first arrival wins)
    orphaned_fragments: int = 0  # fragments dropped because their datagram never completed
    timed_out_datagrams: int = 0  # pending datagrams dropped after timeout_ns
    evicted_datagrams: int = 0  # pending datagrams dropped to respect max_datagrams/max_bytes
    malformed_fragments: int = 0  # beyond the maximum datagram size, or two different ends
    reused_ids: int = 0  # pending datagrams dropped because a different fragment reused their key


@dataclass
class _Pending:
    first_ns: int
    pieces: dict[int, bytes] = field(default_factory=dict)  # offset -> bytes
    end: int | None = None  # total length, known once the last fragment arrived
    nbytes: int = 0
    offsets: list[int] = field(default_factory=list)  # the keys of pieces, sorted
    scan: int = 0  # offsets[:scan] are all inside the contiguous prefix
    prefix: int = 0  # bytes 0..prefix are held (a lower bound of what _try_complete joins)


class Reassembler:
    """Reassemble fragmented datagrams.

    Args:
        timeout_ns: a pending datagram whose first fragment arrived more than this long
            (host capture time, ns) before a new fragment is dropped as orphaned.
        max_datagrams: most datagrams pending at once; the oldest is evicted beyond.
        max_bytes: most bytes held at once (fragment data + :data:`FRAGMENT_OVERHEAD` each); the
            oldest datagrams are evicted beyond.
        max_datagram_bytes: largest reassembled payload accepted (65535 for IPv4).
    """

    def __init__(
        self,
        *,
        timeout_ns: int = 30_000_000_000,
        max_datagrams: int = 1024,
        max_bytes: int = 64 * 1024 * 1024,
        max_datagram_bytes: int = IPV4_MAX_DATAGRAM,
    ) -> None:
        if timeout_ns <= 0 or max_datagrams <= 0 or max_bytes <= 0:
            raise ValueError("timeout_ns, max_datagrams and max_bytes must be positive")
        self.timeout_ns = int(timeout_ns)
        self.max_datagrams = int(max_datagrams)
        self.max_bytes = int(max_bytes)
        self.max_datagram_bytes = int(max_datagram_bytes)
        self.stats = ReassemblyStats()
        self._pending: OrderedDict[Hashable, _Pending] = OrderedDict()  # oldest first
        self._held = 0

    @property
    def pending_datagrams(self) -> int:
        """Datagrams waiting for fragments."""
        return len(self._pending)

    @property
    def held_bytes(self) -> int:
        """Bytes currently charged: fragment data plus :data:`FRAGMENT_OVERHEAD` per held fragment."""
        return self._held

    def _drop(self, key: Hashable) -> None:
        entry = self._pending.pop(key)
        self._held -= entry.nbytes
        self.stats.orphaned_fragments += len(entry.pieces)

    def expire(self, now_ns: int) -> None:
        """Drop every pending datagram whose first fragment is older than ``timeout_ns`` at ``now_ns``."""
        while self._pending:
            key, entry = next(iter(self._pending.items()))
            if now_ns - entry.first_ns <= self.timeout_ns:
                break
            self._drop(key)
            self.stats.timed_out_datagrams += 1

    def add(self, key: Hashable, offset: int, more: bool, data: bytes | memoryview, timestamp_ns: int) -> bytes | None:
        """Offer one fragment; return the whole datagram payload when this fragment completes it.

        Args:
            key: identifies the datagram (e.g. ``(4, src, dst, proto, ip_id)``).
            offset: byte offset of ``data`` in the datagram payload (fragment offset × 8).
            more: the More Fragments flag (False on the last fragment).
            data: the fragment's payload bytes (copied when held).
            timestamp_ns: host capture time of the fragment.

        Returns:
            The reassembled payload (bytes), or None while fragments are missing or when the
            fragment was dropped (counted in :attr:`stats`).
        """
        st = self.stats
        st.fragments += 1
        self.expire(timestamp_ns)
        end = offset + len(data)
        if offset < 0 or end > self.max_datagram_bytes or (more and len(data) == 0):
            st.malformed_fragments += 1
            return None
        entry = self._pending.get(key)
        if entry is not None:
            old = entry.pieces.get(offset)
            if old is not None and old != data:
                # A real duplicate is byte-identical. Different bytes at the same offset mean the
                # sender reused the ID for a new datagram (the first one lost fragments): start over.
                self._drop(key)
                st.reused_ids += 1
                entry = None
        if entry is None:
            entry = _Pending(first_ns=timestamp_ns)
            self._pending[key] = entry
        if not more:
            if entry.end is not None and entry.end != end:
                # two different "last" fragments: the datagram cannot be trusted
                self._drop(key)
                st.malformed_fragments += 1
                return None
            entry.end = end
        if offset in entry.pieces:
            st.duplicate_fragments += 1
            return None  # identical to what is held (the datagram was incomplete before, and still is)
        entry.pieces[offset] = bytes(data)
        entry.nbytes += len(data) + FRAGMENT_OVERHEAD
        self._held += len(data) + FRAGMENT_OVERHEAD
        self._extend_prefix(entry, offset, len(data))
        done = self._try_complete(key, entry) if entry.end is not None and entry.prefix >= entry.end else None
        if done is None:
            self._enforce_bounds(keep=key)
        return done

    @staticmethod
    def _extend_prefix(entry: _Pending, offset: int, length: int) -> None:
        """Grow the contiguous prefix held from byte 0, each piece visited once (amortised), so that
        the full join of :meth:`_try_complete` runs only once the datagram can be whole. (Joining on
        every fragment made a datagram of 8192 fragments with a hole at its end cost 3 s.)"""
        offs = entry.offsets
        i = bisect.bisect_left(offs, offset)
        offs.insert(i, offset)
        if i < entry.scan:  # starts inside the prefix already walked
            entry.scan += 1
            entry.prefix = max(entry.prefix, offset + length)
        pieces = entry.pieces
        while entry.scan < len(offs) and offs[entry.scan] <= entry.prefix:
            o = offs[entry.scan]
            entry.prefix = max(entry.prefix, o + len(pieces[o]))
            entry.scan += 1

    def _try_complete(self, key: Hashable, entry: _Pending) -> bytes | None:
        if entry.end is None:
            return None
        covered = 0
        parts: list[bytes] = []
        overlaps = 0
        for off in sorted(entry.pieces):
            piece = entry.pieces[off]
            if off > covered:
                return None  # a hole
            tail = off + len(piece)
            if tail <= covered:
                overlaps += 1  # fully inside what we have (different offset): nothing new
                continue
            if off < covered:
                overlaps += 1
            parts.append(piece[covered - off :])
            covered = tail
        if covered < entry.end:
            return None
        payload = b"".join(parts)[: entry.end]
        del self._pending[key]
        self._held -= entry.nbytes
        self.stats.overlapping_fragments += overlaps
        self.stats.reassembled += 1
        return payload

    def _enforce_bounds(self, keep: Hashable) -> None:
        while self._pending and (len(self._pending) > self.max_datagrams or self._held > self.max_bytes):
            keys = iter(self._pending)
            victim = next(keys)
            if victim == keep:  # the datagram just added is the oldest: evict the next oldest
                victim = next(keys, keep)  # ... or itself when alone and larger than max_bytes
            self._drop(victim)
            self.stats.evicted_datagrams += 1

    def flush(self) -> int:
        """Drop every pending datagram (end of input); return the number of fragments dropped."""
        before = self.stats.orphaned_fragments
        for key in list(self._pending):
            self._drop(key)
        return self.stats.orphaned_fragments - before
