"""ViewServer in-process with a real Foxglove WebSocket client: several sensors get their own names,
frame ids and channels; the status says packets, frames and loss per sensor; the SDK's own schema
names are advertised (foxglove.PointCloud, foxglove.RawImage, foxglove.FrameTransform)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import lidarpkt

pytest.importorskip("foxglove")
pytest.importorskip("websockets")
pytest.importorskip("google.protobuf")

from lidarpkt.view.server import ViewError, ViewServer, parse_ws  # noqa: E402
from test_view_capture import CANNED, expected_points  # noqa: E402
from view_client import FoxgloveClient, points_of, stamp_ns  # noqa: E402


def with_source(frame, source: str):
    return dataclasses.replace(frame, sensor=dataclasses.replace(frame.sensor, source=source))


def test_three_sensors_each_with_their_channels():
    vlp = list(lidarpkt.open(CANNED / "vlp16-strongest.pcap"))[:3]
    ous = list(lidarpkt.open(CANNED / "os1-64-dual.pcap", metadata=str(CANNED / "os1-64-dual.json")))[:2]
    with ViewServer("127.0.0.1", 0, first_frame_wait_s=5.0) as server:
        client = FoxgloveClient(f"ws://127.0.0.1:{server.port}")
        try:
            for a, b in zip(vlp, vlp):
                server.publish(with_source(a, "10.0.0.1:2368"))
                server.publish(with_source(b, "10.0.0.2:2368"))
            for f in ous:
                server.publish(f)
            server.count_packets("10.0.0.1:2368", 100)
            statuses = {s["sensor"]: s for s in server.publish_status()}
            assert client.wait_for(lambda c: len(c.on("/ouster/points/strongest")) == len(ous)
                                   and len(c.on("/velodyne_2/points/strongest")) == len(vlp)
                                   and len(c.on("/ouster/status")) == 1, 30)
        finally:
            client.close()
    assert statuses["velodyne"]["packets"] == 100 and statuses["velodyne_2"]["packets"] == 0
    assert {s: d["frames"] for s, d in statuses.items()} == {"velodyne": 3, "velodyne_2": 3, "ouster": 2}
    schemas = {ch["topic"]: ch["schemaName"] for ch in client.channels.values()}
    assert schemas["/velodyne/points/strongest"] == "foxglove.PointCloud"
    assert schemas["/ouster/range_image/second_strongest"] == "foxglove.RawImage"
    assert schemas["/velodyne_2/transform"] == "foxglove.FrameTransform"
    for name in ("velodyne", "velodyne_2"):
        got = client.on(f"/{name}/points/strongest")
        assert [m.message.frame_id for m in got] == [name] * 3
        assert [stamp_ns(m.message) for m in got] == [f.timestamp_ns for f in vlp]
    cloud = client.on("/ouster/points/strongest")[0].message
    assert cloud.pose.orientation.w == 1.0 and cloud.point_stride == 24  # points in the sensor frame itself
    tf = client.on("/ouster/transform")[0].message
    assert (tf.parent_frame_id, tf.child_frame_id, tf.rotation.w) == ("base_link", "ouster", 1.0)
    for slot, label in enumerate(ous[0].return_labels):
        for frame, m in zip(ous, client.on(f"/ouster/points/{label}")):
            xyz, fields = points_of(m.message)
            want_xyz, want_range, _ = expected_points(frame, slot, frame.xyz())
            np.testing.assert_array_equal(xyz, want_xyz)
            np.testing.assert_array_equal(fields["reflectivity"], frame.reflectivity[slot][frame.range_mm[slot] > 0])
            assert (fields["return"] == slot).all()
        refl = client.on(f"/ouster/reflectivity_image/{label}")[0].message
        img = np.frombuffer(refl.data, "u1" if refl.encoding == "mono8" else "<u2").reshape(refl.height, refl.width)
        np.testing.assert_array_equal(img, ous[0].destaggered(ous[0].reflectivity[slot]))


@pytest.mark.parametrize("text", ["8765", "host:", "host:99999", ":8765"])
def test_parse_ws_rejects(text):
    with pytest.raises(ViewError, match="--ws"):
        parse_ws(text)


def test_parse_ws():
    assert parse_ws("0.0.0.0:8765") == ("0.0.0.0", 8765) and parse_ws("[::1]:0") == ("::1", 0)
