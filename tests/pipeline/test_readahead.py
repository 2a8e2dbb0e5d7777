"""Read-ahead (packets read by a background thread): same results as without the thread.

``lidarpkt.open(..., read_ahead=True)`` must give the frames (every field), their order, the
stats, the errors and the warnings of ``read_ahead=False``, at the same point of the stream;
abandoning the iteration must leave no thread.
"""

from __future__ import annotations

import dataclasses
import gc
import struct
import threading
import warnings

import numpy as np
import pytest

import lidarpkt
from lidarpkt.core.readahead import THREAD_NAME, ReadAhead
from lidarpkt.errors import UsageError, CaptureFormatError, DroppedPacketsWarning, SkippedPacketWarning, TruncatedCaptureWarning
from lidarpkt.core.packet import Endpoint, Packet
from lidarpkt.containers.pcap_reader import read_packets
from lidarpkt.writers.pcap import write_pcap, write_pcapng

OUSTER = [
    ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"),
    ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"),
    ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json"),
    ("rust-lidar-utils/ouster_example.pcap", "rust-lidar-utils/ouster_example.json"),
]
VLP16 = ["veloview/vlp-16-test-90deg-1-50-frames.pcap", "rust-lidar-utils/velodyne_vlp16.pcap"]


def _read_ahead_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == THREAD_NAME]


@pytest.fixture(autouse=True)
def _no_thread_left():
    yield
    gc.collect()
    assert not _read_ahead_threads()


def _same_value(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype
                and a.shape == b.shape and np.array_equal(a.view(np.uint8), b.view(np.uint8)))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same_value(a[k], b[k]) for k in a)
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return type(a) is type(b) and all(_same_value(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a) if f.name != "geometry")
    return a == b


def _assert_same_frames(fa, fb) -> None:
    assert len(fa) == len(fb)
    for a, b in zip(fa, fb):
        for f in dataclasses.fields(a):
            assert _same_value(getattr(a, f.name), getattr(b, f.name)), (a.frame_id, f.name)


def _both(path, **options):
    """(frames, FrameReader, warnings) without and with read-ahead."""
    out = []
    for ra in (False, True):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with lidarpkt.open(path, read_ahead=ra, **options) as reader:
                assert reader.read_ahead is ra
                frames = list(reader)
        out.append((frames, reader, [(type(w.message), str(w.message)) for w in caught]))
    return out


def _check_same(path, **options):
    (fa, ra, wa), (fb, rb, wb) = _both(path, **options)
    _assert_same_frames(fa, fb)
    assert ra.stats == rb.stats
    assert ra.reader.stats == rb.reader.stats
    assert wa == wb
    return fa


@pytest.mark.parametrize("pcap,meta", OUSTER)
@pytest.mark.parametrize("batch_packets", [4096, 7])
def test_ouster_frames_are_identical_with_read_ahead(ext, pcap, meta, batch_packets):
    frames = _check_same(ext(pcap), metadata=ext(meta), batch_packets=batch_packets)
    assert frames


@pytest.mark.parametrize("pcap", VLP16)
@pytest.mark.parametrize("batch_packets", [4096, 5])
def test_vlp16_frames_are_identical_with_read_ahead(ext, pcap, batch_packets):
    assert _check_same(ext(pcap), batch_packets=batch_packets)


def _vlp16_capture(path, n=3000, seed=1) -> None:
    from lidarpkt.vendors.velodyne import encode_data_packets

    rng = np.random.default_rng(seed)
    t_ns = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 1_327_104
    az = (np.rint((np.arange(n)[:, None] * 1327.104 + np.arange(12)[None, :] * 110.592) * 0.36) % 36000).astype(np.int64)
    dist = rng.integers(0, 7000, size=(n, 12, 32))
    refl = rng.integers(0, 120, size=(n, 12, 32))
    payload = encode_data_packets(az, dist, refl, (t_ns // 1000) % 3_600_000_000, "strongest")
    src, dst = Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368)
    other = Endpoint("10.0.0.9", 5000)
    packets = []
    for i in range(n):
        packets.append(Packet(int(t_ns[i]), src, dst, payload[i].tobytes()))
        if i % 500 == 0:  # an unrouted stream in between
            packets.append(Packet(int(t_ns[i]) + 1, other, dst, b"x" * 100))
    write_pcap(path, packets, udp_checksum=False)


def test_generated_capture_is_identical_with_read_ahead(tmp_path):
    path = tmp_path / "vlp16.pcap"
    _vlp16_capture(path)
    frames = _check_same(path, batch_packets=256)
    assert len(frames) > 3
    # and the XYZ of those frames
    (fa, _, _), (fb, _, _) = _both(path)
    for a, b in zip(fa, fb):
        assert np.array_equal(a.xyz().view(np.uint64), b.xyz().view(np.uint64))


def test_default_reads_ahead_only_for_large_pcap_files(tmp_path, ext):
    small = ext("rust-lidar-utils/velodyne_vlp16.pcap")
    assert lidarpkt.open(small).read_ahead is False
    assert lidarpkt.open(small, read_ahead=True).read_ahead is True
    big = tmp_path / "big.pcap"
    _vlp16_capture(big, n=8000)
    assert big.stat().st_size >= 8 << 20
    reader = lidarpkt.open(big)
    assert reader.read_ahead is ((__import__("os").cpu_count() or 1) > 1)
    assert not _read_ahead_threads()  # no thread before the first frame is asked for
    reader.close()


def _cut(path, tmp_path, cut_from_end=300):
    data = path.read_bytes()
    out = tmp_path / "cut.pcap"
    out.write_bytes(data[: len(data) - cut_from_end])
    return out


def test_truncated_capture_warns_at_the_same_point(tmp_path):
    """The TruncatedCaptureWarning comes after the packets before the cut: between the same frames."""
    full = tmp_path / "full.pcap"
    _vlp16_capture(full, n=800)
    path = _cut(full, tmp_path)
    results = []
    for ra in (False, True):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            # per frame: its id, partial, and the warnings seen by the time it came out
            events = [(f.frame_id, f.partial, len(caught)) for f in lidarpkt.open(path, read_ahead=ra, batch_packets=64)]
        results.append((events, [(type(w.message), str(w.message)) for w in caught]))
    assert results[0] == results[1]
    # then, at the end of the read, the one summary of what was not decoded (2 non-lidar packets here)
    assert [t for t, _ in results[0][1]] == [TruncatedCaptureWarning, DroppedPacketsWarning]
    assert results[0][0][-2][2] == 0 and results[0][0][-1][2] == 1  # before the last (partial) frame


def test_warning_is_raised_in_the_caller_as_an_error_filter_says(tmp_path):
    """A warning filter set in the caller's thread applies to the reader's warnings (re-emitted there)."""
    full = tmp_path / "full.pcap"
    _vlp16_capture(full, n=800)
    path = _cut(full, tmp_path)
    counts = []
    for ra in (False, True):
        n = 0
        with warnings.catch_warnings():
            warnings.simplefilter("error", TruncatedCaptureWarning)
            with pytest.raises(TruncatedCaptureWarning):
                with lidarpkt.open(path, read_ahead=ra, batch_packets=64) as reader:
                    for _ in reader:
                        n += 1
        counts.append((n, reader.stats.packets))
    assert counts[0] == counts[1]


def test_unsupported_link_type_warning_comes_at_the_same_point(tmp_path):
    """SkippedPacketWarning of the per-record path (records of a link type lidarpkt does not read),
    in the middle of the capture: seen between the same frames with and without read-ahead."""
    from lidarpkt.writers.framing import frames_for
    from lidarpkt.writers.pcap import Interface, write_pcapng_records

    src = tmp_path / "vlp16.pcap"
    _vlp16_capture(src, n=1500)
    packets = list(read_packets(src))
    records = [(0, p.timestamp_ns, f) for p in packets for f in frames_for(p)]
    records.insert(900, (1, records[900][1], b"\x00" * 60))  # link type 147, mid-stream
    path = tmp_path / "linktype.pcapng"
    write_pcapng_records(path, records, interfaces=[Interface(), Interface(link=147)])
    seen = []
    for ra in (False, True):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            reader = lidarpkt.open(path, read_ahead=ra, batch_packets=64)
            events = [(f.frame_id, f.partial, len(caught)) for f in reader]
        seen.append((events, [(type(w.message), str(w.message)) for w in caught], reader.reader.stats, reader.stats))
    assert seen[0] == seen[1]
    # the skipped record mid-stream, then at the end the one summary of what was not decoded
    assert [t for t, _ in seen[0][1]] == [SkippedPacketWarning, DroppedPacketsWarning]
    counts = [n for _, _, n in seen[0][0]]
    assert counts[0] == 0 and counts[-1] == 1  # mid-stream


def _bad_pcapng(tmp_path):
    """A pcapng whose section header has an impossible length: CaptureFormatError while reading."""
    path = tmp_path / "bad.pcapng"
    packets = [Packet(1_700_000_000_000_000_000 + i, Endpoint("192.168.1.201", 2368),
                      Endpoint("255.255.255.255", 2368), bytes(1206)) for i in range(3)]
    write_pcapng(path, packets)
    data = bytearray(path.read_bytes())
    struct.pack_into("<I", data, 4, 7)
    path.write_bytes(bytes(data))
    return path


def test_reader_error_in_the_thread_is_raised_in_the_caller_with_its_type(tmp_path):
    path = _bad_pcapng(tmp_path)
    errors = []
    for ra in (False, True):
        with pytest.raises(CaptureFormatError) as info:
            list(lidarpkt.open(path, read_ahead=ra))
        errors.append((type(info.value), str(info.value)))
    assert errors[0] == errors[1]


def test_not_a_capture_is_refused_as_before(tmp_path):
    path = tmp_path / "x.pcap"
    path.write_bytes(b"hello, this is not a capture at all")
    for ra in (False, True):
        with pytest.raises(lidarpkt.errors.UnsupportedContainerError):
            lidarpkt.open(path, read_ahead=ra)


@pytest.fixture(scope="module")
def longer_than_the_queue(tmp_path_factory):
    """A capture of more payload than the read-ahead queue holds (16 MB), so that the thread is still
    reading, blocked on the full queue, when the first frame comes out (with a shorter one, the
    compiled pcap walk could read it all before that, and the thread would be gone already)."""
    from lidarpkt.core.readahead import DEFAULT_MAX_BYTES

    path = tmp_path_factory.mktemp("readahead") / "vlp16.pcap"
    n = DEFAULT_MAX_BYTES // 1206 + 4000
    _vlp16_capture(path, n=n)
    return path


@pytest.mark.parametrize("how", ["break", "close", "with", "del"])
def test_abandoned_iteration_leaves_no_thread(longer_than_the_queue, how):
    path = longer_than_the_queue
    if how == "break":
        for _ in lidarpkt.open(path, read_ahead=True, batch_packets=32):
            assert len(_read_ahead_threads()) == 1
            break
    elif how == "close":
        reader = lidarpkt.open(path, read_ahead=True, batch_packets=32)
        next(reader)
        assert len(_read_ahead_threads()) == 1
        reader.close()
        reader.close()  # idempotent
        with pytest.raises(StopIteration):
            next(reader)
        with pytest.raises(UsageError, match="it was closed"):  # a loop after close() is a mistake, said
            list(reader)
    elif how == "with":
        with lidarpkt.open(path, read_ahead=True, batch_packets=32) as reader:
            next(reader)
            assert len(_read_ahead_threads()) == 1
    else:
        reader = lidarpkt.open(path, read_ahead=True, batch_packets=32)
        next(reader)
        assert len(_read_ahead_threads()) == 1
        del reader  # no reference cycle: finalised at once, without gc.collect()
    assert not _read_ahead_threads()


def test_read_ahead_queue_is_bounded_and_keeps_order():
    produced = []

    class B:
        def __init__(self, i):
            self.i = i
            self.payload = np.zeros(1000, np.uint8)

        def __len__(self):
            return 1

    def make():
        for i in range(50):
            produced.append(i)
            yield B(i)

    ra = ReadAhead(make, max_bytes=3000)
    first = next(ra)
    assert first.i == 0
    for _ in range(100):  # let the thread fill the queue
        if len(produced) >= 5:
            break
        threading.Event().wait(0.01)
    threading.Event().wait(0.05)
    assert len(produced) <= 6  # ≤ 3000 B queued (+ the one in hand and the one waiting to be queued)
    assert [b.i for b in ra] == list(range(1, 50))
    assert not ra.alive


def test_read_ahead_propagates_any_exception_after_the_batches_before_it():
    class Boom(RuntimeError):
        pass

    def make():
        yield from (np.zeros(3) for _ in range(4))
        raise Boom("here")

    got = []
    ra = ReadAhead(make)
    with pytest.raises(Boom, match="here"):
        for b in ra:
            got.append(b)
    assert len(got) == 4 and not ra.alive
