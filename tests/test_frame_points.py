"""``Frame.points()``: one row per return, in one documented order, and every point output
(Parquet, LAS, PLY/PCD, PointCloud2, Foxglove, the velodyne_decoder layout) made of its rows."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from writers_cases import CASES, load


def _cases(*ids):
    return [pytest.param(c, id=c[0]) for c in CASES if c[0] in ids]


@pytest.mark.parametrize("case", _cases("veloview-vlp16", "nebula-rosbag2-dual", "os0-32-dual", "os1-32-g",
                                        "os1-64-fw20", "canned-os1-legacy", "canned-vlp16-dual"))
def test_points_one_row_per_return_with_the_image_values(case):
    _, _, frames = load(case)
    for f in frames:
        pts = f.points()
        mask = (f.range_mm > 0) & f.column_valid[None, None, :]
        assert pts.size == np.count_nonzero(mask)
        names = ["x", "y", "z", "range_mm", "reflectivity", "row", "column", "return_slot", "timestamp_ns"]
        names += [n for n in ("signal", "near_ir") if getattr(f, n) is not None]
        assert list(pts.dtype.names) == names
        slot, row, col = (pts[k].astype(np.int64) for k in ("return_slot", "row", "column"))
        # slot, then row, then column: the C order of [R, H, W]
        key = (slot * f.shape[1] + row) * f.shape[2] + col
        assert np.all(np.diff(key) > 0)
        assert mask[slot, row, col].all()
        assert np.array_equal(np.stack([pts["x"], pts["y"], pts["z"]], -1), f.xyz()[slot, row, col])
        assert np.array_equal(pts["range_mm"], f.range_mm[slot, row, col]) and pts["range_mm"].min() > 0
        assert np.array_equal(pts["reflectivity"], f.reflectivity[slot, row, col])
        offset = 0 if f.pixel_time_offset_ns is None else f.pixel_time_offset_ns[row, col]
        assert np.array_equal(pts["timestamp_ns"], f.column_timestamp_ns[col] + offset)
        if f.signal is not None:
            assert np.array_equal(pts["signal"], f.signal[slot, row, col])
            assert np.array_equal(pts["near_ir"], f.near_ir[row, col])
    f = frames[0]
    p32 = f.points(np.float32)
    assert p32.dtype["x"] == np.float32
    assert np.array_equal(p32["x"], f.xyz(np.float32)[..., 0][f.range_mm.astype(bool) & f.column_valid])


def _with_lost_columns(frame):
    """``frame`` with a third of its columns marked as not delivered but their ranges kept: every
    output must leave those pixels out (no sample), by the one mask ``Frame.has_return``."""
    valid = frame.column_valid.copy()
    valid[::3] = False
    return replace(frame, column_valid=valid)


@pytest.mark.parametrize("case", _cases("canned-vlp16-dual", "canned-os1-dual", "os1-32-g", "veloview-vlp16"))
def test_every_point_output_is_made_of_the_points_rows(case):
    pytest.importorskip("foxglove")
    from lidarpkt.view.messages import frame_points as foxglove_points
    from lidarpkt.writers.cloud import cloud_points
    from lidarpkt.writers.las import las_points
    from lidarpkt.writers.mcap.pointcloud import frame_points as organised_points
    from lidarpkt.writers.parquet import frame_points as parquet_points

    _, _, frames = load(case)
    f = _with_lost_columns(frames[len(frames) // 2])
    assert np.count_nonzero(f.range_mm[..., ~f.column_valid]) > 0  # the lost columns do hold ranges
    pts = f.points()
    assert pts.size == f.has_return().sum() < f.n_returns
    assert f.column_valid[pts["column"]].all()

    cols = parquet_points(f)
    assert np.array_equal(cols["row"], pts["row"]) and np.array_equal(cols["column"], pts["column"])

    cloud = cloud_points(f)
    assert cloud.size == pts.size
    assert np.array_equal(cloud["x"], pts["x"].astype(np.float32))

    fox = np.concatenate([foxglove_points(f, s, pts) for s in range(f.shape[0])])
    assert np.array_equal(fox["row"], pts["row"]) and np.array_equal(fox["range"], pts["range_mm"])

    grid = organised_points(f, pts)
    assert np.count_nonzero(~np.isnan(grid["x"])) == pts.size
    assert np.array_equal(np.sort(grid["range"][grid["range"] > 0]), np.sort(pts["range_mm"]))

    las = las_points(f)
    if f.shape[0] == 1:
        assert np.array_equal(las["row"], pts["row"]) and np.array_equal(las["xyz"][:, 0], pts["x"])
    else:  # a slot-1 row repeating slot 0's return is the same pulse: one LAS point
        repeat = (pts["return_slot"] == 1) & (f.range_mm[0, pts["row"], pts["column"]] == pts["range_mm"])
        assert las["row"].size == pts.size - np.count_nonzero(repeat)

    if f.sensor.vendor == "velodyne":
        from lidarpkt.vendors.velodyne.points import frame_points as velodyne_points

        vel = velodyne_points(f)
        assert f.column_valid[vel["column"]].all()
        assert np.array_equal(np.sort(vel["time_ns"]), np.sort(las["timestamp_ns"]))
