"""Offline packet source: UDP datagrams from pcap and pcapng captures.

Formats (detected by magic number, never by file name): classic libpcap in both byte
orders with microsecond or nanosecond time stamps (and the 24-byte-record "modified"
variant), and pcapng (several sections and interfaces, each with its own link type and
time resolution). Link types: Ethernet (with any number of 802.1Q / 802.1ad tags),
Linux cooked SLL and SLL2, raw IPv4/IPv6, BSD loopback (null and loop). Network
layers: UDP over IPv4 (fragments reassembled) and over IPv6 (extension headers skipped,
fragments reassembled too). Every header layout is declared once below as a NumPy
dtype; struct formats and field offsets are derived from it (and :mod:`lidarpkt.pcapwrite`
packs with the same layouts).

How it is fast: the file is read in large blocks into one reused buffer (not mmap, so
that a file truncated under the reader gives a warning rather than a SIGBUS); record
headers are walked in chunks
(a run of records with one capture length is recognised in one strided NumPy
comparison); the link/IPv4/UDP headers of all records of a chunk are checked with
NumPy gathers; the payloads of plain unfragmented UDP/IPv4 records are cut out in one
copy per stream, and whole in-order IPv4 fragment trains are reassembled with array
operations too. Only the odd records (reordered, duplicated or lost fragments, IPv6,
three or more VLAN tags, damage) go through the per-record parser and
:class:`~lidarpkt.reassembly.Reassembler` (bounded, with a host-time timeout so that a
stale fragment is never merged with a later datagram that reuses its IP ID).

Length fields are never trusted over the captured bytes: a UDP payload ends at the
UDP length, bounded by what was captured (early VLP-16 position packets carry an
IPv4 total length of 1234 for a 540-byte datagram). IP header checksums are never
checked and unfragmented datagrams are never dropped for their UDP checksum; only a
datagram rebuilt from fragments must match its UDP length and, when the sender wrote
one, its UDP checksum (otherwise it mixes the fragments of two datagrams that share an
IP ID; it is counted as malformed).

Damage is reported, not raised, once a file is known to be a capture: a truncated last
record or a record length beyond the end of the file stops reading there, and after the
last good packet a :class:`~lidarpkt.errors.TruncatedCaptureWarning` says where;
malformed records are counted in :class:`ReadStats` (and summed up in one
:class:`~lidarpkt.errors.SkippedPacketWarning`) and skipped. A file that is not a
capture raises :class:`~lidarpkt.errors.CaptureFormatError`.

Filters: ``ports`` matches the *destination* port (the port a sensor is configured to
send to), ``src_addresses`` the source address, ``payload_sizes`` the UDP payload size.
"""

from __future__ import annotations

import os
import socket
import struct
import sys
from collections import Counter
from dataclasses import dataclass, field
from functools import lru_cache
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np

from ._readahead import warn as _warn  # warnings.warn, or queued when a read-ahead thread runs the reader
from . import kernels
from .errors import CaptureFormatError, SkippedPacketWarning, TruncatedCaptureWarning
from .packet import Endpoint, Packet, PacketBatch
from .reassembly import Reassembler

if TYPE_CHECKING:
    from .sources.segments import Segment

__all__ = [
    "PcapReader",
    "ReadStats",
    "read_packets",
    "read_batches",
    "is_capture",
    "capture_format",
    "LINKTYPE_NAMES",
]

# --- magic numbers --------------------------------------------------------------------
PCAP_MAGIC_US = 0xA1B2C3D4
PCAP_MAGIC_NS = 0xA1B23C4D
PCAP_MAGIC_MODIFIED = 0xA1B2CD34  # Kuznetzov's patched libpcap: 24-byte record headers
PCAPNG_SHB = 0x0A0D0D0A
PCAPNG_BOM = 0x1A2B3C4D

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


@lru_cache(maxsize=64)
def header_struct(layout: np.dtype, endian: str | None = None) -> struct.Struct:
    """A :class:`struct.Struct` for a header layout (``endian`` "<"/">" for the container headers)."""
    codes = []
    pos = 0
    for name in layout.names:
        dt, off = layout.fields[name][:2]
        if off != pos:
            raise ValueError(f"{name}: layouts must be packed")
        codes.append(f"{dt.itemsize}s" if dt.kind == "V" else _STRUCT_CODES[f"{dt.kind}{dt.itemsize}"])
        pos += dt.itemsize
    order = endian or (">" if any(layout.fields[n][0].byteorder == ">" for n in layout.names) else "<")
    return struct.Struct(order + "".join(codes))


def field_offset(layout: np.dtype, name: str) -> int:
    """Byte offset of a field in a header layout."""
    return layout.fields[name][1]


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


def _field(buf: np.ndarray, base: np.ndarray, layout: np.dtype, name: str, endian: str | None = None) -> np.ndarray:
    """int64 values of one header field at each ``base`` offset (offsets clipped into the buffer)."""
    dt, off = layout.fields[name][:2]
    if endian is not None and dt.itemsize > 1:
        dt = dt.newbyteorder(endian)
    idx = np.minimum(base + off, buf.shape[0] - dt.itemsize)
    return _gather(buf, idx, dt).astype(np.int64)


_IPV4 = header_struct(IPV4_HEADER)
_IPV6 = header_struct(IPV6_HEADER)
_IPV6_FRAG = header_struct(IPV6_FRAGMENT_HEADER)
_UDP = header_struct(UDP_HEADER)
_ETHERTYPE = struct.Struct(">H")
_MIXED_CHECKSUM = "reassembled datagram fails its UDP checksum (fragments of two datagrams sharing an IP ID?)"
_L2_BYTES = {
    LINKTYPE_ETHERNET: ETHERNET_HEADER.itemsize,
    LINKTYPE_LINUX_SLL: LINUX_SLL_HEADER.itemsize,
    LINKTYPE_LINUX_SLL2: LINUX_SLL2_HEADER.itemsize,
    LINKTYPE_NULL: NULL_HEADER.itemsize,
    LINKTYPE_LOOP: NULL_HEADER.itemsize,
    **{lt: 0 for lt in _RAW_LINKS},
}

MAX_RECORD_BYTES = 1 << 18  # largest caplen accepted (libpcap's MAXIMUM_SNAPLEN, 262144)
MAX_PCAPNG_BLOCK = 1 << 24  # larger "blocks" are taken as corruption, not allocated
MAX_CHUNK_BYTES = 8 << 20  # a chunk (and so a batch) spans at most this much of the file: 8 MB keeps a chunk in
# L3 while its records are walked, grouped and copied out (mixed VLP-16 capture: 28 ms per 100 MB against 32-39 ms
# with 32 MB chunks)
READ_BLOCK_BYTES = 16 << 20  # the file is read in blocks this large (into one reused buffer); 16 MB rather than
# 32: as fast alone (4-32 MB within noise), and with lidarpkt.open's read-ahead thread the first block (read
# before any decoding) and the last (decoded after all reading) are the parts that do not overlap. (4 MB blocks
# made the Ouster pipeline 40 % slower: the batches' payload arrays, allocated fresh, page-faulted more)
_SEC_NS = 1_000_000_000
_NATIVE_ORDER = "<" if sys.byteorder == "little" else ">"


