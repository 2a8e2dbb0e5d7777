"""``lidarpkt view FILE`` (a subprocess) seen through a real Foxglove WebSocket client (websockets +
protobuf, tests/view_client.py): after subscribing it receives exactly the frames ``lidarpkt.open``
gives, with every point's XYZ the float32 rounding of ``Frame.xyz()``, and the images,
transform and status of each sensor."""

from __future__ import annotations

import numpy as np
import pytest

import lidarpkt
from conftest import external

pytest.importorskip("foxglove")
pytest.importorskip("websockets")
pytest.importorskip("google.protobuf")

from view_client import FoxgloveClient, LidarpktProcess, points_of, stamp_ns  # noqa: E402

CANNED = __import__("pathlib").Path(__file__).resolve().parents[2] / "lidarpkt" / "fixtures" / "canned"


def expected_points(frame, slot: int, xyz: np.ndarray):
    """What a client must see for one slot: the returns of valid columns, row-major."""
    hit = (frame.range_mm[slot] > 0) & frame.column_valid[None, :]
    return xyz[slot][hit].astype(np.float32), frame.range_mm[slot][hit], np.nonzero(hit)[0]


def check_frames(client: FoxgloveClient, frames: list, name: str) -> None:
    """Every frame of ``frames`` arrived, in order, on each slot's topic, with its exact points."""
    labels = frames[0].return_labels
    for slot, label in enumerate(labels):
        got = client.on(f"/{name}/points/{label}")
        assert [stamp_ns(m.message) for m in got] == [f.timestamp_ns for f in frames], label
        for frame, m in zip(frames, got):
            xyz, fields = points_of(m.message)
            want_xyz, want_range, want_rows = expected_points(frame, slot, frame.xyz())
            assert m.message.frame_id == name
            assert len(xyz) == len(want_xyz)
            np.testing.assert_array_equal(xyz, want_xyz)
            np.testing.assert_array_equal(fields["range"], want_range)
            np.testing.assert_array_equal(fields["row"], want_rows)
            assert (fields["return"] == slot).all()
            assert not (xyz == 0).all(axis=1).any(), "a point on the origin"
        images = client.on(f"/{name}/range_image/{label}")
        assert len(images) == len(frames)
        for frame, m in zip(frames, images):
            img = np.frombuffer(m.message.data, "<f4").reshape(m.message.height, m.message.width)
            want = frame.range_mm[slot].astype("<f4") * np.float32(1e-3)
            if frame.sensor.vendor == "ouster":
                want = frame.destaggered(want)
            assert m.message.encoding == "32FC1"
            np.testing.assert_array_equal(img, want)
    tf = client.on(f"/{name}/transform")
    assert len(tf) == len(frames) and tf[0].message.child_frame_id == name


def view_file(tmp_path, path, *extra: str, frames_expected: int, name: str, labels) -> FoxgloveClient:
    with LidarpktProcess(tmp_path / "view.log", "view", str(path), "--ws", "127.0.0.1:0", *extra,
                         ready="serving ws://") as view:
        client = FoxgloveClient(f"ws://127.0.0.1:{view.port_after('serving ws://')}")
        try:
            assert client.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
            topics = [f"/{name}/points/{label}" for label in labels]
            assert client.wait_for(lambda c: all(len(c.on(t)) >= frames_expected for t in topics), 120), \
                view.log.read_text()
            assert client.wait_for(lambda c: any(m.message["frames"] == frames_expected
                                                 for m in c.on(f"/{name}/status")), 30)
        finally:
            client.close()
            assert view.stop() == 0, view.log.read_text()
    return client


def test_vlp16_dual_capture_file(tmp_path):
    path = CANNED / "vlp16-dual.pcap"
    frames = list(lidarpkt.open(path))
    client = view_file(tmp_path, path, "--rate", "4", frames_expected=len(frames), name="velodyne",
                       labels=frames[0].return_labels)
    assert set(client.topics()) >= {"/velodyne/points/last", "/velodyne/points/strongest",
                                    "/velodyne/reflectivity_image/strongest", "/velodyne/status"}
    check_frames(client, frames, "velodyne")
    status = client.on("/velodyne/status")[-1].message
    assert status["lost_packets"] == sum(f.counters.lost_packets for f in frames)


def test_vlp16_external_capture_at_20hz(tmp_path):
    path = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    frames = list(lidarpkt.open(path))
    assert len(frames) == 52  # VeloView's count, partial first and last included
    client = view_file(tmp_path, path, "--rate", "5", frames_expected=len(frames), name="velodyne",
                       labels=frames[0].return_labels)
    check_frames(client, frames, "velodyne")


