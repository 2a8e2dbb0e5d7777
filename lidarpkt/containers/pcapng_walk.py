"""pcapng: the walk over its blocks (sections, interfaces, enhanced/simple/obsolete packet blocks) in chunks.

Each section has its own byte order and interfaces, each interface its own link type and time
resolution. The compiled ``kernels.native.walk_pcapng`` takes runs of enhanced packet blocks; the
blocks that need a decision are taken one by one here. A walk can start at a packet block (after
reading its section's header and interface blocks: a :class:`~lidarpkt.containers.segments.Segment`'s
``pcapng_preamble``) and end its chunks at a given offset.
"""

from __future__ import annotations

import struct
import sys
from typing import Iterator

import numpy as np

from lidarpkt.core import kernels
from ..errors import CaptureFormatError
from .gathers import Chunk
from .layouts import (
    PCAPNG_BLOCK_HEADER,
    PCAPNG_EPB,
    PCAPNG_IDB,
    PCAPNG_OPB,
    PCAPNG_OPTION,
    PCAPNG_SECTION_HEADER,
    PCAPNG_SPB,
    field_offset,
    header_struct,
)
from .magic import PCAPNG_SHB
from .pcap_walk import SEC_NS, BlockReader, Walk

__all__ = ["PcapngWalk", "MAX_PCAPNG_BLOCK"]

MAX_PCAPNG_BLOCK = 1 << 24  # larger "blocks" are taken as corruption, not allocated
_NATIVE_ORDER = "<" if sys.byteorder == "little" else ">"


