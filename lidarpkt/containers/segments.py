"""Segments of a large capture: record-aligned byte ranges that can be decoded independently.

:func:`plan_segments` walks a capture's record headers once (classic pcap: the compiled walk
``kernels.native.walk_pcap`` or a NumPy-free Python twin; pcapng: one step per block header) and
cuts it into :class:`Segment` s of about ``segment_bytes``. ``lidarpkt.open(path, segment=seg)``
then yields the frames that *belong* to the segment, and the frames of all segments, in segment
order, are the frames of the whole file (see :class:`SegmentOwnership` for the rule).

MCAP files and ROS bags are one segment per file: their chunk indexes would give chunk-aligned
starts, but a message stream cut there needs the reader to start mid-chunk-sequence, which the
``mcap``/``rosbags`` readers do not offer; a fleet archive of bags parallelises over files.

A boundary never falls on an IPv4 fragment other than the first of its datagram (the plan moves it
to the next record that is not a continuation), so that no datagram is reassembled on both sides.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidarpkt.core import kernels
from ..errors import CaptureFormatError
from .magic import container_kind

__all__ = ["Segment", "plan_segments", "DEFAULT_SEGMENT_BYTES"]

DEFAULT_SEGMENT_BYTES = 256 << 20  # the archive's --segment-size default
_PCAP_GLOBAL = 24
_READ = 16 << 20  # the index pass reads record headers in blocks this large
_MAX_RECORD = 1 << 18
_MAX_BLOCK = 1 << 24
_PCAP_MAGICS = {0xA1B2C3D4: 1000, 0xA1B23C4D: 1, 0xA1B2CD34: 1000}  # → ns per time-stamp fraction


@dataclass(frozen=True)
class Segment:
    """One record-aligned byte range of a capture (picklable; made by :func:`plan_segments`).

    Attributes:
        path: the capture file.
        index: 0-based position of the segment in the file; ``count`` segments in all.
        start_offset, end_offset: the file offsets of its first record and of the first record
            after it (the file size for the last segment); the whole file for MCAP/bags.
        container: ``"pcap"``, ``"pcapng"``, ``"mcap"``, ``"rosbag1"`` or ``"rosbag2"``.
        pcapng_preamble: pcapng only: offsets of the section header block and the interface
            description blocks in effect at ``start_offset`` (a reader starting there reads them first).
    """

    path: str
    index: int
    count: int
    start_offset: int
    end_offset: int
    container: str
    pcapng_preamble: tuple[int, ...] = ()

    @property
    def first(self) -> bool:
        """True for the segment that starts the file (its first frames are the streams' first)."""
        return self.index == 0

    @property
    def size_bytes(self) -> int:
        return self.end_offset - self.start_offset


def plan_segments(path: str | os.PathLike[str], segment_bytes: int = DEFAULT_SEGMENT_BYTES, *,
                  walk: bool = True) -> list[Segment]:
    """Record-aligned segments of about ``segment_bytes`` each (at least one; the last may be shorter).

    ``walk=False`` (classic pcap only; pcapng always walks): each cut is found by re-synchronising on
    the record headers in a window after its nominal offset (:func:`_pcap_sync`) instead of walking
    every record header from the start, which reads the whole file once more. Such a plan is only
    as sure as the re-synchronisation, and a damaged record before a cut does not end the plan
    there: the reader of the segment before each cut must check that its walk meets the cut
    (``PcapReader.split_offset``) and that it did not stop at damage, as ``lidarpkt.open(path,
    workers=N)`` does.

    Raises:
        UnsupportedContainerError: the file is no capture lidarpkt reads.
        CaptureFormatError: a pcap/pcapng header is unusable. Damage further in ends the last
            segment there (the reader reports it as the whole-file reader does).
        ValueError: ``segment_bytes`` below 1.
    """
    if segment_bytes < 1:
        raise ValueError("segment_bytes must be at least 1")
    kind = container_kind(path)
    p = Path(path)
    if kind != "pcap":
        return [Segment(str(p), 0, 1, 0, _size(p), kind)]
    with open(p, "rb") as fh:
        head = fh.read(4)
    if head == b"\x0a\x0d\x0d\x0a":
        cuts = _pcapng_cuts(p, int(segment_bytes))
        container = "pcapng"
    else:
        cuts = [(o, ()) for o in (_pcap_cuts if walk else _pcap_sync_cuts)(p, int(segment_bytes))]
        container = "pcap"
    size = _size(p)
    starts = [(0, ())] + [c for c in cuts if 0 < c[0] < size]
    ends = [c[0] for c in starts[1:]] + [size]
    n = len(starts)
    return [Segment(str(p), i, n, s, e, container, pre) for i, ((s, pre), e) in enumerate(zip(starts, ends))]


def _size(p: Path) -> int:
    if p.is_dir():
        return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    return p.stat().st_size


# ---------------------------------------------------------------- classic pcap
@dataclass(frozen=True)
class _PcapHeader:
    endian: str
    hdr: int  # record header bytes
    max_cap: int  # the largest captured length a record may have
    network: int  # link type
    frac_limit: int  # time stamp fractions are below this (10**6 µs, 10**9 ns)


def _pcap_header(p: Path, fh) -> _PcapHeader | None:
    head = fh.read(_PCAP_GLOBAL)
    if len(head) < _PCAP_GLOBAL:
        return None
    magic = struct.unpack("<I", head[:4])[0]
    endian = "<" if magic in _PCAP_MAGICS else ">"
    magic = struct.unpack(endian + "I", head[:4])[0]
    if magic not in _PCAP_MAGICS:
        raise CaptureFormatError(f"{p}: not a pcap capture (magic {head[:4].hex(' ')})")
    hdr = 16 + (8 if magic == 0xA1B2CD34 else 0)
    snaplen, network = struct.unpack(endian + "II", head[16:24])
    return _PcapHeader(endian, hdr, min(max(snaplen, _MAX_RECORD), _READ - hdr), network & 0xFFFF,
                       10**9 // _PCAP_MAGICS[magic])


def _pcap_cuts(p: Path, segment_bytes: int) -> list[int]:
    """Offsets of the records that start the 2nd, 3rd... segment."""
    with open(p, "rb", buffering=0) as fh:
        ph = _pcap_header(p, fh)
        if ph is None:
            return []
        endian, hdr, max_cap = ph.endian, ph.hdr, ph.max_cap
        size = os.fstat(fh.fileno()).st_size
        cuts: list[int] = []
        off = _PCAP_GLOBAL
        target = off + segment_bytes
        while off < size:
            nxt = _pcap_skip(fh, off, min(target, size), endian, hdr, max_cap)
            if nxt is None or nxt >= size:
                break
            nxt = _past_fragments(fh, nxt, size, endian, hdr, max_cap, ph.network)
            if nxt is None or nxt >= size:
                break
            cuts.append(nxt)
            off, target = nxt, nxt + segment_bytes
        return cuts


def _pcap_skip(fh, off: int, limit: int, endian: str, hdr: int, max_cap: int) -> int | None:
    """Offset of the first record starting at or after ``limit``, walking headers from ``off``;
    ``None`` at damage or the end of the file (the last segment ends there)."""
    u32 = struct.Struct(endian + "I").unpack_from
    swap = (endian == ">") != (struct.pack("=I", 1) == struct.pack(">I", 1))
    native = kernels.native
    found = np.empty(1 << 16 if native is not None else 0, np.int64)  # the compiled walk's record offsets
    while True:
        fh.seek(off)
        raw = fh.read(_READ)
        end, rel, target = len(raw), 0, limit - off
        if native is not None:
            block = np.frombuffer(raw, np.uint8)
            while rel < target:
                _k, new_rel, _ = native.walk_pcap(block, rel, end, 8, hdr, swap, max_cap, found.shape[0], target, found)
                if new_rel == rel:
                    break
                rel = new_rel
        else:
            while rel < target and rel + hdr <= end:
                cap = u32(raw, rel + 8)[0]
                if cap > max_cap or rel + hdr + cap > end:
                    break
                rel += hdr + cap
        if rel >= target:
            return off + rel
        if rel == 0:
            return None
        off += rel


SYNC_WINDOW = 1 << 18  # a re-synchronised cut is followed by an unbroken chain of record headers this long
_SYNC_MIN_RECORDS = 16  # and of at least this many records (or by one reaching the end of the file exactly)
_SYNC_MIN_CAP = 28  # no UDP datagram is captured in fewer bytes (raw IPv4: 20 + 8); zeroed payload bytes are no header
_SYNC_MAX_GAP_S = 3600  # time stamps of consecutive records in the chain differ by less than this


def _pcap_sync_cuts(p: Path, segment_bytes: int) -> list[int]:
    """Offsets that start the 2nd, 3rd... segment, each found by :func:`_pcap_sync` at its nominal offset."""
    with open(p, "rb", buffering=0) as fh:
        ph = _pcap_header(p, fh)
        if ph is None:
            return []
        size = os.fstat(fh.fileno()).st_size
        window = min(SYNC_WINDOW, max(segment_bytes // 2, 1))
        cuts: list[int] = []
        target = _PCAP_GLOBAL + segment_bytes
        while target < size:
            at = _pcap_sync(fh, target, ph, window, size)
            if at is not None:
                at = _past_fragments(fh, at, size, ph.endian, ph.hdr, ph.max_cap, ph.network)
            if at is None or at >= size:
                break
            cuts.append(at)
            target = at + segment_bytes
        return cuts


def _pcap_sync(fh, target: int, ph: _PcapHeader, window: int, size: int) -> int | None:
    """The first offset at or after ``target`` where record headers chain unbroken through ``window``
    bytes and :data:`_SYNC_MIN_RECORDS` records, or to the end of the file exactly, each plausible: a
    captured length of at least :data:`_SYNC_MIN_CAP`, at most the original length and ``max_cap``,
    a time stamp fraction in range, a time stamp within :data:`_SYNC_MAX_GAP_S` of the record
    before and, on Ethernet, an EtherType that is a type; ``None`` when there is no such chain
    (damage, data that is no run of records). A payload that is itself a run of such records
    ending where its datagram ends (a capture file sent over UDP) can still pass: the reader of the
    segment before the cut catches that (``PcapReader.split_offset``)."""
    want = 2 * window + (1 << 16)
    most = 2 * window + (_SYNC_MIN_RECORDS + 1) * (ph.max_cap + ph.hdr)
    while True:
        fh.seek(target)
        raw = fh.read(want)
        at_eof = target + len(raw) >= size
        start, ran_off = _sync_in(raw, ph, window, at_eof)
        if start is not None:
            return target + start
        if not ran_off or at_eof or want >= most:
            return None
        want = min(4 * want, most)  # the first chain that may be the one runs past what was read


def _sync_in(raw: bytes, ph: _PcapHeader, window: int, at_eof: bool) -> tuple[int | None, bool]:
    """(offset in ``raw`` of the first chain :func:`_pcap_sync` accepts or None, whether a chain ran off
    the end of ``raw`` before it could be accepted or refused)."""
    n = len(raw) - ph.hdr + 1  # offsets where a whole record header fits
    if n <= 0:
        return None, not at_eof
    u32 = np.dtype(ph.endian + "u4")
    # every byte offset read as a record header (unaligned strided views of the window)
    ts_sec, frac, cap, orig = (np.ndarray((n,), u32, raw, k, (1,)) for k in (0, 4, 8, 12))
    plausible = (cap >= _SYNC_MIN_CAP) & (cap <= orig) & (cap <= ph.max_cap) & (frac < ph.frac_limit) & \
        (orig <= (1 << 18))
    # Ethernet: the EtherType field holds a type (>= 0x0600), never a length or zeros
    ether = ph.hdr + 12 if ph.network == 1 else None
    for start in np.flatnonzero(plausible).tolist():
        at, prev_ts, count = start, int(ts_sec[start]), 0
        while at < n and plausible[at] and abs(int(ts_sec[at]) - prev_ts) < _SYNC_MAX_GAP_S and \
                (ether is None or at + ether >= len(raw) or raw[at + ether] >= 6):
            prev_ts = int(ts_sec[at])
            at += ph.hdr + int(cap[at])
            count += 1
            if (at >= start + window and count >= _SYNC_MIN_RECORDS) or (at_eof and at == len(raw)):
                return start, False
        if at >= n and not (at_eof and at > len(raw)):
            return None, True
    return None, False


def _past_fragments(fh, off: int, size: int, endian: str, hdr: int, max_cap: int, linktype: int) -> int | None:
    """``off``, or the first later record that is not an IPv4 fragment continuing a datagram."""
    for _ in range(64):  # a datagram has at most 45 fragments of a 1500-byte MTU
        if off + hdr > size:
            return None
        fh.seek(off)
        rec = fh.read(hdr + 64)
        cap = struct.unpack_from(endian + "I", rec, 8)[0]
        if cap > max_cap:
            return None
        if not _continues_fragment(rec[hdr:hdr + min(cap, 64)], linktype):
            return off
        off += hdr + cap
    return off


def _continues_fragment(data: bytes, linktype: int) -> bool:
    """True when a record (Ethernet, VLAN-tagged or not, or raw IPv4) is an IPv4 fragment at a
    non-zero offset; other link types are not looked into."""
    if linktype == 1:
        at, etype = 14, data[12:14]
        while etype in (b"\x81\x00", b"\x88\xa8", b"\x91\x00") and len(data) >= at + 4:
            etype, at = data[at + 2:at + 4], at + 4
        if etype != b"\x08\x00":
            return False
    elif linktype in (101, 228, 12, 14):
        at = 0
    else:
        return False
    if len(data) < at + 8 or data[at] >> 4 != 4:
        return False
    return (struct.unpack_from(">H", data, at + 6)[0] & 0x1FFF) != 0


# ---------------------------------------------------------------- pcapng
def _pcapng_cuts(p: Path, segment_bytes: int) -> list[tuple[int, tuple[int, ...]]]:
    """(offset, preamble) of the packet blocks that start the 2nd, 3rd... segment."""
    cuts: list[tuple[int, tuple[int, ...]]] = []
    with open(p, "rb", buffering=0) as fh:
        size = os.fstat(fh.fileno()).st_size
        off, base, buf = 0, 0, b""
        endian = "<"
        preamble: list[int] = []
        links: list[int] = []  # link type of each interface of the section
        target = segment_bytes
        while off + 12 <= size:
            if off + 12 > base + len(buf):
                fh.seek(off)
                base, buf = off, fh.read(_READ)
            rel = off - base
            btype_le = struct.unpack_from("<I", buf, rel)[0]
            if btype_le == 0x0A0D0D0A:
                endian = "<" if buf[rel + 8:rel + 12] == b"\x4d\x3c\x2b\x1a" else ">"
                preamble, links = [off], []
            btype, blen = struct.unpack_from(endian + "II", buf, rel)
            if blen < 12 or blen % 4 or blen > _MAX_BLOCK or off + blen > size:
                break  # damage: the last segment ends there, as the reader's walk does
            if btype == 1:
                preamble.append(off)
                links.append(struct.unpack_from(endian + "H", _block_head(fh, buf, base, off, 10), 8)[0])
            elif btype in (2, 3, 6) and off >= target and preamble:
                head = _block_head(fh, buf, base, off, 28 + 64)
                iface = 0 if btype == 3 else struct.unpack_from(endian + ("H" if btype == 2 else "I"), head, 8)[0]
                data = head[12:] if btype == 3 else head[28:]
                if iface >= len(links) or not _continues_fragment(data, links[iface]):
                    cuts.append((off, tuple(preamble)))
                    target = off + segment_bytes
            off += blen
    return cuts


def _block_head(fh, buf: bytes, base: int, off: int, n: int) -> bytes:
    """Up to ``n`` bytes of the file from ``off`` (from the buffer read at ``base`` when it holds them)."""
    rel = off - base
    if rel + n <= len(buf):
        return buf[rel:rel + n]
    fh.seek(off)
    return fh.read(n)


# ---------------------------------------------------------------- which frames a segment yields
@dataclass
class _StreamState:
    owned: bool  # the frame being assembled belongs to this segment
    post_seen: bool = False  # the stream's first packet at/after the segment's end was pushed
    closed: bool = False  # nothing more of this stream belongs to the segment: its packets are not decoded


class SegmentOwnership:
    """Which frames of a segment's reader belong to the segment.

    The rule: a frame belongs to the segment that holds the **last packet of the frame before
    it** (of the same sensor), and the first frame of a stream that starts in the file's first
    segment to that segment. Every frame has exactly one owner, and the owner can decode it
    exactly: it read the packet before the frame's start, so it saw the cut (azimuth wrap, new
    Ouster frame id, gap) as the whole-file reader does, and it reads on past its end until that
    frame is complete. So the reader of segment k:

    - discards each stream's first frame unless k is 0 (it may have begun before the segment, or
      at the segment's first packet, in which case its predecessor lies in segment k-1);
    - keeps every frame started by a cut seen while pushing packets before its end;
    - pushes each stream's first packet at/after its end alone: a frame completed by it that does
      not contain it (the cut is before it) makes the next frame the segment's; a frame that does
      contain it (a VLP-16 cut inside the packet, an Ouster frame it completes) does not;
    - stops decoding a stream once the frame it is assembling is not the segment's, and stops
      reading once every stream has stopped (streams first seen after its end are not decoded).

    Not covered: a second sensor whose stream *starts* inside segment k > 0 loses its first
    (partial) frame, which no reader can tell from a frame cut by the segment start.
    """

    def __init__(self, segment: Segment) -> None:
        self.segment = segment
        self.streams: dict[tuple, _StreamState] = {}

    def state(self, key: tuple, post_end: bool) -> _StreamState:
        st = self.streams.get(key)
        if st is None:
            st = self.streams[key] = _StreamState(owned=self.segment.first and not post_end, closed=post_end)
        return st

    def split_first_post(self, key: tuple, batch):
        """The batches to push for a batch at/after the end: its first packet alone, when it is the stream's first."""
        st = self.streams.get(key)
        if st is None or st.post_seen or st.closed or len(batch) == 1:
            return [batch]
        return [batch.select(np.arange(1)), batch.select(np.arange(1, len(batch)))]

    def keep(self, key: tuple, frames: list, post_end: bool, holds_packet) -> list:
        """The frames of one push that belong to the segment; ``holds_packet(frame)``: does the frame
        contain the pushed packet (asked only for the stream's first packet at/after the end)."""
        st = self.state(key, post_end)
        first_post = post_end and not st.post_seen
        out = []
        for i, frame in enumerate(frames):
            if st.owned:
                out.append(frame)
            st.owned = (not post_end) or (first_post and i == 0 and not holds_packet(frame))
        if post_end:
            st.post_seen = True
            st.closed = not st.owned
        return out

    def finish(self, key: tuple, frames: list) -> list:
        """The frames a stream's decoder gives at the end of the file (owned while its pending frame is)."""
        st = self.streams.get(key)
        if st is None or st.closed:
            return []
        out = [frames[0]] if frames and st.owned else []
        st.closed = True
        return out

    def done(self, past_end: bool) -> bool:
        """True when reading further cannot give this segment another frame."""
        return past_end and all(st.closed for st in self.streams.values())