@dataclass
class ReadStats:
    """What a :class:`PcapReader` found. Counts are of records unless the name says otherwise."""

    path: str = ""
    format: str = ""  # "pcap" or "pcapng"
    records: int = 0  # packet records read (pcap records, pcapng EPB/SPB/OPB)
    bytes_read: int = 0  # file bytes walked (headers included)
    udp_packets: int = 0  # UDP datagrams found (after reassembly, before filters)
    yielded: int = 0  # datagrams handed out (after filters)
    filtered: int = 0  # datagrams dropped by the port/address/size filters
    non_udp: int = 0  # records that are not UDP (ARP, TCP, ICMP, other ethertypes...)
    fragments: int = 0  # IP fragments seen
    reassembled: int = 0  # datagrams rebuilt from fragments
    orphaned_fragments: int = 0  # fragments whose datagram never completed (timed out, evicted, end of file)
    duplicate_fragments: int = 0
    malformed: int = 0  # records skipped as damaged (see malformed_reasons)
    malformed_reasons: Counter = field(default_factory=Counter)
    truncated: bool = False  # reading stopped at damage before the end of the file
    truncated_reason: str = ""
    link_types: Counter = field(default_factory=Counter)  # link type name -> records
    interfaces: int = 0  # pcapng interfaces (1 for classic pcap)
    snaplen: int = 0
    nanosecond: bool = False  # classic pcap with ns time stamps
    big_endian: bool = False

    def as_dict(self) -> dict:
        """A JSON-ready copy."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["malformed_reasons"] = dict(self.malformed_reasons)
        out["link_types"] = dict(self.link_types)
        return out


def capture_format(path: str | os.PathLike[str]) -> str | None:
    """``"pcap"``, ``"pcapng"`` or None, from the first four bytes of the file."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        return None
    return _format_from_magic(head)


def _format_from_magic(head: bytes) -> str | None:
    if len(head) < 4:
        return None
    le, be = struct.unpack_from("<I", head)[0], struct.unpack_from(">I", head)[0]
    if PCAPNG_SHB in (le, be):
        return "pcapng"
    if {le, be} & {PCAP_MAGIC_US, PCAP_MAGIC_NS, PCAP_MAGIC_MODIFIED}:
        return "pcap"
    return None


def is_capture(path: str | os.PathLike[str]) -> bool:
    """True when the file starts with a pcap or pcapng magic number (never raises)."""
    return capture_format(path) is not None


# --- chunks of records ------------------------------------------------------------------
@dataclass
class _Chunk:
    """Records of one chunk: where their link-layer bytes are in the file buffer."""

    data_off: np.ndarray  # int64[n] offset of the first captured byte
    caplen: np.ndarray  # int64[n]
    ts_ns: np.ndarray  # int64[n]
    linktype: np.ndarray  # int64[n]


def _gather(buf: np.ndarray, idx: np.ndarray, dtype) -> np.ndarray:
    """Values of ``dtype`` at byte offsets ``idx`` of ``buf`` (offsets must be in range)."""
    size = np.dtype(dtype).itemsize
    if size == 1:
        return buf[idx]
    return _copy_rows(buf, idx, size).view(dtype).reshape(-1)


def _few_groups(k1: np.ndarray, k2: np.ndarray, limit: int = 8) -> list[np.ndarray] | None:
    """Row indices of each distinct ``(k1, k2)`` pair, in order of first appearance, or ``None``
    when there are more than ``limit`` pairs.

    A chunk usually holds one to a few streams (a VLP-16's data and position packets); one
    comparison pass per stream is far cheaper than the sorts of ``np.unique``.
    """
    left = np.arange(k1.shape[0])
    groups = []
    while left.size:
        if len(groups) == limit:
            return None
        first = left[0]
        mine = (k1[left] == k1[first]) & (k2[left] == k2[first])
        if mine.all():
            groups.append(left)
            break
        groups.append(left[mine])
        left = left[~mine]
    return groups


def _pcapng_time_ns(raw: int, interface: tuple[int, int, int, int, int]) -> int | None:
    """A pcapng packet's raw time stamp in ns since the epoch (``if_tsresol`` and ``if_tsoffset`` of its
    interface applied), or ``None`` when that does not fit an int64."""
    _lt, _snap, mul, div, ts_off = interface
    ts_ns = ts_off * _SEC_NS + (raw * mul) // div
    return ts_ns if -(1 << 63) <= ts_ns < (1 << 63) else None


def _ipv4_text(values: np.ndarray) -> list[str]:
    return [socket.inet_ntoa(v.to_bytes(4, "big")) for v in values.tolist()]


def _copy_rows(buf: np.ndarray, offs: np.ndarray, length: int) -> np.ndarray:
    """``uint8[n, length]`` copy of the bytes at each offset of ``buf``.

    Row k of a (read-only, zero-copy) sliding-window view is ``buf[k:k+length]``, so one
    fancy index on its first axis copies every payload as a contiguous row (memcpy-speed),
    far faster than gathering an ``n × length`` index array.
    """
    n = offs.shape[0]
    if n == 0 or length == 0:
        return np.zeros((n, length), np.uint8)
    native = kernels.native
    if native is not None:
        out = np.empty((n, length), np.uint8)
        native.gather_rows(buf, np.ascontiguousarray(offs, np.int64), out)
        return out
    windows = np.ndarray((buf.shape[0] - length + 1, length), np.uint8, buf, 0, (1, 1))
    return windows[offs]


class _Blocks:
    """Reads a file in blocks into one reused buffer (no mmap: a file truncated while it is read
    must give a short read, not a SIGBUS; memory stays bounded by the block size)."""

    def __init__(self, fh, size: int) -> None:
        self.fh = fh
        self.size = size
        self._buf: np.ndarray | None = None

    def read(self, offset: int) -> np.ndarray:
        """The file's bytes from ``offset``: up to READ_BLOCK_BYTES of them (fewer at the end)."""
        want = max(0, min(READ_BLOCK_BYTES, self.size - offset))
        if self._buf is None or self._buf.shape[0] < want:
            self._buf = np.empty(max(want, 1), np.uint8)
        view = memoryview(self._buf)[:want]
        self.fh.seek(offset)
        got = 0
        while got < want:
            k = self.fh.readinto(view[got:])
            if not k:
                self.size = offset + got  # the file shrank while being read: it ends here now
                break
            got += k
        return self._buf[:got]


