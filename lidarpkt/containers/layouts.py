"""Header layouts of the link, IPv4/IPv6 and UDP layers and of the pcap/pcapng containers, declared once.

Every layout is a NumPy dtype with the field names of the specs and RFCs; struct formats and field
offsets are derived from it. The readers gather fields with them, and :mod:`lidarpkt.writers.pcap`
packs with the same layouts. Also the RFC 1071 checksum both sides use.
"""

from __future__ import annotations

import struct
from functools import lru_cache
from typing import Literal

import numpy as np

ByteOrder = Literal["<", ">"]  # a layout's byte order where the container decides it (pcap, pcapng, BSD loopback)

# --- link types (tcpdump.org/linktypes.html) --------------------------------------------
LINKTYPE_NULL = 0
LINKTYPE_ETHERNET = 1
LINKTYPE_RAW = 101
LINKTYPE_RAW_OPENBSD = 14  # DLT_RAW on OpenBSD
LINKTYPE_RAW_BSD = 12  # DLT_RAW on most BSDs
LINKTYPE_LOOP = 108
LINKTYPE_LINUX_SLL = 113
LINKTYPE_IPV4 = 228
LINKTYPE_IPV6 = 229
LINKTYPE_LINUX_SLL2 = 276

LINKTYPE_NAMES: dict[int, str] = {
    LINKTYPE_NULL: "null",
    LINKTYPE_ETHERNET: "ethernet",
    LINKTYPE_RAW: "raw",
    LINKTYPE_RAW_BSD: "raw",
    LINKTYPE_RAW_OPENBSD: "raw",
    LINKTYPE_LOOP: "loop",
    LINKTYPE_LINUX_SLL: "linux_sll",
    LINKTYPE_LINUX_SLL2: "linux_sll2",
    LINKTYPE_IPV4: "ipv4",
    LINKTYPE_IPV6: "ipv6",
}
_RAW_LINKS = (LINKTYPE_RAW, LINKTYPE_RAW_BSD, LINKTYPE_RAW_OPENBSD, LINKTYPE_IPV4, LINKTYPE_IPV6)

ETHERTYPE_IPV4 = 0x0800
ETHERTYPE_IPV6 = 0x86DD
_VLAN_TPIDS = (0x8100, 0x88A8, 0x9100, 0x9200)  # 802.1Q, 802.1ad, legacy QinQ tags
_BSD_AF_INET = 2
_BSD_AF_INET6 = (10, 24, 28, 30)  # Linux, NetBSD/OpenBSD, FreeBSD, Darwin
IPPROTO_UDP = 17
_IPV6_EXT_HEADERS = (0, 43, 60)  # hop-by-hop, routing, destination options
_IPV6_FRAGMENT = 44
_IPV6_AH = 51

# --- header layouts, declared once (field names as in the pcap/pcapng specs and the RFCs) ----------
# Container headers take the file's byte order ("=" here, given at use); network headers are big-endian.
PCAP_GLOBAL_HEADER = np.dtype([("magic_number", "=u4"), ("version_major", "=u2"), ("version_minor", "=u2"),
                               ("thiszone", "=i4"), ("sigfigs", "=u4"), ("snaplen", "=u4"), ("network", "=u4")])
PCAP_RECORD_HEADER = np.dtype([("ts_sec", "=u4"), ("ts_frac", "=u4"), ("incl_len", "=u4"), ("orig_len", "=u4")])
PCAP_MODIFIED_EXTRA = np.dtype([("ifindex", "=u4"), ("protocol", "=u2"), ("pkt_type", "u1"), ("pad", "u1")])
PCAPNG_BLOCK_HEADER = np.dtype([("block_type", "=u4"), ("block_total_length", "=u4")])
PCAPNG_SECTION_HEADER = np.dtype([("byte_order_magic", "=u4"), ("major_version", "=u2"), ("minor_version", "=u2"),
                       ("section_length", "=i8")])
PCAPNG_IDB = np.dtype([("linktype", "=u2"), ("reserved", "=u2"), ("snaplen", "=u4")])
PCAPNG_EPB = np.dtype([("interface_id", "=u4"), ("timestamp_high", "=u4"), ("timestamp_low", "=u4"),
                       ("captured_len", "=u4"), ("original_len", "=u4")])
PCAPNG_OPB = np.dtype([("interface_id", "=u2"), ("drops_count", "=u2"), ("timestamp_high", "=u4"),
                       ("timestamp_low", "=u4"), ("captured_len", "=u4"), ("original_len", "=u4")])
PCAPNG_SPB = np.dtype([("original_len", "=u4")])
PCAPNG_OPTION = np.dtype([("option_code", "=u2"), ("option_length", "=u2")])
ETHERNET_HEADER = np.dtype([("dst_mac", "V6"), ("src_mac", "V6"), ("ethertype", ">u2")])
VLAN_TAG = np.dtype([("tci", ">u2"), ("ethertype", ">u2")])  # follows a TPID that took the ethertype's place
LINUX_SLL_HEADER = np.dtype([("packet_type", ">u2"), ("arphrd_type", ">u2"), ("addr_len", ">u2"),
                             ("addr", "V8"), ("protocol", ">u2")])
