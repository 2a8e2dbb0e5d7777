"""The link, IPv4/IPv6 and UDP layers: checks of a whole chunk at once, and the per-record general path.

:func:`ipv4_headers` and :func:`plain_udp` find, with NumPy gathers, the records that hold plain
UDP/IPv4 at a fixed link offset (the common case). :class:`RecordParser` takes every other record
one by one: IPv6 (extension headers skipped), three or more VLAN tags, fragments that need the
:class:`~lidarpkt.containers.reassembly.Reassembler`, damage (counted, never raised).

Length fields are never trusted over the captured bytes: a UDP payload ends at the UDP length,
bounded by what was captured (early VLP-16 position packets carry an IPv4 total length of 1234 for
a 540-byte datagram). IP header checksums are never checked and unfragmented datagrams are never
dropped for their UDP checksum; only a datagram rebuilt from fragments must match its UDP length
and, when the sender wrote one, its UDP checksum.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from lidarpkt.core.readahead import warn as _warn  # warnings.warn, or queued when a read-ahead thread runs the reader
from ..errors import SkippedPacketWarning
from .gathers import Chunk, field as _field
from .layouts import (
    _BSD_AF_INET,
    _BSD_AF_INET6,
    _ETHERTYPE,
    _IPV4,
    _IPV6,
    _IPV6_AH,
    _IPV6_EXT_HEADERS,
    _IPV6_FRAG,
    _IPV6_FRAGMENT,
    _L2_BYTES,
    _RAW_LINKS,
    _UDP,
    _VLAN_TPIDS,
    ETHERNET_HEADER,
    ETHERTYPE_IPV4,
    ETHERTYPE_IPV6,
    IPPROTO_UDP,
    IPV4_HEADER,
    IPV6_FRAGMENT_HEADER,
    IPV6_HEADER,
    LINKTYPE_ETHERNET,
    LINKTYPE_LINUX_SLL,
    LINKTYPE_LINUX_SLL2,
    LINKTYPE_LOOP,
    LINKTYPE_NULL,
    LINUX_SLL2_HEADER,
    LINUX_SLL_HEADER,
    NULL_HEADER,
    UDP_HEADER,
    VLAN_TAG,
    _fold,
    _udp_pseudo_sum,
    field_offset,
    header_struct,
    internet_checksum,
)
from .trains import MIXED_CHECKSUM as _MIXED_CHECKSUM

if TYPE_CHECKING:
    from .read_stats import ReadStats
    from .reassembly import Reassembler

__all__ = ["ipv4_headers", "plain_udp", "RecordParser", "canonical_address", "is_ipv4_text", "ipv4_text"]


def ipv4_headers(buf: np.ndarray, c: Chunk):
    """Records holding UDP/IPv4 at a fixed link offset: ``(ok, l2, l3, ihl)`` (offsets 0 where not ok)."""
    n = c.caplen.shape[0]
    lt = c.linktype
    l2 = np.full(n, -1, np.int64)
    for link, nbytes in _L2_BYTES.items():
        l2[lt == link] = nbytes
    ok = (l2 >= 0) & (c.caplen >= l2 + IPV4_HEADER.itemsize + UDP_HEADER.itemsize)
    d = np.where(ok, c.data_off, 0)
    # link-layer protocol fields
    eth = lt == LINKTYPE_ETHERNET
    if eth.any():
        etype = _field(buf, d, ETHERNET_HEADER, "ethertype")
        for _ in range(2):  # up to two VLAN tags here (802.1Q, QinQ); deeper stacks take the general path
            tagged = eth & np.isin(etype, _VLAN_TPIDS)
            if not tagged.any():
                break
            etype = np.where(tagged, _field(buf, d + l2, VLAN_TAG, "ethertype"), etype)
            l2 = np.where(tagged, l2 + VLAN_TAG.itemsize, l2)
        ok &= ~eth | ((etype == ETHERTYPE_IPV4) & (c.caplen >= l2 + IPV4_HEADER.itemsize + UDP_HEADER.itemsize))
    for link, layout, name in (
        (LINKTYPE_LINUX_SLL, LINUX_SLL_HEADER, "protocol"),
        (LINKTYPE_LINUX_SLL2, LINUX_SLL2_HEADER, "protocol"),
    ):
        mine = lt == link
        if mine.any():
            ok &= ~mine | (_field(buf, d, layout, name) == ETHERTYPE_IPV4)
    null = (lt == LINKTYPE_NULL) | (lt == LINKTYPE_LOOP)
    if null.any():
        fam = _field(buf, d, NULL_HEADER, "family", "<")
        ok &= ~null | (fam == _BSD_AF_INET) | (fam == _BSD_AF_INET << 24)  # either byte order
    l3 = np.where(ok, d + l2, 0)
    vihl = _field(buf, l3, IPV4_HEADER, "version_ihl")
    ihl = (vihl & 0x0F) * 4
    ok &= ((vihl >> 4) == 4) & (ihl >= IPV4_HEADER.itemsize) & (c.caplen >= l2 + ihl + UDP_HEADER.itemsize)
    ok &= _field(buf, l3, IPV4_HEADER, "protocol") == IPPROTO_UDP
    l3 = np.where(ok, l3, 0)
    return ok, l2, l3, ihl


def plain_udp(buf: np.ndarray, c: Chunk, ok, l2, l3, ihl, frag_bits):
    """Unfragmented UDP/IPv4 records whose UDP length fits the captured bytes, and their UDP offsets."""
    fast = ok & ((frag_bits & 0x3FFF) == 0)
    l4 = np.where(fast, l3 + ihl, 0)
    udp_len = _field(buf, l4, UDP_HEADER, "length")
    fast &= (udp_len >= UDP_HEADER.itemsize) & (udp_len <= c.caplen - l2 - ihl)
    return fast, l4

class RecordParser:
    """The general path: one record at a time, to ``(src, sport, dst, dport, payload)`` after the filters.

    Holds the filters (``ports``: destination ports; ``src_addresses``; ``payload_sizes``), the
    :class:`ReadStats` it counts into (``stats``) and the reassembler (``_reasm``).
    """

    path: str
    stats: ReadStats
    _reasm: Reassembler
    _warned_links: set[int]
    ports: frozenset[int] | None
    src_addresses: frozenset[str] | None
    payload_sizes: frozenset[int] | None

    def _bad(self, reason: str) -> None:
        self.stats.malformed += 1
        self.stats.malformed_reasons[reason] += 1

    def _parse_record(self, lt: int, data: memoryview, ts_ns: int):
        """One record → (src, sport, dst, dport, payload) after filters, or None (counted)."""
        n = len(data)
        if lt == LINKTYPE_ETHERNET:
            off = ETHERNET_HEADER.itemsize
            if n < off:
                return self._bad("frame shorter than an Ethernet header")
            etype = _ETHERTYPE.unpack_from(data, field_offset(ETHERNET_HEADER, "ethertype"))[0]
            while etype in _VLAN_TPIDS:  # 802.1Q / 802.1ad tags, stacked or not
                if n < off + VLAN_TAG.itemsize:
                    return self._bad("frame cut inside a VLAN tag")
                etype = _ETHERTYPE.unpack_from(data, off + field_offset(VLAN_TAG, "ethertype"))[0]
                off += VLAN_TAG.itemsize
        elif lt in (LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2):
            layout = LINUX_SLL_HEADER if lt == LINKTYPE_LINUX_SLL else LINUX_SLL2_HEADER
            off = layout.itemsize
            if n < off:
                return self._bad(f"frame shorter than a Linux {'SLL' if lt == LINKTYPE_LINUX_SLL else 'SLL2'} header")
            etype = _ETHERTYPE.unpack_from(data, field_offset(layout, "protocol"))[0]
        elif lt in _RAW_LINKS:
            if n < 1:
                return self._bad("empty raw IP record")
            version = data[0] >> 4
            etype = ETHERTYPE_IPV4 if version == 4 else ETHERTYPE_IPV6 if version == 6 else -1
            off = 0
        elif lt in (LINKTYPE_NULL, LINKTYPE_LOOP):
            off = NULL_HEADER.itemsize
            if n < off:
                return self._bad("frame shorter than a loopback header")
            first, other = ("<", ">") if lt == LINKTYPE_NULL else (">", "<")
            fam = header_struct(NULL_HEADER, first).unpack_from(data)[0]
            if fam > 0xFFFF:  # written by a host of the other byte order
                fam = header_struct(NULL_HEADER, other).unpack_from(data)[0]
            etype = ETHERTYPE_IPV4 if fam == _BSD_AF_INET else ETHERTYPE_IPV6 if fam in _BSD_AF_INET6 else -1
        else:
            self.stats.non_udp += 1
            if lt not in self._warned_links:
                self._warned_links.add(lt)
                _warn(
                    SkippedPacketWarning(f"{self.path}: records of unsupported link type {lt} skipped"), stacklevel=5
                )
            return None
        if etype == ETHERTYPE_IPV4:
            return self._parse_ipv4(data, off, ts_ns)
        if etype == ETHERTYPE_IPV6:
            return self._parse_ipv6(data, off, ts_ns)
        self.stats.non_udp += 1
        return None

    def _parse_ipv4(self, data: memoryview, off: int, ts_ns: int):
        n = len(data)
        if n < off + IPV4_HEADER.itemsize:
            return self._bad("IPv4 header cut short")
        vihl, _tos, total, ident, frag, _ttl, proto, _csum, src, dst = _IPV4.unpack_from(data, off)
        ihl = (vihl & 0x0F) * 4
        if vihl >> 4 != 4 or ihl < IPV4_HEADER.itemsize or n < off + ihl:
            return self._bad("bad IPv4 header length or version")
        if proto != IPPROTO_UDP:
            self.stats.non_udp += 1
            return None
        src_text, dst_text = ipv4_text(np.array([src, dst]))
        more = bool(frag & 0x2000)
        frag_off = (frag & 0x1FFF) * 8
        if more or frag_off:
            # fragments: the IP total length is the only end marker; bound it by the capture
            if total < ihl:
                return self._bad("IPv4 fragment with total length below its header length")
            if off + total > n:
                return self._bad("IPv4 fragment cut short by the snap length")
            key = (4, src.to_bytes(4, "big"), dst.to_bytes(4, "big"), proto, ident)
            payload = self._reasm.add(key, frag_off, more, data[off + ihl : off + total], ts_ns)
            if payload is None:
                return None
            return self._udp(payload, 0, len(payload), src_text, dst_text, (key[1], key[2]))
        # unfragmented: the UDP length ends the payload, whatever the IP total length says
        return self._udp(data, off + ihl, n, src_text, dst_text)

    def _parse_ipv6(self, data: memoryview, off: int, ts_ns: int):
        n = len(data)
        if n < off + IPV6_HEADER.itemsize:
            return self._bad("IPv6 header cut short")
        vcf, plen, nh, _hops, src, dst = _IPV6.unpack_from(data, off)
        if vcf >> 28 != 6:
            return self._bad("bad IPv6 version")
        p = off + IPV6_HEADER.itemsize
        frag = None
        while True:
            if nh in _IPV6_EXT_HEADERS or nh == _IPV6_AH:
                if n < p + 2:
                    return self._bad("IPv6 extension header cut short")
                ext = (data[p + 1] + 2) * 4 if nh == _IPV6_AH else (data[p + 1] + 1) * 8
                nh = data[p]
                p += ext
            elif nh == _IPV6_FRAGMENT:
                if n < p + IPV6_FRAGMENT_HEADER.itemsize:
                    return self._bad("IPv6 fragment header cut short")
                nh, _res, fo, ident = _IPV6_FRAG.unpack_from(data, p)
                frag = (fo & 0xFFF8, bool(fo & 1), ident)
                p += IPV6_FRAGMENT_HEADER.itemsize
            else:
                break
        if p > n:
            return self._bad("IPv6 extension headers longer than the packet")
        if nh != IPPROTO_UDP:
            self.stats.non_udp += 1
            return None
        import socket  # here, not at the top: importing it costs every command ms, and IPv6 records are rare

        s, d = socket.inet_ntop(socket.AF_INET6, src), socket.inet_ntop(socket.AF_INET6, dst)
        end = min(n, off + IPV6_HEADER.itemsize + plen) if plen else n
        if frag is not None:
            frag_off, more, ident = frag
            if plen and off + IPV6_HEADER.itemsize + plen > n:
                return self._bad("IPv6 fragment cut short by the snap length")
            payload = self._reasm.add((6, src, dst, ident), frag_off, more, data[p:end], ts_ns)
            if payload is None:
                return None
            return self._udp(payload, 0, len(payload), s, d, (src, dst))
        return self._udp(data, p, n, s, d)

    def _udp(self, data, p: int, end: int, src: str, dst: str, reassembled_from: tuple[bytes, bytes] | None = None):
        """The UDP datagram at ``data[p:end]`` (end = captured bytes available).

        ``reassembled_from``: the (source, destination) address bytes of a datagram rebuilt from
        fragments, whose length and non-zero checksum are then checked: fragments of two datagrams
        that share an IP ID (after losses) would give a mix. Unfragmented datagrams are not checked.
        """
        hdr = UDP_HEADER.itemsize
        if end - p < hdr:
            return self._bad("UDP header cut short")
        sport, dport, ulen, csum = _UDP.unpack_from(data, p)
        if ulen < hdr:
            return self._bad("UDP length below 8")
        if reassembled_from is not None:
            if ulen != end - p:
                return self._bad("reassembled datagram length differs from its UDP length")
            if csum and _fold(_udp_pseudo_sum(*reassembled_from, ulen) + (~internet_checksum(bytes(data[p:end])) & 0xFFFF)) != 0xFFFF:
                return self._bad(_MIXED_CHECKSUM)
        if p + ulen > end:
            return self._bad("UDP datagram cut short (snap length or a bad UDP length)")
        self.stats.udp_packets += 1
        if (
            (self.ports is not None and dport not in self.ports)
            or (self.src_addresses is not None and src not in self.src_addresses)
            or (self.payload_sizes is not None and ulen - hdr not in self.payload_sizes)
        ):
            self.stats.filtered += 1
            return None
        return src, sport, dst, dport, bytes(data[p + hdr : p + ulen])


def canonical_address(text: str) -> str:
    """The address as Endpoint.address spells it (IPv6 compressed, lower case); other text unchanged."""
    import socket

    text = str(text).strip()
    for family in (socket.AF_INET, socket.AF_INET6):
        try:
            return socket.inet_ntop(family, socket.inet_pton(family, text))
        except OSError:
            continue
    return text


def is_ipv4_text(text: str) -> bool:
    import socket

    try:
        socket.inet_aton(text)
    except OSError:
        return False
    return text.count(".") == 3



def ipv4_text(values: np.ndarray) -> list[str]:
    """Dotted-quad text of IPv4 addresses given as integers (``socket.inet_ntoa``'s)."""
    return [f"{v >> 24}.{(v >> 16) & 255}.{(v >> 8) & 255}.{v & 255}" for v in values.tolist()]
