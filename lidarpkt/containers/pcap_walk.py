"""Classic pcap: the file read in blocks, and the walk over its record headers in chunks.

A run of records with one capture length is recognised in one strided NumPy comparison, mixed
lengths (VLP-16 data and position packets) record by record in a tight loop; the compiled
``kernels.native.walk_pcap`` does both when the extension is built. A walk can start at any record
offset and end its chunks at a given offset (a :class:`~lidarpkt.containers.segments.Segment`'s).
"""

from __future__ import annotations

import struct
import sys
import threading
from typing import TYPE_CHECKING, Iterator

import numpy as np

from lidarpkt.core import kernels
from ..errors import CaptureFormatError
from .gathers import Chunk, field
from .layouts import (
    LINKTYPE_NAMES,
    ByteOrder,
    PCAP_GLOBAL_HEADER,
    PCAP_MODIFIED_EXTRA,
    PCAP_RECORD_HEADER,
    field_offset,
    header_struct,
)
from .magic import PCAP_MAGIC_MODIFIED, PCAP_MAGIC_NS, PCAP_MAGIC_US

if TYPE_CHECKING:
    from .segments import Segment

__all__ = ["BlockReader", "Walk", "PcapWalk", "MAX_RECORD_BYTES", "SEC_NS"]

MAX_RECORD_BYTES = 1 << 18  # largest caplen accepted (libpcap's MAXIMUM_SNAPLEN, 262144)
SEC_NS = 1_000_000_000
POST_END_CHUNK_BYTES = 1 << 20  # reading a segment: chunks past its end (a VLP-16 frame is ~0.2 MB, an OS-128 one 1.6 MB)
POST_END_READ_BYTES = 2 * POST_END_CHUNK_BYTES + MAX_RECORD_BYTES  # and file blocks: a whole chunk fits
FIRST_BLOCK_BYTES = 1 << 20  # the first read of a pass: its packets are decoded while the read-ahead thread reads
# the next block, where a whole first block would keep the caller waiting for 8 MB to be read and faulted in
# (VLP-16 60 s whole process 0.99 of the time, paired; 256 KB no faster again)


_spare = threading.local()  # the last read block of this thread, lent to the next reader once nothing uses it


def _block(nbytes: int) -> np.ndarray:
    """A read buffer of at least ``nbytes``: the thread's last one when no reader or view holds it any more (the
    readers of a capture's segments, one after another, fault one block's pages in once, not one per segment)."""
    buf = getattr(_spare, "block", None)
    if buf is None or buf.shape[0] < nbytes or sys.getrefcount(buf) > 3:  # 3: buf, _spare.block, the argument
        buf = _spare.block = np.empty(nbytes, np.uint8)
    return buf


class BlockReader:
    """Reads a file in blocks into one reused buffer (no mmap: a file truncated while it is read
    must give a short read, not a SIGBUS; memory stays bounded by the block size)."""

    def __init__(self, fh, size: int, block_bytes: int, segment_end: int | None = None) -> None:
        self.fh = fh
        self.size = size
        self.block_bytes = block_bytes
        self.segment_end = segment_end  # reading a segment: blocks reach at most POST_END_READ_BYTES past its end
        self._buf: np.ndarray | None = None
        self.short = False  # the last read was cut at FIRST_BLOCK_BYTES

    def read(self, offset: int) -> np.ndarray:
        """The file's bytes from ``offset``: up to ``block_bytes`` of them (fewer at the end), but at most
        :data:`FIRST_BLOCK_BYTES` on the first read; :attr:`short` says whether that cut it (a walk whose
        record or block does not fit then reads again from the same offset, in full)."""
        want = max(0, min(self.block_bytes, self.size - offset))
        if self.segment_end is not None:  # past a segment's end only its last frame is read
            want = min(want, max(0, self.segment_end - offset) + POST_END_READ_BYTES)
        full, want = want, want if self._buf is not None else min(want, FIRST_BLOCK_BYTES)
        self.short = want < full
        if self._buf is None or self._buf.shape[0] < want:
            self._buf = _block(max(want, 1))
        view = self._buf.data[:want]  # the array's own memoryview
        self.fh.seek(offset)
        got = 0
        while got < want:
            k = self.fh.readinto(view[got:])
            if not k:
                self.size = offset + got  # the file shrank while being read: it ends here now
                break
            got += k
        return self._buf[:got]


