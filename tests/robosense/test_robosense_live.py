"""The RoboSense bag live: ``lidarpkt view`` seen by a real Foxglove WebSocket client, and ``lidarpkt replay`` to
``lidarpkt record`` (a subprocess) over loopback UDP, MSOP and DIFOP on ports of their own; every packet comes back
byte for byte, and the recording decodes to the bag's frames."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import lidarpkt
from conftest import external
from robosense_bag import BAG, sensor_packets


def _frames(path) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return list(lidarpkt.open(path))


def test_view_sends_the_frames_to_a_websocket_client(tmp_path):
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    pytest.importorskip("google.protobuf")
    from view_client import FoxgloveClient, LidarpktProcess, points_of, stamp_ns

    bag = external(BAG)
    frames = _frames(bag)
    topic = "/robosense/points/strongest"
    with LidarpktProcess(tmp_path / "view.log", "view", str(bag), "--ws", "127.0.0.1:0", ready="serving ws://") as view:
        client = FoxgloveClient(f"ws://127.0.0.1:{view.port_after('serving ws://')}")
        try:
            assert client.wait_for(lambda c: len(c.on(topic)) >= len(frames), 120), view.log.read_text()
        finally:
            client.close()
            assert view.stop() == 0, view.log.read_text()
    got = client.on(topic)
    assert [stamp_ns(m.message) for m in got] == [f.timestamp_ns for f in frames]
    for frame, m in zip(frames, got):
        xyz, fields = points_of(m.message)
        hit = (frame.range_mm[0] > 0) & frame.column_valid[None, :]
        np.testing.assert_array_equal(xyz, frame.xyz()[0][hit].astype(np.float32))
        np.testing.assert_array_equal(fields["range"], frame.range_mm[0][hit])
        assert m.message.frame_id == "robosense"


def test_replay_to_record_on_the_msop_and_difop_ports(tmp_path):
    mcap_reader = pytest.importorskip("mcap.reader")
    from mcap_ros2.decoder import DecoderFactory

    from lidarpkt.recorder.replay import replay
    from test_replay_record import Recorder, _free_ports

    bag = external(BAG)
    packets = sensor_packets()  # MSOP to 6699, DIFOP to 7788
    msop_port, difop_port = _free_ports(2)
    rec = Recorder(tmp_path, [msop_port, difop_port], "--chunk-seconds", "0.2", "-q")
    try:
        stats = replay(packets, "127.0.0.1", msop_port, rate=4.0, port_map={7788: difop_port})
        rec.wait_until_read()
    finally:
        rc = rec.stop()
    assert rc == 0, rec.log.read_text()
    assert stats.per_port == {msop_port: 750, difop_port: 1}
    report = json.loads(rec.report.read_text())
    assert report["datagrams_received"] == 751 and report["lost_total"] == 0 and report["out_of_order"] == 0
    kinds = {s["kind"]: s for s in report["streams"]}
    assert kinds["robosense_msop"]["packets"] == 750 and kinds["robosense_difop"]["packets"] == 1
    with open(rec.out, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[DecoderFactory()])
        scans = [m for _, ch, _, m in reader.iter_decoded_messages() if ch.topic == "/robosense_packets"]
    got = sorted(bytes(p.data[:p.size]) for s in scans for p in s.packets)
    assert got == sorted(p.payload for p in packets)  # byte for byte (the DIFOP's scan sorts among the MSOP's)
    assert [bool(p.is_difop) for s in scans for p in s.packets].count(True) == 1
    again, direct = _frames(rec.out), _frames(bag)
    assert len(again) == len(direct) > 0
    for a, b in zip(again, direct):  # host times differ (a new capture); the sensor's data must not
        assert a.sensor.model == b.sensor.model and a.return_labels == b.return_labels
        np.testing.assert_array_equal(a.range_mm, b.range_mm)
        np.testing.assert_array_equal(a.xyz(), b.xyz())
