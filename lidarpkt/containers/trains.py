"""Whole IPv4 fragment trains of a chunk reassembled with array operations (the vectorised fast path).

A train qualifies when its fragments (same source, destination and IP ID) have offsets 0, then
each the end of the previous one in record order, More Fragments on all but the last, all within
the reassembly timeout, a UDP header whose length fits, and no datagram of that key is pending in
the general reassembler. Everything else (duplicates, reordering, an ID reused by a stale fragment
as in duplicate_id.pcap, trains cut by the chunk end) goes through
:class:`~lidarpkt.containers.reassembly.Reassembler` record by record.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .gathers import Chunk, copy_rows, field
from .layouts import IPPROTO_UDP, IPV4_HEADER, UDP_HEADER, _fold, _row_word_sums
from .reassembly import Reassembler

MIXED_CHECKSUM = "reassembled datagram fails its UDP checksum (fragments of two datagrams sharing an IP ID?)"


class Trains(NamedTuple):
    """What :func:`fragment_trains` rebuilt from one chunk.

    ``consumed``: bool[n] records used; ``dgrams``: per-datagram arrays (pos, ts, src, dst, ports,
    plen, and row: the datagram's row in ``payloads[plen]``, the ``uint8[k, plen]`` payloads of each
    size); ``fragments`` and ``datagrams``: how many of each the fast path took.
    """

    consumed: np.ndarray
    dgrams: dict[str, np.ndarray]
    payloads: dict[int, np.ndarray]
    fragments: int
    datagrams: int


def fragment_trains(buf: np.ndarray, c: Chunk, ok, l2, l3, ihl, frag_bits, reasm: Reassembler, stats) -> Trains | None:
    """Whole UDP/IPv4 datagrams whose fragments all lie in chunk ``c``, or None when there are none.

    Datagrams whose non-zero UDP checksum fails are counted in ``stats`` as malformed and left out.
    """
    fr = _sorted_fragments(buf, c, ok, l2, l3, ihl, frag_bits)
    if fr is None:
        return None
    runs = _qualifying_runs(buf, fr, reasm)
    if runs is None:
        return None
    return _assemble(buf, c, fr, runs, stats)


def _sorted_fragments(buf, c: Chunk, ok, l2, l3, ihl, frag_bits) -> dict | None:
    """The fragment records of the chunk, sorted by (source, destination, IP ID, record)."""
    cand = ok & ((frag_bits & 0x3FFF) != 0)
    if not cand.any():
        return None
    total = field(buf, l3, IPV4_HEADER, "total_length")
    cand &= (total > ihl) & (l2 + total <= c.caplen)
    p = np.flatnonzero(cand)
    if p.shape[0] == 0:
        return None
    l3p = l3[p]
    fb = frag_bits[p]
    fr = {
        "p": p,
        "src": field(buf, l3p, IPV4_HEADER, "src"),
        "dst": field(buf, l3p, IPV4_HEADER, "dst"),
        "ident": field(buf, l3p, IPV4_HEADER, "identification"),
        "off": (fb & 0x1FFF) * 8,
        "mf": (fb >> 13) & 1,
        "dstart": l3p + ihl[p],
        "dlen": total[p] - ihl[p],
        "ts": c.ts_ns[p],
    }
    order = np.lexsort((fr["p"], fr["ident"], fr["dst"], fr["src"]))
    return {k: v[order] for k, v in fr.items()}


def _qualifying_runs(buf, fr: dict, reasm: Reassembler) -> dict | None:
    """Runs of fragments (one datagram each) and which of them the fast path may rebuild."""
    src, dst, ident, off, mf, dlen = fr["src"], fr["dst"], fr["ident"], fr["off"], fr["mf"], fr["dlen"]
    m = src.shape[0]
    new_key = np.ones(m, bool)
    new_key[1:] = (src[1:] != src[:-1]) | (dst[1:] != dst[:-1]) | (ident[1:] != ident[:-1])
    # an IP ID is reused: a run of one key also ends after each last fragment
    new_run = new_key.copy()
    new_run[1:] |= mf[:-1] == 0
    starts = np.flatnonzero(new_run)
    ends = np.append(starts[1:], m) - 1
    last = np.zeros(m, bool)
    last[ends] = True
    prev_end = np.empty(m, np.int64)
    prev_end[0] = 0
    prev_end[1:] = off[:-1] + dlen[:-1]
    elem_ok = np.where(new_run, off == 0, off == prev_end) & (mf == np.where(last, 0, 1))
    run_ok = np.logical_and.reduceat(elem_ok, starts)
    span = np.maximum.reduceat(fr["ts"], starts) - np.minimum.reduceat(fr["ts"], starts)
    run_ok &= span <= reasm.timeout_ns
    dgram_len = off[ends] + dlen[ends]
    run_ok &= (dgram_len <= reasm.max_datagram_bytes) & (dlen[starts] >= UDP_HEADER.itemsize)
    ustart = fr["dstart"][starts]
    ulen = field(buf, ustart, UDP_HEADER, "length")
    run_ok &= ulen == dgram_len  # a reassembled datagram has no padding: anything else is damage
    if reasm.pending_datagrams:  # a stale datagram of the same key decides in the general path
        pending = reasm._pending
        for r in np.flatnonzero(run_ok).tolist():
            i = starts[r]
            key = (4, int(src[i]).to_bytes(4, "big"), int(dst[i]).to_bytes(4, "big"), IPPROTO_UDP, int(ident[i]))
            if key in pending:
                run_ok[r] = False
    # once a run of a key fails, the later runs of that key must go through the reassembler too
    # (the failed run's fragments are pending there and decide what the later ones become)
    bad_cum = np.cumsum(~run_ok)
    key_start_run = np.maximum.accumulate(np.where(new_key[starts], np.arange(starts.shape[0]), 0))
    bad_before_key = np.where(key_start_run > 0, bad_cum[key_start_run - 1], 0)
    run_ok &= (bad_cum - bad_before_key) == 0
    if not run_ok.any():
        return None
    return {"new_run": new_run, "starts": starts, "ends": ends, "run_ok": run_ok, "ustart": ustart, "ulen": ulen}


def _assemble(buf, c: Chunk, fr: dict, runs: dict, stats) -> Trains:
    """The datagrams of the qualifying runs: their arrays, and the fragments' pieces copied into payloads."""
    new_run, starts, ends, run_ok = runs["new_run"], runs["starts"], runs["ends"], runs["run_ok"]
    p, dstart = fr["p"], fr["dstart"]
    run_id = np.cumsum(new_run) - 1
    elem_good = run_ok[run_id]
    consumed = np.zeros(c.caplen.shape[0], bool)
    consumed[p[elem_good]] = True
    good_runs = np.flatnonzero(run_ok)
    dgram_of_run = np.full(run_ok.shape[0], -1, np.int64)
    dgram_of_run[good_runs] = np.arange(good_runs.shape[0])
    gs, ge = starts[good_runs], ends[good_runs]
    ulen = runs["ulen"][good_runs]
    plen = ulen - 8
    dgrams = {
        "pos": p[ge],  # the record that completes the datagram
        "ts": c.ts_ns[p[ge]],
        "src": fr["src"][gs],
        "dst": fr["dst"][gs],
        "ports": (field(buf, dstart[gs], UDP_HEADER, "src_port") << 16) | field(buf, dstart[gs], UDP_HEADER, "dst_port"),
        "plen": plen,
    }
    e = np.flatnonzero(elem_good)
    dg = dgram_of_run[run_id[e]]
    first = new_run[e]
    # payload bytes = datagram bytes from 8 (after the UDP header) to the UDP length
    src_off = dstart[e] + np.where(first, 8, 0)
    dst_off = np.where(first, 0, fr["off"][e] - 8)
    length = np.minimum(fr["dlen"][e] - np.where(first, 8, 0), plen[dg] - dst_off)
    keep = length > 0
    pieces = {"dgram": dg[keep], "src_off": src_off[keep], "dst_off": dst_off[keep], "length": length[keep]}
    csum = field(buf, runs["ustart"][good_runs], UDP_HEADER, "checksum")
    dgrams, payloads = _payloads(buf, dgrams, ulen, csum, pieces, stats)
    return Trains(consumed, dgrams, payloads, int(e.shape[0]), int(good_runs.shape[0]))


