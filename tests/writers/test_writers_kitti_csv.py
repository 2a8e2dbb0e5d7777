"""KITTI and CSV points: every capture written and read back without lidarpkt (NumPy reading the ``.bin``
files as KITTI's devkit does; DuckDB reading the CSV), equal to ``Frame.points()`` and to the Parquet
export row for row."""

from __future__ import annotations

import datetime
from pathlib import Path

import numpy as np
import pytest

from lidarpkt.errors import OutputError
from lidarpkt.writers import open_writer
from lidarpkt.writers.base import sensor_tag
from writers_cases import CASES, case, load  # noqa: F401 - the parametrised fixture

duckdb = pytest.importorskip("duckdb")
pytest.importorskip("pyarrow")


def _write(fmt, frames, out, cap, **options):
    with open_writer(fmt, out, capture=cap, **options) as w:
        for f in frames:
            w.write(f)
    return w.close()


def _utc_ns(line: str) -> int:
    """KITTI's ``YYYY-MM-DD HH:MM:SS.fffffffff`` (UTC) → ns since the epoch, parsed by the standard library."""
    head, nanos = line.split(".")
    dt = datetime.datetime.strptime(head, "%Y-%m-%d %H:%M:%S").replace(tzinfo=datetime.timezone.utc)
    return int(dt.timestamp()) * 1_000_000_000 + int(nanos)


def test_kitti_files_of_a_frame_equal_frame_points(tmp_path, case):
    cap, _, frames = load(case)
    files = _write("kitti", frames, tmp_path / "out.kitti", cap)
    last = {}  # (sensor folder, frame id) -> frame: a frame id met again replaces the file
    for f in frames:
        last[(f"{cap.stem}_{sensor_tag(f.sensor)}", f.frame_id)] = f
    bins = sorted(p for p in files if p.suffix == ".bin")
    assert len(bins) == len(last)
    for (folder, frame_id), f in last.items():
        seq = tmp_path / "out.kitti" / folder / "velodyne_points"
        data = np.fromfile(seq / "data" / f"{frame_id:010d}.bin", dtype="<f4").reshape(-1, 4)  # as the devkit reads
        pts = f.points()
        assert data.shape == (pts.size, 4)
        for k, name in enumerate("xyz"):
            np.testing.assert_array_equal(data[:, k], pts[name].astype(np.float32), err_msg=name)
        np.testing.assert_array_equal(data[:, 3], (pts["reflectivity"] / 255.0).astype(np.float32))
        assert np.all((data[:, 3] >= 0) & (data[:, 3] <= 1))
        np.testing.assert_array_equal(np.rint(data[:, 3] * 255).astype(np.uint8), pts["reflectivity"])
    for folder in {k[0] for k in last}:
        seq = tmp_path / "out.kitti" / folder / "velodyne_points"
        ids = sorted(i for (d, i) in last if d == folder)
        lines = {name: (seq / name).read_text().splitlines() for name in
                 ("timestamps.txt", "timestamps_start.txt", "timestamps_end.txt")}
        assert all(len(v) == len(ids) for v in lines.values())  # line k is the k-th .bin in name order
        for k, frame_id in enumerate(ids):
            f = last[(folder, frame_id)]
            valid = f.column_timestamp_ns[f.column_valid]
            start, end, forward = (_utc_ns(lines[n][k]) for n in
                                   ("timestamps_start.txt", "timestamps_end.txt", "timestamps.txt"))
            assert (start, end) == (valid.min(), valid.max())
            pts = f.points()
            if pts.size:  # the return nearest the +x axis, as KITTI's scanner facing forward
                azimuth = np.abs(np.arctan2(pts["y"], pts["x"]))
                assert forward in set(pts["timestamp_ns"][azimuth == azimuth.min()].tolist())
                assert start <= forward <= valid.max() + 1_000_000  # Ouster pixel offsets within the column's ms