class Walk:
    """What the container walks share: the capture, its stats, the chunk limits and the segment being read.

    ``chunk_bytes`` (the most file bytes one chunk spans) is set by the reader before each pass.
    """

    def __init__(self, path: str, stats, batch_packets: int, segment: "Segment | None") -> None:
        self.path = path
        self.stats = stats
        self.batch_packets = batch_packets
        self.segment = segment
        self.chunk_bytes = 8 << 20
        self.chunk_at = 0  # file offset of the first record of the chunk last yielded

    def truncate(self, reason: str) -> None:
        """Reading stops at damage: say where and why (warned by the reader after the last good packet)."""
        self.stats.truncated = True
        self.stats.truncated_reason = reason

    def split_limit(self, base: int, chunk_start: int) -> int:
        """Where the chunk that starts at ``chunk_start`` of the block read at file offset ``base`` ends
        (relative to the block): MAX_CHUNK_BYTES on, or earlier at the end of the segment being read, so
        that no chunk (and so no batch) holds records from both sides of it."""
        lim = chunk_start + self.chunk_bytes
        if self.segment is not None and base + chunk_start < self.segment.end_offset:
            lim = min(lim, self.segment.end_offset - base)
        elif self.segment is not None:  # past the end only the segment's last frame is read: small chunks
            lim = min(lim, chunk_start + POST_END_CHUNK_BYTES)
        return lim


