"""The MCAP writer stands alone: ``open_writer("mcap", out, topics=("packets", "points"))`` fed by one pass over
the capture (``lidarpkt.writers.write_captures``) writes what ``lidarpkt decode --topics packets,points`` writes,
message for message and log time for log time, in a process that never loads the recorder."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from conftest import REPO_ROOT, external

mcap_reader = pytest.importorskip("mcap.reader")

CASES = [  # (capture, metadata): a VLP-16 (data + position packets) and an Ouster (lidar + IMU) capture
    ("veloview/vlp-16-test-90deg-1-50-frames.pcap", None),
    ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json"),
]

LIBRARY_SCRIPT = """
import json, sys
from lidarpkt.writers import open_writer, write_captures
capture, out, metadata = sys.argv[1], sys.argv[2], (sys.argv[3] if len(sys.argv) > 3 else None)
with open_writer("mcap", out, capture=capture, topics=("packets", "points")) as writer:
    write_captures([capture], [writer], metadata=metadata)
print(json.dumps(sorted(m for m in sys.modules if m.startswith("lidarpkt.recorder") or m == "recorder")))
"""


def _records(path):
    """(every message as (topic, log time, publish time, data), metadata records) in file order."""
    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh)
        msgs = [(ch.topic, m.log_time, m.publish_time, bytes(m.data))
                for _, ch, m in reader.iter_messages(log_time_order=False)]
        fh.seek(0)
        meta = [(r.name, dict(r.metadata)) for r in mcap_reader.make_reader(fh).iter_metadata()]
    return msgs, meta


@pytest.mark.parametrize("capture, metadata", CASES, ids=["vlp16", "os1-64"])
def test_open_writer_mcap_equals_decode_without_the_recorder(tmp_path, capture, metadata):
    cap = external(capture)
    md = [str(external(metadata))] if metadata else []
    decoded = tmp_path / "decode.mcap"
    run = subprocess.run([sys.executable, "-m", "lidarpkt", "decode", str(cap), "-o", str(decoded), "-q",
                          "--topics", "packets,points", *(["--metadata", md[0]] if md else [])],
                         capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
    assert run.returncode == 0, run.stderr
    written = tmp_path / "library.mcap"
    run = subprocess.run([sys.executable, "-c", LIBRARY_SCRIPT, str(cap), str(written), *md],
                         capture_output=True, text=True, timeout=120, cwd=REPO_ROOT)
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout.splitlines()[-1]) == []  # no recorder module was loaded

    want, want_meta = _records(decoded)
    got, got_meta = _records(written)
    topics = {t for t, *_ in want}
    assert {"/velodyne_packets", "/ouster/lidar_packets"} & topics and {"/velodyne_points", "/ouster/points"} & topics
    assert len(got) == len(want)
    for k, (a, b) in enumerate(zip(got, want)):
        assert a[:3] == b[:3], f"message {k}: {a[:3]} != {b[:3]}"
        assert a[3] == b[3], f"message {k} on {a[0]}: the data differ"
    assert got_meta == want_meta


def test_veloview_capture_gives_every_packet_message(tmp_path):
    """The issue's numbers: the VeloView capture gives 52 clouds and 418 packet messages: one message per
    position packet (counted here from the capture by the pcap reader) and one VelodyneScan per rotation of
    its 1902 data packets."""
    from lidarpkt.containers.pcap_reader import read_packets
    from lidarpkt.writers import open_writer, write_captures

    cap = external(CASES[0][0])
    with open_writer("mcap", tmp_path / "x.mcap", capture=cap, topics=("packets", "points")) as writer:
        write_captures([cap], [writer])
    msgs, _ = _records(tmp_path / "x.mcap")
    by_topic: dict[str, int] = {}
    for topic, *_ in msgs:
        by_topic[topic] = by_topic.get(topic, 0) + 1
    position = sum(1 for p in read_packets(cap) if len(p.payload) == 512)
    assert by_topic["/velodyne_points"] == writer.frames_written == 52
    assert by_topic["/velodyne_position_packets"] == position == 367
    assert by_topic["/velodyne_packets"] + position == writer.packet_messages == 418


def test_packets_need_the_pass_over_the_capture(tmp_path):
    """The writer opens no input: asked for packets but given frames alone (or nothing), it says how to
    hand it the capture, and leaves no file."""
    import lidarpkt
    from lidarpkt.errors import OutputError
    from lidarpkt.writers import open_writer

    with pytest.raises(OutputError, match="write_captures"):
        with open_writer("mcap", tmp_path / "x.mcap", topics=("packets",)):
            pass
    cap = external(CASES[0][0])
    with pytest.raises(OutputError, match="write_captures"):
        with open_writer("mcap", tmp_path / "x.mcap", capture=cap, topics=("packets", "points")) as writer:
            for frame in lidarpkt.open(cap):
                writer.write(frame)
    assert list(tmp_path.iterdir()) == []