def test_kitti_abort_leaves_nothing_and_segments_are_sequences_of_their_own(tmp_path):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-vlp16-dual"))
    with pytest.raises(RuntimeError):
        with open_writer("kitti", tmp_path / "k", capture=cap) as w:
            w.write(frames[0])
            raise RuntimeError("killed")
    assert list((tmp_path / "k").rglob("*")) == []
    for part, chunk in (("seg0000", frames[:3]), ("seg0001", frames[3:])):
        _write("kitti", chunk, tmp_path / "k", cap, part=part)
    tag = sensor_tag(frames[0].sensor)
    assert sorted(p.name for p in (tmp_path / "k").iterdir()) == [f"{cap.stem}_{tag}.seg0000", f"{cap.stem}_{tag}.seg0001"]
    assert len((tmp_path / "k" / f"{cap.stem}_{tag}.seg0001" / "velodyne_points" / "timestamps.txt")
               .read_text().splitlines()) == len(frames) - 3


CSV_TYPES = {"frame_id": "BIGINT", "frame_timestamp_ns": "BIGINT", "timestamp_ns": "BIGINT", "row": "USMALLINT",
             "column": "USMALLINT", "azimuth_deg": "DOUBLE", "return_slot": "UTINYINT", "range_m": "DOUBLE",
             "x": "FLOAT", "y": "FLOAT", "z": "FLOAT", "reflectivity": "UTINYINT", "signal": "USMALLINT",
             "near_ir": "USMALLINT", "capture": "VARCHAR", "sensor": "VARCHAR", "return_label": "VARCHAR"}


def _duckdb_rows(con, source: str):
    cols = ", ".join(f'"{c}"' for c in CSV_TYPES)
    return con.sql(f"SELECT {cols} FROM {source}").to_arrow_table()


def _duck_types() -> str:
    return "{" + ", ".join(f"'{k}': '{v}'" for k, v in CSV_TYPES.items()) + "}"


def test_csv_read_by_duckdb_equals_the_parquet_export_row_for_row(tmp_path, case):
    cap, _, frames = load(case)
    [csv] = _write("csv", frames, tmp_path / "pts.csv", cap)
    _write("parquet", frames, tmp_path / "ds", cap)
    con = duckdb.connect()
    got = _duckdb_rows(con, f"read_csv('{csv}', header=true, types={_duck_types()})")
    want = _duckdb_rows(con, f"read_parquet('{tmp_path}/ds/**/*.parquet', hive_partitioning=true, "
                         "hive_types_autocast=false)")  # a capture named by digits stays a name
    assert got.num_rows == want.num_rows == sum(f.points().size for f in frames)
    assert got.schema == want.schema
    for name in CSV_TYPES:  # column by column, nulls included, in the files' row order
        assert got.column(name).equals(want.column(name)), name
    if frames[0].signal is None:
        assert got.column("signal").null_count == got.num_rows
    header = csv.read_text().splitlines()[0].replace('"', "").split(",")
    assert header == ["capture", "sensor", "frame_id", "frame_timestamp_ns", "timestamp_ns", "row", "column",
                      "azimuth_deg", "return_slot", "return_label", "range_m", "x", "y", "z", "reflectivity",
                      "signal", "near_ir"]


def test_csv_one_file_per_frame_holds_that_frame(tmp_path):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-os1-dual"))
    files = _write("csv", frames, tmp_path / "by1.csv", cap, frames_per_file=1)
    tag = sensor_tag(frames[0].sensor)
    assert sorted(p.name for p in files) == sorted(f"{cap.stem}_{tag}_{f.frame_id:06d}.csv" for f in frames)
    con = duckdb.connect()
    for f in frames:
        path = tmp_path / "by1.csv" / f"{cap.stem}_{tag}_{f.frame_id:06d}.csv"
        rows = con.execute(f"SELECT frame_id, x, row FROM read_csv('{path}', types={_duck_types()})").fetchnumpy()
        pts = f.points()
        assert set(rows["frame_id"].tolist()) == {f.frame_id}
        np.testing.assert_array_equal(rows["x"], pts["x"].astype(np.float32))
        np.testing.assert_array_equal(rows["row"], pts["row"])
    assert not [p for p in (tmp_path / "by1.csv").iterdir() if p.name.startswith(".")]


def test_csv_bad_option_and_missing_folder(tmp_path):
    with pytest.raises(OutputError, match="--frames-per-file 0"):
        open_writer("csv", tmp_path / "x.csv", frames_per_file=0)
    with pytest.raises(OutputError, match="does not exist"):
        open_writer("csv", tmp_path / "no" / "x.csv")
    assert not list(Path(tmp_path).iterdir())
