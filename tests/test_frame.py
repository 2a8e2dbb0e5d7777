"""The shared Frame type: fixed azimuth grid, destaggering, stacking."""

import numpy as np
import pytest

from lidarpkt.errors import AnalysisError
from lidarpkt.core.frame import Frame
from lidarpkt.core.sequence import FrameStack
from lidarpkt.core.sensor import SensorInfo

from conftest import REPO_ROOT


def make_sensor(vendor="velodyne", grid=0.2, shift=None, rows=2):
    return SensorInfo(
        vendor=vendor, model="test", rows=rows, columns_per_frame=4, return_mode="strongest",
        return_labels=("strongest",), beam_altitude_deg=np.zeros(rows), beam_azimuth_deg=np.zeros(rows),
        grid_resolution_deg=grid, pixel_shift_by_row=shift,
    )


def make_frame(azimuth, valid=None, sensor=None, frame_id=0, partial=False):
    w = len(azimuth)
    rng = (np.arange(2 * w, dtype=np.uint32) + 1).reshape(1, 2, w)
    return Frame(
        sensor=sensor or make_sensor(), frame_id=frame_id, range_mm=rng,
        reflectivity=np.ones((1, 2, w), np.uint8), return_labels=("strongest",),
        column_valid=np.ones(w, bool) if valid is None else np.asarray(valid),
        column_timestamp_ns=np.arange(w, dtype=np.int64) * 1000 + 5,
        azimuth_deg=np.asarray(azimuth, float), pixel_time_offset_ns=np.zeros((2, w), np.int64),
        partial=partial,
    )


def test_on_grid_places_columns_in_bins_keeps_first_and_counts_collisions():
    # 90° bins: 10° and 20° collide in bin 0 (first kept); 200° goes to bin 2; 359.9° to bin 3.
    frame = make_frame([10.0, 20.0, 200.0, 359.9])
    grid = frame.on_grid(90.0)
    assert grid.shape == (1, 2, 4)
    assert grid.column_valid.tolist() == [True, False, True, True]
    assert grid.range_mm[0, :, 0].tolist() == [1, 5]  # column 0 (10°), not column 1
    assert grid.range_mm[0, :, 2].tolist() == [3, 7]
    assert grid.range_mm[0, :, 1].tolist() == [0, 0]
    assert grid.column_timestamp_ns.tolist() == [5, 0, 2005, 3005]
    assert grid.azimuth_deg[[0, 2, 3]].tolist() == [10.0, 200.0, 359.9]
    assert grid.counters.grid_collisions == 1


def test_on_grid_ignores_invalid_columns():
    frame = make_frame([10.0, 20.0], valid=[False, True])
    grid = frame.on_grid(90.0)
    assert grid.range_mm[0, :, 0].tolist() == [2, 4]
    assert grid.counters.grid_collisions == 0


def test_on_grid_rejects_resolution_not_dividing_360():
    with pytest.raises(AnalysisError):
        make_frame([0.0]).on_grid(0.7)


def test_destagger_matches_definition():
    shift = np.array([1, 3])
    frame = make_frame([0, 90, 180, 270], sensor=make_sensor("ouster", None, shift))
    img = np.arange(8).reshape(2, 4)
    out = frame.destaggered(img)
    for u in range(2):
        for c in range(4):
            assert out[u, (c + shift[u]) % 4] == img[u, c]


def test_stack_skips_partial_frames_and_checks_shapes():
    frames = [make_frame([0, 100, 200], frame_id=i, partial=(i == 0)) for i in range(3)]
    stack = FrameStack.from_frames(frames, resolution_deg=90.0)
    assert len(stack) == 2 and stack.frame_id.tolist() == [1, 2]
    assert stack.range_mm.shape == (2, 1, 2, 4)
    with pytest.raises(AnalysisError):
        FrameStack.from_frames([frames[0]])


def test_xyz_dtype_float32_and_a_bad_dtype():
    """xyz(numpy.float32) gives float32 points (VLP-16: the float64 ones rounded); any other dtype is a
    UsageError naming the two it takes."""
    import lidarpkt
    from lidarpkt.errors import UsageError

    frame = next(iter(lidarpkt.open(REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-dual.pcap")))
    p64, p32 = frame.xyz(), frame.xyz(np.float32)
    assert p32.dtype == np.float32 and np.array_equal(p32, p64.astype(np.float32))
    for bad in (np.float16, np.int32, "no such type"):
        with pytest.raises(UsageError, match="float64 or float32"):
            frame.xyz(bad)
