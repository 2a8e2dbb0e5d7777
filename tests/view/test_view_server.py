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


@pytest.mark.parametrize("offered", [["foxglove.sdk.v1"], ["foxglove.websocket.v1"],
                                     ["foxglove.websocket.v1", "foxglove.sdk.v1"]])
def test_viewers_of_either_subprotocol_name_receive_the_frames(offered):
    """foxglove-sdk 0.30 alone answers an offer of only ``foxglove.websocket.v1`` (Foxglove Studio's web
    builds, older Lichtblick) with HTTP 400; through the view's front both names connect, each
    client is answered with the name it offered, and gets every frame."""
    vlp = list(lidarpkt.open(CANNED / "vlp16-strongest.pcap"))[:3]
    with ViewServer("127.0.0.1", 0, first_frame_wait_s=5.0) as server:
        client = FoxgloveClient(f"ws://127.0.0.1:{server.port}", subprotocols=offered)
        try:
            assert client.subprotocol == ("foxglove.sdk.v1" if "foxglove.sdk.v1" in offered else offered[0])
            for frame in vlp:
                server.publish(frame)
            assert client.wait_for(lambda c: len(c.on("/velodyne/points/strongest")) == len(vlp), 30)
        finally:
            client.close()
    got = client.on("/velodyne/points/strongest")
    assert [stamp_ns(m.message) for m in got] == [f.timestamp_ns for f in vlp]
    xyz, _ = points_of(got[0].message)
    np.testing.assert_array_equal(xyz, expected_points(vlp[0], 0, vlp[0].xyz())[0])
    assert client.server_info["name"] == "lidarpkt"


def test_the_sdk_alone_refuses_the_older_name_and_the_front_still_refuses_unknown_ones():
    """Why the front exists (foxglove-sdk's own server refuses ``foxglove.websocket.v1``), and that it
    renames only that name: an unknown subprotocol is still refused with the SDK's HTTP 400."""
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    with ViewServer("127.0.0.1", 0) as server:
        direct = f"ws://127.0.0.1:{server._server.port}"
        with pytest.raises(InvalidStatus, match="400"):
            connect(direct, subprotocols=["foxglove.websocket.v1"], open_timeout=10)
        with pytest.raises(InvalidStatus, match="400"):
            connect(f"ws://127.0.0.1:{server.port}", subprotocols=["ros.bridge.v2"], open_timeout=10)


def test_subprotocol_renaming_in_the_handshake_heads():
    from lidarpkt.view.front import rename_answer, rename_offer

    head = (b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Key: k\r\n"
            b"sec-websocket-protocol:  foxglove.websocket.v1 , other\r\n\r\n")
    renamed, did = rename_offer(head)
    assert did and b"sec-websocket-protocol: foxglove.sdk.v1, other\r\n" in renamed
    assert renamed.startswith(b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Key: k\r\n") and renamed.endswith(b"\r\n\r\n")
    both = head.replace(b"other", b"foxglove.sdk.v1")
    assert rename_offer(both) == (both, False)  # the client knows the newer name: untouched
    plain = b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"
    assert rename_offer(plain) == (plain, False)
    answer = b"HTTP/1.1 101 Switching Protocols\r\nSec-WebSocket-Protocol: foxglove.sdk.v1\r\n\r\n"
    assert rename_answer(answer) == answer.replace(b"foxglove.sdk.v1", b"foxglove.websocket.v1")
