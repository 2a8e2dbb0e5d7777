"""Parquet writer: every capture written in both layouts and read back with pyarrow and DuckDB
(not lidarpkt), equal to ``lidarpkt.open``; the frames layout round-trips a Frame exactly."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.errors import OutputError
from lidarpkt.writers import open_writer
from writers_cases import case, load  # noqa: F401 - the parametrised fixture

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
duckdb = pytest.importorskip("duckdb")


def _expected(frames) -> dict[str, np.ndarray]:
    """Every return of the frames, in frame order then slot, row, column (as the writer stores them)."""
    cols: dict[str, list] = {k: [] for k in ("sensor", "frame_id", "slot", "row", "column", "range_mm", "x", "y",
                                             "z", "refl", "signal", "near_ir", "t")}
    for f in frames:
        xyz = f.xyz()
        for s in range(f.shape[0]):
            rows, columns = np.nonzero((f.range_mm[s] > 0) & f.column_valid[None, :])
            cols["sensor"].append(np.full(rows.size, f.sensor.serial or f.sensor.source, object))
            cols["frame_id"].append(np.full(rows.size, f.frame_id))
            cols["slot"].append(np.full(rows.size, s))
            cols["row"].append(rows)
            cols["column"].append(columns)
            cols["range_mm"].append(f.range_mm[s, rows, columns])
            for k, axis in (("x", 0), ("y", 1), ("z", 2)):
                cols[k].append(xyz[s, rows, columns, axis].astype(np.float32))
            cols["refl"].append(f.reflectivity[s, rows, columns])
            nan = np.full(rows.size, np.nan)  # null in Parquet where the profile has no such field
            cols["signal"].append(nan if f.signal is None else f.signal[s, rows, columns].astype(float))
            cols["near_ir"].append(nan if f.near_ir is None else f.near_ir[rows, columns].astype(float))
            offset = 0 if f.pixel_time_offset_ns is None else f.pixel_time_offset_ns[rows, columns]
            cols["t"].append(f.column_timestamp_ns[columns] + offset)
    return {k: np.concatenate(v) if v else np.array([]) for k, v in cols.items()}


def _write(frames, out, cap, **options):
    with open_writer("parquet", out, capture=cap, **options) as w:
        for f in frames:
            w.write(f)
    return w.close()


def test_points_read_by_pyarrow_and_duckdb_equal_lidarpkt_open(tmp_path, case):
    cap, _, frames = load(case)
    paths = _write(frames, tmp_path / "ds", cap)
    assert len(paths) == 1 and paths[0].parent.name == f"capture={cap.name}"
    exp = _expected(frames)
    t = pq.read_table(tmp_path / "ds")  # hive partition discovered by pyarrow itself
    assert t.num_rows == sum(f.n_returns for f in frames) == exp["frame_id"].size
    assert set(t.column("capture").to_pylist()) == {cap.name}
    sensor = t.column("sensor").combine_chunks()
    np.testing.assert_array_equal(np.asarray(sensor.dictionary.to_pylist(), object)[sensor.indices.to_numpy()],
                                  exp["sensor"])
    for col, key in (("frame_id", "frame_id"), ("return_slot", "slot"), ("row", "row"), ("column", "column"),
                     ("reflectivity", "refl"), ("timestamp_ns", "t"), ("x", "x"), ("y", "y"), ("z", "z")):
        np.testing.assert_array_equal(t.column(col).to_numpy(), exp[key], err_msg=col)
    np.testing.assert_array_equal(np.round(t.column("range_m").to_numpy() * 1000).astype(np.int64), exp["range_mm"])
    for col in ("signal", "near_ir"):
        np.testing.assert_array_equal(t.column(col).to_numpy(zero_copy_only=False).astype(float), exp[col])
    if frames[0].sensor.vendor == "velodyne":
        assert t.column("signal").null_count == t.num_rows
    labels = t.column("return_label").combine_chunks()
    np.testing.assert_array_equal(np.asarray(labels.dictionary.to_pylist(), object)[labels.indices.to_numpy()],
                                  np.asarray(frames[0].return_labels, object)[exp["slot"]])
    # DuckDB, reading the files itself: counts per frame and the coordinates
    con = duckdb.connect()
    got = con.execute(f"SELECT sensor, frame_id, count(*) FROM read_parquet('{tmp_path}/ds/**/*.parquet', "
                      "hive_partitioning=true) GROUP BY ALL ORDER BY ALL").fetchall()
    want = sorted({(f.sensor.serial or f.sensor.source, f.frame_id): f.n_returns for f in frames}.items())
    assert [(s, i, n) for s, i, n in got] == [(s, i, n) for (s, i), n in want]
    xyz = con.execute(f"SELECT x, y, z FROM read_parquet('{tmp_path}/ds/**/*.parquet', file_row_number=true) "
                      "ORDER BY file_row_number").fetchnumpy()
    for k in "xyz":
        np.testing.assert_array_equal(xyz[k], exp[k])


def test_points_rows_equal_frame_points(tmp_path, case):
    """The points layout holds exactly the rows of ``Frame.points()``, in its order (x, y, z rounded
    to the file's float32, range in metres), read back by pyarrow."""
    cap, _, frames = load(case)
    _write(frames, tmp_path / "ds", cap)
    t = pq.read_table(tmp_path / "ds")
    assert t.num_rows == sum(f.points().size for f in frames)
    start = 0
    for f in frames:  # one frame at a time: a profile without signal has no such field in points()
        pts = f.points()
        rows = t.slice(start, pts.size)
        start += pts.size
        for name in ("row", "column", "return_slot", "timestamp_ns", "reflectivity"):
            np.testing.assert_array_equal(rows.column(name).to_numpy(), pts[name], err_msg=name)
            assert rows.column(name).type.to_pandas_dtype() == pts.dtype[name], name
        for name in "xyz":
            np.testing.assert_array_equal(rows.column(name).to_numpy(), pts[name].astype(np.float32), err_msg=name)
        np.testing.assert_array_equal(rows.column("range_m").to_numpy(), pts["range_mm"] / 1000.0)
        for name in ("signal", "near_ir"):
            if name in pts.dtype.names:
                np.testing.assert_array_equal(rows.column(name).to_numpy(), pts[name], err_msg=name)
            else:
                assert rows.column(name).null_count == rows.num_rows


FIELDS = ("range_mm", "reflectivity", "signal", "near_ir", "flags", "pixel_time_offset_ns", "column_valid",
          "column_timestamp_ns", "azimuth_deg", "measurement_id", "status", "encoder_count")


def test_frames_layout_round_trips_exactly(tmp_path, case):
    from lidarpkt.writers.parquet import read_frames

    cap, _, frames = load(case)
    _write(frames, tmp_path / "ds", cap, layout="frames")
    back = list(read_frames(tmp_path / "ds"))
    assert len(back) == len(frames)
    for a, b in zip(frames, back):
        assert (a.frame_id, a.partial, a.return_labels, a.counters) == (b.frame_id, b.partial, b.return_labels,
                                                                         b.counters)
        for name in FIELDS:
            x, y = getattr(a, name), getattr(b, name)
            assert (x is None) == (y is None), name
            if x is not None:
                assert x.dtype == y.dtype and x.shape == y.shape and np.array_equal(x, y), name
        assert a.extra.keys() == b.extra.keys()
        for k in a.extra:
            assert a.extra[k].dtype == b.extra[k].dtype and np.array_equal(a.extra[k], b.extra[k]), k
        assert a.sensor.describe() == b.sensor.describe() or _same_description(a.sensor, b.sensor)
        np.testing.assert_array_equal(a.xyz(), b.xyz())
    # one row per frame, the shape in its own columns, readable without lidarpkt
    t = pq.read_table(tmp_path / "ds")
    assert t.num_rows == len(frames)
    assert t.column("columns").to_pylist() == [f.shape[2] for f in frames]


def _same_description(a, b) -> bool:
    da, db = a.describe(), b.describe()
    return da.keys() == db.keys() and all(np.array_equal(np.asarray(da[k], object), np.asarray(db[k], object))
                                          for k in da)


def test_partial_output_is_hidden_and_removed_on_error(tmp_path):
    from writers_cases import CASES

    cap, _, frames = load(CASES[-1])
    out = tmp_path / "ds"
    with pytest.raises(RuntimeError):
        with open_writer("parquet", out, capture=cap, row_group_rows=10) as w:
            w.write(frames[0])
            hidden = [p for p in out.rglob("*") if p.is_file()]
            assert hidden and all(p.name.startswith(".") and p.name.endswith(".tmp") for p in hidden)
            raise RuntimeError("the job died")
    assert not list(out.rglob("*"))  # neither the temporary nor its empty partition folder


def test_segments_have_distinct_names_and_union_is_the_whole(tmp_path):
    from writers_cases import CASES

    cap, _, frames = load(CASES[0])
    whole = _write(frames, tmp_path / "whole", cap)
    parts = _write(frames[:1], tmp_path / "seg", cap, part="seg0000") + \
        _write(frames[1:], tmp_path / "seg", cap, part="seg0001")
    assert len({p.name for p in parts}) == 2
    a, b = pq.read_table(tmp_path / "whole"), pq.read_table(tmp_path / "seg")
    assert a.num_rows == b.num_rows and whole
    assert a.sort_by([("frame_id", "ascending")]).column("x").equals(b.sort_by([("frame_id", "ascending")]).column("x"))


def test_bad_layout_is_an_output_error(tmp_path):
    with pytest.raises(OutputError, match="--layout"):
        open_writer("parquet", tmp_path / "x", capture="a.pcap", layout="pixels")


def test_points_dataset_read_by_dask_dataframe(tmp_path):
    dd = pytest.importorskip("dask.dataframe")
    from writers_cases import CASES

    out = tmp_path / "ds"
    want = {}
    for c in (CASES[0], next(c for c in CASES if c[0] == "canned-os1-dual")):  # both vendors in one dataset
        cap, _, frames = load(c)
        _write(frames, out, cap)
        want[cap.name] = sum(f.n_returns for f in frames)
    df = dd.read_parquet(str(out))
    got = df.groupby("capture", observed=True).size().compute(scheduler="synchronous")
    assert {str(k): int(v) for k, v in got.items()} == want
    assert set(df.columns) >= {"x", "y", "z", "timestamp_ns", "return_label", "signal", "near_ir"}


def test_frames_layout_keeps_a_custom_velodyne_calibration(tmp_path):
    from conftest import external
    from lidarpkt.writers.parquet import read_frames

    import lidarpkt

    cap = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    cal = external("veloview/VLP-16.xml")
    frames = list(lidarpkt.open(cap, metadata=cal))[:3]
    stock = list(lidarpkt.open(cap))[:3]
    assert not np.array_equal(frames[1].xyz(), stock[1].xyz())  # the file's corrections change the points
    _write(frames, tmp_path / "ds", cap, layout="frames")
    for a, b in zip(frames, read_frames(tmp_path / "ds")):
        np.testing.assert_array_equal(a.xyz(), b.xyz())


def test_frames_layout_keeps_record_arrays_of_extra(tmp_path):
    """Zone-monitoring frames (ouster-sdk's OSF of an OS-0-128 with zones) carry ``zone_states``, a record
    array: its fields and values come back from the frames layout as they went in."""
    import lidarpkt
    from conftest import external
    from lidarpkt.writers.parquet import read_frames

    cap = external("ouster-sdk/single_frame_zm.osf")
    frames = list(lidarpkt.open(cap))
    assert frames[0].extra["zone_states"].dtype.names  # the case: a record array among the extras
    _write(frames, tmp_path / "ds", cap, layout="frames")
    back = list(read_frames(tmp_path / "ds"))
    assert len(back) == len(frames)
    for a, b in zip(frames, back):
        assert a.extra.keys() == b.extra.keys()
        for k in a.extra:
            assert a.extra[k].dtype == b.extra[k].dtype and np.array_equal(a.extra[k], b.extra[k]), k
