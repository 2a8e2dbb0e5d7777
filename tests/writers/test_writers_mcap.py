"""MCAP from ``decode`` on every capture, read back with rosbags (the version our pins install, through
a rosbag2 folder as ``ros2 bag`` would make one): every message is yielded, every log time lies inside
the capture's span (first to last packet, read by dpkt or rosbags, not lidarpkt), no point sits at the
origin for a pixel without a return (NaN, ``is_dense`` false), frame ids per sensor, ``/tf_static``."""

from __future__ import annotations

import math
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from lidarpkt.errors import OutputError
from lidarpkt.writers import open_writer
from lidarpkt.writers.mcap import schemas
from lidarpkt.vendors.velodyne import ros as vros
from writers_cases import CASES, capture, case, load  # noqa: F401 - the parametrised fixture

rosbag2 = pytest.importorskip("rosbags.rosbag2")
mcap_reader = pytest.importorskip("mcap.reader")


def _decode(*argv) -> int:
    from lidarpkt.cli import main

    saved = warnings.showwarning
    try:
        return main(["decode", *map(str, argv), "-q"])
    finally:
        warnings.showwarning = saved


def _as_rosbag2(mcap_path: Path, folder: Path):
    """A rosbag2 folder holding the MCAP file, its metadata.yaml from the MCAP summary (mcap library)."""
    with open(mcap_path, "rb") as fh:
        summary = mcap_reader.make_reader(fh).get_summary()
    st = summary.statistics
    folder.mkdir()
    shutil.copy(mcap_path, folder / "b_0.mcap")
    topics = "".join(
        f"    - topic_metadata:\n        name: {ch.topic}\n        type: {summary.schemas[ch.schema_id].name}\n"
        f"        serialization_format: cdr\n        offered_qos_profiles: ''\n"
        f"      message_count: {st.channel_message_counts.get(cid, 0)}\n" for cid, ch in summary.channels.items())
    (folder / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 8\n  storage_identifier: mcap\n"
        f"  duration:\n    nanoseconds: {st.message_end_time - st.message_start_time}\n"
        f"  starting_time:\n    nanoseconds_since_epoch: {st.message_start_time}\n"
        f"  message_count: {st.message_count}\n  topics_with_message_count:\n{topics}"
        "  compression_format: ''\n  compression_mode: ''\n  relative_file_paths:\n    - b_0.mcap\n")
    return folder, st.message_count


def _rosbags_messages(mcap_path: Path, tmp_path: Path):
    folder, count = _as_rosbag2(mcap_path, tmp_path / "bag")
    with rosbag2.Reader(folder) as reader:
        msgs = [(c.topic, c.msgtype, t, raw) for c, t, raw in reader.messages()]
    return msgs, count


def _capture_span(cap: Path) -> tuple[int, int]:
    """First and last packet times of a capture, by dpkt (pcap) or rosbags (rosbag2 folder)."""
    if cap.is_dir():  # a VelodyneScan holds a rotation of packets, each with its receive stamp
        times = []
        with rosbag2.Reader(cap) as reader:
            for c, t, raw in reader.messages():
                msg = schemas.decode(c.msgtype, raw) if c.msgtype == vros.VELODYNE_SCAN else None
                times += [p.stamp.sec * 10**9 + p.stamp.nanosec for p in msg.packets] if msg else [t]
    else:
        import dpkt

        with open(cap, "rb") as fh:
            times = [round(ts * 1e9) for ts, _ in dpkt.pcap.UniversalReader(fh)]
    return min(times), max(times)


def test_decode_mcap_read_by_rosbags_every_message_in_span_no_origin_points(tmp_path, case):
    cap, md = capture(case)
    out = tmp_path / "x.mcap"
    assert _decode(cap, *sum((["--metadata", m] for m in md or []), []), "-o", out, "--topics", "packets,points") == 0
    msgs, count = _rosbags_messages(out, tmp_path)
    assert len(msgs) == count > 0  # rosbags yields every message
    start, end = _capture_span(cap)
    tolerance = 1000 if not cap.is_dir() else 0  # pcap times in µs, read by dpkt as floats
    assert all(start - tolerance <= t <= end + tolerance for _, _, t, _ in msgs), (start, end)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = list(lidarpkt.open(cap, metadata=md))
    clouds = [(topic, schemas.decode(ty, raw)) for topic, ty, _, raw in msgs if ty == schemas.POINTCLOUD2]
    assert len(clouds) == sum(f.shape[0] for f in frames)
    by_stamp = {(f.timestamp_ns, f.sensor.vendor, slot): (f, slot) for f in frames for slot in range(f.shape[0])}
    assert len(by_stamp) == len(clouds)
    for topic, pc in clouds:
        slot = 0 if topic[-1] == "s" else int(topic[-1]) - 1  # /velodyne_points, /ouster/points2 ...
        f, slot = by_stamp[(pc.header.stamp.sec * 10**9 + pc.header.stamp.nanosec, f_vendor(topic), slot)]
        offsets = {x.name: x.offset for x in pc.fields}
        raw = np.frombuffer(bytes(pc.data), np.uint8).reshape(-1, pc.point_step)
        xyz = np.stack([raw[:, offsets[k]:offsets[k] + 4].copy().view("<f4")[:, 0] for k in "xyz"], -1)
        rng = raw[:, offsets["range"]:offsets["range"] + 4].copy().view("<u4")[:, 0]
        no_return = np.isnan(xyz).all(axis=1)
        assert not np.isnan(xyz[~no_return]).any()
        valid = np.broadcast_to(f.column_valid, f.shape[1:])
        if f.sensor.vendor == "ouster":
            valid = f.destaggered(valid)
        assert np.array_equal(no_return, ((rng == 0) | ~valid.reshape(-1)))  # NaN exactly where no return
        assert no_return.sum() == np.count_nonzero((f.range_mm[slot] == 0) | ~f.column_valid)
        assert not np.any(np.all(xyz[~no_return] == 0, axis=1))  # nothing at the origin
        assert pc.is_dense == (not no_return.any())


