"""lidarpkt.open(path, workers=N): the frames, order, arrays, ids and extras of workers=1.

Every external capture and canned fixture is decoded whole in one thread, by the pipeline of
workers=2 (a decode thread beside the read-ahead), and by three threads over small segments (the
segment floor lowered so that these small files are cut into many segments, boundaries mid-frame
and beside position/IMU packets and fragment trains); a generated 10 s VLP-16 capture goes through
the default plan. Plus: closing early stops the threads, warnings reach the caller's thread, bad
``workers`` values are refused, MCAP files and bags take the pipeline.
"""

from __future__ import annotations

import os
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import UsageError
from lidarpkt.pipeline import parallel, processes
from lidarpkt.errors import UnknownSensorError
from lidarpkt.pipeline.reader import FrameReader

from conftest import REPO_ROOT, external
from test_segments import ARRAYS, CANNED_NAMES, OUSTER_EXTERNAL, VELODYNE_EXTERNAL

sys.path.insert(0, str(REPO_ROOT / "benchmarks"))

CANNED = REPO_ROOT / "lidarpkt" / "fixtures" / "canned"
# the captures the segment tests cut, plus the legacy OS-1-64 capture (its metadata has another name)
EXTERNAL = OUSTER_EXTERNAL + ["ouster-sdk/OS-1-64_1024x10_fw20"] + VELODYNE_EXTERNAL

def _capture(name: str) -> tuple[Path, Path | None]:
    path = CANNED / f"{name}.pcap" if name in CANNED_NAMES else external(f"{name}.pcap")
    md = path.with_suffix(".json")
    if name.endswith("OS-1-64_1024x10_fw20"):
        md = path.with_name("OS-1-64_sensor_config_reduced.json")
    return path, (md if md.exists() else None)


def _frames(path, md, **options) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # damaged test captures warn alike in one thread and in two
        return list(lidarpkt.open(path, metadata=md, **options))


def _assert_same(one: list, two: list, where: str) -> None:
    assert len(one) == len(two) > 0, (where, len(one), len(two))
    for i, (a, b) in enumerate(zip(one, two)):
        at = f"{where} frame {i}"
        assert a.frame_id == b.frame_id, (at, a.frame_id, b.frame_id)
        for name in ARRAYS:
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None) == (y is None), (at, name)
            if x is not None:
                assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), (at, name)
        assert (a.partial, a.counters, a.return_labels, a.timestamp_ns) == \
               (b.partial, b.counters, b.return_labels, b.timestamp_ns), at
        assert (str(a.sensor.source), a.sensor.model, a.sensor.return_mode) == \
               (str(b.sensor.source), b.sensor.model, b.sensor.return_mode), at
        assert str(a.sensor.describe()) == str(b.sensor.describe()), at
        assert set(a.extra) == set(b.extra), at
        for k in a.extra:
            assert np.array_equal(a.extra[k], b.extra[k]), (at, k)
    # one SensorInfo object per sensor and mode, as the single-threaded reader gives
    assert len({id(f.sensor) for f in one}) == len({id(f.sensor) for f in two}), where


@pytest.fixture
def small_segments(monkeypatch):
    """Cut even the small test captures: segments of ~40 kB (a few VLP-16 frames or part of an Ouster frame; 4 kB at the least)."""
    monkeypatch.setattr(parallel, "MIN_SEGMENT_BYTES", 4_000)
    monkeypatch.setattr(parallel, "MAX_SEGMENT_BYTES", 40_000)


@pytest.mark.parametrize("name", CANNED_NAMES + EXTERNAL)
def test_two_and_three_workers_give_the_frames_of_one(name, small_segments, monkeypatch):
    path, md = _capture(name)
    one = _frames(path, md, read_ahead=False)
    for workers in (2, 3):  # forked processes over the segments
        reader = lidarpkt.open(path, metadata=md, workers=workers)
        if path.stat().st_size > 20_000:  # duplicate_id holds two datagrams: nothing to cut
            assert isinstance(reader, parallel.ParallelFrameReader) and reader.processes and len(reader.segments) >= 2
        reader.close()
        _assert_same(one, _frames(path, md, workers=workers), f"{path.name} {workers} processes")
    with monkeypatch.context() as m:  # where no process can be forked: the pipeline, and threads over segments
        m.setattr(processes, "can_fork", lambda: False)
        reader = lidarpkt.open(path, metadata=md, workers=2)
        assert isinstance(reader, parallel.PipelinedFrameReader)
        reader.close()
        _assert_same(one, _frames(path, md, workers=2), f"{path.name} pipeline")
        _assert_same(one, _frames(path, md, workers=3), f"{path.name} threads")


