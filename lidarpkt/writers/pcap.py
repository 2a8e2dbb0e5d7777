"""Writing captures: classic pcap and pcapng files of packets framed as a real network frames them
(:mod:`lidarpkt.writers.framing`, the one builder of the frames).

Used by the tests, the fixture generator, ``lidarpkt export --format pcap`` and the benchmarks:
:func:`write_pcap_records` / :func:`write_pcapng_records` write already-built frames (so that tests can
reorder, duplicate or damage fragments), :func:`write_pcap` / :func:`write_pcapng` write packets, and
:class:`PcapBatchWriter` writes batches of any source as one pcap in capture order.
"""

from __future__ import annotations

import io
import os
import struct
from dataclasses import dataclass
from typing import BinaryIO, Callable, Iterable, Iterator, Sequence

import numpy as np

from ..errors import PacketFormatError
from lidarpkt.core.packet import Endpoint, Packet, PacketBatch
from lidarpkt.containers.magic import PCAP_MAGIC_NS, PCAP_MAGIC_US, PCAPNG_BOM, PCAPNG_SHB
from lidarpkt.containers.layouts import (
    PCAP_GLOBAL_HEADER,
    PCAP_RECORD_HEADER,
    PCAPNG_BLOCK_HEADER,
    PCAPNG_EPB,
    PCAPNG_IDB,
    PCAPNG_OPTION,
    PCAPNG_SECTION_HEADER,
    PCAPNG_SPB,
    header_struct,
)

from .framing import LINKTYPES, _header_rows, _linktype, batch_frames, framed_packets

__all__ = [
    "Interface",
    "write_pcap",
    "write_pcap_records",
    "pcap_bytes",
    "write_pcapng",
    "write_pcapng_records",
    "pcapng_bytes",
    "PcapBatchWriter",
]

Record = tuple  # (timestamp_ns, frame bytes) or (timestamp_ns, frame bytes, original length)


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
    records = ((p.timestamp_ns, f) for p, frames in framed_packets(
        packets, link=link, mtu=mtu, vlan=vlan, big_endian=big_endian, udp_checksum=udp_checksum) for f in frames)
    write_pcap_records(path, records, link=link, nanosecond=nanosecond, big_endian=big_endian, snaplen=snaplen)


# --- packet batches of any source ----------------------------------------------------------------
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
                parts.append((_take(batch, take), src, dst))
                keep.append((_take(batch, ~take), src, dst))
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
        for frame in batch_frames(src, dst, batch.payload, ident, mtu=self.mtu):
            caplen = min(frame.shape[1], self.snaplen)
            cols.append(_header_rows(PCAP_RECORD_HEADER.newbyteorder("<"), n, ts_sec=sec, ts_frac=frac,
                                     incl_len=caplen, orig_len=frame.shape[1]))
            cols.append(frame[:, :caplen])
        return np.concatenate(cols, axis=1)


def _take(batch: PacketBatch, mask: np.ndarray) -> PacketBatch:
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
    names = {v: k for k, v in LINKTYPES.items()}

    def link_of(p: Packet) -> tuple[str, tuple[int, ...]]:
        link = interfaces[interface_of(p) if interface_of else 0].link
        name = link if isinstance(link, str) else names[int(link)]
        return name, vlan if name == "ethernet" else ()

    def records() -> Iterator[tuple]:
        for p, frames in framed_packets(packets, link_of=link_of, mtu=mtu, big_endian=big_endian,
                                        udp_checksum=udp_checksum):
            i = interface_of(p) if interface_of else 0
            for f in frames:
                yield (i, p.timestamp_ns, f)

    write_pcapng_records(path, records(), interfaces=interfaces, big_endian=big_endian, block=block)
