"""``lidarpkt record --points`` and ``record --view`` on a live replay over loopback (real subprocesses).

* ``--points``: the MCAP gets one ``sensor_msgs/PointCloud2`` per frame and return slot, decoded
  off the receive path; every message deserializes with rosbags' stock ROS 2 type store, and the
  points equal those of ``lidarpkt.open``'s frames (:func:`lidarpkt.writers.mcap.pointcloud.frame_points`);
  their log times lie inside the span of the recorded packets. Ouster too, with the metadata
  fetched from ``replay --http`` (``record --sensor``) and written to ``/ouster/metadata``.
* ``--view``: a Foxglove client watching while recording; the recording loses 0 packets and
  holds the same packets as ``record`` alone on the same replay.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import lidarpkt
from conftest import external

pytest.importorskip("foxglove")
mcap_reader = pytest.importorskip("mcap.reader")

from test_view_capture import CANNED  # noqa: E402
from test_view_live import free_udp_ports  # noqa: E402
from view_client import FoxgloveClient, LidarpktProcess  # noqa: E402


def read_mcap(path):
    """``[(topic, log_time_ns, message)]`` deserialized by rosbags (stock ROS 2 Humble types, plus the
    schema text the file carries for the driver messages)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    out = []
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh)
        summary = reader.get_summary()
        extra = {}
        for schema in summary.schemas.values():
            if schema.name not in store.types:
                extra.update(get_types_from_msg(schema.data.decode(), schema.name))
        store.register(extra)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            out.append((channel.topic, message.log_time, store.deserialize_cdr(message.data, schema.name)))
    return out


def packet_log_times(messages) -> tuple[int, int]:
    times = [t for topic, t, _ in messages if "packets" in topic]
    return min(times), max(times)


def check_points(messages, frames, topics) -> None:
    from lidarpkt.writers.mcap.pointcloud import frame_points

    for slot, topic in enumerate(topics):
        clouds = [m for t, _, m in messages if t == topic]
        assert len(clouds) == len(frames), (topic, len(clouds), len(frames))
        for frame, cloud in zip(frames, clouds):
            want = frame_points(frame)[slot]
            assert (cloud.height, cloud.width) == want.shape
            assert bytes(cloud.data) == np.ascontiguousarray(want).tobytes()
    lo, hi = packet_log_times(messages)
    point_times = [t for topic, t, _ in messages if topic in topics]
    assert lo <= min(point_times) and max(point_times) <= hi


def record_replay(tmp_path, capture, *record_args, replay_args, name="rec", view_client=False, rate="4"):
    """Run ``record`` on fresh ports while ``replay`` sends ``capture``; returns (report, messages, client)."""
    data, position = free_udp_ports(2)
    out, report = tmp_path / f"{name}.mcap", tmp_path / f"{name}.json"
    client = None
    with LidarpktProcess(tmp_path / f"{name}.log", "record", "--bind", "127.0.0.1", "--port", str(data),
                         "--port", str(position), "-o", str(out), "--report", str(report), *record_args,
                         ready="listening on") as rec:
        try:
            if view_client:
                client = FoxgloveClient(f"ws://127.0.0.1:{rec.port_after('serving ws://')}")
            with LidarpktProcess(tmp_path / f"{name}-replay.log", "replay", str(capture), "--rate", rate,
                                 "--to", f"127.0.0.1:{data}", "--port-map", f"8308:{position}",
                                 *replay_args) as replay:
                assert replay.proc.wait(timeout=120) == 0, replay.log.read_text()
            assert rec.stop() == 0, rec.log.read_text()
        finally:
            if client is not None:
                client.close()
    return json.loads(report.read_text()), read_mcap(out), client


def test_record_points_vlp16_dual(tmp_path):
    capture = CANNED / "vlp16-dual.pcap"
    frames = list(lidarpkt.open(capture))
    summary, messages, _ = record_replay(tmp_path, capture, "--points", replay_args=[])
    assert summary["lost_total"] == 0 and summary["packets"] == 829  # 828 data + 1 position
    assert summary["points_frames_written"] == len(frames) and summary["packets_not_decoded"] == 0
    check_points(messages, frames, ["/velodyne_points", "/velodyne_points2"])