class PcapReader:
    """UDP datagrams of one pcap or pcapng file.

    Args:
        path: the capture file.
        ports: keep only datagrams whose *destination* port is one of these.
        src_addresses: keep only datagrams from these source addresses (text, as in
            :class:`~lidarpkt.packet.Endpoint`).
        payload_sizes: keep only datagrams with one of these payload sizes (bytes).
        batch_packets: records per chunk, and so the most packets in one batch.
        reassembly_timeout_ns, max_pending_datagrams, max_pending_bytes: bounds of the
            fragment reassembler (see :class:`lidarpkt.reassembly.Reassembler`).

    Raises:
        CaptureFormatError: when the file is not a pcap/pcapng capture (the message names
            the file and its first bytes) or its header is unusable. Opening checks the
            header at once; damage further in is reported while iterating.

    Each of :meth:`packets` and :meth:`batches` reads the file from the start; :attr:`stats`
    describes the last complete or partial pass.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        ports: Iterable[int] | None = None,
        src_addresses: Iterable[str] | None = None,
        payload_sizes: Iterable[int] | None = None,
        batch_packets: int = 8192,
        reassembly_timeout_ns: int = 30_000_000_000,
        max_pending_datagrams: int = 1024,
        max_pending_bytes: int = 64 * 1024 * 1024,
        segment: "Segment | None" = None,
    ) -> None:
        self.path = os.fspath(path)
        self.segment = segment
        self.split_ordinal: int | None = None  # segment reading: ordinal of the first packet at/after its end
        self._chunk_at = 0  # file offset of the first record of the chunk being yielded
        self.ports = None if ports is None else frozenset(int(p) for p in ports)
        self.src_addresses = None if src_addresses is None else frozenset(_canonical_address(a) for a in src_addresses)
        self.payload_sizes = None if payload_sizes is None else frozenset(int(s) for s in payload_sizes)
        if batch_packets < 1:
            raise ValueError("batch_packets must be at least 1")
        self.batch_packets = int(batch_packets)
        self._reassembly_args = dict(
            timeout_ns=reassembly_timeout_ns, max_datagrams=max_pending_datagrams, max_bytes=max_pending_bytes
        )
        self.stats = ReadStats(path=self.path)
        if os.path.exists(self.path) and not os.path.isdir(self.path) and not os.path.isfile(self.path):
            # a pipe or device could be read only once, and only whole into memory
            raise CaptureFormatError(
                f"{self.path}: not a regular file (pipes and devices are not read); save the capture to a file first"
            )
        try:
            with open(self.path, "rb") as fh:
                head = fh.read(64)
        except FileNotFoundError:
            raise CaptureFormatError(f"{self.path}: no such file") from None
        except IsADirectoryError:
            raise CaptureFormatError(f"{self.path}: is a directory, not a pcap/pcapng capture") from None
        except OSError as exc:
            raise CaptureFormatError(f"{self.path}: cannot read: {exc.strerror or exc}") from None
        self.format = _format_from_magic(head)
        if self.format is None:
            if not head:
                raise CaptureFormatError(f"{self.path}: empty file (0 bytes), not a pcap/pcapng capture")
            raise CaptureFormatError(
                f"{self.path}: not a pcap or pcapng capture: first bytes are {head[:8].hex(' ')}"
                f" ({head[:8]!r}); expected a pcap magic (d4 c3 b2 a1, 4d 3c b2 a1 or swapped) or a "
                "pcapng section header (0a 0d 0d 0a)"
            )
        if self.format == "pcap":
            self._parse_pcap_header(head)

    # --- public iteration ----------------------------------------------------------------
    def batches(self) -> Iterator[PacketBatch]:
        """Same-stream, same-size batches of datagrams.

        Each batch holds consecutive packets (in capture order) of one (src, dst, payload
        size) stream from one chunk of at most ``batch_packets`` records; ``batch.index`` is
        the ordinal of each packet among all packets yielded by this pass. Batches come in
        the order of their first packet, and all packets of a batch precede those of any
        later batch of the same stream.
        """
        for group in self._chunk_batches():
            yield from group

    def packets(self) -> Iterator[Packet]:
        """Every datagram as a :class:`~lidarpkt.packet.Packet`, in capture order.

        A reassembled datagram takes the place (and the time stamp) of its last arriving
        fragment, like a socket would deliver it.
        """
        for group in self._chunk_batches():
            yield from self._merge(group)

    def _chunk_batches(self) -> Iterator[list[PacketBatch]]:
        """The batches of each chunk of records (their ordinals interleave within a chunk only)."""
        try:
            fh = open(self.path, "rb", buffering=0)
        except OSError as exc:  # removed or made unreadable since the reader was made
            raise CaptureFormatError(f"{self.path}: cannot read: {exc.strerror or exc}") from None
        with fh:
            blocks = _Blocks(fh, os.fstat(fh.fileno()).st_size)
            self._begin()
            base = 0
            walker = self._walk_pcap(blocks) if self.format == "pcap" else self._walk_pcapng(blocks)
            split = self.segment.end_offset if self.segment is not None else None
            for buf, chunk in walker:
                if split is not None and self.split_ordinal is None and self._chunk_at >= split:
                    self.split_ordinal = base  # chunks never straddle the segment's end (see _split_limit)
                produced = self._process_chunk(buf, chunk, base)
                if produced:
                    base = max(int(b.index[-1]) for b in produced) + 1
                    yield produced
            self._finish()

    @staticmethod
    def _merge(batches: list[PacketBatch]) -> Iterator[Packet]:
        if not batches:
            return
        order = np.argsort(np.concatenate([b.index for b in batches]), kind="stable")
        which = np.concatenate([np.full(len(b), i, np.int64) for i, b in enumerate(batches)])
        row = np.concatenate([np.arange(len(b)) for b in batches])
        for k in order.tolist():
            b = batches[which[k]]
            r = row[k]
            yield Packet(int(b.timestamp_ns[r]), b.src, b.dst, b.payload[r].tobytes())

    def __iter__(self) -> Iterator[Packet]:
        return self.packets()

    def _begin(self) -> None:
        old = self.stats
        fresh = ReadStats(
            path=self.path,
            format=self.format,
            snaplen=old.snaplen,
            nanosecond=old.nanosecond,
            big_endian=old.big_endian,
            interfaces=old.interfaces,
        )
        old.__dict__.update(fresh.__dict__)  # in place: callers may hold a reference to stats
        self._reasm = Reassembler(**self._reassembly_args)
        self.split_ordinal = None
        self._vec_fragments = 0  # fragments / datagrams reassembled by _fragment_trains
        self._vec_reassembled = 0
        self._warned_links: set[int] = set()

    def _finish(self) -> None:
        self._reasm.flush()
        self._sync_reassembly_stats()
        st = self.stats
        if st.truncated:  # warned only now, so that every good record was yielded first
            _warn(TruncatedCaptureWarning(f"{self.path}: {st.truncated_reason}"), stacklevel=3)
        if st.malformed:
            reasons = ", ".join(f"{k}: {v}" for k, v in st.malformed_reasons.most_common())
            _warn(
                SkippedPacketWarning(f"{self.path}: skipped {st.malformed} malformed record(s) ({reasons})"),
                stacklevel=3,
            )

    def _sync_reassembly_stats(self) -> None:
        rs = self._reasm.stats
        st = self.stats
        st.fragments = rs.fragments + self._vec_fragments
        st.reassembled = rs.reassembled + self._vec_reassembled
        st.orphaned_fragments = rs.orphaned_fragments + rs.malformed_fragments
        st.duplicate_fragments = rs.duplicate_fragments

    def _truncate(self, reason: str) -> None:
        self.stats.truncated = True
        self.stats.truncated_reason = reason

    # --- classic pcap --------------------------------------------------------------------------
    def _parse_pcap_header(self, head: bytes) -> None:
        if len(head) < PCAP_GLOBAL_HEADER.itemsize:
            raise CaptureFormatError(
                f"{self.path}: pcap global header cut short ({len(head)} of {PCAP_GLOBAL_HEADER.itemsize} bytes)"
            )
        magic_le = struct.unpack_from("<I", head)[0]
        if magic_le in (PCAP_MAGIC_US, PCAP_MAGIC_NS, PCAP_MAGIC_MODIFIED):
            endian = "<"
        else:
            endian = ">"
        magic, major, minor, _zone, _sigfigs, snaplen, network = header_struct(PCAP_GLOBAL_HEADER, endian).unpack_from(head)
        if major != 2:
            raise CaptureFormatError(f"{self.path}: pcap version {major}.{minor} is not supported (expected 2.4)")
        self._endian = endian
        self._rec_hdr = PCAP_RECORD_HEADER.itemsize + (PCAP_MODIFIED_EXTRA.itemsize if magic == PCAP_MAGIC_MODIFIED else 0)
        self._frac_ns = 1 if magic == PCAP_MAGIC_NS else 1000
        # the upper 16 bits may carry FCS information; a trailing FCS is harmless (UDP length bounds payloads)
        self._linktype = network & 0xFFFF
        if self._linktype not in LINKTYPE_NAMES:
            raise CaptureFormatError(
                f"{self.path}: link type {self._linktype} is not supported (supported: Ethernet, Linux SLL/SLL2, "
                "raw IPv4/IPv6, BSD loopback)"
            )
        self.stats.snaplen = snaplen
        self.stats.nanosecond = magic == PCAP_MAGIC_NS
        self.stats.big_endian = endian == ">"
        self.stats.interfaces = 1
        self._snaplen = snaplen

    def _walk_pcap(self, blocks: "_Blocks") -> Iterator[tuple[np.ndarray, _Chunk]]:
        """(block, chunk) pairs of a classic pcap file; chunk offsets are relative to the block."""
        hdr = self._rec_hdr
        u32 = struct.Struct(self._endian + "I").unpack_from
        caplen_at = field_offset(PCAP_RECORD_HEADER, "incl_len")
        # libpcap's own limit, or a larger snap length the file declares, but never more than a read block
        max_cap = min(max(self._snaplen, MAX_RECORD_BYTES), READ_BLOCK_BYTES - hdr)
        cap_dtype = np.dtype(self._endian + "u4")
        chunk = self.batch_packets
        glob = PCAP_GLOBAL_HEADER.itemsize
        window = 64  # speculative run length
        backoff = 0  # records to walk one by one before speculating again
        misses = 0  # speculations in a row that found short runs
        st = self.stats
        native = kernels.native
        swap = (self._endian == ">") != (sys.byteorder == "big")
        st.bytes_read = min(glob, blocks.size)
        if blocks.size < glob:
            self._truncate(f"file ends inside the pcap global header ({blocks.size} of {glob} bytes)")
            return
        off = glob if self.segment is None else max(glob, self.segment.start_offset)  # file offset of the next record
        while off < blocks.size:
            buf = blocks.read(off)
            end = buf.shape[0]
            last_block = off + end >= blocks.size
            mv = memoryview(buf)
            rel = 0
            stop = refill = False
            while not (stop or refill):
                pieces: list[np.ndarray] = []
                singles: list[int] = []
                n = 0
                chunk_start = rel
                byte_end = self._split_limit(off, chunk_start)  # records of this chunk start before byte_end
                while n < chunk and rel < byte_end:
                    if rel + hdr > end:
                        if not last_block:
                            refill = True
                        elif rel != end:
                            self._truncate(
                                f"capture cut short: {end - rel} byte(s) of a record header at offset {off + rel} "
                                f"(after {st.records + n} complete records)"
                            )
                        stop = not refill
                        break
                    cap = u32(mv, rel + caplen_at)[0]
                    if cap > max_cap:
                        self._truncate(
                            f"record at offset {off + rel} claims {cap} captured bytes (more than the snap length "
                            f"{self._snaplen} and the {MAX_RECORD_BYTES}-byte limit, or than {max_cap} bytes): the "
                            f"file is corrupt from there; kept the {st.records + n} records before it"
                        )
                        stop = True
                        break
                    stride = hdr + cap
                    if rel + stride > end:
                        if not last_block:
                            refill = True
                        else:
                            self._truncate(
                                f"last record at offset {off + rel} claims {cap} captured bytes but only "
                                f"{end - rel - hdr} remain in the file (after {st.records + n} complete records)"
                            )
                            stop = True
                        break
                    if native is not None:
                        # the compiled walk: every whole record up to the chunk's limits, in one call
                        room = chunk - n
                        found = np.empty(room, np.int64)
                        k, rel, _ = native.walk_pcap(buf, rel, end, caplen_at, hdr, swap, max_cap, room, byte_end, found)
                        pieces.append(found[:k])
                        n += k
                        continue
                    if backoff <= 0:
                        k_max = min(chunk - n, (end - rel) // stride, window,
                                    -(-(byte_end - rel) // stride))  # starts before the limit
                        if k_max >= 8:
                            # a run of records with this capture length, checked in one strided comparison
                            caps = np.ndarray((k_max,), cap_dtype, buf, rel + caplen_at, (stride,))
                            bad = np.flatnonzero(caps != cap)
                            k = int(bad[0]) if bad.size else k_max
                            if singles:
                                pieces.append(np.asarray(singles, np.int64))
                                singles = []
                            pieces.append(rel + stride * np.arange(k, dtype=np.int64))
                            n += k
                            rel += k * stride
                            if k == k_max:
                                window = min(window * 2, 1 << 16)
                            else:
                                window = max(64, 2 * k)
                            if k >= 32:
                                misses = 0
                            else:  # mixed sizes: speculate ever less often (each miss costs ~10 µs)
                                backoff = min(32 << misses, 8192)
                                misses += 1
                            continue
                    # record by record (mixed sizes, e.g. VLP-16 data and position packets): a tight loop
                    # for up to `backoff` records; any record needing a decision ends it early
                    singles.append(rel)
                    rel += stride
                    n += 1
                    lim = min(chunk - n, backoff - 1)
                    byte_lim = byte_end
                    before = len(singles)
                    append = singles.append
                    while lim > 0 and rel < byte_lim and rel + hdr <= end:
                        cap = u32(mv, rel + caplen_at)[0]
                        nxt = rel + hdr + cap
                        if cap > max_cap or nxt > end:
                            break
                        append(rel)
                        rel = nxt
                        lim -= 1
                    walked = len(singles) - before
                    n += walked
                    backoff -= 1 + walked
                if singles:
                    pieces.append(np.asarray(singles, np.int64))
                if n:
                    offs = pieces[0] if len(pieces) == 1 else np.concatenate(pieces)
                    st.records += n
                    st.bytes_read = off + rel
                    self._chunk_at = off + chunk_start
                    yield buf, _Chunk(
                        data_off=offs + hdr,
                        caplen=_field(buf, offs, PCAP_RECORD_HEADER, "incl_len", self._endian),
                        ts_ns=_field(buf, offs, PCAP_RECORD_HEADER, "ts_sec", self._endian) * _SEC_NS
                        + _field(buf, offs, PCAP_RECORD_HEADER, "ts_frac", self._endian) * self._frac_ns,
                        linktype=np.full(n, self._linktype, np.int64),
                    )
                if rel >= end:
                    break
            if stop:
                return
            if refill and rel == 0:  # cannot happen: a block holds the largest record allowed
                self._truncate(f"record at offset {off} does not fit a read block")
                return
            off += rel

    def _split_limit(self, base: int, chunk_start: int) -> int:
        """Where the chunk that starts at ``chunk_start`` of the block read at file offset ``base`` ends
        (relative to the block): MAX_CHUNK_BYTES on, or earlier at the end of the segment being read, so
        that no chunk (and so no batch) holds records from both sides of it."""
        lim = chunk_start + MAX_CHUNK_BYTES
        if self.segment is not None and base + chunk_start < self.segment.end_offset:
            lim = min(lim, self.segment.end_offset - base)
        return lim

    def _walk_pcapng(self, blocks: "_Blocks") -> Iterator[tuple[np.ndarray, _Chunk]]:
        """(block, chunk) pairs of a pcapng file (a Python loop over its blocks)."""
        st = self.stats
        chunk = self.batch_packets
        endian = "<"
        ifaces: list[tuple[int, int, int, int, int]] = []  # (linktype, snaplen, mul, div, offset_s) per section
        n_ifaces_total = 0
        # records of the chunk being gathered: arrays from the compiled walk, then the lists of the
        # record-by-record walk (moved into `pieces` before the next array piece, to keep the order)
        pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        offs: list[int] = []
        caps: list[int] = []
        tss: list[int] = []
        links: list[int] = []
        pending = 0  # records in pieces and lists
        first = True
        size = blocks.size
        native = kernels.native
        if size < PCAPNG_BLOCK_HEADER.itemsize + 4:
            raise CaptureFormatError(f"{self.path}: pcapng file cut short inside its first block ({size} bytes)")

        def lists_to_piece() -> None:
            if offs:
                pieces.append((np.asarray(offs, np.int64), np.asarray(caps, np.int64), np.asarray(tss, np.int64),
                               np.asarray(links, np.int64)))
                offs.clear(), caps.clear(), tss.clear(), links.clear()

        def flush(buf: np.ndarray, abs_end: int) -> tuple[np.ndarray, _Chunk]:
            nonlocal pending
            lists_to_piece()
            self._chunk_at = chunk_start
            parts = pieces[0] if len(pieces) == 1 else tuple(np.concatenate(col) for col in zip(*pieces))
            st.records += pending
            st.bytes_read = abs_end
            pieces.clear()
            pending = 0
            return buf, _Chunk(*parts)

        off = 0  # file offset of the next pcapng block
        split = None if self.segment is None else self.segment.end_offset
        if self.segment is not None and self.segment.start_offset > 0:
            # a segment starts mid-file: its section's header and interface blocks come first
            endian, ifaces = self._pcapng_preamble(blocks, self.segment.pcapng_preamble)
            n_ifaces_total, first = len(ifaces), False
            off = self.segment.start_offset
        base = off  # file offset of buf[0]
        buf = blocks.read(off)
        mv = memoryview(buf)
        chunk_start = off
        def refill() -> bool:
            """Read on from ``off`` when the current block ends inside the pcapng block there."""
            nonlocal base, buf, mv, chunk_start
            if base + buf.shape[0] >= blocks.size or off == base:
                return False  # the file ends here (or one block cannot hold it: reported as damage)
            base, buf = off, blocks.read(off)
            mv = memoryview(buf)
            chunk_start = off
            return True

        while off < blocks.size:
            if pending and split is not None and chunk_start < split <= off:
                yield flush(buf, off)  # no chunk holds records from both sides of the segment's end
                chunk_start = off
            rel = off - base
            end = buf.shape[0]
            if rel + 12 > end and base + end < blocks.size:
                if pending:
                    yield flush(buf, off)
                if refill():
                    continue
            if rel + 12 > end:
                self._truncate(f"capture cut short: {end - rel} byte(s) of a pcapng block header at offset {off}")
                break
            if native is not None and ifaces and not first:
                # the compiled walk over the enhanced packet blocks that follow; it stops before any
                # block that needs a decision, which the loop below then takes
                room = chunk - pending
                data, capl, iface, raw = (np.empty(room, np.int64), np.empty(room, np.int64),
                                          np.empty(room, np.int64), np.empty(room, np.uint64))
                k, nxt = native.walk_pcapng(buf, rel, end, endian != _NATIVE_ORDER, len(ifaces), MAX_PCAPNG_BLOCK,
                                            room, self._split_limit(base, chunk_start - base), data, capl, iface, raw)
                if k:
                    lists_to_piece()
                    got = self._pcapng_times(ifaces, data[:k], capl[:k], iface[:k], raw[:k])
                    pieces.append(got)
                    pending += got[0].shape[0]
                    off = base + nxt
                    if pending >= chunk or off - chunk_start >= MAX_CHUNK_BYTES:
                        yield flush(buf, off)
                        chunk_start = off
                    continue
            btype_le = struct.unpack_from("<I", mv, rel)[0]
            if btype_le == PCAPNG_SHB:
                if rel + 16 > end:
                    self._truncate(f"capture cut short inside the section header block at offset {off}")
                    break
                bom_at = rel + PCAPNG_BLOCK_HEADER.itemsize + field_offset(PCAPNG_SECTION_HEADER, "byte_order_magic")
                bom = mv[bom_at : bom_at + 4].tobytes()
                if bom == b"\x4d\x3c\x2b\x1a":
                    endian = "<"
                elif bom == b"\x1a\x2b\x3c\x4d":
                    endian = ">"
                else:
                    msg = f"pcapng section header at offset {off} has a bad byte-order magic {bom.hex(' ')}"
                    if first:
                        raise CaptureFormatError(f"{self.path}: {msg}")
                    self._truncate(msg + "; stopped there")
                    break
                ifaces = []
                st.big_endian = endian == ">"
            btype, blen = header_struct(PCAPNG_BLOCK_HEADER, endian).unpack_from(mv, rel)
            if blen < 12 or blen % 4 or blen > MAX_PCAPNG_BLOCK:
                msg = f"pcapng block at offset {off} (type {btype:#x}) has an impossible length {blen}"
                if first:
                    raise CaptureFormatError(f"{self.path}: {msg}")
                self._truncate(msg + f"; kept the {st.records + pending} records before it")
                break
            if rel + blen > end and base + end < blocks.size:
                if pending:
                    yield flush(buf, off)
                if refill():
                    continue
            if rel + blen > end:
                self._truncate(
                    f"pcapng block at offset {off} (type {btype:#x}) claims {blen} bytes but only {end - rel} "
                    f"remain in the file; kept the {st.records + pending} records before it"
                )
                break
            trailer = struct.unpack_from(endian + "I", mv, rel + blen - 4)[0]
            if trailer != blen:
                msg = (
                    f"pcapng block at offset {off} (type {btype:#x}): leading length {blen} and trailing length "
                    f"{trailer} differ"
                )
                if first:
                    raise CaptureFormatError(f"{self.path}: {msg}")
                self._truncate(msg + f"; kept the {st.records + pending} records before it")
                break
            first = False
            body = rel + PCAPNG_BLOCK_HEADER.itemsize
            body_end = rel + blen - 4
            off += blen
            if btype == 1:  # interface description block
                iface_desc = _pcapng_interface(mv, body, body_end, endian)
                if iface_desc is None:
                    st.malformed += 1
                    st.malformed_reasons["short pcapng interface block"] += 1
                    continue
                ifaces.append(iface_desc)
                n_ifaces_total += 1
                st.interfaces = n_ifaces_total
                st.snaplen = max(st.snaplen, iface_desc[1])
                continue
            if btype not in (6, 2, 3):  # not an enhanced, obsolete or simple packet block
                continue
            if btype == 3:
                if body_end - body < PCAPNG_SPB.itemsize:
                    st.malformed += 1
                    st.malformed_reasons["short pcapng packet block"] += 1
                    continue
                orig = header_struct(PCAPNG_SPB, endian).unpack_from(mv, body)[0]
                iface, ts_raw, data = 0, None, body + PCAPNG_SPB.itemsize
                cap = min(orig, body_end - data)
            else:
                if body_end - body < PCAPNG_EPB.itemsize:
                    st.malformed += 1
                    st.malformed_reasons["short pcapng packet block"] += 1
                    continue
                if btype == 6:
                    iface, hi, lo, cap, _orig = header_struct(PCAPNG_EPB, endian).unpack_from(mv, body)
                else:
                    iface, _drops, hi, lo, cap, _orig = header_struct(PCAPNG_OPB, endian).unpack_from(mv, body)
                ts_raw = (hi << 32) | lo
                data = body + PCAPNG_EPB.itemsize  # the OPB header has the same size
            if iface >= len(ifaces) or data + cap > body_end:
                st.malformed += 1
                st.malformed_reasons[
                    "pcapng packet for an undeclared interface" if iface >= len(ifaces) else
                    "pcapng packet longer than its block"
                ] += 1
                continue
            lt = ifaces[iface][0]
            ts_ns = 0 if ts_raw is None else _pcapng_time_ns(ts_raw, ifaces[iface])
            if ts_ns is None:
                st.malformed += 1
                st.malformed_reasons["pcapng time stamp out of range"] += 1
                continue
            offs.append(data)
            caps.append(cap)
            tss.append(ts_ns)
            links.append(lt)
            pending += 1
            if pending >= chunk or off - chunk_start >= MAX_CHUNK_BYTES:
                yield flush(buf, off)
                chunk_start = off
        if pending:
            yield flush(buf, off)
        st.bytes_read = off

    def _pcapng_preamble(self, blocks: "_Blocks", offsets: tuple[int, ...]) -> tuple[str, list]:
        """Byte order and interfaces of a pcapng section, from its section header block and interface
        description blocks at ``offsets`` (as :func:`lidarpkt.sources.segments.plan_segments` found them)."""
        endian, ifaces = "<", []
        st = self.stats
        for o in offsets:
            blocks.fh.seek(o)
            head = blocks.fh.read(PCAPNG_BLOCK_HEADER.itemsize + 4)
            if len(head) < 12:
                raise CaptureFormatError(f"{self.path}: pcapng block at offset {o} cut short; plan the segments again")
            if struct.unpack_from("<I", head)[0] == PCAPNG_SHB:
                endian = "<" if head[8:12] == b"\x4d\x3c\x2b\x1a" else ">"
                ifaces = []
                st.big_endian = endian == ">"
                continue
            btype, blen = header_struct(PCAPNG_BLOCK_HEADER, endian).unpack_from(head)
            if btype != 1 or not 12 <= blen <= MAX_PCAPNG_BLOCK:
                raise CaptureFormatError(f"{self.path}: no pcapng interface block at offset {o}; plan the segments again")
            blocks.fh.seek(o)
            mv = memoryview(blocks.fh.read(blen))
            desc = _pcapng_interface(mv, PCAPNG_BLOCK_HEADER.itemsize, blen - 4, endian)
            if desc is not None:
                ifaces.append(desc)
                st.snaplen = max(st.snaplen, desc[1])
        st.interfaces = len(ifaces)
        return endian, ifaces

    def _pcapng_times(self, ifaces: list[tuple[int, int, int, int, int]], data: np.ndarray, caplen: np.ndarray,
                      iface: np.ndarray, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(data_off, caplen, ts_ns, linktype)`` of enhanced packet blocks found by the compiled walk:
        raw time stamps in each interface's units to ns, whole arrays at a time where int64 holds the
        products (always, for µs and ns resolutions), else record by record; records whose time does
        not fit int64 ns are counted as malformed and dropped, as in the record-by-record walk."""
        ts = np.empty(raw.shape[0], np.int64)
        keep = np.ones(raw.shape[0], bool)
        for j in np.unique(iface).tolist():
            mine = iface == j
            r = raw[mine]
            _lt, _snap, mul, div, ts_off = ifaces[j]
            top = int(r.max())
            if top * mul < (1 << 63) and -(1 << 63) <= ts_off * _SEC_NS and ts_off * _SEC_NS + top * mul // div < (1 << 63):
                ts[mine] = r.astype(np.int64) * mul // div + ts_off * _SEC_NS
                continue
            vals = [_pcapng_time_ns(v, ifaces[j]) for v in r.tolist()]
            bad = np.array([v is None for v in vals])
            ts[mine] = [0 if v is None else v for v in vals]
            keep[np.flatnonzero(mine)[bad]] = False
        if not keep.all():
            n_bad = int((~keep).sum())
            self.stats.malformed += n_bad
            self.stats.malformed_reasons["pcapng time stamp out of range"] += n_bad
            data, caplen, iface, ts = data[keep], caplen[keep], iface[keep], ts[keep]
        linktype = np.array([f[0] for f in ifaces], np.int64)[iface]
        return data, caplen, ts, linktype

    # --- per-chunk decoding ------------------------------------------------------------------------
    def _ipv4_headers(self, buf: np.ndarray, c: _Chunk):
        """Records holding UDP/IPv4 at a fixed link offset: ``(ok, l2, l3, ihl)`` (offsets 0 where not ok)."""
        n = c.caplen.shape[0]
        size = buf.shape[0]
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

    def _plain_udp(self, buf: np.ndarray, c: _Chunk, ok, l2, l3, ihl, frag_bits):
        """Unfragmented UDP/IPv4 records whose UDP length fits the captured bytes, and their UDP offsets."""
        fast = ok & ((frag_bits & 0x3FFF) == 0)
        l4 = np.where(fast, l3 + ihl, 0)
        udp_len = _field(buf, l4, UDP_HEADER, "length")
        fast &= (udp_len >= UDP_HEADER.itemsize) & (udp_len <= c.caplen - l2 - ihl)
        return fast, l4

    def _fragment_trains(self, buf: np.ndarray, c: _Chunk, ok, l2, l3, ihl, frag_bits):
        """Whole UDP/IPv4 datagrams whose fragments all lie in this chunk, reassembled with array operations.

        A train qualifies when its fragments (same source, destination and IP ID) have offsets
        0, then each the end of the previous one in record order, More Fragments on all but the
        last, all within the reassembly timeout, a UDP header whose length fits, and no datagram
        of that key is pending in the general reassembler. Everything else (duplicates, reordering,
        an ID reused by a stale fragment as in duplicate_id.pcap, trains cut by the chunk end) goes
        through :class:`~lidarpkt.reassembly.Reassembler` record by record.

        Returns None, or ``(consumed, dgrams, payloads)``: ``consumed`` bool[n] records used;
        ``dgrams`` a dict of per-datagram arrays (pos, ts, src, dst, ports, plen, and row: the
        datagram's row in ``payloads[plen]``, the ``uint8[k, plen]`` payloads of each size).
        Datagrams whose non-zero UDP checksum fails are counted as malformed and left out.
        """
        cand = ok & ((frag_bits & 0x3FFF) != 0)
        if not cand.any():
            return None
        total = _field(buf, l3, IPV4_HEADER, "total_length")
        cand &= (total > ihl) & (l2 + total <= c.caplen)
        p = np.flatnonzero(cand)
        if p.shape[0] == 0:
            return None
        l3p = l3[p]
        src = _field(buf, l3p, IPV4_HEADER, "src")
        dst = _field(buf, l3p, IPV4_HEADER, "dst")
        ident = _field(buf, l3p, IPV4_HEADER, "identification")
        fb = frag_bits[p]
        off = (fb & 0x1FFF) * 8
        mf = (fb >> 13) & 1
        dstart = l3p + ihl[p]
        dlen = total[p] - ihl[p]
        ts = c.ts_ns[p]
        order = np.lexsort((p, ident, dst, src))
        p, src, dst, ident, off, mf, dstart, dlen, ts = (
            a[order] for a in (p, src, dst, ident, off, mf, dstart, dlen, ts)
        )
        m = p.shape[0]
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
        span = np.maximum.reduceat(ts, starts) - np.minimum.reduceat(ts, starts)
        run_ok &= span <= self._reasm.timeout_ns
        dgram_len = off[ends] + dlen[ends]
        run_ok &= (dgram_len <= self._reasm.max_datagram_bytes) & (dlen[starts] >= UDP_HEADER.itemsize)
        ustart = dstart[starts]
        ulen = _field(buf, ustart, UDP_HEADER, "length")
        run_ok &= ulen == dgram_len  # a reassembled datagram has no padding: anything else is damage
        if self._reasm.pending_datagrams:  # a stale datagram of the same key decides in the general path
            pending = self._reasm._pending
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
        run_id = np.cumsum(new_run) - 1
        elem_good = run_ok[run_id]
        consumed = np.zeros(c.caplen.shape[0], bool)
        consumed[p[elem_good]] = True
        good_runs = np.flatnonzero(run_ok)
        dgram_of_run = np.full(run_ok.shape[0], -1, np.int64)
        dgram_of_run[good_runs] = np.arange(good_runs.shape[0])
        gs, ge = starts[good_runs], ends[good_runs]
        plen = ulen[good_runs] - 8
        dgrams = {
            "pos": p[ge],  # the record that completes the datagram
            "ts": c.ts_ns[p[ge]],
            "src": src[gs],
            "dst": dst[gs],
            "ports": (_field(buf, dstart[gs], UDP_HEADER, "src_port") << 16) | _field(buf, dstart[gs], UDP_HEADER, "dst_port"),
            "plen": plen,
        }
        e = np.flatnonzero(elem_good)
        dg = dgram_of_run[run_id[e]]
        first = new_run[e]
        # payload bytes = datagram bytes from 8 (after the UDP header) to the UDP length
        src_off = dstart[e] + np.where(first, 8, 0)
        dst_off = np.where(first, 0, off[e] - 8)
        length = np.minimum(dlen[e] - np.where(first, 8, 0), plen[dg] - dst_off)
        keep = length > 0
        pieces = {"dgram": dg[keep], "src_off": src_off[keep], "dst_off": dst_off[keep], "length": length[keep]}
        self._vec_fragments += int(e.shape[0])
        self._vec_reassembled += int(good_runs.shape[0])
        # build the payloads, one array per size, and check the UDP checksums: a datagram whose
        # fragments came from two datagrams sharing an IP ID (after losses) fails it
        csum = _field(buf, ustart[good_runs], UDP_HEADER, "checksum")
        nd = good_runs.shape[0]
        row = np.empty(nd, np.int64)
        valid = np.ones(nd, bool)
        payloads: dict[int, np.ndarray] = {}
        for size in np.unique(plen).tolist():
            ids = np.flatnonzero(plen == size)
            arr = np.empty((ids.shape[0], size), np.uint8)
            self._fill_trains(buf, arr, np.arange(ids.shape[0]), ids, pieces)
            row[ids] = np.arange(ids.shape[0])
            checked = csum[ids] != 0  # 0 = the sender computed none (IPv4)
            if checked.any():
                s_, d_, u_ = dgrams["src"][ids], dgrams["dst"][ids], ulen[good_runs][ids]
                ports = dgrams["ports"][ids]
                total = (
                    (s_ >> 16) + (s_ & 0xFFFF) + (d_ >> 16) + (d_ & 0xFFFF) + IPPROTO_UDP + 2 * u_
                    + (ports >> 16) + (ports & 0xFFFF) + csum[ids] + _row_word_sums(arr)
                )
                valid[ids] &= ~checked | (_fold(total) == 0xFFFF)
            payloads[size] = arr
        if not valid.all():
            bad = int((~valid).sum())
            self.stats.malformed += bad
            self.stats.malformed_reasons[_MIXED_CHECKSUM] += bad
            dgrams = {k: v[valid] for k, v in dgrams.items()}
            row = row[valid]
        dgrams["row"] = row
        return consumed, dgrams, payloads

    @staticmethod
    def _fill_trains(buf, payload, rows, dgram_ids, pieces) -> None:
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
            payload[prow[which], dst : dst + length] = _copy_rows(buf, pieces["src_off"][which], length)

    def _process_chunk(self, buf: np.ndarray, c: _Chunk, base: int) -> list[PacketBatch]:
        st = self.stats
        n = c.caplen.shape[0]
        for lt, cnt in zip(*np.unique(c.linktype, return_counts=True)):
            st.link_types[LINKTYPE_NAMES.get(int(lt), f"linktype {int(lt)}")] += int(cnt)
        ok, l2, l3, ihl = self._ipv4_headers(buf, c)
        frag_bits = _field(buf, l3, IPV4_HEADER, "flags_fragment_offset")
        fast, l4 = self._plain_udp(buf, c, ok, l2, l3, ihl, frag_bits)
        trains = self._fragment_trains(buf, c, ok, l2, l3, ihl, frag_bits)
        handled = fast if trains is None else (fast | trains[0])

        # the general path, record by record, in capture order (reassembly needs the order)
        slow_pos: list[int] = []
        slow_pkts: list[tuple[str, int, str, int, bytes]] = []
        slow_ts: list[int] = []
        if not handled.all():
            slow = np.flatnonzero(~handled)
            offs = c.data_off[slow].tolist()
            caps = c.caplen[slow].tolist()
            lts = c.linktype[slow].tolist()
            tss = c.ts_ns[slow].tolist()
            mv = memoryview(buf)
            for i, o, cap, lt, ts in zip(slow.tolist(), offs, caps, lts, tss):
                got = self._parse_record(lt, mv[o : o + cap], ts)
                if got is not None:
                    slow_pos.append(i)
                    slow_pkts.append(got)
                    slow_ts.append(ts)
        self._sync_reassembly_stats()

        # datagrams found with array operations: plain records (kind 0) and fragment trains (kind 1)
        fast_pos = np.flatnonzero(fast)
        l4 = l4[fast_pos]
        ip_off = l3[fast_pos]
        vec = {
            "pos": fast_pos,
            "src": _field(buf, ip_off, IPV4_HEADER, "src"),
            "dst": _field(buf, ip_off, IPV4_HEADER, "dst"),
            "ports": (_field(buf, l4, UDP_HEADER, "src_port") << 16) | _field(buf, l4, UDP_HEADER, "dst_port"),
            "plen": _field(buf, l4, UDP_HEADER, "length") - UDP_HEADER.itemsize,
            "ts": c.ts_ns[fast_pos],
            "ref": l4 + UDP_HEADER.itemsize,  # kind 0: payload offset in the file; kind 1: row in train_payloads
            "kind": np.zeros(fast_pos.shape[0], np.int8),
        }
        train_payloads: dict[int, np.ndarray] = {}
        if trains is not None:
            _, dg, train_payloads = trains
            nd = dg["pos"].shape[0]
            dg = dict(dg)
            row = dg.pop("row")
            extra = dict(dg, ref=row, kind=np.ones(nd, np.int8))
            vec = {k: np.concatenate([vec[k], extra[k]]) for k in vec}
            order = np.argsort(vec["pos"], kind="stable")
            vec = {k: v[order] for k, v in vec.items()}
        n_vec = vec["pos"].shape[0]
        if n_vec:
            keep = np.ones(n_vec, bool)
            if self.ports is not None:
                keep &= np.isin(vec["ports"] & 0xFFFF, np.fromiter(self.ports, np.int64))
            if self.payload_sizes is not None:
                keep &= np.isin(vec["plen"], np.fromiter(self.payload_sizes, np.int64))
            if self.src_addresses is not None:
                v4 = [int.from_bytes(socket.inet_aton(a), "big") for a in self.src_addresses if _is_ipv4_text(a)]
                keep &= np.isin(vec["src"], np.asarray(v4, np.int64))
            st.udp_packets += n_vec
            st.filtered += int(n_vec - keep.sum())
            if not keep.all():
                vec = {k: v[keep] for k, v in vec.items()}
                n_vec = vec["pos"].shape[0]

        # ordinals: every kept record yields at most one packet, in record order
        slow_pos_a = np.asarray(slow_pos, np.int64)
        all_pos = np.sort(np.concatenate([vec["pos"], slow_pos_a]))
        total = all_pos.shape[0]
        if total == 0:
            return []
        vec_ord = base + np.searchsorted(all_pos, vec["pos"])
        slow_ord = base + np.searchsorted(all_pos, slow_pos_a)

        groups: dict[tuple, dict] = {}
        if n_vec:
            src_ip, dst_ip, ports, plen = vec["src"], vec["dst"], vec["ports"], vec["plen"]
            k1 = (src_ip << 32) | dst_ip
            k2 = (ports << 20) | plen
            selections = _few_groups(k1, k2)
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
                s_ip, d_ip = _ipv4_text(np.array([src_ip[first], dst_ip[first]]))
                pp = int(ports[first])
                key = (s_ip, pp >> 16, d_ip, pp & 0xFFFF, int(plen[first]))
                groups[key] = {"vec": sel, "slow": []}
        for j, (s_ip, sport, d_ip, dport, payload) in enumerate(slow_pkts):
            key = (s_ip, sport, d_ip, dport, len(payload))
            groups.setdefault(key, {"vec": None, "slow": []})["slow"].append(j)

        out: list[PacketBatch] = []
        for key, g in groups.items():
            s_ip, sport, d_ip, dport, size = key
            vsel = g["vec"] if g["vec"] is not None else np.zeros(0, np.int64)
            ssel = g["slow"]
            kinds = vec["kind"][vsel]
            if not ssel and not kinds.any():  # the common case: plain records only, already in order
                payload = _copy_rows(buf, vec["ref"][vsel], size)
                ts = vec["ts"][vsel]
                idx = vec_ord[vsel]
            else:
                s_ord = slow_ord[ssel]
                idx = np.concatenate([vec_ord[vsel], s_ord])
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
                    payload[wv[plain]] = _copy_rows(buf, vec["ref"][vsel[plain]], size)
                if (~plain).any():
                    payload[wv[~plain]] = train_payloads[size][vec["ref"][vsel[~plain]]]
                for r, j in zip(where[nv:].tolist(), ssel):
                    payload[r] = np.frombuffer(slow_pkts[j][4], np.uint8)
                    ts[r] = slow_ts[j]
            out.append(PacketBatch(Endpoint(s_ip, sport), Endpoint(d_ip, dport), ts, payload, idx))
        out.sort(key=lambda b: int(b.index[0]))
        st.yielded += total
        return out

    # --- the general (per-record) path ----------------------------------------------------------------
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
        src_text, dst_text = _ipv4_text(np.array([src, dst]))
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