@pytest.mark.parametrize("ring", [1 << 20, 40_000])
def test_frames_kept_or_dropped_through_a_small_ring(ring, small_segments, monkeypatch):
    """The caller may drop each frame (the workers then wait for ring space) or keep them all (a worker whose
    ring is full while the caller waits for it sends the frame's bytes through the pipe): the same frames;
    a frame's arrays stay valid after the reader is closed and the workers are gone."""
    monkeypatch.setattr(processes, "RING_BYTES", ring)
    path, md = _capture("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10")
    one = _frames(path, md, read_ahead=False)
    kept = _frames(path, md, workers=2)
    _assert_same(one, kept, "kept")
    streamed = []
    for frame in lidarpkt.open(path, metadata=md, workers=2):
        streamed.append(frame.range_mm.copy())
    assert len(streamed) == len(one) and all(np.array_equal(a, f.range_mm) for a, f in zip(streamed, one))


def test_default_workers_by_capture_size(small_segments, monkeypatch):
    """workers=None: one thread for a small capture, processes (up to 4, no more than the idle CPUs) for a large
    pcap; one thread when fewer than MIN_DEFAULT_WORKERS (3) CPUs are idle, in a daemonic process (a Dask
    worker) or when the capture is a bag. The forking path is exercised here with the minimum lowered to 2."""
    path, md = _capture("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10")
    assert isinstance(lidarpkt.open(path, metadata=md), FrameReader)
    monkeypatch.setattr(parallel, "PARALLEL_MIN_BYTES", 100_000)
    monkeypatch.setattr(parallel, "_load_average", lambda: 0.0)  # an idle machine
    cpus = len(os.sched_getaffinity(0))
    if cpus < parallel.MIN_DEFAULT_WORKERS:  # two cores: one thread, however idle
        assert isinstance(lidarpkt.open(path, metadata=md), FrameReader)
    monkeypatch.setattr(parallel, "MIN_DEFAULT_WORKERS", 2)
    reader = lidarpkt.open(path, metadata=md)
    if cpus > 1:
        assert isinstance(reader, parallel.ParallelFrameReader) and reader.processes
        assert reader.workers == min(cpus, parallel.MAX_DEFAULT_WORKERS)
        _assert_same(_frames(path, md, read_ahead=False), list(reader), "default")
    reader.close()
    monkeypatch.setattr(parallel, "_load_average", lambda: cpus - 1.0)  # one CPU idle: one thread
    assert isinstance(lidarpkt.open(path, metadata=md), FrameReader)
    monkeypatch.setattr(parallel, "_load_average", lambda: 0.0)
    monkeypatch.setattr(processes, "can_fork", lambda: False)
    assert isinstance(lidarpkt.open(path, metadata=md), FrameReader)
    monkeypatch.setattr(processes, "can_fork", lambda: True)
    assert isinstance(lidarpkt.open(external("nebula/vlp16/1673400471837873222")), FrameReader)


@pytest.mark.parametrize("name", ["vlp16-strongest", "os1-64-dual"])
def test_options_pass_through(name, small_segments):
    path, md = _capture(name)
    opts = {"include_partial": False, "batch_packets": 7}
    one = _frames(path, md, **opts)
    two = _frames(path, md, workers=3, **opts)
    _assert_same(one, two, path.name)
    assert not any(f.partial for f in two)


def test_default_plan_on_a_generated_vlp16_capture(tmp_path):
    import bench_velodyne

    path = tmp_path / "vlp16_10s.pcap"
    bench_velodyne.build(path, 10.0, mode="dual")
    reader = lidarpkt.open(path, workers=3)
    assert isinstance(reader, parallel.ParallelFrameReader) and len(reader.segments) >= 2
    two = list(reader)
    one = _frames(path, None)
    _assert_same(one, two, path.name)
    assert reader.stats.frames == len(two)
    assert reader.stats.packets_of("velodyne", "data") >= sum(int((f.extra["packet_index"] >= 0).any()) for f in one)


