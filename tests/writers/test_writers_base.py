"""The writer interface: choice by suffix or name, temporary-then-rename for every format, segment
names, the old import paths of the moved modules, the light base import; NPZ on every capture read
by NumPy equal to ``lidarpkt.open``'s frames on their grid."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO_ROOT
from lidarpkt.errors import LidarpktError, OutputError
from lidarpkt.writers import FORMATS, format_from_suffix, open_writer
from writers_cases import CASES, case, load  # noqa: F401 - the parametrised fixture


def test_format_from_suffix_and_unknown_suffix():
    assert [format_from_suffix(f"x.{s}") for s in ("mcap", "npz", "parquet", "las", "LAZ", "ply", "pcd", "csv",
                                                   "kitti", "rrd", "bag", "rosbag2")] == \
        ["mcap", "npz", "parquet", "las", "laz", "ply", "pcd", "csv", "kitti", "rrd", "rosbag1", "rosbag2"]
    with pytest.raises(OutputError, match=r"-o x\.txt: unknown output type '\.txt'; the accepted suffixes are "
                                          r"\.mcap, \.npz, \.parquet, \.las, \.laz, \.ply, \.pcd, \.csv, \.kitti, "
                                          r"\.rrd, \.bag, \.rosbag2"):
        format_from_suffix("x.txt")
    with pytest.raises(LidarpktError, match="choose among mcap, npz, parquet, las, laz, ply, pcd, csv, kitti, rrd, "
                                            "rosbag1, rosbag2"):
        open_writer("xyz", "out")


def _hidden(path, root) -> bool:
    return any(part.startswith(".") for part in path.relative_to(root).parts)


def _out(tmp_path, fmt):
    return tmp_path / ("out" if FORMATS[fmt].directory else f"out{FORMATS[fmt].suffixes[0]}")


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_every_format_hides_partial_files_and_abort_removes_them(tmp_path, fmt):
    _, _, frames = load(next(c for c in CASES if c[0] == "canned-os1-dual"))
    with pytest.raises(RuntimeError):
        with open_writer(fmt, _out(tmp_path, fmt), capture="drive.pcap") as w:
            w.write(frames[0])
            w.write(frames[1])
            visible = [p for p in tmp_path.rglob("*") if p.is_file() and not _hidden(p, tmp_path)]
            # only per-frame formats have complete files yet (each renamed when its frame was done)
            assert len(visible) == (2 if fmt in ("ply", "pcd") else 0), visible
            raise RuntimeError("the job was killed")
    left = [p for p in tmp_path.rglob("*") if p.is_file()]
    assert not [p for p in tmp_path.rglob("*") if _hidden(p, tmp_path)], left  # no temporary left behind
    assert len(left) == (2 if fmt in ("ply", "pcd") else 0)


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_every_format_segments_have_distinct_names(tmp_path, fmt):
    _, _, frames = load(next(c for c in CASES if c[0] == "canned-vlp16-dual"))
    out = _out(tmp_path, fmt)
    names = []
    for k, chunk in enumerate((frames[:3], frames[3:])):
        with open_writer(fmt, out, capture="drive.pcap", part=f"seg{k:04d}") as w:
            for f in chunk:
                w.write(f)
        names += [p.relative_to(tmp_path) for p in w.close()]
    assert len(names) == len(set(names)) and names
    if fmt in ("ply", "pcd"):  # per-frame files are named by capture, sensor and frame id only
        assert sorted(p.name for p in names) == sorted(
            f"drive_{frames[0].sensor.source.replace(':', '-')}_{f.frame_id:06d}.{fmt}" for f in frames)
    assert not [p for p in tmp_path.rglob("*") if _hidden(p, tmp_path)]


def test_missing_folder_is_an_output_error(tmp_path):
    for fmt in FORMATS:
        with pytest.raises(OutputError, match="does not exist"):
            open_writer(fmt, tmp_path / "no" / "such" / f"x.{fmt}", capture="a.pcap")


def test_npz_read_by_numpy_equals_frames_on_grid(tmp_path, case):
    cap, _, frames = load(case)
    with open_writer("npz", tmp_path / "x.npz", capture=cap) as w:
        for f in frames:
            w.write(f)
    [path] = w.close()
    sensors = list(dict.fromkeys((f.sensor.vendor, f.sensor.model, f.sensor.source, f.shape[0], f.shape[1])
                                 for f in frames))
    with np.load(path) as d:
        for k, key in enumerate(sensors):
            prefix = "" if k == 0 else f"s{k}_"
            mine = [f.on_grid() for f in frames if (f.sensor.vendor, f.sensor.model, f.sensor.source,
                                                    f.shape[0], f.shape[1]) == key]
            assert d[prefix + "frame_id"].tolist() == [f.frame_id for f in mine]
            for name in ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "azimuth_deg"):
                np.testing.assert_array_equal(d[prefix + name], np.stack([getattr(f, name) for f in mine]), name)
            assert tuple(d[prefix + "return_labels"]) == mine[0].return_labels


def test_base_import_needs_no_export_library():
    code = ("import sys, lidarpkt, lidarpkt.writers, lidarpkt.writers.mcap.frames, lidarpkt.cli.decode\n"
            "heavy = {'pyarrow', 'laspy', 'plyfile', 'pypcd4', 'duckdb'} & set(sys.modules)\n"
            "print(sorted(heavy))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT, timeout=60)
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stderr


def test_decode_verb_writes_every_export_suffix(tmp_path, capsys):
    import warnings

    from lidarpkt.cli import main

    a, b = (REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / n for n in ("vlp16-dual.pcap", "vlp16-last.pcap"))

    def decode(*argv):
        saved = warnings.showwarning
        try:
            return main(["decode", str(a), str(b), "-q", *map(str, argv)])
        finally:
            warnings.showwarning = saved

    assert decode("-o", tmp_path / "pts.parquet") == 0
    assert sorted(p.name for p in (tmp_path / "pts.parquet").iterdir()) == \
        ["capture=vlp16-dual.pcap", "capture=vlp16-last.pcap"]
    assert decode("-o", tmp_path / "frames.parquet", "--layout", "frames") == 0
    from lidarpkt.writers.parquet import read_frames

    assert len(list(read_frames(tmp_path / "frames.parquet"))) == 14
    assert decode("-o", tmp_path / "all.las") == 0 and (tmp_path / "all.las").is_file()
    assert decode("-o", tmp_path / "laz", "--frames-per-file", "4") == 2  # a folder needs a suffix
    assert "the accepted suffixes are" in capsys.readouterr().err
    assert decode("-o", tmp_path / "by4.laz", "--frames-per-file", "4") == 0
    assert len(list((tmp_path / "by4.laz").iterdir())) == 2 * 2  # frame ids 0-3 and 4-6 of each input
    assert decode("-o", tmp_path / "x.laz", "--frames-per-file", "0") == 2
    assert "--frames-per-file 0" in capsys.readouterr().err
    assert decode("-o", tmp_path / "y.npz", "--layout", "frames") == 2
    assert "--layout frames: only Parquet" in capsys.readouterr().err
    assert decode("-o", tmp_path / "clouds.ply") == 0
    assert len(list((tmp_path / "clouds.ply").iterdir())) == 14
    assert not [p for p in tmp_path.rglob("*") if _hidden(p, tmp_path)]


def test_a_missing_export_library_names_the_extra(tmp_path):
    code = ("import sys\nsys.modules['plyfile'] = None  # as if the export extra were not installed\n"
            "from lidarpkt.writers import open_writer\nfrom lidarpkt.errors import OutputError\n"
            f"try:\n    open_writer('ply', {str(tmp_path / 'out')!r})\nexcept OutputError as e:\n    print(e)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT, timeout=60)
    assert "needs the Python package 'plyfile'" in r.stdout and "lidarpkt[export]" in r.stdout, r.stdout + r.stderr
    assert not (tmp_path / "out").exists()


def test_decode_python_api_has_the_cli_defaults(tmp_path):
    from lidarpkt.cli.decode import decode_captures

    cap = REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "os1-64-dual.pcap"
    md = REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "os1-64-dual.json"
    decode_captures([cap], tmp_path / "x.mcap", metadata=[md], base_frame="base", mount=["0,0,1,0,0,0"])
    from mcap.reader import make_reader

    with open(tmp_path / "x.mcap", "rb") as fh:
        topics = {c.topic for c in make_reader(fh).get_summary().channels.values()}
    assert {"/ouster/lidar_packets", "/ouster/points", "/ouster/points2", "/tf_static"} <= topics  # packets,points
    with pytest.raises(OutputError, match="no option colour"):
        decode_captures([cap], tmp_path / "y.npz", colour=True)