LINUX_SLL2_HEADER = np.dtype([("protocol", ">u2"), ("reserved", ">u2"), ("interface_index", ">u4"),
                              ("arphrd_type", ">u2"), ("packet_type", "u1"), ("addr_len", "u1"), ("addr", "V8")])
NULL_HEADER = np.dtype([("family", "=u4")])  # the writing host's byte order (LINKTYPE_LOOP: big-endian)
IPV4_HEADER = np.dtype([("version_ihl", "u1"), ("tos", "u1"), ("total_length", ">u2"), ("identification", ">u2"),
                        ("flags_fragment_offset", ">u2"), ("ttl", "u1"), ("protocol", "u1"),
                        ("header_checksum", ">u2"), ("src", ">u4"), ("dst", ">u4")])
IPV6_HEADER = np.dtype([("version_class_flow", ">u4"), ("payload_length", ">u2"), ("next_header", "u1"),
                        ("hop_limit", "u1"), ("src", "V16"), ("dst", "V16")])
IPV6_FRAGMENT_HEADER = np.dtype([("next_header", "u1"), ("reserved", "u1"), ("fragment_offset_m", ">u2"),
                                 ("identification", ">u4")])
UDP_HEADER = np.dtype([("src_port", ">u2"), ("dst_port", ">u2"), ("length", ">u2"), ("checksum", ">u2")])

_STRUCT_CODES = {"u1": "B", "u2": "H", "u4": "I", "u8": "Q", "i1": "b", "i2": "h", "i4": "i", "i8": "q"}


def field_names(layout: np.dtype) -> tuple[str, ...]:
    """The field names of a structured layout, in order; TypeError for a dtype without fields."""
    if layout.names is None:
        raise TypeError(f"layout: {layout} is not a structured dtype")
    return layout.names


def field_info(layout: np.dtype, name: str) -> tuple[np.dtype, int]:
    """``(dtype, byte offset)`` of field ``name`` of a structured layout; TypeError for a dtype
    without fields, KeyError for an unknown name."""
    if layout.fields is None:
        raise TypeError(f"layout: {layout} is not a structured dtype")
    dt, off = layout.fields[name][:2]
    return dt, off


@lru_cache(maxsize=64)
def header_struct(layout: np.dtype, endian: str | None = None) -> struct.Struct:
    """A :class:`struct.Struct` for a header layout (``endian`` "<"/">" for the container headers)."""
    codes = []
    pos = 0
    names = field_names(layout)
    for name in names:
        dt, off = field_info(layout, name)
        if off != pos:
            raise ValueError(f"{name}: layouts must be packed")
        codes.append(f"{dt.itemsize}s" if dt.kind == "V" else _STRUCT_CODES[f"{dt.kind}{dt.itemsize}"])
        pos += dt.itemsize
    order = endian or (">" if any(field_info(layout, n)[0].byteorder == ">" for n in names) else "<")
    return struct.Struct(order + "".join(codes))


def field_offset(layout: np.dtype, name: str) -> int:
    """Byte offset of a field in a header layout."""
    return field_info(layout, name)[1]


def _fold(total):
    """Fold a one's-complement sum (int or int64 array) to 16 bits."""
    for _ in range(4):
        total = (total & 0xFFFF) + (total >> 16)
    return total


def _row_word_sums(rows: np.ndarray) -> np.ndarray:
    """Sum of the big-endian 16-bit words of each row of a ``uint8[n, L]`` array (odd L: zero-padded)."""
    even = rows.shape[1] & ~1
    total = np.ascontiguousarray(rows[:, :even]).view(">u2").sum(axis=1, dtype=np.int64)
    if even != rows.shape[1]:
        total += rows[:, -1].astype(np.int64) << 8
    return total


def internet_checksum(*parts: bytes) -> int:
    """RFC 1071 checksum of the concatenated parts (each zero-padded to an even length)."""
    total = 0
    for part in parts:
        if len(part):
            total += int(_row_word_sums(np.frombuffer(part, np.uint8).reshape(1, -1))[0])
    return (~_fold(total)) & 0xFFFF


def _udp_pseudo_sum(src: bytes, dst: bytes, udp_length: int) -> int:
    """One's-complement sum of the IPv4/IPv6 pseudo-header of a UDP datagram."""
    words = np.frombuffer(src + dst, ">u2")
    return int(words.sum(dtype=np.int64)) + IPPROTO_UDP + udp_length


_IPV4 = header_struct(IPV4_HEADER)
_IPV6 = header_struct(IPV6_HEADER)
_IPV6_FRAG = header_struct(IPV6_FRAGMENT_HEADER)
_UDP = header_struct(UDP_HEADER)
_ETHERTYPE = struct.Struct(">H")
_L2_BYTES = {
    LINKTYPE_ETHERNET: ETHERNET_HEADER.itemsize,
    LINKTYPE_LINUX_SLL: LINUX_SLL_HEADER.itemsize,
    LINKTYPE_LINUX_SLL2: LINUX_SLL2_HEADER.itemsize,
    LINKTYPE_NULL: NULL_HEADER.itemsize,
    LINKTYPE_LOOP: NULL_HEADER.itemsize,
    **{lt: 0 for lt in _RAW_LINKS},
}
