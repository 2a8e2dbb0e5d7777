"""Offline packet source: UDP datagrams from pcap and pcapng captures (``lidarpkt.containers.pcap_reader`` is this module).

Formats (detected by magic number, never by file name): classic libpcap in both byte
orders with microsecond or nanosecond time stamps (and the 24-byte-record "modified"
variant), and pcapng (several sections and interfaces, each with its own link type and
time resolution). Link types: Ethernet (with any number of 802.1Q / 802.1ad tags),
Linux cooked SLL and SLL2, raw IPv4/IPv6, BSD loopback (null and loop). Network
layers: UDP over IPv4 (fragments reassembled) and over IPv6 (extension headers skipped,
fragments reassembled too). Every header layout is declared once below as a NumPy
dtype in :mod:`lidarpkt.containers.layouts`; struct formats and field offsets are derived from it
(and :mod:`lidarpkt.writers.pcap` packs with the same layouts). The pieces: :mod:`.pcap_walk` and
:mod:`.pcapng_walk` (record headers to chunks), :mod:`.datagram` and :mod:`.trains` (link/IP/UDP
layers and fragments), :mod:`.batching` (chunks to batches); this module wires them.

How it is fast: the file is read in large blocks into one reused buffer (not mmap, so
that a file truncated under the reader gives a warning rather than a SIGBUS); record
headers are walked in chunks
(a run of records with one capture length is recognised in one strided NumPy
comparison); the link/IPv4/UDP headers of all records of a chunk are checked with
NumPy gathers; the payloads of plain unfragmented UDP/IPv4 records are cut out in one
copy per stream, and whole in-order IPv4 fragment trains are reassembled with array
operations too. Only the odd records (reordered, duplicated or lost fragments, IPv6,
three or more VLAN tags, damage) go through the per-record parser and
:class:`~lidarpkt.containers.reassembly.Reassembler` (bounded, with a host-time timeout so that a
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
malformed records are counted in :class:`~lidarpkt.containers.read_stats.ReadStats` (and summed up in one
:class:`~lidarpkt.errors.SkippedPacketWarning`) and skipped. A file that is not a
capture raises :class:`~lidarpkt.errors.CaptureFormatError`.

Filters: ``ports`` matches the *destination* port (the port a sensor is configured to
send to), ``src_addresses`` the source address, ``payload_sizes`` the UDP payload size.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Iterable, Iterator

import numpy as np

from lidarpkt.core.readahead import warn as _warn  # warnings.warn, or queued when a read-ahead thread runs the reader
from ..errors import CaptureFormatError, SkippedPacketWarning, TruncatedCaptureWarning
from lidarpkt.core.packet import Packet, PacketBatch
from .batching import ChunkDecoder
from .datagram import canonical_address
from .magic import capture_format, format_from_magic, is_capture
from .pcap_walk import BlockReader, PcapWalk
from .pcapng_walk import PcapngWalk
from .read_stats import ReadStats
from .reassembly import Reassembler

if TYPE_CHECKING:
    from .segments import Segment

__all__ = [
    "PcapReader",
    "read_packets",
    "read_batches",
    "is_capture",
    "capture_format",
]

MAX_CHUNK_BYTES = 8 << 20  # a chunk (and so a batch) spans at most this much of the file: 8 MB keeps a chunk in
# L3 while its records are walked, grouped and copied out (mixed VLP-16 capture: 28 ms per 100 MB against 32-39 ms
# with 32 MB chunks)
BATCH_PACKETS = 2048  # records per chunk by default: a decoder turns a batch into frames at once, so the frames
# waiting to be handed out are a batch's (2048 VLP-16 packets: 14 dual rotations, ~9 MB with their pixel times),
# not 8192 packets' (55 rotations); as fast per packet in warm runs (OS-2-128, OS-0-32, VLP-16 dual)
READ_BLOCK_BYTES = 8 << 20  # the file is read in blocks this large (into one reused buffer); 4-32 MB ran within
# noise alone. (4 MB blocks made the Ouster pipeline 40 % slower: the batches' payload arrays, allocated fresh,
# page-faulted more)


class PcapReader:
    """UDP datagrams of one pcap or pcapng file.

    Args:
        path: the capture file.
        ports: keep only datagrams whose *destination* port is one of these.
        src_addresses: keep only datagrams from these source addresses (text, as in
            :class:`~lidarpkt.core.packet.Endpoint`).
        payload_sizes: keep only datagrams with one of these payload sizes (bytes).
        batch_packets: records per chunk, and so the most packets in one batch.
        reassembly_timeout_ns, max_pending_datagrams, max_pending_bytes: bounds of the
            fragment reassembler (see :class:`lidarpkt.containers.reassembly.Reassembler`).
        segment: read only from this segment's first record, with chunks ending at its end
            (``split_ordinal`` is then the ordinal of the first packet after it, and ``split_offset``
            the file offset of the first record at or after it: the end itself when the end is
            a record boundary of the walk from the segment's start); see
            :mod:`lidarpkt.containers.segments`. ``lidarpkt.open(path, segment=...)`` uses it.

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
        batch_packets: int = BATCH_PACKETS,
        reassembly_timeout_ns: int = 30_000_000_000,
        max_pending_datagrams: int = 1024,
        max_pending_bytes: int = 64 * 1024 * 1024,
        segment: "Segment | None" = None,
    ) -> None:
        self.path = os.fspath(path)
        self.segment = segment
        self.split_ordinal: int | None = None  # segment reading: ordinal of the first packet at/after its end
        self.split_offset: int | None = None  # segment reading: file offset of the first record at/after its end
        self.ports = None if ports is None else frozenset(int(p) for p in ports)
        self.src_addresses = None if src_addresses is None else frozenset(canonical_address(a) for a in src_addresses)
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
        self.format = format_from_magic(head)
        if self.format is None:
            if not head:
                raise CaptureFormatError(f"{self.path}: empty file (0 bytes), not a pcap/pcapng capture")
            raise CaptureFormatError(
                f"{self.path}: not a pcap or pcapng capture: first bytes are {head[:8].hex(' ')}"
                f" ({head[:8]!r}); expected a pcap magic (d4 c3 b2 a1, 4d 3c b2 a1 or swapped) or a "
                "pcapng section header (0a 0d 0d 0a)"
            )
        walk_type = PcapWalk if self.format == "pcap" else PcapngWalk
        self._walk = walk_type(self.path, self.stats, self.batch_packets, segment)
        if isinstance(self._walk, PcapWalk):  # pcapng's headers are blocks, read by the walk
            self._walk.parse_header(head)


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
        """Every datagram as a :class:`~lidarpkt.core.packet.Packet`, in capture order.

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
            blocks = BlockReader(fh, os.fstat(fh.fileno()).st_size, READ_BLOCK_BYTES,
                                 self.segment.end_offset if self.segment is not None else None)
            self._begin()
            base = 0
            self._walk.chunk_bytes = MAX_CHUNK_BYTES
            split = self.segment.end_offset if self.segment is not None else None
            for buf, chunk in self._walk.chunks(blocks):
                if split is not None and self.split_ordinal is None and self._walk.chunk_at >= split:
                    self.split_ordinal = base  # chunks never straddle the segment's end (see Walk.split_limit)
                    self.split_offset = self._walk.chunk_at  # the end itself when the cut is a record boundary
                produced = self._decoder.decode(buf, chunk, base)
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

    def recorded_sensor_file(self) -> None:
        """pcap/pcapng files carry no sensor metadata (the :class:`~lidarpkt.containers.PacketSource` protocol)."""
        return None

    @property
    def _reasm(self) -> Reassembler:
        """The fragment reassembler of the current (or last) pass (tests watch its bounds)."""
        return self._decoder._reasm

    def _begin(self) -> None:
        old = self.stats
        fresh = ReadStats(
            path=self.path,
            format=self.format or "",
            snaplen=old.snaplen,
            nanosecond=old.nanosecond,
            big_endian=old.big_endian,
            interfaces=old.interfaces,
        )
        old.__dict__.update(fresh.__dict__)  # in place: callers may hold a reference to stats
        self.split_ordinal = self.split_offset = None
        self._decoder = ChunkDecoder(self.path, self.stats, self.ports, self.src_addresses, self.payload_sizes,
                                     self._reassembly_args)

    def _finish(self) -> None:
        self._decoder.finish()
        st = self.stats
        if st.truncated:  # warned only now, so that every good record was yielded first
            _warn(TruncatedCaptureWarning(f"{self.path}: {st.truncated_reason}"), stacklevel=3)
        if st.malformed:
            reasons = ", ".join(f"{k}: {v}" for k, v in st.malformed_reasons.most_common())
            _warn(
                SkippedPacketWarning(f"{self.path}: skipped {st.malformed} malformed record(s) ({reasons})"),
                stacklevel=3,
            )


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