def test_record_points_in_the_frame_and_mount_asked_for(tmp_path):
    """record --points --frame-id/--base-frame/--mount: the clouds carry the frame id and /tf_static
    mounts it on the base frame (the same options and messages as decode's MCAP)."""
    capture = CANNED / "vlp16-dual.pcap"
    frames = list(lidarpkt.open(capture))
    summary, messages, _ = record_replay(tmp_path, capture, "--points", "--frame-id", "lidar_top",
                                         "--base-frame", "base_link", "--mount", "1.5,0,2,0,0,90", replay_args=[])
    assert summary["lost_total"] == 0 and summary["points_frames_written"] == len(frames)
    check_points(messages, frames, ["/velodyne_points", "/velodyne_points2"])
    clouds = [m for t, _, m in messages if t in ("/velodyne_points", "/velodyne_points2")]
    assert {c.header.frame_id for c in clouds} == {"lidar_top"}
    (tf,) = [m for t, _, m in messages if t == "/tf_static"]
    (mount,) = tf.transforms
    assert (mount.header.frame_id, mount.child_frame_id) == ("base_link", "lidar_top")
    v, q = mount.transform.translation, mount.transform.rotation
    assert (v.x, v.y, v.z) == (1.5, 0.0, 2.0)
    np.testing.assert_allclose([q.x, q.y, q.z, q.w], [0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)  # yaw 90°


def test_record_points_ouster_with_metadata_from_the_sensor(tmp_path):
    capture = external("ouster-sdk/OS-1-64_1024x10_fw20.pcap")
    metadata = external("ouster-sdk/OS-1-64_sensor_config_reduced.json")
    frames = list(lidarpkt.open(capture, metadata=str(metadata)))
    lidar, imu = free_udp_ports(2)
    md = lidarpkt.vendors.ouster.load_metadata(str(metadata))
    out, report = tmp_path / "os.mcap", tmp_path / "os.json"
    with LidarpktProcess(tmp_path / "http.log", "replay", str(capture), "--metadata", str(metadata),
                         "--http", "127.0.0.1:0", "--start-after-fetch", "1.5", "--to", f"127.0.0.1:{lidar}",
                         "--port-map", f"{md.imu_port}:{imu}", ready="serving the sensor metadata") as replay:
        with LidarpktProcess(tmp_path / "rec.log", "record", "--bind", "127.0.0.1", "--port", str(lidar),
                             "--port", str(imu), "--sensor", f"127.0.0.1:{replay.port_after('http://')}",
                             "--points", "-o", str(out), "--report", str(report), ready="listening on") as rec:
            assert replay.proc.wait(timeout=120) == 0, replay.log.read_text()
            assert rec.stop() == 0, rec.log.read_text()
    summary = json.loads(report.read_text())
    assert summary["lost_total"] == 0
    messages = read_mcap(out)
    served = [m.data for t, _, m in messages if t == "/ouster/metadata"]
    assert len(served) == 1 and json.loads(served[0]) == json.loads(metadata.read_text())
    check_points(messages, frames, ["/ouster/points"])


def test_record_view_loses_no_packet(tmp_path):
    capture = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    frames = list(lidarpkt.open(capture))
    alone, alone_msgs, _ = record_replay(tmp_path, capture, replay_args=[], name="alone")
    viewed, viewed_msgs, client = record_replay(tmp_path, capture, "--view", "--points", "--ws", "127.0.0.1:0",
                                                replay_args=[], name="viewed", view_client=True)
    for s in (alone, viewed):
        assert s["lost_total"] == 0 and s["kernel_drops"] == 0 and s["queue_overflow"] == 0
    assert viewed["packets"] == alone["packets"] == 1902 + 367  # every data and position packet

    def payloads(msgs):
        return [bytes(p.data) for t, _, m in msgs if t == "/velodyne_packets" for p in m.packets]

    assert payloads(viewed_msgs) == payloads(alone_msgs)
    # every decoded frame is written as points; decoding for points and view may fall behind on a
    # loaded machine, and then what it skipped is counted (the packets themselves are all above)
    assert viewed["points_frames_written"] == viewed["frames_decoded"], viewed
    if viewed["packets_not_decoded"] == 0:
        assert viewed["frames_decoded"] == len(frames), viewed
    else:
        assert viewed["frames_decoded"] < len(frames), viewed
    seen = client.on("/velodyne/points/strongest")
    # the viewer saw every frame it was not made to drop (the last one is published at the stop)
    assert len(seen) == viewed["frames_decoded"] - viewed["view_frames_dropped"], (len(seen), viewed)


def test_record_view_that_cannot_serve_leaves_no_recording(tmp_path):
    import socket
    import subprocess
    import sys

    out = tmp_path / "never.mcap"
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "lidarpkt", "record", "--bind", "127.0.0.1", "--port",
                            str(free_udp_ports(1)[0]), "-o", str(out), "--view", "--ws", f"127.0.0.1:{port}"],
                           capture_output=True, text=True, timeout=60, cwd=CANNED.parents[1])
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lidarpkt: error: --ws 127.0.0.1:{port}: cannot serve there")
    assert not out.exists()