class PcapWalk(Walk):
    """Chunks of records of a classic pcap file (both byte orders, µs or ns, the 24-byte-record variant)."""

    def parse_header(self, head: bytes) -> None:
        """Check the global header (raises :class:`CaptureFormatError`) and keep what the walk needs."""
        if len(head) < PCAP_GLOBAL_HEADER.itemsize:
            raise CaptureFormatError(
                f"{self.path}: pcap global header cut short ({len(head)} of {PCAP_GLOBAL_HEADER.itemsize} bytes)"
            )
        magic_le = struct.unpack_from("<I", head)[0]
        endian: ByteOrder
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

    def chunks(self, blocks: BlockReader) -> Iterator[tuple[np.ndarray, Chunk]]:
        """(block, chunk) pairs of a classic pcap file; chunk offsets are relative to the block."""
        hdr = self._rec_hdr
        self._u32 = struct.Struct(self._endian + "I").unpack_from
        self._caplen_at = field_offset(PCAP_RECORD_HEADER, "incl_len")
        # libpcap's own limit, or a larger snap length the file declares, but never more than a read block
        self._max_cap = min(max(self._snaplen, MAX_RECORD_BYTES), blocks.block_bytes - hdr)
        self._cap_dtype = np.dtype(self._endian + "u4")
        self._swap = (self._endian == ">") != (sys.byteorder == "big")
        self._window = 64  # speculative run length
        self._backoff = 0  # records to walk one by one before speculating again
        self._misses = 0  # speculations in a row that found short runs
        glob = PCAP_GLOBAL_HEADER.itemsize
        st = self.stats
        st.bytes_read = min(glob, blocks.size)
        if blocks.size < glob:
            self.truncate(f"file ends inside the pcap global header ({blocks.size} of {glob} bytes)")
            return
        off = glob if self.segment is None else max(glob, self.segment.start_offset)  # file offset of the next record
        while off < blocks.size:
            buf = blocks.read(off)
            end = buf.shape[0]
            last_block = off + end >= blocks.size
            rel = 0
            stop = refill = False
            while not (stop or refill):
                chunk_start = rel
                offs, rel, stop, refill = self._chunk_records(buf, off, rel, end, last_block)
                if offs is not None:
                    st.records += offs.shape[0]
                    st.bytes_read = off + rel
                    self.chunk_at = off + chunk_start
                    yield buf, Chunk(
                        data_off=offs + hdr,
                        caplen=field(buf, offs, PCAP_RECORD_HEADER, "incl_len", self._endian),
                        ts_ns=field(buf, offs, PCAP_RECORD_HEADER, "ts_sec", self._endian) * SEC_NS
                        + field(buf, offs, PCAP_RECORD_HEADER, "ts_frac", self._endian) * self._frac_ns,
                        linktype=np.full(offs.shape[0], self._linktype, np.int64),
                    )
                if rel >= end:
                    break
            if stop:
                return
            if refill and rel == 0 and not blocks.short:  # cannot happen: a block holds the largest record allowed
                self.truncate(f"record at offset {off} does not fit a read block")
                return
            off += rel

    def _chunk_records(self, buf: np.ndarray, off: int, rel: int, end: int, last_block: bool):
        """``(offsets, rel, stop, refill)``: the records of one chunk from ``buf[rel:]`` (the block read at
        file offset ``off``; None when there are none), where the walk goes on, and whether it stops at
        damage or needs the next block."""
        pieces: list[np.ndarray] = []
        singles: list[int] = []
        n = 0
        chunk = self.batch_packets
        byte_end = self.split_limit(off, rel)  # records of this chunk start before byte_end
        mv = buf.data
        native = kernels.native
        stop = refill = False
        while n < chunk and rel < byte_end:
            stride, stop, refill = self._next_stride(mv, off, rel, end, last_block, n)
            if stride is None:
                break
            if native is not None:
                # the compiled walk: every whole record up to the chunk's limits, in one call
                room = chunk - n
                found = np.empty(room, np.int64)
                k, rel, _ = native.walk_pcap(buf, rel, end, self._caplen_at, self._rec_hdr, self._swap, self._max_cap,
                                             room, byte_end, found)
                pieces.append(found[:k])
                n += k
                continue
            if self._backoff <= 0:
                k = self._speculate(buf, rel, end, stride, chunk - n, byte_end)
                if k:
                    if singles:
                        pieces.append(np.asarray(singles, np.int64))
                        singles = []
                    pieces.append(rel + stride * np.arange(k, dtype=np.int64))
                    n += k
                    rel += k * stride
                    continue
            rel, walked = self._singles(mv, rel, end, stride, chunk - n, byte_end, singles)
            n += walked
        if singles:
            pieces.append(np.asarray(singles, np.int64))
        if not n:
            return None, rel, stop, refill
        return (pieces[0] if len(pieces) == 1 else np.concatenate(pieces)), rel, stop, refill

    def _next_stride(self, mv: memoryview, off: int, rel: int, end: int, last_block: bool, n: int):
        """``(stride, stop, refill)`` of the record at ``rel``: its size with its header, or None with why
        the walk cannot take it (the block ends: refill; damage: stop, reported by :meth:`truncate`)."""
        hdr = self._rec_hdr
        records = self.stats.records + n
        if rel + hdr > end:
            if not last_block:
                return None, False, True
            if rel != end:
                self.truncate(f"capture cut short: {end - rel} byte(s) of a record header at offset {off + rel} "
                              f"(after {records} complete records)")
            return None, True, False
        cap = self._u32(mv, rel + self._caplen_at)[0]
        if cap > self._max_cap:
            self.truncate(
                f"record at offset {off + rel} claims {cap} captured bytes (more than the snap length "
                f"{self._snaplen} and the {MAX_RECORD_BYTES}-byte limit, or than {self._max_cap} bytes): the "
                f"file is corrupt from there; kept the {records} records before it"
            )
            return None, True, False
        if rel + hdr + cap > end:
            if not last_block:
                return None, False, True
            self.truncate(f"last record at offset {off + rel} claims {cap} captured bytes but only "
                          f"{end - rel - hdr} remain in the file (after {records} complete records)")
            return None, True, False
        return hdr + cap, False, False

    def _speculate(self, buf: np.ndarray, rel: int, end: int, stride: int, room: int, byte_end: int) -> int:
        """How many records from ``rel`` on have the capture length of the first (a run checked in one
        strided comparison); 0 when too few could (then the caller walks record by record)."""
        k_max = min(room, (end - rel) // stride, self._window, -(-(byte_end - rel) // stride))  # starts before the limit
        if k_max < 8:
            return 0
        caps = np.ndarray((k_max,), self._cap_dtype, buf, rel + self._caplen_at, (stride,))
        bad = np.flatnonzero(caps != stride - self._rec_hdr)
        k = int(bad[0]) if bad.size else k_max
        self._window = min(self._window * 2, 1 << 16) if k == k_max else max(64, 2 * k)
        if k >= 32:
            self._misses = 0
        else:  # mixed sizes: speculate ever less often (each miss costs ~10 µs)
            self._backoff = min(32 << self._misses, 8192)
            self._misses += 1
        return k

    def _singles(self, mv: memoryview, rel: int, end: int, stride: int, room: int, byte_end: int,
                 singles: list[int]) -> tuple[int, int]:
        """Record by record (mixed sizes, e.g. VLP-16 data and position packets): a tight loop for up to
        ``backoff`` records; any record needing a decision ends it early. Returns (rel, records taken)."""
        singles.append(rel)
        rel += stride
        lim = min(room - 1, self._backoff - 1)
        hdr, max_cap, caplen_at, u32 = self._rec_hdr, self._max_cap, self._caplen_at, self._u32
        before = len(singles)
        append = singles.append
        while lim > 0 and rel < byte_end and rel + hdr <= end:
            cap = u32(mv, rel + caplen_at)[0]
            nxt = rel + hdr + cap
            if cap > max_cap or nxt > end:
                break
            append(rel)
            rel = nxt
            lim -= 1
        walked = 1 + len(singles) - before
        self._backoff -= walked
        return rel, walked
