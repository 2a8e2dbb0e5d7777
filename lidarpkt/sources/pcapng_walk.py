"""pcapng: the walk over its blocks (sections, interfaces, enhanced/simple/obsolete packet blocks) in chunks.

Each section has its own byte order and interfaces, each interface its own link type and time
resolution. The compiled ``kernels.native.walk_pcapng`` takes runs of enhanced packet blocks; the
blocks that need a decision are taken one by one here. A walk can start at a packet block (after
reading its section's header and interface blocks: a :class:`~lidarpkt.sources.segments.Segment`'s
``pcapng_preamble``) and end its chunks at a given offset.
"""

from __future__ import annotations

import struct
import sys
from typing import Iterator

import numpy as np

from .. import kernels
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


class PcapngWalk(Walk):
    """Chunks of packet records of a pcapng file."""

    def chunks(self, blocks: BlockReader) -> Iterator[tuple[np.ndarray, Chunk]]:
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

        def flush(buf: np.ndarray, abs_end: int) -> tuple[np.ndarray, Chunk]:
            nonlocal pending
            lists_to_piece()
            self.chunk_at = chunk_start
            parts = pieces[0] if len(pieces) == 1 else tuple(np.concatenate(col) for col in zip(*pieces))
            st.records += pending
            st.bytes_read = abs_end
            pieces.clear()
            pending = 0
            return buf, Chunk(*parts)

        off = 0  # file offset of the next pcapng block
        split = None if self.segment is None else self.segment.end_offset
        if self.segment is not None and self.segment.start_offset > 0:
            # a segment starts mid-file: its section's header and interface blocks come first
            endian, ifaces = self.preamble(blocks, self.segment.pcapng_preamble)
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
                self.truncate(f"capture cut short: {end - rel} byte(s) of a pcapng block header at offset {off}")
                break
            if native is not None and ifaces and not first:
                # the compiled walk over the enhanced packet blocks that follow; it stops before any
                # block that needs a decision, which the loop below then takes
                room = chunk - pending
                data, capl, iface, raw = (np.empty(room, np.int64), np.empty(room, np.int64),
                                          np.empty(room, np.int64), np.empty(room, np.uint64))
                k, nxt = native.walk_pcapng(buf, rel, end, endian != _NATIVE_ORDER, len(ifaces), MAX_PCAPNG_BLOCK,
                                            room, self.split_limit(base, chunk_start - base), data, capl, iface, raw)
                if k:
                    lists_to_piece()
                    got = self._times(ifaces, data[:k], capl[:k], iface[:k], raw[:k])
                    pieces.append(got)
                    pending += got[0].shape[0]
                    off = base + nxt
                    if pending >= chunk or off - chunk_start >= self.chunk_bytes:
                        yield flush(buf, off)
                        chunk_start = off
                    continue
            btype_le = struct.unpack_from("<I", mv, rel)[0]
            if btype_le == PCAPNG_SHB:
                if rel + 16 > end:
                    self.truncate(f"capture cut short inside the section header block at offset {off}")
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
                    self.truncate(msg + "; stopped there")
                    break
                ifaces = []
                st.big_endian = endian == ">"
            btype, blen = header_struct(PCAPNG_BLOCK_HEADER, endian).unpack_from(mv, rel)
            if blen < 12 or blen % 4 or blen > MAX_PCAPNG_BLOCK:
                msg = f"pcapng block at offset {off} (type {btype:#x}) has an impossible length {blen}"
                if first:
                    raise CaptureFormatError(f"{self.path}: {msg}")
                self.truncate(msg + f"; kept the {st.records + pending} records before it")
                break
            if rel + blen > end and base + end < blocks.size:
                if pending:
                    yield flush(buf, off)
                if refill():
                    continue
            if rel + blen > end:
                self.truncate(
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
                self.truncate(msg + f"; kept the {st.records + pending} records before it")
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
            if pending >= chunk or off - chunk_start >= self.chunk_bytes:
                yield flush(buf, off)
                chunk_start = off
        if pending:
            yield flush(buf, off)
        st.bytes_read = off

    def preamble(self, blocks: BlockReader, offsets: tuple[int, ...]) -> tuple[str, list]:
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

