"""Segmented export equals whole-file export in every format that runs segments, frame ids included.

Captures are cut by a small ``segment_bytes`` so that boundaries fall mid-frame, beside VLP-16
position packets and between Ouster's IPv4 fragments; each format's own reader (pyarrow, laspy,
plyfile/pypcd4 bytes, NumPy) reads both exports, and they must agree row for row and file for file,
including VLP-16 ``frame_id`` (an ordinal of the whole file) and ``packet_index``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

from archive_cases import build_archive, output_files
from conftest import external
from lidarpkt.archive import export
from lidarpkt.archive.ordinals import CountTask, count_segment, start_ordinals

CUT = "150kB"


@pytest.fixture(scope="module")
def captures(tmp_path_factory) -> list[Path]:
    root = build_archive(tmp_path_factory.mktemp("seg") / "archive")
    veloview = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")  # position packets between data packets
    shutil.copy(veloview, root / veloview.name)
    return [root / "vlp16-dual.pcap", root / "vlp16-strongest.pcap", root / veloview.name,
            root / "os1-64-dual.pcap", root / "drive2" / "crc_test.pcap"]


def _both(captures, tmp_path, fmt, **opts):
    whole = export(captures, tmp_path / "whole", format=fmt, workers=1, **opts).to_pylist()
    cut = export(captures, tmp_path / "cut", format=fmt, workers=1, segment_bytes=CUT, **opts).to_pylist()
    assert all(r["status"] == "done" for r in whole + cut), [r["error"] for r in whole + cut]
    for w in whole:  # every capture really was cut, and the parts add up
        parts = [r for r in cut if r["key"].split("#")[0] == w["key"]]
        assert len(parts) >= 2 and all(r["part"] for r in parts), w["key"]
        for field in ("frames", "points", "lost_packets"):
            assert sum(r[field] for r in parts) == w[field], (w["key"], field)
    return tmp_path / "whole", tmp_path / "cut", cut


def _plain(table):
    for i, f in enumerate(table.schema):
        if pa.types.is_dictionary(f.type):
            table = table.set_column(i, f.name, table.column(i).cast(pa.string()))
    return table


def test_parquet_points_equal_row_for_row_including_frame_id(captures, tmp_path):
    whole, cut, _ = _both(captures, tmp_path, "parquet")
    a = _plain(ds.dataset(whole, format="parquet", partitioning="hive").to_table())
    b = _plain(ds.dataset(cut, format="parquet", partitioning="hive").to_table())
    key = [(k, "ascending") for k in ("capture", "sensor", "frame_id", "return_slot", "row", "column")]
    a, b = a.sort_by(key), b.sort_by(key)
    assert a.num_rows == b.num_rows > 0 and a.column_names == b.column_names
    for name in a.column_names:
        assert a.column(name).equals(b.column(name)), name
    vlp = np.array([c.startswith(("vlp", "veloview")) or "vlp-16" in c for c in a.column("capture").to_pylist()])
    ids = a.column("frame_id").to_numpy()
    assert vlp.any() and (~vlp).any() and ids[vlp].max() >= 49  # the VLP-16 ordinals of the whole file


def test_parquet_frames_layout_equal_frame_for_frame(captures, tmp_path):
    whole, cut, _ = _both(captures, tmp_path, "parquet", layout="frames")
    a = _plain(ds.dataset(whole, format="parquet", partitioning="hive").to_table())
    b = _plain(ds.dataset(cut, format="parquet", partitioning="hive").to_table())
    key = [(k, "ascending") for k in ("capture", "sensor", "frame_id")]
    a, b = a.sort_by(key), b.sort_by(key)
    assert a.num_rows == b.num_rows > 0
    for name in a.column_names:  # the range images, per-column arrays, extra (packet_index) and frame ids
        assert a.column(name).to_pylist() == b.column(name).to_pylist(), name


def test_las_points_equal_in_segment_order(captures, tmp_path):
    laspy = pytest.importorskip("laspy")
    whole, cut, rows = _both(captures, tmp_path, "las")
    for w in sorted((whole).glob("*.las")):
        want = laspy.read(w)
        parts = sorted(cut.glob(f"{w.stem}.seg*.las"))
        got = [laspy.read(p) for p in parts]
        assert len(parts) >= 2
        for dim in want.point_format.dimension_names:
            if dim in ("X", "Y", "Z"):
                continue
            joined = np.concatenate([np.asarray(g[dim]) for g in got])
            np.testing.assert_array_equal(joined, np.asarray(want[dim]), err_msg=f"{w.name}:{dim}")
        for axis in "xyz":  # each file has its own offset: equal to the precision of the scale
            joined = np.concatenate([np.asarray(g[axis]) for g in got])
            np.testing.assert_allclose(joined, np.asarray(want[axis]), rtol=0, atol=want.header.scales[0] * 1.01)


@pytest.mark.parametrize("fmt", ["ply", "pcd"])
def test_per_frame_files_are_the_same_files(captures, tmp_path, fmt):
    whole, cut, rows = _both(captures, tmp_path, fmt)
    fa, fb = output_files(whole), output_files(cut)
    assert sorted(fa) == sorted(fb) and len(fa) == sum(r["frames"] for r in rows)
    for rel in fa:
        assert fa[rel].read_bytes() == fb[rel].read_bytes(), rel


def test_npz_arrays_concatenate_to_the_whole_file(captures, tmp_path):
    whole, cut, _ = _both(captures, tmp_path, "npz")
    for w in sorted(whole.glob("*.npz")):
        parts = sorted(cut.glob(f"{w.stem}.seg*.npz"))
        with np.load(w) as want:
            got = [dict(np.load(p)) for p in parts]
            for name in ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "frame_id", "partial",
                         "lost_packets"):
                joined = np.concatenate([g[name] for g in got if name in g])
                np.testing.assert_array_equal(joined, want[name], err_msg=f"{w.name}:{name}")
            assert all(str(g["sensor_json"]) == str(want["sensor_json"]) for g in got), w.name  # the rate too


@pytest.mark.parametrize("index", [0, 2])  # VLP-16 dual; the VeloView capture (position packets)
def test_count_pass_gives_each_segment_the_whole_file_ordinals(captures, index):
    """Each segment read on its own from its counted start gives the whole file's frames: frame id,
    packet_index, sensor rate, one for one."""
    import warnings

    import lidarpkt
    from lidarpkt.archive.ordinals import renumber_from
    from lidarpkt.containers.segments import plan_segments

    path = captures[index]
    segments = plan_segments(path, 150_000)
    counts = [count_segment(CountTask(f"s{i}", str(path), s)) for i, s in enumerate(segments)]
    assert all(c.error is None for c in counts) and len(counts) > 2
    starts = start_ordinals(counts[:-1])
    assert starts[-1].packet_index == sum(c.packets for c in counts[:-1]) > 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        whole = [(f.frame_id, f.extra["packet_index"].tolist(), f.sensor.frequency_hz) for f in lidarpkt.open(path)]
        joined = []
        for seg, start in zip(segments, starts):
            renumber = renumber_from(start)
            joined += [(f.frame_id, f.extra["packet_index"].tolist(), f.sensor.frequency_hz)
                       for f in map(renumber.frame, lidarpkt.open(path, segment=seg))]
    assert joined == whole and whole[-1][0] == len(whole) - 1
    assert sum(n for c in counts for _, n in c.frames) == len(whole)


@pytest.mark.slow
def test_segmented_job_on_two_worker_processes_equals_in_process(captures, tmp_path):
    """workers=2: the count pass and the units on one LocalCluster of 2 processes, same files."""
    pytest.importorskip("distributed")
    from archive_cases import assert_same_outputs

    pick = captures[:2] + captures[3:4]
    one = export(pick, tmp_path / "one", format="parquet", workers=1, segment_bytes=CUT).to_pylist()
    two = export(pick, tmp_path / "two", format="parquet", workers=2, segment_bytes=CUT).to_pylist()
    assert [r["status"] for r in two] == ["done"] * len(one) and len(one) > 6
    assert_same_outputs(tmp_path / "one", tmp_path / "two")


def test_a_damaged_earlier_segment_fails_the_later_ones_with_its_reason():
    from lidarpkt.archive.ordinals import SegmentCount

    starts = start_ordinals([SegmentCount("a#seg0000", (("x", 3),), 10), SegmentCount("a#seg0001", error="a: bad"),
                             SegmentCount("a#seg0002", (("x", 1),), 5)])
    assert starts[1].frame_id == (("x", 3),) and starts[1].packet_index == 10
    assert starts[2] == starts[3] and "a: bad" in starts[2] and "a#seg0001" in starts[2]


def test_laz_frames_per_file_groups_by_whole_file_frame_id(captures, tmp_path):
    """With --frames-per-file 2, each segment's file holds frames of one group (ids 2k, 2k+1 of the
    whole file) and is named by the group's first id; the files together hold the whole file's points."""
    laspy = pytest.importorskip("laspy")
    pick = captures[:1] + captures[3:4]
    whole, cut, rows = _both(pick, tmp_path, "laz", frames_per_file=2)
    for rel, path in output_files(cut).items():
        ids = np.unique(np.asarray(laspy.read(path)["frame_id"]))
        first = int(rel.rsplit("_", 1)[1].split(".")[0])
        assert set(ids // 2) == {first // 2} and first % 2 == 0, rel
    want = np.concatenate([np.asarray(laspy.read(p)["frame_id"]) for p in output_files(whole).values()])
    got = np.concatenate([np.asarray(laspy.read(p)["frame_id"]) for p in output_files(cut).values()])
    np.testing.assert_array_equal(np.sort(got), np.sort(want))


def test_segments_whose_start_cannot_be_counted_are_set_apart_with_the_reason(captures, tmp_path):
    """The capture is damaged after planning (here: emptied): segment 0 still runs (it needs no
    count) and every later one is held back with the count's error, naming the file."""
    from lidarpkt.archive.engine import EngineOptions
    from lidarpkt.archive.export import _with_ordinals, plan_units, writer_options

    path = tmp_path / "drive.pcap"
    shutil.copy(captures[0], path)
    tasks, _, failed = plan_units([path], str(tmp_path / "out"), "npz", writer_options("npz"), segment_bytes=150_000)
    assert not failed and len(tasks) > 2
    path.write_bytes(b"")
    ready, unknown = _with_ordinals(tasks, tasks, EngineOptions(workers=1))
    assert [t.segment.index for t in ready] == [0]
    assert [t.segment.index for t in unknown] == list(range(1, len(tasks)))
    assert all(isinstance(t.ordinals, str) and str(path) in t.ordinals for t in unknown)
