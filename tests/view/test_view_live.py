"""The live view over loopback: ``lidarpkt replay`` sends a capture, ``lidarpkt view`` (a subprocess,
the receive path of ``record``) decodes it, and a real Foxglove WebSocket client receives exactly the
frames ``lidarpkt.open`` gives: VLP-16 dual, and Ouster with its metadata fetched over HTTP from
``replay --http`` (``view --sensor``). The last frame, still being assembled when the stream stops,
is published when the view is stopped."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest

import lidarpkt
from conftest import external

pytest.importorskip("foxglove")
pytest.importorskip("websockets")
pytest.importorskip("google.protobuf")

from test_view_capture import CANNED, expected_points  # noqa: E402
from test_replay_record import _free_ports as free_udp_ports  # noqa: E402  (one helper for free UDP ports)
from view_client import FoxgloveClient, LidarpktProcess, points_of, stamp_ns  # noqa: E402


def check_live_frames(client: FoxgloveClient, frames: list, name: str, *, same_clock: bool) -> None:
    """Every frame, in order, each slot's points exactly; sensor stamps equal (Ouster: the sensor's
    clock), or for VLP-16 (hour from the host clock) equal up to one offset for the whole stream."""
    for slot, label in enumerate(frames[0].return_labels):
        got = client.on(f"/{name}/points/{label}")
        assert len(got) == len(frames), (label, len(got), len(frames))
        stamps = np.array([stamp_ns(m.message) for m in got])
        want = np.array([f.timestamp_ns for f in frames])
        if same_clock:
            np.testing.assert_array_equal(stamps, want)
        else:
            np.testing.assert_array_equal(stamps - stamps[0], want - want[0])
        for frame, m in zip(frames, got):
            xyz, fields = points_of(m.message)
            want_xyz, want_range, want_rows = expected_points(frame, slot, frame.xyz())
            assert len(xyz) == len(want_xyz)
            np.testing.assert_array_equal(xyz, want_xyz)
            np.testing.assert_array_equal(fields["range"], want_range)
            np.testing.assert_array_equal(fields["row"], want_rows)


def watch(view: LidarpktProcess, start_replay, frames, name) -> FoxgloveClient:
    """Connect a client to ``view``, run the replay ``start_replay()`` gives (a LidarpktProcess context)
    to its end, then stop the view (which publishes the last frame) and check what the client got."""
    client = FoxgloveClient(f"ws://127.0.0.1:{view.port_after('serving ws://')}")
    try:
        with start_replay() as replay:
            assert replay.proc.wait(timeout=120) == 0, replay.log.read_text()
        topic = f"/{name}/points/{frames[0].return_labels[0]}"
        # all but the last frame arrive while the stream runs; the last is released at the stop
        assert client.wait_for(lambda c: len(c.on(topic)) >= len(frames) - 1, 60), view.log.read_text()
        assert view.stop() == 0, view.log.read_text()
        assert client.closed.wait(30)
    finally:
        client.close()
    check_live_frames(client, frames, name, same_clock=(name == "ouster"))
    return client


def test_vlp16_dual_replayed_live(tmp_path):
    capture = CANNED / "vlp16-dual.pcap"
    frames = list(lidarpkt.open(capture))
    # the position packet arrives mid-stream with the capture's GPS time (months before the replay's
    # host times): live frame times keep the host clock's hour, so no frame is lost to it
    data, position = free_udp_ports(2)
    with LidarpktProcess(tmp_path / "view.log", "view", "--ws", "127.0.0.1:0", "--bind", "127.0.0.1",
                         "--port", str(data), "--port", str(position), ready="listening on") as view:
        client = watch(view, lambda: LidarpktProcess(
            tmp_path / "replay.log", "replay", str(capture), "--rate", "2", "--to", f"127.0.0.1:{data}",
            "--port-map", f"8308:{position}"), frames, "velodyne")
    statuses = [m.message for m in client.on("/velodyne/status")]
    assert statuses and statuses[-1]["frames"] == len(frames) and statuses[-1]["lost_packets"] == 0
    assert statuses[-1]["view_frames_dropped"] == 0
    assert max(s["packets"] for s in statuses) > 0


@pytest.mark.parametrize("capture, metadata", [
    (CANNED / "os1-64-legacy.pcap", CANNED / "os1-64-legacy.json"),
    ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json"),
])
def test_ouster_live_with_metadata_over_http(tmp_path, capture, metadata):
    if isinstance(capture, str):
        capture, metadata = external(capture), external(metadata)
    frames = list(lidarpkt.open(capture, metadata=str(metadata)))
    lidar, imu = free_udp_ports(2)
    md = lidarpkt.vendors.ouster.load_metadata(str(metadata))
    with LidarpktProcess(tmp_path / "http.log", "replay", str(capture), "--metadata", str(metadata),
                         "--http", "127.0.0.1:0", "--start-after-fetch", "1.5", "--to", f"127.0.0.1:{lidar}",
                         "--port-map", f"{md.imu_port}:{imu}", ready="serving the sensor metadata") as replay:
        http = replay.port_after("http://")
        with LidarpktProcess(tmp_path / "view.log", "view", "--ws", "127.0.0.1:0", "--bind", "127.0.0.1",
                             "--sensor", f"127.0.0.1:{http}", "--port", str(lidar), "--port", str(imu),
                             ready="listening on") as view:
            watch(view, lambda: contextlib.nullcontext(replay), frames, "ouster")  # already started: it waits
