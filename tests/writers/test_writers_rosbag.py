"""ROS bags from ``decode`` on every capture, read back by ROS's own reader and by rosbags:

* the ROS 1 bag by Debian's ``python3-rosbag`` (ROS 1's reader, run by the system's ``/usr/bin/python3``
  in a subprocess: ``ros1_dump.py``): the topics, types and message counts of lidarpkt's MCAP output,
  ROS 1's MD5 sums, and every PointCloud2 holding ``lidarpkt.open``'s points of its frame;
* the rosbag2 folder, both storages, by rosbags: the very messages (topic, type, time, bytes) of
  lidarpkt's MCAP output, read by the ``mcap`` library;
* either bag by ``lidarpkt.open``: the capture's packets byte for byte with their times, and its frames.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import warnings
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from conftest import REPO_ROOT
from lidarpkt.errors import OutputError
from lidarpkt.writers import open_writer
from test_writers_mcap import _decode  # decode as the CLI runs it, in this process
from writers_cases import CASES, capture, case, load  # noqa: F401 - the parametrised fixture

rosbag2 = pytest.importorskip("rosbags.rosbag2")
mcap_reader = pytest.importorskip("mcap.reader")

SYSTEM_PYTHON = "/usr/bin/python3"
ROS1_MD5 = {  # ROS 1's own sums of the standard messages (roslib's, as `rosmsg md5` prints them)
    "sensor_msgs/PointCloud2": "1158d486dd51d683ce2f1be655c3c181", "sensor_msgs/Imu": "6a62c6daae103f4ff57a132d6f95cec2",
    "tf2_msgs/TFMessage": "94810edda583a504dfda3829e70d7eec", "std_msgs/String": "992ce8a1687cec8c8bd883ec73ca41d1",
    "velodyne_msgs/VelodyneScan": "50804fc9533a0e579e6322c04ae70566"}


def _md_args(md) -> list:
    return sum((["--metadata", m] for m in md or []), [])


def _mcap_messages(path: Path) -> list[tuple[str, str, int, bytes]]:
    with open(path, "rb") as fh:
        return sorted((ch.topic, schema.name, msg.log_time, bytes(msg.data))
                      for schema, ch, msg in mcap_reader.make_reader(fh).iter_messages())


def _ros1_dump(bag: Path, out: Path) -> dict:
    """What Debian's python3-rosbag reads of ``bag`` (see ros1_dump.py)."""
    if not Path(SYSTEM_PYTHON).is_file() or subprocess.run([SYSTEM_PYTHON, "-c", "import rosbag"],
                                                           capture_output=True, timeout=60).returncode:
        pytest.skip("Debian's python3-rosbag is not installed (apt-get install -y python3-rosbag); .ci/run installs it")
    out.mkdir()
    r = subprocess.run([SYSTEM_PYTHON, str(Path(__file__).with_name("ros1_dump.py")), str(bag), str(out)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    return json.loads((out / "index.json").read_text())


def _cloud_fields(entry: dict, data: bytes) -> dict[str, np.ndarray]:
    """A PointCloud2's fields as arrays, from its own PointField list (FLOAT32 7, UINT16 4, UINT32 6)."""
    types = {7: "<f4", 4: "<u2", 6: "<u4"}
    raw = np.frombuffer(data, np.uint8).reshape(-1, entry["point_step"])
    return {name: raw[:, off:off + np.dtype(types[dt]).itemsize].copy().view(types[dt])[:, 0]
            for name, off, dt, _ in entry["fields"]}


def test_ros1_bag_read_by_rosbag_holds_the_mcap_topics_and_every_cloud_the_frames_points(tmp_path, case):
    cap, md = capture(case)
    assert _decode(cap, *_md_args(md), "-o", tmp_path / "x.bag") == 0
    assert _decode(cap, *_md_args(md), "-o", tmp_path / "x.mcap") == 0
    dump = _ros1_dump(tmp_path / "x.bag", tmp_path / "dump")
    mcap = _mcap_messages(tmp_path / "x.mcap")
    want: dict[str, list] = {}
    for topic, msgtype, _, _ in mcap:
        entry = want.setdefault(topic, [msgtype.replace("/msg/", "/"), 0])
        entry[1] += 1
    assert dump["topics"] == want  # the same topics, types (ROS 1 names) and counts
    for msgtype, md5 in dump["md5"].items():
        assert md5 == ROS1_MD5.get(msgtype, md5), msgtype
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = list(lidarpkt.open(cap, metadata=md))
    by_stamp = {(f.timestamp_ns, f.sensor.vendor, slot): f for f in frames for slot in range(f.shape[0])}
    assert len(dump["clouds"]) == len(by_stamp) == sum(f.shape[0] for f in frames)
    for k, entry in enumerate(dump["clouds"]):
        topic = entry["topic"]
        slot = 0 if not topic[-1].isdigit() else int(topic[-1]) - 1  # /velodyne_points, /ouster/points2 ...
        vendor = "velodyne" if topic.startswith("/velodyne") else "ouster"
        f = by_stamp[(entry["stamp_ns"], vendor, slot)]
        assert (entry["height"], entry["width"]) == f.shape[1:]
        cloud = _cloud_fields(entry, (tmp_path / "dump" / f"cloud_{k}.bin").read_bytes())
        hit = ~np.isnan(cloud["x"])
        pts = f.points()
        pts = pts[pts["return_slot"] == slot]
        assert hit.sum() == pts.size and entry["is_dense"] == bool(hit.all())
        # the cloud's returns are the frame's points: the same (x, y, z, range, reflectivity), in display order
        got = np.column_stack([cloud["x"], cloud["y"], cloud["z"], cloud["range"], cloud["reflectivity"]])[hit]
        want_pts = np.column_stack([pts["x"].astype(np.float32), pts["y"].astype(np.float32),
                                    pts["z"].astype(np.float32), pts["range_mm"], pts["reflectivity"]])
        order = lambda a: a[np.lexsort(a.T[::-1])]  # noqa: E731
        np.testing.assert_array_equal(order(got.astype(np.float64)), order(want_pts.astype(np.float64)))
        assert cloud["range"][~hit].max(initial=0) == 0
        assert entry["seq"] == 0 and entry["frame_id"] in ("velodyne", "os_sensor", "velodyne_1", "os_sensor_1")


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_rosbag2_read_by_rosbags_gives_the_mcap_messages(tmp_path, case, storage):
    cap, md = capture(case)
    assert _decode(cap, *_md_args(md), "-o", tmp_path / "x.mcap") == 0
    assert _decode(cap, *_md_args(md), "-o", tmp_path / "x.rosbag2", "--storage", storage) == 0
    files = sorted(p.name for p in (tmp_path / "x.rosbag2").iterdir())
    assert files == ["metadata.yaml", f"x_0.{'db3' if storage == 'sqlite3' else 'mcap'}"]
    with rosbag2.Reader(tmp_path / "x.rosbag2") as reader:
        got = sorted((c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages())
        counts = {c.topic: c.msgcount for c in reader.connections}
        qos = {c.topic: c.ext.offered_qos_profiles for c in reader.connections}
    mcap = _mcap_messages(tmp_path / "x.mcap")
    assert got == mcap  # topic, type, time and bytes of every message
    assert counts == {t: sum(1 for m in mcap if m[0] == t) for t in {m[0] for m in mcap}}
    from lidarpkt.core.ros import QOS_SENSOR_DATA

    assert all(("durability: 1" in q) == (t in ("/tf_static", "/ouster/metadata")) for t, q in qos.items())
    assert qos.get("/velodyne_points", QOS_SENSOR_DATA) == QOS_SENSOR_DATA


def _packets(path) -> list[tuple[int, bytes]]:
    from lidarpkt.vendors.registry import open_packets

    return sorted((t, row.tobytes()) for b in open_packets(path).batches()
                  for t, row in zip(b.timestamp_ns.tolist(), b.payload))


@pytest.mark.parametrize("name", ["canned-vlp16-dual", "canned-os1-dual", "os0-128", "nebula-rosbag2-dual",
                                  "two-sensors-dual"])
def test_lidarpkt_open_on_either_bag_gives_the_capture(tmp_path, name):
    cap, md = capture(next(c for c in CASES if c[0] == name))
    outs = [tmp_path / "x.bag", tmp_path / "s.rosbag2", tmp_path / "m.rosbag2"]
    for out in outs:
        storage = ["--storage", "mcap"] if out.name == "m.rosbag2" else []
        assert _decode(cap, *_md_args(md), "-o", out, "--topics", "packets", *storage) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        direct = list(lidarpkt.open(cap, metadata=md))
        packets = _packets(cap)
        for out in outs:
            assert _packets(out) == packets, out  # byte for byte, with their times
            again = list(lidarpkt.open(out, metadata=md))
            assert len(again) == len(direct) > 0
            # each sensor's frames in order (two sensors' frames interleave by when each was complete)
            by_sensor = lambda frames: sorted(frames, key=lambda f: str(f.sensor.serial))  # noqa: E731 - stable
            for a, b in zip(by_sensor(direct), by_sensor(again)):
                assert (a.frame_id, a.partial, a.sensor.vendor) == (b.frame_id, b.partial, b.sensor.vendor)
                for field in ("range_mm", "reflectivity", "column_valid", "column_timestamp_ns", "azimuth_deg",
                              "signal", "near_ir", "measurement_id", "status"):
                    x, y = getattr(a, field), getattr(b, field)
                    assert (x is None and y is None) or np.array_equal(x, y), (out, field)


def test_bag_outputs_are_whole_or_absent_and_bad_options_are_one_line(tmp_path, capsys):
    cap, _, frames = load(next(c for c in CASES if c[0] == "canned-vlp16-dual"))
    for fmt, out, options in (("rosbag1", tmp_path / "x.bag", {}), ("rosbag2", tmp_path / "x.rosbag2", {}),
                              ("rosbag2", tmp_path / "y.rosbag2", {"storage": "mcap"})):
        with pytest.raises(RuntimeError):
            with open_writer(fmt, out, capture=cap, **options) as w:
                w.write(frames[0])
                assert [p.name for p in tmp_path.iterdir() if not p.name.startswith(".")] == []
                raise RuntimeError("killed")
        assert list(tmp_path.iterdir()) == []  # no temporary file or folder left
    with pytest.raises(OutputError, match="--storage sqlite: choose sqlite3 or mcap"):
        open_writer("rosbag2", tmp_path / "z.rosbag2", storage="sqlite")
    (tmp_path / "old.rosbag2").mkdir()
    (tmp_path / "old.rosbag2" / "metadata.yaml").write_text("an earlier bag")
    with pytest.raises(OutputError, match="exists already"):
        open_writer("rosbag2", tmp_path / "old.rosbag2", capture=cap)
    shutil.rmtree(tmp_path / "old.rosbag2")
    canned = REPO_ROOT / "lidarpkt" / "fixtures" / "canned" / "vlp16-dual.pcap"
    assert _decode(canned, "-o", tmp_path / "x.bag", "--storage", "mcap") == 2
    assert capsys.readouterr().err.strip().endswith("--storage mcap: only rosbag2 outputs have storages (-o OUT.rosbag2)")
    assert _decode(canned, "-o", tmp_path / "x.rosbag2", "--topics", "packets,clouds") == 2
    assert "--topics" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []
