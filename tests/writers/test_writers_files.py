"""LAS/LAZ, PLY and PCD writers: every capture written and read back with laspy, plyfile and pypcd4
(not lidarpkt), equal to ``lidarpkt.open``: every return, XYZ to the precision of the format, counts
per frame, LAS return numbers agreeing with the dual slots, GPS time."""

from __future__ import annotations

import calendar

import numpy as np
import pytest

from lidarpkt.writers import open_writer
from writers_cases import CASES, case, load  # noqa: F401 - the parametrised fixture

laspy = pytest.importorskip("laspy")
plyfile = pytest.importorskip("plyfile")
pypcd4 = pytest.importorskip("pypcd4")


def _write(fmt, frames, out, cap, **options):
    with open_writer(fmt, out, capture=cap, **options) as w:
        for f in frames:
            w.write(f)
    return w.close()


def _las_expected(frames):
    """(sensor, frame_id, row, column, return_number, number_of_returns, x, y, z, reflectivity) of every LAS
    point the frames should give, from LAS's definition: the distinct returns of one pulse, nearest first.
    Sensors are numbered in order of appearance (``point_source_id``)."""
    out, sensors = [], {}
    for f in frames:
        sid = sensors.setdefault((f.sensor.vendor, f.sensor.source, f.sensor.serial), len(sensors))
        xyz = f.xyz()
        rng = np.where(f.column_valid, f.range_mm, 0).astype(np.int64)
        # per pixel, the slots in order of range (empty slots last), and which of them are distinct returns
        order = np.argsort(np.where(rng > 0, rng, np.iinfo(np.int64).max), axis=0, kind="stable")
        ranked = np.take_along_axis(rng, order, axis=0)
        new = (ranked > 0) & np.concatenate([np.ones_like(ranked[:1], bool), ranked[1:] != ranked[:-1]])
        count = new.sum(axis=0)
        number = np.cumsum(new, axis=0)
        for k in range(f.shape[0]):
            rows, cols = np.nonzero(new[k])
            s = order[k, rows, cols]
            out.append(np.column_stack([np.full(rows.size, sid), np.full(rows.size, f.frame_id), rows, cols,
                                        number[k, rows, cols], count[rows, cols], xyz[s, rows, cols],
                                        f.reflectivity[s, rows, cols]]).astype(np.float64))
    return _sorted(np.concatenate(out))


def _sorted(a):
    return a[np.lexsort(a[:, 4::-1].T)]


@pytest.mark.parametrize("fmt", ["las", "laz"])
def test_las_read_by_laspy_equals_lidarpkt_open(tmp_path, case, fmt):
    cap, _, frames = load(case)
    [path] = _write(fmt, frames, tmp_path / f"x.{fmt}", cap)
    las = laspy.read(path)
    assert las.header.version.major == 1 and las.header.version.minor == 4 and las.header.point_format.id == 6
    assert np.all(las.header.scales <= 0.001)  # 1 mm or better
    rn, nr = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    got = _sorted(np.column_stack([las.point_source_id, las["frame_id"], las["row"], las["column"], rn, nr,
                                   las.x, las.y, las.z, las.intensity]).astype(np.float64))
    exp = _las_expected(frames)
    assert len(got) == len(exp) == las.header.point_count
    np.testing.assert_array_equal(got[:, [0, 1, 2, 3, 4, 5, 9]], exp[:, [0, 1, 2, 3, 4, 5, 9]])
    np.testing.assert_allclose(got[:, 6:9], exp[:, 6:9], rtol=0, atol=0.5 * las.header.scales[0] + 1e-9)
    assert set(np.unique(nr)) <= ({1} if frames[0].shape[0] == 1 else {1, 2})


def test_las_return_numbers_on_a_dual_capture_are_not_trivial(tmp_path):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-vlp16-dual"))
    [path] = _write("las", frames, tmp_path / "x.las", cap)
    las = laspy.read(path)
    r = np.hypot(np.hypot(las.x, las.y), las.z)
    key = np.column_stack([las["frame_id"], las["row"], las["column"]])
    rn, nr = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    two = nr == 2
    assert two.sum() > 0 and (~two).sum() > 0
    order = np.lexsort((rn[two], *key[two].T[::-1]))
    pairs = r[two][order].reshape(-1, 2)  # (1 of 2, 2 of 2) of each pulse
    assert np.all(pairs[:, 0] < pairs[:, 1])
    # a pixel whose slots repeat one return is a single point 1 of 1, not two
    f = frames[0]
    same = (f.range_mm[0] == f.range_mm[1]) & (f.range_mm[0] > 0) & f.column_valid
    sel = las["frame_id"] == f.frame_id
    single = {(int(a), int(b)) for a, b, n in zip(las["row"][sel], las["column"][sel], nr[sel])
              if n == 1}
    assert same.sum() > 0 and all((int(a), int(b)) in single for a, b in zip(*np.nonzero(same)))