def _payloads(buf, dgrams: dict, ulen, csum, pieces: dict, stats) -> tuple[dict, dict[int, np.ndarray]]:
    """Build the payloads, one array per size, and check the UDP checksums: a datagram whose
    fragments came from two datagrams sharing an IP ID (after losses) fails it and is left out."""
    plen = dgrams["plen"]
    nd = plen.shape[0]
    row = np.empty(nd, np.int64)
    valid = np.ones(nd, bool)
    payloads: dict[int, np.ndarray] = {}
    for size in np.unique(plen).tolist():
        ids = np.flatnonzero(plen == size)
        arr = np.empty((ids.shape[0], size), np.uint8)
        fill_trains(buf, arr, np.arange(ids.shape[0]), ids, pieces)
        row[ids] = np.arange(ids.shape[0])
        checked = csum[ids] != 0  # 0 = the sender computed none (IPv4)
        if checked.any():
            s_, d_, u_ = dgrams["src"][ids], dgrams["dst"][ids], ulen[ids]
            ports = dgrams["ports"][ids]
            total = (
                (s_ >> 16) + (s_ & 0xFFFF) + (d_ >> 16) + (d_ & 0xFFFF) + IPPROTO_UDP + 2 * u_
                + (ports >> 16) + (ports & 0xFFFF) + csum[ids] + _row_word_sums(arr)
            )
            valid[ids] &= ~checked | (_fold(total) == 0xFFFF)
        payloads[size] = arr
    if not valid.all():
        bad = int((~valid).sum())
        stats.malformed += bad
        stats.malformed_reasons[MIXED_CHECKSUM] += bad
        dgrams = {k: v[valid] for k, v in dgrams.items()}
        row = row[valid]
    dgrams["row"] = row
    return dgrams, payloads


def fill_trains(buf, payload, rows, dgram_ids, pieces) -> None:
    """Copy the fragments of datagrams ``dgram_ids`` into ``payload[rows]`` (one copy per piece shape)."""
    n_dgrams = int(pieces["dgram"].max()) + 1 if pieces["dgram"].shape[0] else 0
    row_of = np.full(max(n_dgrams, int(dgram_ids.max()) + 1), -1, np.int64)
    row_of[dgram_ids] = rows
    prow = row_of[pieces["dgram"]]
    sel = np.flatnonzero(prow >= 0)
    if sel.shape[0] == 0:
        return
    code = pieces["dst_off"][sel] * 65536 + pieces["length"][sel]
    classes, inverse = np.unique(code, return_inverse=True)
    inverse = inverse.reshape(-1)
    for k, cl in enumerate(classes.tolist()):
        dst, length = divmod(cl, 65536)
        which = sel[inverse == k]
        payload[prow[which], dst : dst + length] = copy_rows(buf, pieces["src_off"][which], length)