class _Gathered:
    """Records of the chunk being gathered: arrays from the compiled walk, then the lists of the
    record-by-record walk (moved into ``pieces`` before the next array piece, to keep the order)."""

    def __init__(self) -> None:
        self.pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.lists: tuple[list[int], list[int], list[int], list[int]] = ([], [], [], [])
        self.pending = 0  # records in pieces and lists

    def add_piece(self, piece: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> None:
        self._lists_to_piece()
        self.pieces.append(piece)
        self.pending += piece[0].shape[0]

    def take(self) -> Chunk:
        self._lists_to_piece()
        pieces = self.pieces
        parts = pieces[0] if len(pieces) == 1 else tuple(np.concatenate(col) for col in zip(*pieces))
        self.pieces = []
        self.pending = 0
        return Chunk(*parts)

    def _lists_to_piece(self) -> None:
        if self.lists[0]:
            data_off, caplen, ts_ns, linktype = (np.asarray(col, np.int64) for col in self.lists)
            self.pieces.append((data_off, caplen, ts_ns, linktype))
            for col in self.lists:
                col.clear()


class PcapngWalk(Walk):
    """Chunks of packet records of a pcapng file."""

    _interfaces_seen = 0  # interfaces of all sections so far in this pass (ReadStats.interfaces)

    def chunks(self, blocks: BlockReader) -> Iterator[tuple[np.ndarray, Chunk]]:
        """(block, chunk) pairs of a pcapng file (a Python loop over its blocks)."""
        st = self.stats
        chunk = self.batch_packets
        endian = "<"
        ifaces: list[tuple[int, int, int, int, int]] = []  # (linktype, snaplen, mul, div, offset_s) per section
        got = _Gathered()
        packet, unpack_from = self._packet, struct.unpack_from
        first = True
        native = kernels.native
        if blocks.size < PCAPNG_BLOCK_HEADER.itemsize + 4:
            raise CaptureFormatError(f"{self.path}: pcapng file cut short inside its first block ({blocks.size} bytes)")
        off = 0  # file offset of the next pcapng block
        split = None if self.segment is None else self.segment.end_offset
        if self.segment is not None and self.segment.start_offset > 0:
            # a segment starts mid-file: its section's header and interface blocks come first
            endian, ifaces = self.preamble(blocks, self.segment.pcapng_preamble)
            first, off = False, self.segment.start_offset
        self._interfaces_seen = len(ifaces)
        base = chunk_start = off  # file offsets of buf[0] and of the chunk being gathered
        buf = blocks.read(off)
        mv = buf.data
        while off < blocks.size:
            rel = off - base
            end = buf.shape[0]
            # fewer bytes left in the block than a block header and a section header's byte-order magic
            # (16), with more in the file: read on from here
            read_on = rel + 16 > end and base + end < blocks.size
            if got.pending and ((split is not None and chunk_start < split <= off)  # no chunk spans a segment's end
                                or read_on):
                yield self._flush(got, buf, chunk_start, off)
                chunk_start = off
            if read_on and (off != base or blocks.short):
                base = chunk_start = off
                buf = blocks.read(off)
                mv = buf.data
                continue
            if rel + 12 > end:
                self.truncate(f"capture cut short: {end - rel} byte(s) of a pcapng block header at offset {off}")
                break
            if native is not None and ifaces and not first:
                # the compiled walk over the enhanced packet blocks that follow; it stops before any
                # block that needs a decision, which the loop below then takes
                nxt = self._native_run(got, buf, rel, end, endian, ifaces, self.split_limit(base, chunk_start - base))
                if nxt is not None:
                    off = base + nxt
                    if got.pending >= chunk or off - chunk_start >= self.chunk_bytes:
                        yield self._flush(got, buf, chunk_start, off)
                        chunk_start = off
                    continue
            if unpack_from("<I", mv, rel)[0] == PCAPNG_SHB:
                section_endian = self._section_endian(mv, rel, end, off, first)
                if section_endian is None:
                    break
                endian = section_endian
                ifaces = []
            btype, blen = header_struct(PCAPNG_BLOCK_HEADER, endian).unpack_from(mv, rel)
            whole = (12 <= blen <= MAX_PCAPNG_BLOCK and not blen % 4) or self._check_length(
                btype, blen, off, first, got.pending)
            if whole and rel + blen > end and base + end < blocks.size:
                if got.pending:
                    yield self._flush(got, buf, chunk_start, off)
                if off != base or blocks.short:  # read on (a block larger than a whole read block is damage, below)
                    base = chunk_start = off
                    buf = blocks.read(off)
                    mv = buf.data
                    continue
            if not whole or not ((rel + blen <= end and unpack_from(endian + "I", mv, rel + blen - 4)[0] == blen)
                                 or self._check_trailer(mv, rel, end, btype, blen, endian, off, first, got.pending)):
                break
            first = False
            body, body_end = rel + PCAPNG_BLOCK_HEADER.itemsize, rel + blen - 4
            off += blen
            if btype == 1:  # interface description block
                self._interface(mv, body, body_end, endian, ifaces)
            elif btype in (6, 2, 3):  # an enhanced, obsolete or simple packet block
                if packet(mv, btype, body, body_end, endian, ifaces, got):
                    if got.pending >= chunk or off - chunk_start >= self.chunk_bytes:
                        yield self._flush(got, buf, chunk_start, off)
                        chunk_start = off
        if got.pending:
            yield self._flush(got, buf, chunk_start, off)
        st.bytes_read = off

    def _flush(self, got: "_Gathered", buf: np.ndarray, chunk_start: int, abs_end: int) -> tuple[np.ndarray, Chunk]:
        """The gathered records as a chunk (its first record at or after ``chunk_start``; the walk is at ``abs_end``)."""
        self.chunk_at = chunk_start
        self.stats.records += got.pending
        self.stats.bytes_read = abs_end
        return buf, got.take()

    def _native_run(self, got: "_Gathered", buf: np.ndarray, rel: int, end: int, endian: str, ifaces: list,
                    byte_limit: int) -> int | None:
        """Enhanced packet blocks from ``rel`` by the compiled walk, added to ``got``; where the walk
        stopped (relative to ``buf``), or None when it took none."""
        native = kernels.native
        if native is None:  # the callers check; this keeps the walk correct without them
            return None
        room = self.batch_packets - got.pending
        data, capl, iface, raw = (np.empty(room, np.int64), np.empty(room, np.int64),
                                  np.empty(room, np.int64), np.empty(room, np.uint64))
        k, nxt = native.walk_pcapng(buf, rel, end, endian != _NATIVE_ORDER, len(ifaces), MAX_PCAPNG_BLOCK,
                                    room, byte_limit, data, capl, iface, raw)
        if not k:
            return None
        got.add_piece(self._times(ifaces, data[:k], capl[:k], iface[:k], raw[:k]))
        return nxt

    def _section_endian(self, mv: memoryview, rel: int, end: int, off: int, first: bool) -> str | None:
        """Byte order of the section header block at ``rel``; None (reported) when it is cut or bad."""
        if rel + 16 > end:
            self.truncate(f"capture cut short inside the section header block at offset {off}")
            return None
        bom_at = rel + PCAPNG_BLOCK_HEADER.itemsize + field_offset(PCAPNG_SECTION_HEADER, "byte_order_magic")
        bom = mv[bom_at : bom_at + 4].tobytes()
        if bom in (b"\x4d\x3c\x2b\x1a", b"\x1a\x2b\x3c\x4d"):
            endian = "<" if bom == b"\x4d\x3c\x2b\x1a" else ">"
            self.stats.big_endian = endian == ">"
            return endian
        msg = f"pcapng section header at offset {off} has a bad byte-order magic {bom.hex(' ')}"
        if first:
            raise CaptureFormatError(f"{self.path}: {msg}")
        self.truncate(msg + "; stopped there")
        return None

    def _check_length(self, btype: int, blen: int, off: int, first: bool, pending: int) -> bool:
        """False (reported; raised for the file's first block) when a block length is impossible."""
        if 12 <= blen <= MAX_PCAPNG_BLOCK and not blen % 4:
            return True
        return self._damage(f"pcapng block at offset {off} (type {btype:#x}) has an impossible length {blen}",
                            first, pending)

    def _check_trailer(self, mv: memoryview, rel: int, end: int, btype: int, blen: int, endian: str, off: int,
                       first: bool, pending: int) -> bool:
        """False (reported) when the block runs past the file's end or its trailing length differs."""
        if rel + blen > end:
            self.truncate(
                f"pcapng block at offset {off} (type {btype:#x}) claims {blen} bytes but only {end - rel} "
                f"remain in the file; kept the {self.stats.records + pending} records before it"
            )
            return False
        trailer = struct.unpack_from(endian + "I", mv, rel + blen - 4)[0]
        if trailer == blen:
            return True
        return self._damage(f"pcapng block at offset {off} (type {btype:#x}): leading length {blen} and trailing "
                            f"length {trailer} differ", first, pending)

    def _damage(self, msg: str, first: bool, pending: int) -> bool:
        """A damaged block: not a capture when it is the file's first (raised), else the end of reading."""
        if first:
            raise CaptureFormatError(f"{self.path}: {msg}")
        self.truncate(msg + f"; kept the {self.stats.records + pending} records before it")
        return False

    def _interface(self, mv: memoryview, body: int, body_end: int, endian: str, ifaces: list) -> None:
        """An interface description block: its link type and time resolution join the section's interfaces."""
        st = self.stats
        desc = _pcapng_interface(mv, body, body_end, endian)
        if desc is None:
            st.malformed += 1
            st.malformed_reasons["short pcapng interface block"] += 1
            return
        ifaces.append(desc)
        self._interfaces_seen += 1
        st.interfaces = self._interfaces_seen
        st.snaplen = max(st.snaplen, desc[1])

    def _packet(self, mv: memoryview, btype: int, body: int, body_end: int, endian: str, ifaces: list,
                got: "_Gathered") -> bool:
        """Adds a packet block's record (data offset, caplen, ts_ns, link type) to ``got``; False when it is
        malformed (counted)."""
        if btype == 3:
            if body_end - body < PCAPNG_SPB.itemsize:
                return self._malformed("short pcapng packet block")
            orig = header_struct(PCAPNG_SPB, endian).unpack_from(mv, body)[0]
            iface, ts_raw, data = 0, None, body + PCAPNG_SPB.itemsize
            cap = min(orig, body_end - data)
        else:
            if body_end - body < PCAPNG_EPB.itemsize:
                return self._malformed("short pcapng packet block")
            if btype == 6:
                iface, hi, lo, cap, _orig = header_struct(PCAPNG_EPB, endian).unpack_from(mv, body)
            else:
                iface, _drops, hi, lo, cap, _orig = header_struct(PCAPNG_OPB, endian).unpack_from(mv, body)
            ts_raw = (hi << 32) | lo
            data = body + PCAPNG_EPB.itemsize  # the OPB header has the same size
        if iface >= len(ifaces):
            return self._malformed("pcapng packet for an undeclared interface")
        if data + cap > body_end:
            return self._malformed("pcapng packet longer than its block")
        ts_ns = 0 if ts_raw is None else _pcapng_time_ns(ts_raw, ifaces[iface])
        if ts_ns is None:
            return self._malformed("pcapng time stamp out of range")
        offs, caps, tss, links = got.lists
        offs.append(data)
        caps.append(cap)
        tss.append(ts_ns)
        links.append(ifaces[iface][0])
        got.pending += 1
        return True

    def _malformed(self, reason: str) -> bool:
        self.stats.malformed += 1
        self.stats.malformed_reasons[reason] += 1
        return False

    def preamble(self, blocks: BlockReader, offsets: tuple[int, ...]) -> tuple[str, list]:
        """Byte order and interfaces of a pcapng section, from its section header block and interface
        description blocks at ``offsets`` (as :func:`lidarpkt.containers.segments.plan_segments` found them)."""
        endian = "<"
        ifaces: list[tuple[int, int, int, int, int]] = []
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

    def _times(self, ifaces: list[tuple[int, int, int, int, int]], data: np.ndarray, caplen: np.ndarray,
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
            if top * mul < (1 << 63) and -(1 << 63) <= ts_off * SEC_NS and ts_off * SEC_NS + top * mul // div < (1 << 63):
                ts[mine] = r.astype(np.int64) * mul // div + ts_off * SEC_NS
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



def _pcapng_time_ns(raw: int, interface: tuple[int, int, int, int, int]) -> int | None:
    """A pcapng packet's raw time stamp in ns since the epoch (``if_tsresol`` and ``if_tsoffset`` of its
    interface applied), or ``None`` when that does not fit an int64."""
    _lt, _snap, mul, div, ts_off = interface
    ts_ns = ts_off * SEC_NS + (raw * mul) // div
    return ts_ns if -(1 << 63) <= ts_ns < (1 << 63) else None


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
                mul, div = SEC_NS, 1 << (r & 0x7F)
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

