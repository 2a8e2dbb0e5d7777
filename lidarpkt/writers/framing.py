"""UDP datagrams framed as a network carries them: the one builder of the frames lidarpkt writes.

:func:`batch_frames` frames the ``N`` datagrams of one stream at once in NumPy, layer by layer:

- UDP: header and checksum over the IPv4/IPv6 pseudo-header (:func:`udp_rows`);
- IP: IPv4 (fragmented at the MTU like a real sender: 1480-byte fragment payloads at MTU 1500) or
  IPv6 (fragment extension header when larger than the MTU) (:func:`ip_rows`);
- link layer: Ethernet with optional stacked VLAN tags, Linux SLL, SLL2, raw IP, BSD loopback
  (:func:`link_header`, the same bytes before every IP packet of a stream).

The functions of one datagram are that builder on one row: :func:`udp_datagram`, :func:`ip_packets`,
:func:`link_frame` and :func:`frames_for` (all three layers for one :class:`~lidarpkt.core.packet.Packet`);
:func:`framed_packets` frames a sequence of packets (those of one stream together). The
files are written by :mod:`lidarpkt.writers.pcap`. The address text decides IPv4 or IPv6 (``":"`` in it
means IPv6).
"""

from __future__ import annotations

import socket
from typing import Callable, Iterable, Iterator, Sequence

import numpy as np

from lidarpkt.containers.layouts import (
    ETHERNET_HEADER,
    IPV4_HEADER,
    IPV6_FRAGMENT_HEADER,
    IPV6_HEADER,
    LINUX_SLL2_HEADER,
    LINUX_SLL_HEADER,
    NULL_HEADER,
    UDP_HEADER,
    VLAN_TAG,
    _fold,
    _row_word_sums,
    _udp_pseudo_sum,
    header_struct,
)
from lidarpkt.core.packet import Endpoint, Packet
from lidarpkt.errors import PacketFormatError

# the link headers are packed with the layout the reader parses them with (lidarpkt.containers.layouts)
_ETH = header_struct(ETHERNET_HEADER)
_VLAN = header_struct(VLAN_TAG)
_SLL = header_struct(LINUX_SLL_HEADER)
_SLL2 = header_struct(LINUX_SLL2_HEADER)

__all__ = ["LINKTYPES", "udp_rows", "ip_rows", "fragment_ipv4", "link_header", "batch_frames", "udp_datagram",
           "ip_packets", "link_frame", "frames_for", "framed_packets"]

LINKTYPES = {"null": 0, "ethernet": 1, "raw": 101, "linux_sll": 113, "linux_sll2": 276}
_ETHERTYPE = {4: 0x0800, 6: 0x86DD}
_AF = {4: 2, 6: 24}  # BSD loopback address families (24 = AF_INET6 on NetBSD/OpenBSD, read by all tools)
SRC_MAC = bytes.fromhex("607688000000")  # the Velodyne OUI every VLP-16 capture shows
BROADCAST_MAC = b"\xff" * 6
DST_MAC = bytes.fromhex("020000000001")  # locally administered

IPPROTO_UDP = 17
IPV6_NEXT_FRAGMENT = 44
WINDOW_PACKETS = 4096  # framed_packets frames the packets of a stream among this many in a row at once
WINDOW_BYTES = 16 << 20  # ... and among this many payload bytes


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


def _header_rows(layout: np.dtype, n: int, **fields) -> np.ndarray:
    """``uint8[n, layout.itemsize]``: ``n`` headers of ``layout`` with the given fields (scalars or arrays)."""
    rows = np.zeros(n, layout)
    for name, value in fields.items():
        rows[name] = np.frombuffer(value, layout[name])[0] if isinstance(value, bytes) else value
    return rows.view(np.uint8).reshape(n, layout.itemsize)


def _rows(data: bytes) -> np.ndarray:
    return np.frombuffer(data, np.uint8).reshape(1, len(data))