def f_vendor(topic: str) -> str:
    return "velodyne" if topic.startswith("/velodyne") else "ouster"


def test_frame_ids_per_sensor_and_tf_static(tmp_path):
    case = next(c for c in CASES if c[0] == "two-sensors-dual")
    cap, md = capture(case)
    out = tmp_path / "x.mcap"
    assert _decode(cap, "--metadata", md[0], "--metadata", md[1], "-o", out, "--topics", "points",
                   "--frame-id", "lidar_a", "--frame-id", "lidar_b", "--base-frame", "base_link",
                   "--mount", "1,2,3,0,0,90", "--mount", "0,0,0.5,180,0,0") == 0
    msgs, count = _rosbags_messages(out, tmp_path)
    assert len(msgs) == count
    tf_msgs = [(t, schemas.decode(ty, raw)) for topic, ty, t, raw in msgs if topic == "/tf_static"]
    assert len(tf_msgs) == 2
    start, _ = _capture_span(cap)
    by_child = {}
    for t, m in tf_msgs:
        assert abs(t - start) <= 1000
        for tr in m.transforms:
            assert tr.header.frame_id == "base_link"
            by_child[tr.child_frame_id] = tr.transform
    assert set(by_child) == {"lidar_a", "lidar_b"}
    a, b = by_child["lidar_a"], by_child["lidar_b"]
    assert (a.translation.x, a.translation.y, a.translation.z) == (1.0, 2.0, 3.0)
    # yaw 90°: a rotation of 90° about z, quaternion (0, 0, sin 45°, cos 45°); roll 180°: (1, 0, 0, 0)
    h = math.sqrt(0.5)
    np.testing.assert_allclose([a.rotation.x, a.rotation.y, a.rotation.z, a.rotation.w], [0, 0, h, h], atol=1e-12)
    np.testing.assert_allclose([b.rotation.x, b.rotation.y, b.rotation.z, b.rotation.w], [1, 0, 0, 0], atol=1e-12)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        frames = list(lidarpkt.open(cap, metadata=md))
    order = list(dict.fromkeys(f.sensor.source for f in frames))  # sensors in order of appearance
    clouds = [schemas.decode(ty, raw) for topic, ty, _, raw in msgs if ty == schemas.POINTCLOUD2]
    names = {"lidar_a": order[0], "lidar_b": order[1]}
    got = [names[pc.header.frame_id] for pc in clouds]
    assert got == [f.sensor.source for f in frames for _ in range(f.shape[0])]


def test_frame_id_by_serial(tmp_path):
    case = next(c for c in CASES if c[0] == "canned-os1-dual")
    cap, md = capture(case)
    _, _, frames = load(case)
    out = tmp_path / "x.mcap"
    assert _decode(cap, "--metadata", md[0], "-o", out, "--topics", "points",
                   "--frame-id", f"{frames[0].sensor.serial}=roof") == 0
    msgs, _ = _rosbags_messages(out, tmp_path)
    assert {schemas.decode(ty, raw).header.frame_id for _, ty, _, raw in msgs} == {"roof"}
    assert not [m for m in msgs if m[0] == "/tf_static"]  # no base frame, no transforms


@pytest.mark.parametrize("argv, message", [
    (("--mount", "1,2,3,0,0,0"), "--base-frame"),
    (("--base-frame", "base", "--mount", "1,2,3"), "six numbers"),
    (("--frame-id", "a", "--frame-id", "a"), "--frame-id"),
])
def test_frame_option_errors_exit_2_with_no_output(tmp_path, capsys, argv, message):
    case = next(c for c in CASES if c[0] == "two-sensors-dual")
    cap, md = capture(case)
    out = tmp_path / "x.mcap"
    assert _decode(cap, "--metadata", md[0], "--metadata", md[1], "-o", out, *argv) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # no output, no temporary


def test_writer_abort_leaves_nothing_and_parts_have_distinct_names(tmp_path):
    _, _, frames = load(CASES[0])
    with pytest.raises(RuntimeError):
        with open_writer("mcap", tmp_path / "x.mcap", capture="a.pcap") as w:
            w.write(frames[0])
            raise RuntimeError("killed")
    assert list(tmp_path.iterdir()) == []
    with open_writer("mcap", tmp_path / "x.mcap", capture="a.pcap", part="seg0001") as w:
        w.write(frames[0])
    assert [p.name for p in w.close()] == ["x.seg0001.mcap"]
    with pytest.raises(OutputError, match="choose among"):
        open_writer("mcap", tmp_path / "y.mcap", topics=["clouds"])