def test_las_gps_time_is_adjusted_standard_gps_time(tmp_path):
    from lidarpkt.writers.las import adjusted_gps_time

    # 2021-01-01T00:00:00Z: GPS − UTC = 18 s; GPS seconds since 1980-01-06 = 1293494418
    unix = calendar.timegm((2021, 1, 1, 0, 0, 0))
    assert adjusted_gps_time(np.array([unix * 10**9]))[0] == 1293494418 - 1e9
    assert adjusted_gps_time(np.array([calendar.timegm((2016, 6, 1, 0, 0, 0)) * 10**9]))[0] == \
        calendar.timegm((2016, 6, 1, 0, 0, 0)) - 315964800 + 17 - 1e9
    cap, _, frames = load(CASES[0])
    [path] = _write("las", frames, tmp_path / "x.las", cap)
    las = laspy.read(path)
    assert las.header.global_encoding.gps_time_type == laspy.header.GpsTimeType.STANDARD
    assert las.header.global_encoding.wkt  # LAS 1.4 R15 §2.4: set for point formats 6-10
    f = frames[0]
    sel = np.flatnonzero(las["frame_id"] == f.frame_id)
    t_ns = f.column_timestamp_ns[las["column"][sel]] + f.pixel_time_offset_ns[las["row"][sel], las["column"][sel]]
    np.testing.assert_allclose(las.gps_time[sel], adjusted_gps_time(t_ns), rtol=0, atol=1e-6)


def test_las_frames_per_file_groups_by_frame_id(tmp_path):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-vlp16-dual"))
    paths = _write("laz", frames, tmp_path / "out", cap, frames_per_file=3)
    assert len(paths) == len({f.frame_id // 3 for f in frames})
    [whole] = _write("laz", frames, tmp_path / "w.laz", cap)
    total = laspy.read(whole)
    parts = [laspy.read(p) for p in paths]
    assert sum(len(p.points) for p in parts) == len(total.points)
    for p in parts:
        assert len(set(np.unique(p["frame_id"]) // 3)) == 1


def _cloud_expected(f):
    xyz = f.xyz().astype(np.float32)
    keep = (f.range_mm > 0) & f.column_valid
    slot = np.nonzero(keep)[0]
    pts = np.column_stack([slot, xyz[keep]]).astype(np.float64)
    return pts[np.lexsort(pts.T[::-1])]


@pytest.mark.parametrize("fmt", ["ply", "pcd"])
def test_ply_pcd_read_by_their_libraries_equal_lidarpkt_open(tmp_path, case, fmt):
    cap, _, frames = load(case)
    paths = _write(fmt, frames, tmp_path / "out", cap)
    assert len(paths) == len(frames) == len(set(paths))
    for f, path in zip(frames, paths):
        assert f"_{f.frame_id:06d}." in path.name
        if fmt == "ply":
            data = plyfile.PlyData.read(path)["vertex"].data
            names = data.dtype.names
            cols = {n: data[n] for n in names}
        else:
            cloud = pypcd4.PointCloud.from_path(path)
            names = cloud.fields
            cols = {n: cloud.numpy((n,))[:, 0] for n in names}
        dual = f.shape[0] > 1
        assert tuple(names) == ("x", "y", "z", "intensity", "ring", "time") + (("return",) if dual else ())
        assert len(cols["x"]) == f.n_returns
        slot = cols["return"] if dual else np.zeros(len(cols["x"]))
        got = np.column_stack([slot, cols["x"], cols["y"], cols["z"]]).astype(np.float64)
        np.testing.assert_array_equal(got[np.lexsort(got.T[::-1])], _cloud_expected(f))
        assert cols["ring"].max() < f.shape[1] and cols["time"].min() >= 0 and cols["time"].max() < 0.2
