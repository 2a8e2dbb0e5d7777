"""Segments of a capture (lidarpkt.containers.segments): the frames of all segments are the whole file's.

Every external capture and canned fixture is cut small (boundaries mid-frame, beside VLP-16
position and Ouster IMU packets, next to the 12-fragment trains of the canned OS1-64 datagrams); the
frames of the segments, in segment order, must equal ``lidarpkt.open``'s frames of the whole
file array for array. VLP-16 ordinals (``frame_id``, ``extra["packet_index"]``) count from the
segment's reading start: they must differ from the whole file's by one constant per segment.
"""

from __future__ import annotations

import pickle
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from lidarpkt.containers.pcap_reader import read_packets
from lidarpkt.writers.pcap import write_pcapng
from lidarpkt.containers import Segment, plan_segments
from lidarpkt.containers.segments import _continues_fragment

from conftest import REPO_ROOT, external

CANNED = REPO_ROOT / "lidarpkt" / "fixtures" / "canned"
OUSTER_EXTERNAL = [
    "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10",
    "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10",
    "ouster-sdk/OS-1-32-G_v2.1.1_1024x10",
    "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10",
    "ouster-sdk/OS-2-32-U0_v2.0.0_1024x10",
    "ouster-sdk/crc_test",
    "ouster-sdk/duplicate_id",
    "rust-lidar-utils/ouster_example",
]
VELODYNE_EXTERNAL = [
    "veloview/vlp-16-test-90deg-1-50-frames",
    "rust-lidar-utils/velodyne_vlp16",
    "rust-lidar-utils/velodyne_example",
]
CANNED_NAMES = ["os1-64-dual", "os1-64-legacy", "vlp16-dual", "vlp16-last", "vlp16-strongest"]
ARRAYS = ("range_mm", "reflectivity", "signal", "near_ir", "flags", "column_valid", "column_timestamp_ns",
          "azimuth_deg", "measurement_id", "status", "encoder_count", "pixel_time_offset_ns")


def _capture(name: str) -> tuple[Path, Path | None]:
    if name in CANNED_NAMES:
        path = CANNED / f"{name}.pcap"
    else:
        path = external(f"{name}.pcap")
    md = path.with_suffix(".json")
    return path, (md if md.exists() else None)


def _frames(path, md, **options) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # damaged test captures warn alike whole and in segments
        return list(lidarpkt.open(path, metadata=md, **options))


def _assert_same_frame(a, b, where: str) -> None:
    for name in ARRAYS:
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), (where, name)
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), (where, name)
    assert a.partial == b.partial, where
    assert a.counters == b.counters, where
    assert a.return_labels == b.return_labels, where
    assert a.timestamp_ns == b.timestamp_ns, where
    assert str(a.sensor.source) == str(b.sensor.source) and a.sensor.model == b.sensor.model, where
    assert set(a.extra) == set(b.extra), where
    for k in a.extra:
        if k != "packet_index":
            assert np.array_equal(a.extra[k], b.extra[k]), (where, k)


def _check_union(path, md, segment_bytes: int, **options) -> list[Segment]:
    """The frames of the segments, in order, equal the whole file's (per sensor, in emission order)."""
    whole = _frames(path, md, **{**options, "read_ahead": False})
    segments = plan_segments(path, segment_bytes)
    assert segments[0].start_offset == 0 and segments[-1].end_offset == path.stat().st_size
    assert all(a.end_offset == b.start_offset for a, b in zip(segments, segments[1:]))
    union, owner = [], []
    for seg in segments:
        got = _frames(path, md, segment=seg, **options)
        union += got
        owner += [seg.index] * len(got)
    assert len(union) == len(whole), (len(union), len(whole))
    by_sensor: dict[str, list] = {}
    for k, f in enumerate(union):
        by_sensor.setdefault(str(f.sensor.source), []).append((f, owner[k]))
    want: dict[str, list] = {}
    for f in whole:
        want.setdefault(str(f.sensor.source), []).append(f)
    assert by_sensor.keys() == want.keys()
    for src, frames in want.items():
        offsets: dict[int, tuple[int, int]] = {}
        for i, (w, (u, seg)) in enumerate(zip(frames, by_sensor[src])):
            _assert_same_frame(w, u, f"{path.name} {src} frame {i} (segment {seg})")
            if w.sensor.vendor == "ouster":
                assert w.frame_id == u.frame_id
                continue
            # VLP-16 ordinals count from the segment's start: one constant offset per segment
            pi_w, pi_u = w.extra["packet_index"], u.extra["packet_index"]
            valid = pi_w >= 0
            assert np.array_equal(pi_w < 0, pi_u < 0)
            shift = (w.frame_id - u.frame_id, int((pi_w[valid] - pi_u[valid])[0]) if valid.any() else None)
            assert valid.sum() == 0 or np.all(pi_w[valid] - pi_u[valid] == shift[1])
            seen = offsets.setdefault(seg, shift)
            assert seen[0] == shift[0] and (None in (seen[1], shift[1]) or seen[1] == shift[1])
    return segments


