"""lidarpkt.containers.reassembly at its boundaries: the timeout and size limits exactly, counters that add up
over several datagrams, and a late fragment landing inside the prefix already walked."""

from __future__ import annotations

from lidarpkt.containers.reassembly import Reassembler

PAYLOAD = bytes(range(256)) * 20  # 5120 bytes


def test_timeout_is_inclusive_and_every_expired_datagram_counts():
    r = Reassembler(timeout_ns=100)
    assert r.add("a", 0, True, PAYLOAD[:1480], 0) is None
    assert r.add("b", 0, True, PAYLOAD[:1480], 5) is None
    r.expire(100)  # exactly the timeout old: kept
    assert r.pending_datagrams == 2 and r.stats.timed_out_datagrams == 0
    r.expire(105)  # "a" is 105 ns old, "b" 100 ns: only "a" goes
    assert r.pending_datagrams == 1 and r.stats.timed_out_datagrams == 1
    r.expire(106)
    assert r.pending_datagrams == 0 and r.stats.timed_out_datagrams == 2 and r.stats.orphaned_fragments == 2


def test_largest_datagram_is_accepted_one_byte_more_is_not():
    r = Reassembler(max_datagram_bytes=3000)
    assert r.add("k", 0, True, PAYLOAD[:1500], 0) is None
    assert r.add("k", 1500, False, PAYLOAD[1500:3000], 0) == PAYLOAD[:3000]
    assert r.stats.malformed_fragments == 0
    assert r.add("j", 1500, False, PAYLOAD[1500:3001], 0) is None
    assert r.stats.malformed_fragments == 1


def test_counters_add_up_over_datagrams():
    r = Reassembler()
    for key in ("a", "b"):  # each: an ID reused after a lost fragment, then an overlapping resend
        r.add(key, 0, True, b"\x01" * 1480, 0)
        r.add(key, 0, True, PAYLOAD[:1480], 0)  # other bytes at a held offset: a new datagram
        r.add(key, 1000, True, PAYLOAD[1000:2000], 0)
        assert r.add(key, 1480, False, PAYLOAD[1480:3000], 0) == PAYLOAD[:3000]
    assert r.stats.reused_ids == 2
    assert r.stats.overlapping_fragments == 4  # per datagram: 1000–2000 starts inside 0–1480, 1480–3000 inside 1000–2000
    assert r.stats.reassembled == 2


def test_a_late_piece_inside_the_walked_prefix_extends_it():
    r = Reassembler()
    assert r.add("k", 0, True, PAYLOAD[:1480], 0) is None
    assert r.add("k", 1480, True, PAYLOAD[1480:2960], 0) is None
    # starts inside what is already contiguous (0–2960) and reaches 4000
    assert r.add("k", 500, True, PAYLOAD[500:4000], 0) is None
    assert r.add("k", 4000, False, PAYLOAD[4000:], 0) == PAYLOAD


def test_byte_bound_keeps_the_datagram_just_added_and_is_inclusive():
    from lidarpkt.containers.reassembly import FRAGMENT_OVERHEAD

    piece = 1000 + FRAGMENT_OVERHEAD
    r = Reassembler(max_bytes=3 * piece)
    r.add("a", 0, True, PAYLOAD[:1000], 0)
    r.add("b", 0, True, PAYLOAD[:1000], 1)
    r.add("a", 1000, True, PAYLOAD[1000:2000], 2)  # exactly max_bytes held: nothing goes
    assert r.held_bytes == 3 * piece and r.pending_datagrams == 2 and r.stats.evicted_datagrams == 0
    # "a" is the oldest and the one just added: the next oldest ("b") is evicted instead
    r.add("a", 2000, True, PAYLOAD[2000:3000], 3)
    assert r.stats.evicted_datagrams == 1 and r.pending_datagrams == 1
    assert r.add("a", 3000, False, PAYLOAD[3000:3100], 4) == PAYLOAD[:3100]