@pytest.mark.parametrize("workers", [2, 3])
def test_close_early_stops_the_threads(workers, small_segments):
    path, md = _capture("veloview/vlp-16-test-90deg-1-50-frames")
    before = threading.active_count()
    reader = lidarpkt.open(path, metadata=md, workers=workers, read_ahead=True)
    first = next(reader)
    assert first.frame_id == 0
    reader.close()
    reader.close()  # idempotent
    deadline = time.monotonic() + 10
    while threading.active_count() > before and time.monotonic() < deadline:
        time.sleep(0.01)
    assert threading.active_count() == before
    for pid in reader._runner.pids:  # the worker processes are gone, and reaped
        with pytest.raises(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)
    assert first.range_mm.sum() > 0  # a frame from the shared ring outlives its worker
    with pytest.raises(StopIteration):
        next(reader)


def test_dropping_the_reader_ends_its_workers(small_segments):
    path, md = _capture("veloview/vlp-16-test-90deg-1-50-frames")
    reader = lidarpkt.open(path, metadata=md, workers=2)
    next(reader)
    pids = list(reader._runner.pids)
    del reader
    import gc

    gc.collect()
    for pid in pids:
        with pytest.raises(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)


@pytest.mark.parametrize("workers", [0, -1, 1.5, "2"])
def test_bad_workers_are_refused(workers):
    with pytest.raises(UsageError, match="workers"):  # a lidarpkt.errors exception, as every public error
        lidarpkt.open(CANNED / "vlp16-strongest.pcap", workers=workers)
    with pytest.raises(ValueError, match="workers"):
        FrameReader(CANNED / "vlp16-strongest.pcap", workers=2)


def test_small_capture_and_segment_option():
    """A capture too small to cut takes the pipeline even with 3 workers; a segment is read in one thread."""
    path = CANNED / "vlp16-strongest.pcap"
    assert isinstance(lidarpkt.open(path, workers=3), parallel.PipelinedFrameReader)  # below the segment floor
    seg = lidarpkt.containers.segments.plan_segments(path, 1 << 30)[0]
    assert isinstance(lidarpkt.open(path, workers=2, segment=seg), FrameReader)


@pytest.mark.parametrize("kind", ["rosbag2", "mcap"])
def test_the_pipeline_reads_every_container(kind, tmp_path):
    """MCAP files and bags cannot be cut, but the pipeline decodes them in a thread all the same."""
    from lidarpkt.cli import main

    if kind == "rosbag2":
        path = external("nebula/vlp16/1673400471837873222")
    else:  # an MCAP recording of the canned OS1-64 capture, its packets and metadata
        path = tmp_path / "os1.mcap"
        assert main(["decode", str(CANNED / "os1-64-dual.pcap"), "--metadata", str(CANNED / "os1-64-dual.json"),
                     "-o", str(path), "-q"]) == 0
    reader = lidarpkt.open(path, workers=2)
    assert isinstance(reader, parallel.PipelinedFrameReader)
    _assert_same(_frames(path, None), list(reader), kind)


def test_the_pipeline_warns_in_the_callers_thread(tmp_path):
    """Warnings of the decode thread (a skipped packet) and of the read-ahead thread inside it (a truncated
    capture) reach the caller's thread, once each, with the single-threaded reader's words, after the
    frames before them."""
    data = bytearray(external("veloview/vlp-16-test-90deg-1-50-frames.pcap").read_bytes())
    path = tmp_path / "cut.pcap"
    path.write_bytes(bytes(data[: len(data) - 700]))  # ends inside a record

    def run(workers):
        seen = []  # (category, message, the thread that showed it)
        with warnings.catch_warnings():  # restores showwarning too
            warnings.simplefilter("always")
            warnings.showwarning = lambda message, *a, **k: seen.append(
                (type(message), str(message), threading.current_thread().name))
            frames = list(lidarpkt.open(path, workers=workers, read_ahead=True))
        return frames, seen

    one, seen_one = run(1)
    two, seen_two = run(2)
    _assert_same(one, two, "truncated")
    assert seen_two == seen_one
    kinds = {k.__name__ for k, _, _ in seen_two}
    assert "TruncatedCaptureWarning" in kinds
    assert {name for _, _, name in seen_two} == {threading.current_thread().name}


