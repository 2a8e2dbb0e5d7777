"""From a chunk of records to same-stream batches of UDP payloads.

:class:`ChunkDecoder` takes the records of one chunk (:class:`~lidarpkt.containers.gathers.Chunk`):
plain UDP/IPv4 records and whole fragment trains with array operations, every other record by
the per-record :class:`~lidarpkt.containers.datagram.RecordParser`; then it applies the filters,
numbers the datagrams (their ordinals in the pass), groups them by (source, destination, payload
size) and copies each group's payloads out in one pass.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lidarpkt.core.packet import Endpoint, PacketBatch
from .datagram import RecordParser, ipv4_headers, ipv4_text, is_ipv4_text, plain_udp
from .gathers import Chunk, copy_rows, few_groups, field
from .layouts import IPV4_HEADER, LINKTYPE_NAMES, UDP_HEADER
from .reassembly import Reassembler
from .trains import Trains, fragment_trains

if TYPE_CHECKING:
    from .read_stats import ReadStats

__all__ = ["ChunkDecoder"]


class ChunkDecoder(RecordParser):
    """Datagrams of the chunks of one pass over a capture, in batches; counts into ``stats``.

    Args:
        path: the capture (for messages).
        stats: the reader's :class:`~lidarpkt.containers.read_stats.ReadStats`, updated in place.
        ports, src_addresses, payload_sizes: the filters (None = keep all).
        reassembly_args: keyword arguments of :class:`~lidarpkt.containers.reassembly.Reassembler`.
    """

    def __init__(self, path: str, stats: ReadStats, ports, src_addresses, payload_sizes, reassembly_args: dict) -> None:
        self.path = path
        self.stats = stats
        self.ports = ports
        self.src_addresses = src_addresses
        self.payload_sizes = payload_sizes
        self._reasm = Reassembler(**reassembly_args)
        self._vec_fragments = 0  # fragments / datagrams reassembled by the fragment-train fast path
        self._vec_reassembled = 0
        self._warned_links: set[int] = set()

    def finish(self) -> None:
        """End of the pass: pending fragments are orphans now."""
        self._reasm.flush()
        self.sync_stats()

    def sync_stats(self) -> None:
        rs = self._reasm.stats
        st = self.stats
        st.fragments = rs.fragments + self._vec_fragments
        st.reassembled = rs.reassembled + self._vec_reassembled
        st.reassembled_vectorised = self._vec_reassembled
        st.orphaned_fragments = rs.orphaned_fragments + rs.malformed_fragments
        st.duplicate_fragments = rs.duplicate_fragments

    # ------------------------------------------------------------------ one chunk
    def decode(self, buf: np.ndarray, c: Chunk, base: int) -> list[PacketBatch]:
        """The batches of chunk ``c`` (its records' bytes in ``buf``); ordinals start at ``base``."""
        st = self.stats
        for lt, cnt in zip(*np.unique(c.linktype, return_counts=True)):
            st.link_types[LINKTYPE_NAMES.get(int(lt), f"linktype {int(lt)}")] += int(cnt)
        ok, l2, l3, ihl = ipv4_headers(buf, c)
        frag_bits = field(buf, l3, IPV4_HEADER, "flags_fragment_offset")
        fast, l4 = plain_udp(buf, c, ok, l2, l3, ihl, frag_bits)
        trains = fragment_trains(buf, c, ok, l2, l3, ihl, frag_bits, self._reasm, st)
        if trains is not None:
            self._vec_fragments += trains.fragments
            self._vec_reassembled += trains.datagrams
        handled = fast if trains is None else (fast | trains.consumed)
        slow_pos, slow_pkts, slow_ts = self._general_path(buf, c, handled)
        self.sync_stats()
        vec = self._filtered(self._vector_datagrams(buf, c, fast, l3, l4, trains))
        # ordinals: every kept record yields at most one packet, in record order
        slow_pos_a = np.asarray(slow_pos, np.int64)
        all_pos = np.sort(np.concatenate([vec["pos"], slow_pos_a]))
        total = all_pos.shape[0]
        if total == 0:
            return []
        vec["ord"] = base + np.searchsorted(all_pos, vec["pos"])
        slow_ord = base + np.searchsorted(all_pos, slow_pos_a)
        train_payloads = trains.payloads if trains is not None else {}
        out = [self._batch(buf, key, g, vec, train_payloads, slow_pkts, slow_ts, slow_ord)
               for key, g in _groups(vec, slow_pkts).items()]
        out.sort(key=lambda b: int(b.index[0]))
        st.yielded += total
        return out

    def _general_path(self, buf: np.ndarray, c: Chunk, handled: np.ndarray):
        """Records the array paths did not take, record by record in capture order (reassembly needs it)."""
        slow_pos: list[int] = []
        slow_pkts: list[tuple[str, int, str, int, bytes]] = []
        slow_ts: list[int] = []
        if not handled.all():
            slow = np.flatnonzero(~handled)
            offs = c.data_off[slow].tolist()
            caps = c.caplen[slow].tolist()
            lts = c.linktype[slow].tolist()
            tss = c.ts_ns[slow].tolist()
            mv = buf.data
            for i, o, cap, lt, ts in zip(slow.tolist(), offs, caps, lts, tss):
                got = self._parse_record(lt, mv[o : o + cap], ts)
                if got is not None:
                    slow_pos.append(i)
                    slow_pkts.append(got)
                    slow_ts.append(ts)
        return slow_pos, slow_pkts, slow_ts

    @staticmethod
    def _vector_datagrams(buf, c: Chunk, fast, l3, l4, trains: Trains | None) -> dict[str, np.ndarray]:
        """Datagrams found with array operations: plain records (kind 0) and fragment trains (kind 1), in record order."""
        fast_pos = np.flatnonzero(fast)
        l4 = l4[fast_pos]
        ip_off = l3[fast_pos]
        vec = {
            "pos": fast_pos,
            "src": field(buf, ip_off, IPV4_HEADER, "src"),
            "dst": field(buf, ip_off, IPV4_HEADER, "dst"),
            "ports": (field(buf, l4, UDP_HEADER, "src_port") << 16) | field(buf, l4, UDP_HEADER, "dst_port"),
            "plen": field(buf, l4, UDP_HEADER, "length") - UDP_HEADER.itemsize,
            "ts": c.ts_ns[fast_pos],
            "ref": l4 + UDP_HEADER.itemsize,  # kind 0: payload offset in the file; kind 1: row in train payloads
            "kind": np.zeros(fast_pos.shape[0], np.int8),
        }
        if trains is not None:
            dg = dict(trains.dgrams)
            nd = dg["pos"].shape[0]
            row = dg.pop("row")
            extra = dict(dg, ref=row, kind=np.ones(nd, np.int8))
            vec = {k: np.concatenate([vec[k], extra[k]]) for k in vec}
            order = np.argsort(vec["pos"], kind="stable")
            vec = {k: v[order] for k, v in vec.items()}
        return vec

    def _filtered(self, vec: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The datagrams the port/size/address filters keep (the others counted in ``stats.filtered``)."""
        n_vec = vec["pos"].shape[0]
        if not n_vec:
            return vec
        keep = np.ones(n_vec, bool)
        if self.ports is not None:
            keep &= np.isin(vec["ports"] & 0xFFFF, np.fromiter(self.ports, np.int64))
        if self.payload_sizes is not None:
            keep &= np.isin(vec["plen"], np.fromiter(self.payload_sizes, np.int64))
        if self.src_addresses is not None:
            import socket  # only for an address filter: importing it costs every command ms

            v4 = [int.from_bytes(socket.inet_aton(a), "big") for a in self.src_addresses if is_ipv4_text(a)]
            keep &= np.isin(vec["src"], np.asarray(v4, np.int64))
        self.stats.udp_packets += n_vec
        self.stats.filtered += int(n_vec - keep.sum())
        if not keep.all():
            vec = {k: v[keep] for k, v in vec.items()}
        return vec

    @staticmethod
    def _batch(buf, key: tuple, g: dict, vec: dict, train_payloads: dict, slow_pkts, slow_ts, slow_ord) -> PacketBatch:
        """One stream's batch: its plain, train and general-path datagrams merged in ordinal order."""
        s_ip, sport, d_ip, dport, size = key
        vsel = g["vec"] if g["vec"] is not None else np.zeros(0, np.int64)
        ssel = g["slow"]
        kinds = vec["kind"][vsel]
        if not ssel and not kinds.any():  # the common case: plain records only, already in order
            payload = copy_rows(buf, vec["ref"][vsel], size)
            ts = vec["ts"][vsel]
            idx = vec["ord"][vsel]
        else:
            s_ord = slow_ord[ssel]
            idx = np.concatenate([vec["ord"][vsel], s_ord])
            order = np.argsort(idx, kind="stable")
            idx = idx[order]
            nrows = idx.shape[0]
            payload = np.empty((nrows, size), np.uint8)
            ts = np.empty(nrows, np.int64)
            where = np.empty(nrows, np.int64)
            where[order] = np.arange(nrows)
            nv = vsel.shape[0]
            wv = where[:nv]
            ts[wv] = vec["ts"][vsel]
            plain = kinds == 0
            if plain.any():
                payload[wv[plain]] = copy_rows(buf, vec["ref"][vsel[plain]], size)
            if (~plain).any():
                payload[wv[~plain]] = train_payloads[size][vec["ref"][vsel[~plain]]]
            for r, j in zip(where[nv:].tolist(), ssel):
                payload[r] = np.frombuffer(slow_pkts[j][4], np.uint8)
                ts[r] = slow_ts[j]
        return PacketBatch(Endpoint(s_ip, sport), Endpoint(d_ip, dport), ts, payload, idx)


def _groups(vec: dict[str, np.ndarray], slow_pkts: list) -> dict[tuple, dict]:
    """(src, sport, dst, dport, size) → the rows of ``vec`` and of ``slow_pkts`` of that stream."""
    groups: dict[tuple, dict] = {}
    if vec["pos"].shape[0]:
        src_ip, dst_ip, ports, plen = vec["src"], vec["dst"], vec["ports"], vec["plen"]
        k1 = (src_ip << 32) | dst_ip
        k2 = (ports << 20) | plen
        selections = few_groups(k1, k2)
        if selections is None:
            # factorise each key half with fast int64 sorts, then the pair codes
            _, inv1 = np.unique(k1, return_inverse=True)
            u2, inv2 = np.unique(k2, return_inverse=True)
            code = inv1.reshape(-1) * len(u2) + inv2.reshape(-1)
            _, inverse, counts = np.unique(code, return_inverse=True, return_counts=True)
            order = np.argsort(inverse.reshape(-1), kind="stable")
            selections = np.split(order, np.cumsum(counts)[:-1])
        for sel in selections:
            first = int(sel[0])
            s_ip, d_ip = ipv4_text(np.array([src_ip[first], dst_ip[first]]))
            pp = int(ports[first])
            key = (s_ip, pp >> 16, d_ip, pp & 0xFFFF, int(plen[first]))
            groups[key] = {"vec": sel, "slow": []}
    for j, (s_ip, sport, d_ip, dport, payload) in enumerate(slow_pkts):
        key = (s_ip, sport, d_ip, dport, len(payload))
        groups.setdefault(key, {"vec": None, "slow": []})["slow"].append(j)
    return groups