# --- the builder: N datagrams of one stream, layer by layer --------------------------------------------
def udp_rows(src: str, sport: int, dst: str, dport: int, payload: np.ndarray, *, checksum: bool = True) -> np.ndarray:
    """``uint8[N, 8 + L]``: UDP header + payload of each row of ``payload`` (``uint8[N, L]``). The checksum
    covers the IPv4/IPv6 pseudo-header (0 = none, IPv4 only: IPv6 forbids it)."""
    n, length = payload.shape[0], 8 + payload.shape[1]
    if length > 0xFFFF:
        raise PacketFormatError(f"UDP payload of {length - 8} bytes does not fit the 16-bit UDP length")
    value: int | np.ndarray = 0
    if checksum or _version(src) == 6:  # RFC 768 over the pseudo-header, the UDP header and each payload
        fixed = _udp_pseudo_sum(_addr_bytes(src), _addr_bytes(dst), length) + sport + dport + length
        value = (~_fold(_row_word_sums(payload) + fixed)) & 0xFFFF
        value = np.where(value == 0, 0xFFFF, value)  # 0 would mean no checksum
    header = _header_rows(UDP_HEADER, n, src_port=sport, dst_port=dport, length=length, checksum=value)
    return np.concatenate([header, payload], axis=1)


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


