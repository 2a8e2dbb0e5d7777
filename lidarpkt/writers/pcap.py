"""Writing captures: classic pcap and pcapng, with the framing a real network adds.

Used by the tests, the fixture generator and the recorder's tools. One implementation
of each layer, reused by both writers:

- :func:`udp_datagram` builds the UDP header (checksum over the pseudo-header);
- :func:`ip_packets` wraps it in IPv4 (fragmented at the MTU like a real sender:
  1480-byte fragment payloads at MTU 1500) or IPv6 (fragment extension header when
  larger than the MTU);
- :func:`link_frame` adds the link layer (Ethernet with optional stacked VLAN tags,
  Linux SLL, SLL2, raw IP, BSD loopback);
- :func:`frames_for` does all three for one :class:`~lidarpkt.core.packet.Packet`;
- :func:`write_pcap_records` / :func:`write_pcapng_records` write already-built frames
  (so that tests can reorder, duplicate or damage fragments), and :func:`write_pcap` /
  :func:`write_pcapng` write packets;
- :func:`batch_frames` frames a whole :class:`~lidarpkt.core.packet.PacketBatch` at once in NumPy
  (the same bytes :func:`frames_for` makes packet by packet), and :class:`PcapBatchWriter`
  writes batches of any source as one pcap in capture order (``lidarpkt export --format pcap``).

The address text decides IPv4 or IPv6 (``":"`` in it means IPv6).
"""

from __future__ import annotations

import io
import os
import socket
import struct
from dataclasses import dataclass
from typing import BinaryIO, Callable, Iterable, Iterator, Sequence

import numpy as np

from ..errors import PacketFormatError
from lidarpkt.core.packet import Endpoint, Packet, PacketBatch
from lidarpkt.containers.magic import PCAP_MAGIC_NS, PCAP_MAGIC_US, PCAPNG_BOM, PCAPNG_SHB
from lidarpkt.containers.layouts import (
    ETHERNET_HEADER,
    IPV4_HEADER,
    IPV6_FRAGMENT_HEADER,
    IPV6_HEADER,
    LINUX_SLL2_HEADER,
    LINUX_SLL_HEADER,
    NULL_HEADER,
    PCAP_GLOBAL_HEADER,
    PCAP_RECORD_HEADER,
    PCAPNG_BLOCK_HEADER,
    PCAPNG_EPB,
    PCAPNG_IDB,
    PCAPNG_OPTION,
    PCAPNG_SECTION_HEADER,
    PCAPNG_SPB,
    UDP_HEADER,
    VLAN_TAG,
    _fold,
    _row_word_sums,
    _udp_pseudo_sum,
    header_struct,
    internet_checksum,
)

# every header is packed with the layout the reader parses it with (lidarpkt.containers.layouts)
_IPV4 = header_struct(IPV4_HEADER)
_IPV6 = header_struct(IPV6_HEADER)
_IPV6_FRAG = header_struct(IPV6_FRAGMENT_HEADER)
_UDP = header_struct(UDP_HEADER)
_ETH = header_struct(ETHERNET_HEADER)
_VLAN = header_struct(VLAN_TAG)
_SLL = header_struct(LINUX_SLL_HEADER)
_SLL2 = header_struct(LINUX_SLL2_HEADER)

__all__ = [
    "LINKTYPES",
    "Interface",
    "udp_datagram",
    "ip_packets",
    "ipv4_header",
    "fragment_ipv4",
    "link_frame",
    "frames_for",
    "write_pcap",
    "write_pcap_records",
    "pcap_bytes",
    "write_pcapng",
    "write_pcapng_records",
    "pcapng_bytes",
    "internet_checksum",
    "batch_frames",
    "PcapBatchWriter",
]

LINKTYPES = {"null": 0, "ethernet": 1, "raw": 101, "linux_sll": 113, "linux_sll2": 276}
_ETHERTYPE = {4: 0x0800, 6: 0x86DD}
_AF = {4: 2, 6: 24}  # BSD loopback address families (24 = AF_INET6 on NetBSD/OpenBSD, read by all tools)
SRC_MAC = bytes.fromhex("607688000000")  # the Velodyne OUI every VLP-16 capture shows
BROADCAST_MAC = b"\xff" * 6
DST_MAC = bytes.fromhex("020000000001")  # locally administered

Record = tuple  # (timestamp_ns, frame bytes) or (timestamp_ns, frame bytes, original length)
IPPROTO_UDP = 17
IPV6_NEXT_FRAGMENT = 44