@pytest.mark.parametrize("name", CANNED_NAMES + OUSTER_EXTERNAL + VELODYNE_EXTERNAL)
@pytest.mark.parametrize("segment_bytes", [40_000, 131_071])
def test_segments_union_equals_whole_file(name, segment_bytes):
    path, md = _capture(name)
    segments = _check_union(path, md, segment_bytes)
    if path.stat().st_size > 3 * segment_bytes:
        assert len(segments) >= 3  # boundaries really fell inside the capture


def test_segments_with_read_ahead_and_velodyne_options():
    path, _ = _capture("veloview/vlp-16-test-90deg-1-50-frames")
    _check_union(path, None, 97_000, read_ahead=True, cut_on_block=True)
    _check_union(path, None, 150_001, cut_angle_deg=90.0, include_partial=False)


def test_boundaries_beside_position_packets():
    # the VeloView capture interleaves 367 position packets (554-byte records) with 1902 data packets
    # (1248-byte records): some segments start with a position packet, some right after one
    path, _ = _capture("veloview/vlp-16-test-90deg-1-50-frames")
    data = path.read_bytes()
    caplen = lambda at: struct.unpack_from("<I", data, at + 8)[0]  # noqa: E731
    segments = plan_segments(path, 21_001)
    starts = [caplen(s.start_offset) for s in segments[1:]]
    after = [caplen(s.start_offset - 16 - 554) == 554 for s in segments[1:]]
    assert set(starts) == {554, 1248} and any(after)
    _check_union(path, None, 21_001)


def _record_offsets(data: bytes) -> list[int]:
    offs, off = [], 24
    while off + 16 <= len(data):
        offs.append(off)
        off += 16 + struct.unpack_from("<I", data, off + 8)[0]
    return offs


@pytest.mark.parametrize("segment_bytes", [30_011, 47_777])
def test_boundaries_never_split_a_fragment_train(segment_bytes):
    # the canned OS1-64 captures send each lidar datagram as 12 IPv4 fragments: a target offset lands
    # inside a train most of the time, and the plan moves the boundary to the next datagram's first fragment
    path, md = _capture("os1-64-dual")
    data = path.read_bytes()
    records = _record_offsets(data)
    segments = plan_segments(path, segment_bytes)
    moved = 0
    for prev, seg in zip(segments, segments[1:]):
        assert seg.start_offset in records
        assert not _continues_fragment(data[seg.start_offset + 16 : seg.start_offset + 16 + 64], 1)
        naive = next(o for o in records if o >= prev.start_offset + segment_bytes)
        moved += naive != seg.start_offset
        assert _continues_fragment(data[naive + 16 : naive + 16 + 64], 1) == (naive != seg.start_offset)
    assert moved >= len(segments) // 2
    _check_union(path, md, segment_bytes)


@pytest.mark.parametrize("name", ["os1-64-dual", "vlp16-dual"])
def test_pcapng_segments_start_after_section_and_interface_blocks(tmp_path, name):
    path, md = _capture(name)
    out = tmp_path / f"{name}.pcapng"
    write_pcapng(out, read_packets(path), mtu=1500)
    segments = plan_segments(out, 50_000)
    assert len(segments) >= 3 and all(s.container == "pcapng" for s in segments)
    assert all(s.pcapng_preamble == (0, segments[1].pcapng_preamble[1]) for s in segments[1:])
    _check_union(out, md, 50_000)


def test_segment_is_small_frozen_and_picklable():
    path, _ = _capture("vlp16-strongest")
    seg = plan_segments(path, 100_000)[1]
    assert pickle.loads(pickle.dumps(seg)) == seg
    with pytest.raises(Exception):
        seg.index = 3  # frozen


def test_containers_without_record_index_are_one_segment():
    bag = external("nebula/vlp16/1673400471837873222")
    (seg,) = plan_segments(bag, 10_000)
    assert seg.container == "rosbag2" and seg.count == 1
    assert len(_frames(bag, None, segment=seg)) == len(_frames(bag, None))


def test_whole_file_as_one_segment_is_the_whole_file():
    path, md = _capture("os1-64-dual")
    (seg,) = plan_segments(path, 1 << 30)
    got, want = _frames(path, md, segment=seg), _frames(path, md)
    assert len(got) == len(want)
    for a, b in zip(got, want):
        _assert_same_frame(a, b, "one segment")
        assert a.frame_id == b.frame_id


def test_plan_rejects_a_bad_size_and_a_non_capture(tmp_path):
    path, _ = _capture("vlp16-strongest")
    with pytest.raises(ValueError):
        plan_segments(path, 0)
    junk = tmp_path / "junk.pcap"
    junk.write_bytes(b"not a capture at all")
    with pytest.raises(lidarpkt.LidarpktError):
        plan_segments(junk, 1000)


