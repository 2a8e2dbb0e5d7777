"""Rerun recordings of every capture, read back by Rerun's own reader: its dataframe API (a local Rerun
server holding the ``.rrd`` as a dataset, queried through DataFusion), not lidarpkt: one entry per frame
on the ``frame`` timeline, each with the frame's points (positions equal to ``Frame.points()``), and the
range image equal to the frame's ``range_mm``."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.errors import OutputError
from lidarpkt.writers import open_writer
from lidarpkt.writers.rerun import RerunFrames
from writers_cases import CASES, case, load  # noqa: F401 - the parametrised fixture

rr = pytest.importorskip("rerun", reason="rerun-sdk is not installed (pip install '.[rerun]')")
pytest.importorskip("datafusion", reason="Rerun's dataframe API needs datafusion (pip install '.[test]')")


def _write(frames, out, cap, **options):
    with open_writer("rrd", out, capture=cap, **options) as w:
        for f in frames:
            w.write(f)
    return w.close()


def read_rrd(path, index: str = "frame"):
    """The recording's rows on ``index`` as a pyarrow Table, by Rerun's dataframe API."""
    with rr.server.Server(datasets={"lidarpkt": [str(path)]}) as server:
        client = server.client()  # held while the query runs: DataFusion calls back into it
        dataset = client.get_dataset("lidarpkt")
        return dataset.reader(index=index).to_arrow_table()


def _entities(frames) -> dict[tuple, tuple[str, tuple[str, ...]]]:
    """Each sensor's entity name and slot labels as the module doc gives them: its vendor, then ``_2``...
    for further sensors of that vendor, in order of appearance; the frame's return labels."""
    out: dict[tuple, tuple[str, tuple[str, ...]]] = {}
    for f in frames:
        key = RerunFrames._key(f)
        if key not in out:
            n = sum(1 for k in out if k[0] == f.sensor.vendor)
            out[key] = (f.sensor.vendor if n == 0 else f"{f.sensor.vendor}_{n + 1}", f.return_labels)
    return out


def test_rrd_read_by_rerun_has_one_entry_per_frame_with_its_points(tmp_path, case):
    cap, _, frames = load(case)
    [path] = _write(frames, tmp_path / "x.rrd", cap)
    table = read_rrd(path)
    rows = {int(v): i for i, v in enumerate(table.column("frame").to_pylist())}
    for key, (name, labels) in _entities(frames).items():
        mine = {f.frame_id: f for f in frames if RerunFrames._key(f) == key}  # a frame id met again: the last
        for slot, label in enumerate(labels):
            column = table.column(f"/{name}/points/{label}:Points3D:positions").to_pylist()
            present = {fid for fid, i in rows.items() if column[i] is not None}
            assert present == set(mine), (name, label)  # one entry per frame, on the frame's id
            for fid, f in mine.items():
                pts = f.points()
                pts = pts[pts["return_slot"] == slot]
                got = np.asarray(column[rows[fid]], np.float32).reshape(-1, 3)
                assert got.shape == (pts.size, 3)  # the frame's point count
                want = np.column_stack([pts["x"], pts["y"], pts["z"]]).astype(np.float32)
                np.testing.assert_array_equal(got, want)
    assert len(table.column("sensor_time").to_pylist()) == table.num_rows


def test_rrd_range_image_and_colours(tmp_path):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-os1-dual"))
    [path] = _write(frames, tmp_path / "x.rrd", cap, color="reflectivity")
    table = read_rrd(path)
    f = frames[0]
    row = table.column("frame").to_pylist().index(f.frame_id)
    buffer = table.column("/ouster/range_image/strongest:DepthImage:buffer").to_pylist()[row][0]
    np.testing.assert_array_equal(np.frombuffer(bytes(buffer), np.uint32).reshape(f.shape[1:]),
                                  f.destaggered(f.range_mm)[0])  # as ouster-sdk displays it
    colours = table.column("/ouster/points/strongest:Points3D:colors").to_pylist()[row]
    pts = f.points()
    pts = pts[pts["return_slot"] == 0]
    assert len(colours) == pts.size
    rgba = np.asarray(colours, np.uint32)
    red, blue = rgba >> 24, (rgba >> 8) & 0xFF
    bright = pts["reflectivity"] >= 100  # the ramp's top (red) from reflectivity 100 up
    assert bright.any() and (~bright).any()
    assert np.all(red[bright] > blue[bright])
    assert np.all(blue[pts["reflectivity"] == 0] > red[pts["reflectivity"] == 0])


def test_rrd_is_whole_or_absent_and_bad_colour_is_an_error(tmp_path):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-vlp16-dual"))
    with pytest.raises(RuntimeError):
        with open_writer("rrd", tmp_path / "x.rrd", capture=cap) as w:
            w.write(frames[0])
            assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OutputError, match="--color hue: choose range or reflectivity"):
        open_writer("rrd", tmp_path / "y.rrd", color="hue")
    assert list(tmp_path.iterdir()) == []