def _linktype(link: str | int) -> int:
    """The LINKTYPE_ number of a link name (or a number, passed through)."""
    if not isinstance(link, str):
        return int(link)
    try:
        return LINKTYPES[link]
    except KeyError:
        raise ValueError(f"unknown link type {link!r}; choose one of {sorted(LINKTYPES)} or a LINKTYPE_ number") from None


def _version(address: str) -> int:
    return 6 if ":" in address else 4


def _addr_bytes(address: str) -> bytes:
    try:
        if _version(address) == 6:
            return socket.inet_pton(socket.AF_INET6, address)
        return socket.inet_aton(address)
    except OSError:
        raise PacketFormatError(f"not an IP address: {address!r}") from None


def udp_datagram(src: str, sport: int, dst: str, dport: int, payload: bytes, *, checksum: bool = True) -> bytes:
    """UDP header + payload. The checksum covers the IPv4/IPv6 pseudo-header (0 = none, IPv4 only)."""
    length = 8 + len(payload)
    if length > 0xFFFF:
        raise PacketFormatError(f"UDP payload of {len(payload)} bytes does not fit the 16-bit UDP length")
    header = _UDP.pack(sport, dport, length, 0)
    if checksum or _version(src) == 6:  # IPv6 forbids a zero UDP checksum
        s, d = _addr_bytes(src), _addr_bytes(dst)
        if len(s) == 4:
            pseudo = s + d + struct.pack(">BBH", 0, IPPROTO_UDP, length)
        else:
            pseudo = s + d + struct.pack(">IxxxB", length, IPPROTO_UDP)
        c = internet_checksum(pseudo, header, payload) or 0xFFFF
        header = _UDP.pack(sport, dport, length, c)
    return header + payload