def _canonical_address(text: str) -> str:
    """The address as Endpoint.address spells it (IPv6 compressed, lower case); other text unchanged."""
    text = str(text).strip()
    for family in (socket.AF_INET, socket.AF_INET6):
        try:
            return socket.inet_ntop(family, socket.inet_pton(family, text))
        except OSError:
            continue
    return text


def _is_ipv4_text(text: str) -> bool:
    try:
        socket.inet_aton(text)
    except OSError:
        return False
    return text.count(".") == 3


def _pcapng_interface(mv: memoryview, body: int, body_end: int, endian: str) -> tuple[int, int, int, int, int] | None:
    """``(linktype, snaplen, mul, div, offset_s)`` of the interface description block body at ``mv[body:body_end]``
    (time stamps in ns are ``offset_s·10⁹ + raw·mul // div``), or ``None`` when it is too short."""
    if body_end - body < PCAPNG_IDB.itemsize:
        return None
    linktype, _res, snaplen = header_struct(PCAPNG_IDB, endian).unpack_from(mv, body)
    mul, div, ts_off = 1000, 1, 0  # default resolution: microseconds
    for code, val in _pcapng_options(mv, body + PCAPNG_IDB.itemsize, body_end, endian):
        if code == 9 and len(val) >= 1:  # if_tsresol
            r = val[0]
            if r & 0x80:
                mul, div = _SEC_NS, 1 << (r & 0x7F)
            elif r <= 9:
                mul, div = 10 ** (9 - r), 1
            else:
                mul, div = 1, 10 ** (r - 9)
        elif code == 14 and len(val) >= 8:  # if_tsoffset
            ts_off = struct.unpack(endian + "q", val[:8])[0]
    return linktype, snaplen, mul, div, ts_off


def _pcapng_options(mv: memoryview, p: int, end: int, endian: str) -> Iterator[tuple[int, bytes]]:
    """(code, value) of the options in ``mv[p:end]``; stops quietly at a malformed option."""
    while p + 4 <= end:
        code, length = header_struct(PCAPNG_OPTION, endian).unpack_from(mv, p)
        if code == 0:
            return
        p += 4
        if p + length > end:
            return
        yield code, mv[p : p + length].tobytes()
        p += (length + 3) & ~3


def read_packets(path: str | os.PathLike[str], **filters) -> Iterator[Packet]:
    """Every UDP datagram of a pcap/pcapng capture, fragments reassembled, in capture order.

    ``filters`` are the keyword arguments of :class:`PcapReader` (``ports``, ``src_addresses``,
    ``payload_sizes``...). Raises :class:`~lidarpkt.errors.CaptureFormatError` when the file is
    not a capture; damage inside it gives warnings (see the module docs).
    """
    return PcapReader(path, **filters).packets()


def read_batches(path: str | os.PathLike[str], **filters) -> Iterator[PacketBatch]:
    """Same-stream batches of a capture's UDP datagrams (see :meth:`PcapReader.batches`)."""
    return PcapReader(path, **filters).batches()