def test_ouster_capture_file_with_metadata(tmp_path):
    path, md = CANNED / "os1-64-legacy.pcap", CANNED / "os1-64-legacy.json"
    frames = list(lidarpkt.open(path, metadata=str(md)))
    client = view_file(tmp_path, path, "--metadata", str(md), frames_expected=len(frames), name="ouster",
                       labels=frames[0].return_labels)
    check_frames(client, frames, "ouster")


def test_bad_ws_flag_is_one_line_error(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "lidarpkt", "view", str(CANNED / "vlp16-dual.pcap"), "--ws", "nohost"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["lidarpkt: error: --ws nohost: not HOST:PORT with a port in 0-65535; give e.g. --ws 127.0.0.1:8765"]


def _run_view(*args: str):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "lidarpkt", "view", *args], capture_output=True, text=True,
                          timeout=60, cwd=CANNED.parents[1])


def test_unreadable_capture_is_an_error_before_serving(tmp_path):
    missing = tmp_path / "missing.pcap"
    r = _run_view(str(missing), "--ws", "127.0.0.1:0")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"lidarpkt: error: {missing}: no such file or directory; check the path"]
    r = _run_view(str(CANNED / "os1-64-legacy.pcap"), "--ws", "127.0.0.1:0")  # Ouster without its metadata
    assert r.returncode == 2 and "serving" not in r.stderr
    assert r.stderr.startswith("lidarpkt: error: ") and "--metadata" in r.stderr


def test_ws_address_in_use_is_one_line_error():
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = _run_view(str(CANNED / "vlp16-dual.pcap"), "--ws", f"127.0.0.1:{port}")
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"lidarpkt: error: --ws 127.0.0.1:{port}: cannot serve there")
    assert lines[0].endswith("choose another HOST:PORT")


def test_capture_and_live_flags_together_are_refused():
    r = _run_view(str(CANNED / "vlp16-dual.pcap"), "--port", "2368")
    assert r.returncode == 2 and r.stderr.startswith("lidarpkt: error: --port/--bind/--multicast/--sensor: not with")


def test_loop_plays_the_capture_again(tmp_path):
    path = CANNED / "vlp16-dual.pcap"
    frames = list(lidarpkt.open(path))
    with LidarpktProcess(tmp_path / "view.log", "view", str(path), "--ws", "127.0.0.1:0", "--loop", "--rate", "5",
                         ready="serving ws://") as view:
        client = FoxgloveClient(f"ws://127.0.0.1:{view.port_after('serving ws://')}")
        try:
            topic = "/velodyne/points/strongest"
            assert client.wait_for(lambda c: len(c.on(topic)) >= 2 * len(frames) + 1, 60), view.log.read_text()
            assert client.wait_for(lambda c: len(c.on("/velodyne/status")) >= 2, 30)
        finally:
            client.close()
            assert view.stop() == 0, view.log.read_text()
    got = [len(points_of(m.message)[0]) for m in client.on(topic)[:2 * len(frames)]]
    slot = frames[0].return_labels.index("strongest")
    want = [int(((f.range_mm[slot] > 0) & f.column_valid[None, :]).sum()) for f in frames]
    assert got == want * 2
    packets = [m.message["packets"] for m in client.on("/velodyne/status")]
    assert packets == sorted(packets) and packets[-1] > 829  # counted on through the rounds


def test_real_vlp16_dual_rosbag2(tmp_path):
    """tier4/nebula's rosbag2 of a real VLP-16 in dual mode (the only real dual capture here)."""
    bag = external("nebula/vlp16/1673400471837873222")
    frames = list(lidarpkt.open(bag))
    client = view_file(tmp_path, bag, "--rate", "4", frames_expected=len(frames), name="velodyne",
                       labels=frames[0].return_labels)
    check_frames(client, frames, "velodyne")


def test_mcap_recorded_by_lidarpkt(tmp_path):
    import subprocess
    import sys

    mcap = tmp_path / "os.mcap"
    subprocess.run([sys.executable, "-m", "lidarpkt", "decode", str(CANNED / "os1-64-legacy.pcap"), "--metadata",
                    str(CANNED / "os1-64-legacy.json"), "-o", str(mcap), "--topics", "packets", "-q"],
                   check=True, timeout=120, cwd=CANNED.parents[1])
    frames = list(lidarpkt.open(mcap))  # the metadata travels in the file
    client = view_file(tmp_path, mcap, frames_expected=len(frames), name="ouster", labels=frames[0].return_labels)
    check_frames(client, frames, "ouster")