def ipv4_header(
    src: str, dst: str, payload_len: int, *, ident: int, proto: int = 17, ttl: int = 64,
    more: bool = False, offset: int = 0, dont_fragment: bool = False, total_length: int | None = None,
) -> bytes:
    """A 20-byte IPv4 header with a valid checksum. ``offset`` in bytes (multiple of 8);
    ``total_length`` overrides the length field (to write damaged captures)."""
    if offset % 8:
        raise ValueError("IPv4 fragment offsets are multiples of 8 bytes")
    flags = (0x4000 if dont_fragment else 0) | (0x2000 if more else 0) | (offset // 8)
    tl = 20 + payload_len if total_length is None else total_length
    s, d = (int.from_bytes(_addr_bytes(a), "big") for a in (src, dst))
    head = _IPV4.pack(0x45, 0, tl, ident & 0xFFFF, flags, ttl, proto, 0, s, d)
    return _IPV4.pack(0x45, 0, tl, ident & 0xFFFF, flags, ttl, proto, internet_checksum(head), s, d)


def fragment_ipv4(payload_len: int, mtu: int) -> list[tuple[int, int, bool]]:
    """(offset, length, more) of each fragment of an IPv4 payload at ``mtu`` (20-byte header)."""
    room = (mtu - 20) // 8 * 8
    if room <= 0:
        raise ValueError(f"MTU {mtu} leaves no room for fragment data")
    if payload_len + 20 <= mtu:
        return [(0, payload_len, False)]
    out = []
    for off in range(0, payload_len, room):
        length = min(room, payload_len - off)
        out.append((off, length, off + length < payload_len))
    return out


def ip_packets(src: str, dst: str, l4: bytes, *, ident: int, mtu: int | None = 1500, proto: int = 17) -> list[bytes]:
    """IP packets carrying ``l4`` (e.g. a UDP datagram): one, or fragments when larger than ``mtu``."""
    if _version(src) != _version(dst):
        raise PacketFormatError(f"source {src} and destination {dst} are not the same IP version")
    if _version(src) == 4:
        if mtu is None:
            if 20 + len(l4) > 0xFFFF:
                raise PacketFormatError("IPv4 datagram larger than 65535 bytes")
            return [ipv4_header(src, dst, len(l4), ident=ident, proto=proto) + l4]
        return [
            ipv4_header(src, dst, length, ident=ident, proto=proto, more=more, offset=off) + l4[off : off + length]
            for off, length, more in fragment_ipv4(len(l4), mtu)
        ]
    s, d = _addr_bytes(src), _addr_bytes(dst)
    if mtu is None or 40 + len(l4) <= mtu:
        return [_IPV6.pack(6 << 28, len(l4), proto, 64, s, d) + l4]
    room = (mtu - IPV6_HEADER.itemsize - IPV6_FRAGMENT_HEADER.itemsize) // 8 * 8
    out = []
    for off in range(0, len(l4), room):
        part = l4[off : off + room]
        more = off + len(part) < len(l4)
        frag = _IPV6_FRAG.pack(proto, 0, off | int(more), ident & 0xFFFFFFFF)
        out.append(_IPV6.pack(6 << 28, len(frag) + len(part), IPV6_NEXT_FRAGMENT, 64, s, d) + frag + part)
    return out


def link_frame(ip: bytes, link: str = "ethernet", *, vlan: Sequence[int] = (), big_endian: bool = False,
               broadcast: bool = False) -> bytes:
    """Wrap an IP packet in a link-layer header.

    ``vlan``: VLAN ids, outermost first (Ethernet only); the outer tags of a stack use the
    802.1ad TPID 0x88A8, the innermost 0x8100. ``big_endian`` sets the byte order of the
    BSD loopback family word (the writing host's order).
    """
    version = ip[0] >> 4
    etype = _ETHERTYPE.get(version)
    if etype is None:
        raise ValueError(f"not an IP packet (version nibble {version})")
    if link == "ethernet":
        # each tag: its TPID sits where the ethertype was, then the TCI and the next ethertype
        tpids = [0x88A8] * (len(vlan) - 1) + [0x8100] if vlan else []
        types = tpids + [etype]
        out = _ETH.pack(BROADCAST_MAC if broadcast else DST_MAC, SRC_MAC, types[0])
        out += b"".join(_VLAN.pack(vid & 0x0FFF, nxt) for vid, nxt in zip(vlan, types[1:]))
        return out + ip
    if vlan:
        raise ValueError("VLAN tags need the Ethernet link type")
    if link == "linux_sll":
        return _SLL.pack(1 if broadcast else 0, 1, 6, SRC_MAC.ljust(8, b"\0"), etype) + ip
    if link == "linux_sll2":
        return _SLL2.pack(etype, 0, 2, 1, 1 if broadcast else 0, 6, SRC_MAC.ljust(8, b"\0")) + ip
    if link == "raw":
        return ip
    if link == "null":
        return header_struct(NULL_HEADER, ">" if big_endian else "<").pack(_AF[version]) + ip
    raise ValueError(f"unknown link type {link!r}; choose one of {sorted(LINKTYPES)}")


def frames_for(packet: Packet, *, link: str = "ethernet", mtu: int | None = 1500, vlan: Sequence[int] = (),
               ident: int = 0, big_endian: bool = False, udp_checksum: bool = True) -> list[bytes]:
    """The link-layer frames a network would carry for one packet (several when fragmented)."""
    if packet.src is None or packet.dst is None:
        raise PacketFormatError("a packet without source/destination endpoints cannot be framed; give it Endpoints")
    l4 = udp_datagram(packet.src.address, packet.src.port, packet.dst.address, packet.dst.port,
                      bytes(packet.payload), checksum=udp_checksum)
    broadcast = packet.dst.address == "255.255.255.255"
    return [
        link_frame(ip, link, vlan=vlan, big_endian=big_endian, broadcast=broadcast)
        for ip in ip_packets(packet.src.address, packet.dst.address, l4, ident=ident, mtu=mtu)
    ]


def _packet_records(packets: Iterable[Packet], **frame_args) -> Iterator[Record]:
    ident = 0
    for p in packets:
        ident = (ident + 1) & 0xFFFF
        for f in frames_for(p, ident=ident, **frame_args):
            yield (p.timestamp_ns, f)


# --- classic pcap ----------------------------------------------------------------------------
def _write_pcap_stream(fh: BinaryIO, records: Iterable[Record], *, linktype: int, nanosecond: bool,
                       big_endian: bool, snaplen: int) -> None:
    e = ">" if big_endian else "<"
    fh.write(header_struct(PCAP_GLOBAL_HEADER, e).pack(PCAP_MAGIC_NS if nanosecond else PCAP_MAGIC_US, 2, 4, 0, 0,
                                                       snaplen, linktype))
    rec = header_struct(PCAP_RECORD_HEADER, e)
    div = 1 if nanosecond else 1000
    for r in records:
        ts, frame = r[0], r[1]
        orig = r[2] if len(r) > 2 else len(frame)
        data = frame[:snaplen]
        sec, frac = divmod(int(ts), 1_000_000_000)
        fh.write(rec.pack(sec, frac // div, len(data), orig))
        fh.write(data)


def write_pcap_records(path: str | os.PathLike[str], records: Iterable[Record], *, link: str | int = "ethernet",
                       nanosecond: bool = False, big_endian: bool = False, snaplen: int = 65535) -> None:
    """Write ready-made frames ``(timestamp_ns, frame[, original_length])`` as a classic pcap.

    Frames longer than ``snaplen`` are cut to it (caplen < original length), like tcpdump does.
    """
    linktype = _linktype(link)
    with open(path, "wb", buffering=1 << 20) as fh:
        _write_pcap_stream(fh, records, linktype=linktype,
                           nanosecond=nanosecond, big_endian=big_endian, snaplen=snaplen)


def pcap_bytes(records: Iterable[Record], *, link: str | int = "ethernet", nanosecond: bool = False,
               big_endian: bool = False, snaplen: int = 65535) -> bytes:
    """The bytes :func:`write_pcap_records` would write (for tests that damage them)."""
    buf = io.BytesIO()
    _write_pcap_stream(buf, records, linktype=_linktype(link),
                       nanosecond=nanosecond, big_endian=big_endian, snaplen=snaplen)
    return buf.getvalue()


def write_pcap(path: str | os.PathLike[str], packets: Iterable[Packet], *, link: str = "ethernet",
               nanosecond: bool = False, big_endian: bool = False, mtu: int | None = 1500,
               vlan: tuple[int, ...] = (), snaplen: int = 65535, udp_checksum: bool = True) -> None:
    """Write packets as a classic pcap, framed and fragmented like a real network.

    Args:
        path: output file (overwritten).
        packets: :class:`~lidarpkt.core.packet.Packet` objects with src/dst endpoints; IPv4 or IPv6
            is taken from the address text.
        link: ``"ethernet"``, ``"linux_sll"``, ``"linux_sll2"``, ``"raw"`` or ``"null"``.
        nanosecond: nanosecond time stamps (magic a1b23c4d) instead of microseconds.
        big_endian: write the file big-endian.
        mtu: fragment datagrams larger than this (IPv4: 1480-byte fragment payloads at 1500);
            None never fragments.
        vlan: 802.1Q/802.1ad VLAN ids, outermost first (Ethernet only).
        snaplen: frames longer than this are cut to it.
        udp_checksum: compute UDP checksums (IPv4 allows 0, as VLP-16s send).

    Raises:
        lidarpkt.errors.PacketFormatError: a packet without endpoints, a bad address, a datagram
            too large for UDP/IP.
        ValueError: an unknown link type or option.
    """
    records = _packet_records(packets, link=link, mtu=mtu, vlan=vlan, big_endian=big_endian,
                              udp_checksum=udp_checksum)
    write_pcap_records(path, records, link=link, nanosecond=nanosecond, big_endian=big_endian, snaplen=snaplen)


# --- packet batches, framed in NumPy -----------------------------------------------------------
def _header_rows(layout: np.dtype, n: int, **fields) -> np.ndarray:
    """``uint8[n, layout.itemsize]``: ``n`` headers of ``layout`` with the given fields (scalars or arrays)."""
    rows = np.zeros(n, layout)
    for name, value in fields.items():
        rows[name] = value
    return rows.view(np.uint8).reshape(n, layout.itemsize)


def batch_frames(src: Endpoint, dst: Endpoint, payload: np.ndarray, ident: np.ndarray, *,
                 mtu: int | None = 1500, udp_checksum: bool = True) -> list[np.ndarray]:
    """The Ethernet frames of ``N`` UDP datagrams of one stream, built for all of them at once.

    Args:
        src, dst: the stream's endpoints (IPv4 or IPv6, as in :func:`frames_for`).
        payload: ``uint8[N, L]`` UDP payloads.
        ident: ``int[N]`` IP identification of each datagram.
        mtu, udp_checksum: as in :func:`write_pcap`.

    Returns:
        one ``uint8[N, F_k]`` array per fragment ``k`` (every datagram of the batch has the same
        size, so fragments alike): row ``i`` of each, in order, are the frames :func:`frames_for`
        makes for datagram ``i`` with ``ident[i]``.

    Raises:
        lidarpkt.errors.PacketFormatError: a bad address, or a datagram too large for UDP/IP.
    """
    n, length = payload.shape
    ident = np.asarray(ident, np.int64)
    if _version(src.address) == 6 or _version(dst.address) == 6:  # rare: framed packet by packet
        frames = [frames_for(Packet(0, src, dst, payload[i].tobytes()), mtu=mtu, ident=int(ident[i]),
                             udp_checksum=udp_checksum) for i in range(n)]
        return [np.frombuffer(b"".join(f[k] for f in frames), np.uint8).reshape(n, -1)
                for k in range(len(frames[0]))] if n else []
    udp_length = 8 + length
    if udp_length > 0xFFFF:
        raise PacketFormatError(f"UDP payload of {length} bytes does not fit the 16-bit UDP length")
    s, d = _addr_bytes(src.address), _addr_bytes(dst.address)
    checksum = 0
    if udp_checksum:  # RFC 768 over the pseudo-header, the UDP header and each payload
        fixed = _udp_pseudo_sum(s, d, udp_length) + src.port + dst.port + udp_length
        checksum = (~_fold(_row_word_sums(payload) + fixed)) & 0xFFFF
        checksum[checksum == 0] = 0xFFFF
    l4 = np.concatenate([_header_rows(UDP_HEADER, n, src_port=src.port, dst_port=dst.port, length=udp_length,
                                      checksum=checksum), payload], axis=1)
    if mtu is None:
        if 20 + udp_length > 0xFFFF:
            raise PacketFormatError("IPv4 datagram larger than 65535 bytes")
        pieces = [(0, udp_length, False)]
    else:
        pieces = fragment_ipv4(udp_length, mtu)
    broadcast = dst.address == "255.255.255.255"
    eth = np.frombuffer(_ETH.pack(BROADCAST_MAC if broadcast else DST_MAC, SRC_MAC, _ETHERTYPE[4]), np.uint8)
    s_int, d_int = int.from_bytes(s, "big"), int.from_bytes(d, "big")
    out = []
    for off, size, more in pieces:
        flags = (0x2000 if more else 0) | (off // 8)
        fixed = 0x4500 + (20 + size) + flags + (64 << 8 | IPPROTO_UDP) + (s_int >> 16) + (s_int & 0xFFFF) \
            + (d_int >> 16) + (d_int & 0xFFFF)
        ip = _header_rows(IPV4_HEADER, n, version_ihl=0x45, total_length=20 + size, identification=ident & 0xFFFF,
                          flags_fragment_offset=flags, ttl=64, protocol=IPPROTO_UDP,
                          header_checksum=(~_fold((ident & 0xFFFF) + fixed)) & 0xFFFF, src=s_int, dst=d_int)
        out.append(np.concatenate([np.broadcast_to(eth, (n, eth.size)), ip, l4[:, off:off + size]], axis=1))
    return out


class PcapBatchWriter:
    """Packet batches of any source (pcap, pcapng, MCAP, ROS bag) written as one classic pcap.

    The packets come out in capture order: batches of several streams interleave (their
    ``index`` says where each packet stood, :class:`~lidarpkt.core.packet.PacketBatch`), and a batch
    is held until the next batch's first index shows which packets can no longer be preceded.
    Each datagram is framed as :func:`write_pcap` frames it (Ethernet, IPv4 fragmented at
    ``mtu``, UDP checksum), ``ident`` counting packets from 1, with its capture time in
    nanoseconds (``nanosecond=False``: microseconds). Headers are built per batch in NumPy.

    ``write(batch, src, dst)``: ``src``/``dst`` stand in for a batch without endpoints (a bag's).
    Raises :class:`~lidarpkt.errors.PacketFormatError` for a batch with neither; ``OSError`` from
    the file.
    """

    def __init__(self, path: str | os.PathLike[str], *, nanosecond: bool = True, mtu: int | None = 1500,
                 snaplen: int = 65535) -> None:
        self.path = path
        self.nanosecond, self.mtu, self.snaplen = nanosecond, mtu, snaplen
        self.packets_written = 0
        self._pending: list[tuple[PacketBatch, Endpoint, Endpoint]] = []
        self._fh = open(path, "wb", buffering=1 << 20)
        self._fh.write(header_struct(PCAP_GLOBAL_HEADER, "<").pack(
            PCAP_MAGIC_NS if nanosecond else PCAP_MAGIC_US, 2, 4, 0, 0, snaplen, LINKTYPES["ethernet"]))

    def write(self, batch: PacketBatch, src: Endpoint | None = None, dst: Endpoint | None = None) -> None:
        if len(batch) == 0:
            return
        src, dst = batch.src or src, batch.dst or dst
        if src is None or dst is None:
            raise PacketFormatError("a packet batch without source/destination endpoints cannot be framed; "
                                    "give src and dst")
        self._flush(int(batch.index[0]))
        self._pending.append((batch, src, dst))

    def close(self) -> None:
        """Write what is held and close the file. Idempotent."""
        if self._fh.closed:
            return
        try:
            self._flush(None)
        finally:
            self._fh.close()

    def __enter__(self) -> "PcapBatchWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _flush(self, below: int | None) -> None:
        """Write every held packet whose index is below ``below`` (all: None), in index order."""
        parts, keep = [], []
        for batch, src, dst in self._pending:
            take = np.ones(len(batch), bool) if below is None else batch.index < below
            if take.all():
                parts.append((batch, src, dst))
            elif take.any():
                parts.append((_rows(batch, take), src, dst))
                keep.append((_rows(batch, ~take), src, dst))
            else:
                keep.append((batch, src, dst))
        self._pending = keep
        if not parts:
            return
        index = np.concatenate([b.index for b, _, _ in parts])
        order = np.argsort(index, kind="stable")
        rank = np.empty_like(order)
        rank[order] = np.arange(order.size)
        flats, starts, sizes = [], [], []
        at = first = 0
        for batch, src, dst in parts:
            n = len(batch)
            ident = self.packets_written + rank[first:first + n] + 1  # frames_for's count, in output order
            first += n
            rows = self._records(batch, src, dst, ident)
            flats.append(rows.reshape(-1))
            starts.append(at + np.arange(n, dtype=np.int64) * rows.shape[1])
            sizes.append(np.full(n, rows.shape[1], np.int64))
            at += rows.size
        start, size = np.concatenate(starts)[order], np.concatenate(sizes)[order]
        flat = np.concatenate(flats)
        # gather each packet's records in index order: start of each byte = its record's start + offset
        offsets = np.arange(int(size.sum()), dtype=np.int64) - np.repeat(np.cumsum(size) - size, size)
        self._fh.write(flat[np.repeat(start, size) + offsets].tobytes())
        self.packets_written += index.size

    def _records(self, batch: PacketBatch, src: Endpoint, dst: Endpoint, ident: np.ndarray) -> np.ndarray:
        """``uint8[N, R]``: each packet's pcap records (record header + frame, one per fragment)."""
        n = len(batch)
        ts = batch.timestamp_ns.astype(np.int64)
        sec, frac = np.divmod(ts, 1_000_000_000)
        if not self.nanosecond:
            frac //= 1000
        cols = []
        for frame in batch_frames(src, dst, np.ascontiguousarray(batch.payload), ident, mtu=self.mtu):
            caplen = min(frame.shape[1], self.snaplen)
            cols.append(_header_rows(PCAP_RECORD_HEADER.newbyteorder("<"), n, ts_sec=sec, ts_frac=frac,
                                     incl_len=caplen, orig_len=frame.shape[1]))
            cols.append(frame[:, :caplen])
        return np.concatenate(cols, axis=1)


def _rows(batch: PacketBatch, mask: np.ndarray) -> PacketBatch:
    return PacketBatch(batch.src, batch.dst, batch.timestamp_ns[mask], batch.payload[mask], batch.index[mask])


# --- pcapng ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Interface:
    """One pcapng interface: link type, snap length and time resolution.

    ``tsresol`` is the if_tsresol option byte: 6 = µs (the default), 9 = ns, 0x80|n = 2^-n s.
    ``tsoffset_s`` is the if_tsoffset option (seconds added to every time stamp).
    """

    link: str | int = "ethernet"
    snaplen: int = 65535
    tsresol: int = 6
    tsoffset_s: int = 0
    name: str | None = None


def _pad4(b: bytes) -> bytes:
    return b + b"\0" * (-len(b) % 4)


def _option(e: str, code: int, value: bytes) -> bytes:
    return header_struct(PCAPNG_OPTION, e).pack(code, len(value)) + _pad4(value)


def _block(e: str, btype: int, body: bytes) -> bytes:
    body = _pad4(body)
    n = 12 + len(body)
    return header_struct(PCAPNG_BLOCK_HEADER, e).pack(btype, n) + body + struct.pack(e + "I", n)


def _ts_units(ts_ns: int, iface: Interface) -> int:
    t = int(ts_ns) - iface.tsoffset_s * 1_000_000_000
    r = iface.tsresol
    if r & 0x80:
        return (t << (r & 0x7F)) // 1_000_000_000
    if r <= 9:
        return t // 10 ** (9 - r)
    return t * 10 ** (r - 9)


def _write_pcapng_stream(fh: BinaryIO, records: Iterable[tuple[int, int, bytes] | tuple[int, int, bytes, int]],
                         interfaces: Sequence[Interface], *, big_endian: bool, block: str) -> None:
    e = ">" if big_endian else "<"
    fh.write(_block(e, PCAPNG_SHB, header_struct(PCAPNG_SECTION_HEADER, e).pack(PCAPNG_BOM, 1, 0, -1)))
    for itf in interfaces:
        lt = _linktype(itf.link)
        opts = b""
        if itf.name:
            opts += _option(e, 2, itf.name.encode())
        if itf.tsresol != 6:
            opts += _option(e, 9, bytes([itf.tsresol]))
        if itf.tsoffset_s:
            opts += _option(e, 14, struct.pack(e + "q", itf.tsoffset_s))
        if opts:
            opts += header_struct(PCAPNG_OPTION, e).pack(0, 0)  # opt_endofopt
        fh.write(_block(e, 1, header_struct(PCAPNG_IDB, e).pack(lt, 0, itf.snaplen) + opts))
    for r in records:
        iface_id, ts, frame = r[0], r[1], r[2]
        orig = r[3] if len(r) > 3 else len(frame)
        itf = interfaces[iface_id]
        data = frame[: itf.snaplen]
        if block == "spb":
            fh.write(_block(e, 3, header_struct(PCAPNG_SPB, e).pack(orig) + data))
        else:
            units = _ts_units(ts, itf)
            epb = header_struct(PCAPNG_EPB, e).pack(iface_id, units >> 32, units & 0xFFFFFFFF, len(data), orig)
            fh.write(_block(e, 6, epb + data))


def write_pcapng_records(path: str | os.PathLike[str], records: Iterable[tuple], *,
                         interfaces: Sequence[Interface] = (Interface(),), big_endian: bool = False,
                         block: str = "epb") -> None:
    """Write ``(interface_id, timestamp_ns, frame[, original_length])`` records as one pcapng section.

    ``block="spb"`` writes simple packet blocks (interface 0, no time stamps).
    """
    with open(path, "wb") as fh:
        _write_pcapng_stream(fh, records, interfaces, big_endian=big_endian, block=block)


def pcapng_bytes(records: Iterable[tuple], *, interfaces: Sequence[Interface] = (Interface(),),
                 big_endian: bool = False, block: str = "epb") -> bytes:
    """The bytes :func:`write_pcapng_records` would write."""
    buf = io.BytesIO()
    _write_pcapng_stream(buf, records, interfaces, big_endian=big_endian, block=block)
    return buf.getvalue()


def write_pcapng(path: str | os.PathLike[str], packets: Iterable[Packet], *,
                 interfaces: Sequence[Interface] = (Interface(),),
                 interface_of: Callable[[Packet], int] | None = None, big_endian: bool = False,
                 mtu: int | None = 1500, vlan: tuple[int, ...] = (), block: str = "epb",
                 udp_checksum: bool = True) -> None:
    """Write packets as a pcapng file with one section and the given interfaces.

    ``interface_of(packet)`` picks each packet's interface (default 0); the frame is built
    for that interface's link type. Other arguments as in :func:`write_pcap`.
    """
    def records() -> Iterator[tuple]:
        ident = 0
        for p in packets:
            ident = (ident + 1) & 0xFFFF
            i = interface_of(p) if interface_of else 0
            link = interfaces[i].link
            link_name = link if isinstance(link, str) else {v: k for k, v in LINKTYPES.items()}[int(link)]
            for f in frames_for(p, link=link_name, mtu=mtu, vlan=vlan if link_name == "ethernet" else (),
                                ident=ident, big_endian=big_endian, udp_checksum=udp_checksum):
                yield (i, p.timestamp_ns, f)

    write_pcapng_records(path, records(), interfaces=interfaces, big_endian=big_endian, block=block)