def ip_rows(src: str, dst: str, l4: np.ndarray, ident: np.ndarray, *, mtu: int | None = 1500,
            proto: int = IPPROTO_UDP) -> list[np.ndarray]:
    """The IP packets carrying each row of ``l4`` (``uint8[N, M]``, e.g. UDP datagrams), with IP identification
    ``ident`` (``int[N]``): one ``uint8[N, F_k]`` array per fragment ``k`` (one when no larger than ``mtu``)."""
    if _version(src) != _version(dst):
        raise PacketFormatError(f"source {src} and destination {dst} are not the same IP version")
    n, size = l4.shape
    ident = np.asarray(ident, np.int64)
    s, d = _addr_bytes(src), _addr_bytes(dst)
    out = []
    if _version(src) == 4:
        if mtu is None:
            if 20 + size > 0xFFFF:
                raise PacketFormatError("IPv4 datagram larger than 65535 bytes")
            pieces = [(0, size, False)]
        else:
            pieces = fragment_ipv4(size, mtu)
        s_int, d_int = int.from_bytes(s, "big"), int.from_bytes(d, "big")
        for off, length, more in pieces:
            flags = (0x2000 if more else 0) | (off // 8)
            fixed = 0x4500 + (20 + length) + flags + (64 << 8 | proto) + (s_int >> 16) + (s_int & 0xFFFF) \
                + (d_int >> 16) + (d_int & 0xFFFF)
            ip = _header_rows(IPV4_HEADER, n, version_ihl=0x45, total_length=20 + length,
                              identification=ident & 0xFFFF, flags_fragment_offset=flags, ttl=64, protocol=proto,
                              header_checksum=(~_fold((ident & 0xFFFF) + fixed)) & 0xFFFF, src=s_int, dst=d_int)
            out.append(np.concatenate([ip, l4[:, off:off + length]], axis=1))
        return out
    if mtu is None or 40 + size <= mtu:
        ip = _header_rows(IPV6_HEADER, n, version_class_flow=6 << 28, payload_length=size, next_header=proto,
                          hop_limit=64, src=s, dst=d)
        return [np.concatenate([ip, l4], axis=1)]
    room = (mtu - IPV6_HEADER.itemsize - IPV6_FRAGMENT_HEADER.itemsize) // 8 * 8
    for off in range(0, size, room):
        length = min(room, size - off)
        ip = _header_rows(IPV6_HEADER, n, version_class_flow=6 << 28, payload_length=8 + length,
                          next_header=IPV6_NEXT_FRAGMENT, hop_limit=64, src=s, dst=d)
        frag = _header_rows(IPV6_FRAGMENT_HEADER, n, next_header=proto, fragment_offset_m=off | (off + length < size),
                            identification=ident & 0xFFFFFFFF)
        out.append(np.concatenate([ip, frag, l4[:, off:off + length]], axis=1))
    return out


def link_header(version: int, link: str = "ethernet", *, vlan: Sequence[int] = (), big_endian: bool = False,
                broadcast: bool = False) -> bytes:
    """The link-layer header before an IP packet of ``version`` (4 or 6).

    ``vlan``: VLAN ids, outermost first (Ethernet only); the outer tags of a stack use the
    802.1ad TPID 0x88A8, the innermost 0x8100. ``big_endian`` sets the byte order of the
    BSD loopback family word (the writing host's order).
    """
    etype = _ETHERTYPE.get(version)
    if etype is None:
        raise ValueError(f"not an IP packet (version nibble {version})")
    if link == "ethernet":
        # each tag: its TPID sits where the ethertype was, then the TCI and the next ethertype
        tpids = [0x88A8] * (len(vlan) - 1) + [0x8100] if vlan else []
        types = tpids + [etype]
        out = _ETH.pack(BROADCAST_MAC if broadcast else DST_MAC, SRC_MAC, types[0])
        return out + b"".join(_VLAN.pack(vid & 0x0FFF, nxt) for vid, nxt in zip(vlan, types[1:]))
    if vlan:
        raise ValueError("VLAN tags need the Ethernet link type")
    if link == "linux_sll":
        return _SLL.pack(1 if broadcast else 0, 1, 6, SRC_MAC.ljust(8, b"\0"), etype)
    if link == "linux_sll2":
        return _SLL2.pack(etype, 0, 2, 1, 1 if broadcast else 0, 6, SRC_MAC.ljust(8, b"\0"))
    if link == "raw":
        return b""
    if link == "null":
        return header_struct(NULL_HEADER, ">" if big_endian else "<").pack(_AF[version])
    raise ValueError(f"unknown link type {link!r}; choose one of {sorted(LINKTYPES)}")


def batch_frames(src: Endpoint, dst: Endpoint, payload: np.ndarray, ident: np.ndarray, *, link: str = "ethernet",
                 mtu: int | None = 1500, vlan: Sequence[int] = (), big_endian: bool = False,
                 udp_checksum: bool = True) -> list[np.ndarray]:
    """The link-layer frames of ``N`` UDP datagrams of one stream, built for all of them at once.

    Args:
        src, dst: the stream's endpoints (IPv4 or IPv6 by the address text).
        payload: ``uint8[N, L]`` UDP payloads.
        ident: ``int[N]`` IP identification of each datagram.
        link, mtu, vlan, big_endian, udp_checksum: as in :func:`write_pcap`.

    Returns:
        one ``uint8[N, F_k]`` array per fragment ``k`` (every datagram of the batch has the same
        size, so fragments alike): row ``i`` of each, in order, are the frames of datagram ``i``.

    Raises:
        lidarpkt.errors.PacketFormatError: a bad address, or a datagram too large for UDP/IP.
        ValueError: an unknown link type, VLAN tags on another link than Ethernet.
    """
    l4 = udp_rows(src.address, src.port, dst.address, dst.port, np.ascontiguousarray(payload), checksum=udp_checksum)
    ips = ip_rows(src.address, dst.address, l4, ident, mtu=mtu)
    head = np.frombuffer(link_header(_version(src.address), link, vlan=vlan, big_endian=big_endian,
                                     broadcast=dst.address == "255.255.255.255"), np.uint8)
    n = payload.shape[0]
    return [np.concatenate([np.broadcast_to(head, (n, head.size)), ip], axis=1) for ip in ips]


# --- one datagram: the builder on one row -------------------------------------------------------------
def udp_datagram(src: str, sport: int, dst: str, dport: int, payload: bytes, *, checksum: bool = True) -> bytes:
    """UDP header + payload (:func:`udp_rows` of one datagram)."""
    return udp_rows(src, sport, dst, dport, _rows(bytes(payload)), checksum=checksum).tobytes()


def ip_packets(src: str, dst: str, l4: bytes, *, ident: int, mtu: int | None = 1500, proto: int = IPPROTO_UDP
               ) -> list[bytes]:
    """IP packets carrying ``l4`` (e.g. a UDP datagram): one, or fragments when larger than ``mtu``."""
    return [ip.tobytes() for ip in ip_rows(src, dst, _rows(bytes(l4)), np.array([ident]), mtu=mtu, proto=proto)]


def link_frame(ip: bytes, link: str = "ethernet", *, vlan: Sequence[int] = (), big_endian: bool = False,
               broadcast: bool = False) -> bytes:
    """An IP packet wrapped in a link-layer header (:func:`link_header`, version from the packet)."""
    return link_header(ip[0] >> 4, link, vlan=vlan, big_endian=big_endian, broadcast=broadcast) + ip


def frames_for(packet: Packet, *, link: str = "ethernet", mtu: int | None = 1500, vlan: Sequence[int] = (),
               ident: int = 0, big_endian: bool = False, udp_checksum: bool = True) -> list[bytes]:
    """The link-layer frames a network would carry for one packet (several when fragmented)."""
    if packet.src is None or packet.dst is None:
        raise PacketFormatError("a packet without source/destination endpoints cannot be framed; give it Endpoints")
    return [f.tobytes() for f in batch_frames(packet.src, packet.dst, _rows(bytes(packet.payload)), np.array([ident]),
                                              link=link, mtu=mtu, vlan=vlan, big_endian=big_endian,
                                              udp_checksum=udp_checksum)]


def framed_packets(packets: Iterable[Packet], *, link_of: Callable[[Packet], tuple[str, Sequence[int]]] | None = None,
                   link: str = "ethernet", vlan: Sequence[int] = (), **frame_args) -> Iterator[tuple[Packet, list[bytes]]]:
    """Each packet with its frames (:func:`frames_for`), IP identification counting packets from 1: the
    packets of one stream, size and link among up to :data:`WINDOW_PACKETS` (:data:`WINDOW_BYTES`) in a row
    are framed together (:func:`batch_frames`).

    ``link_of(packet)``: its ``(link, vlan)`` (default: ``link`` and ``vlan`` for all); ``frame_args``: the
    other options of :func:`batch_frames`.
    """
    window: list[Packet] = []
    size = ident = 0

    def frame_window() -> Iterator[tuple[Packet, list[bytes]]]:
        groups: dict[tuple, list[int]] = {}
        for k, p in enumerate(window):
            if p.src is None or p.dst is None:
                raise PacketFormatError("a packet without source/destination endpoints cannot be framed; give it "
                                        "Endpoints")
            how = link_of(p) if link_of is not None else (link, vlan)
            groups.setdefault((p.src, p.dst, len(p.payload), how[0], tuple(how[1])), []).append(k)
        frames: list[list[bytes]] = [[] for _ in window]
        for (src, dst, length, link_name, tags), rows in groups.items():
            payload = np.frombuffer(b"".join(bytes(window[k].payload) for k in rows), np.uint8).reshape(len(rows), length)
            idents = (ident + 1 + np.array(rows)) & 0xFFFF
            for part in batch_frames(src, dst, payload, idents, link=link_name, vlan=tags, **frame_args):
                for k, row in zip(rows, part):
                    frames[k].append(row.tobytes())
        yield from zip(window, frames)

    for p in packets:
        window.append(p)
        size += len(p.payload)
        if len(window) >= WINDOW_PACKETS or size >= WINDOW_BYTES:
            yield from frame_window()
            ident = (ident + len(window)) & 0xFFFF
            window, size = [], 0
    if window:
        yield from frame_window()