@pytest.mark.parametrize("name", CANNED_NAMES + OUSTER_EXTERNAL + VELODYNE_EXTERNAL)
@pytest.mark.parametrize("segment_bytes", [9_000, 40_000, 131_071])
def test_resynchronised_cuts_are_the_walked_cuts(name, segment_bytes):
    """walk=False finds each cut by re-synchronising on the record headers after its nominal offset, and
    lands on exactly the record the walk from the start finds (fragment trains skipped alike)."""
    path, _ = _capture(name)
    walked = plan_segments(path, segment_bytes)
    synced = plan_segments(path, segment_bytes, walk=False)
    assert synced == walked
    if path.stat().st_size > 3 * segment_bytes and path.suffix == ".pcap":
        assert len(synced) >= 3


def _nested_capture(path: Path, ethertype: int) -> None:
    """UDP datagrams whose payloads are runs of 23 plausible 44-byte pcap records that end exactly where
    the payload does (a capture carried inside a capture), with ``ethertype`` in each inner record."""
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.pcap import write_pcap

    inner = struct.pack("<IIII", 1_700_000_000, 5, 28, 28) + bytes(12) + struct.pack(">H", ethertype) + bytes(14)
    src, dst = Endpoint("10.0.0.1", 5000), Endpoint("10.0.0.2", 2368)
    write_pcap(path, (Packet(1_700_000_000_000_000_000 + i * 1000, src, dst, inner * 23) for i in range(400)))


def test_resynchronising_skips_payload_bytes_that_look_like_headers(tmp_path):
    """Payloads full of plausible record headers whose records hold no Ethernet frame do not fool the
    re-synchronisation: the cut falls on the real record, as the walk from the start finds it."""
    path = tmp_path / "nested.pcap"
    _nested_capture(path, 0x0000)
    for segment_bytes in (10_001, 33_333):
        assert plan_segments(path, segment_bytes, walk=False) == plan_segments(path, segment_bytes)


def test_a_cut_inside_a_record_is_caught_by_the_segment_before_it(tmp_path, monkeypatch):
    """A capture carried inside a capture, Ethernet types and all, can pass for records: the cut then
    falls inside a datagram. The reader of the segment before it walks on past its end, sees that, and
    lidarpkt.open(workers=3) raises a CaptureFormatError naming workers=1 before yielding any frame
    of the segment after the cut."""
    from lidarpkt.pipeline import parallel
    from lidarpkt.errors import CaptureFormatError

    path = tmp_path / "nested.pcap"
    _nested_capture(path, 0x0800)
    walked, synced = plan_segments(path, 40_000), plan_segments(path, 40_000, walk=False)
    assert walked != synced  # fooled: the first cut is inside a datagram
    monkeypatch.setattr(parallel, "plan", lambda p, workers, frame_bytes=None: synced)
    reader = lidarpkt.open(path, workers=3)
    with pytest.raises(CaptureFormatError, match=rf"cut the capture at byte {synced[0].end_offset}.*workers=1"):
        list(reader)




def _modified_pcap(path: Path, packets) -> None:
    """``packets`` as a pcap of the modified format (magic a1b2cd34): 24-byte record headers."""
    from lidarpkt.writers.framing import frames_for

    out = bytearray(struct.pack("<IHHiIII", 0xA1B2CD34, 2, 4, 0, 0, 65535, 1))
    for p in packets:
        (frame,) = frames_for(p)
        sec, ns = divmod(p.timestamp_ns, 10**9)
        out += struct.pack("<IIII", sec, ns // 1000, len(frame), len(frame)) + struct.pack("<IHBB", 2, 0x0800, 0, 0) + frame
    path.write_bytes(bytes(out))


@pytest.mark.parametrize("variant", ["ns", "big-endian", "big-endian ns", "raw", "null", "modified"])
def test_resynchronised_cuts_in_every_pcap_variant(tmp_path, variant):
    """Nanosecond and big-endian files, raw-IP and loopback link types, and the 24-byte records of the
    modified format: the re-synchronised cuts are the walked ones."""
    from lidarpkt.writers.pcap import write_pcap

    packets = list(read_packets(REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-dual.pcap"))[:300]
    path = tmp_path / "v.pcap"
    if variant == "modified":
        _modified_pcap(path, packets)
    else:
        write_pcap(path, packets, nanosecond="ns" in variant, big_endian="big-endian" in variant,
                   link={"raw": "raw", "null": "null"}.get(variant, "ethernet"))
    for segment_bytes in (20_011, 50_000):
        walked = plan_segments(path, segment_bytes)
        assert len(walked) >= 4
        assert plan_segments(path, segment_bytes, walk=False) == walked


def test_open_takes_every_pcap_magic_the_reader_takes(tmp_path):
    """lidarpkt.open recognises the modified format (24-byte records) as the pcap reader does: the same frames."""
    path = tmp_path / "kuz.pcap"
    _modified_pcap(path, read_packets(REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-dual.pcap"))
    got, want = _frames(path, None), _frames(REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-dual.pcap", None)
    assert len(got) == len(want) > 0
    for a, b in zip(got, want):
        _assert_same_frame(a, b, "modified")