def test_no_sensor_in_any_segment_raises(tmp_path, small_segments):
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.pcap import write_pcap

    path = tmp_path / "other.pcap"
    src, dst = Endpoint("10.0.0.1", 5000), Endpoint("10.0.0.2", 53)
    write_pcap(path, (Packet(i * 1000, src, dst, b"\x00" * 900) for i in range(200)))  # no lidar packet
    with pytest.raises(UnknownSensorError, match="no stream of a sensor lidarpkt decodes"):
        list(lidarpkt.open(path, workers=2))


def test_decode_and_analyze_take_workers(tmp_path, small_segments):
    """The CLI verbs that decode pass --workers to lidarpkt.open: the same NPZ and the same report."""
    from lidarpkt.cli import main

    path = str(external("veloview/vlp-16-test-90deg-1-50-frames.pcap"))
    assert isinstance(lidarpkt.open(path, workers=3), parallel.ParallelFrameReader)  # cut into segments
    for n in (1, 2, 3):
        assert main(["decode", path, "-o", str(tmp_path / f"w{n}.npz"), "--workers", str(n), "-q"]) == 0
    for n in (2, 3):
        with np.load(tmp_path / "w1.npz") as one, np.load(tmp_path / f"w{n}.npz") as two:
            assert one.files == two.files
            for k in one.files:
                np.testing.assert_array_equal(one[k], two[k], err_msg=k)
    reports = []
    for n in (1, 3):
        out = tmp_path / f"a{n}.json"
        assert main(["analyze", path, "--pixel", "7,100", "--workers", str(n), "-o", str(out), "-q"]) == 0
        reports.append(out.read_text())
    assert reports[0] == reports[1]


def test_parallel_does_not_import_source():
    """No import circle: the threads over segments get their reader factory from lidarpkt.pipeline.reader, which
    imports lidarpkt.pipeline.parallel, never the other way round (checked in a fresh interpreter)."""
    import subprocess

    code = ("import sys, lidarpkt.pipeline.parallel; "
            "print(sorted(m for m in sys.modules if m in ('lidarpkt.pipeline.reader', 'lidarpkt.pipeline.options')))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=REPO_ROOT)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.split() == ["['lidarpkt.pipeline.options']"]


def test_damage_mid_file_stops_three_workers_where_it_stops_one(tmp_path, small_segments):
    """The cuts of workers=N are found near their offsets, not by walking the records from the start, so
    later segments are decoded past a damaged record. Their frames are not yielded: the reader of the
    segment that holds the damage stops there, as the single-threaded reader does, with its warning."""
    import struct

    from lidarpkt.errors import TruncatedCaptureWarning

    data = bytearray(external("veloview/vlp-16-test-90deg-1-50-frames.pcap").read_bytes())
    off = 24
    while off < len(data) * 0.6:
        off += 16 + struct.unpack_from("<I", data, off + 8)[0]
    struct.pack_into("<I", data, off + 8, 0x7FFF0000)  # a captured length no record has
    path = tmp_path / "damaged.pcap"
    path.write_bytes(bytes(data))
    reader = lidarpkt.open(path, workers=3)
    assert isinstance(reader, parallel.ParallelFrameReader)
    assert any(s.start_offset > off for s in reader.segments)  # segments after the damage were planned
    for workers in (1, 3):
        with pytest.warns(TruncatedCaptureWarning, match=f"offset {off}"):
            got = list(lidarpkt.open(path, workers=workers))
        if workers == 1:
            one = got
    _assert_same(one, got, "damaged")
    assert 10 < len(one) < 45


def test_bench_stages_times_each_stage_of_the_pipeline():
    """benchmarks/bench_stages.py (what bounds workers=2) reads every frame and times each stage alone."""
    import bench_stages

    path, md = _capture("os1-64-dual")
    s = bench_stages.stages(path, str(md), "xyz32", repeat=1)
    assert s["frames"] == len(_frames(path, md))
    assert s["read"] > 0 and s["work"] > 0 and s["one thread"] > s["work"]
