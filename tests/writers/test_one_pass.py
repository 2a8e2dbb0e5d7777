"""One pass: ``lidarpkt decode IN -o x.mcap --topics packets,points`` reads the capture once (the writers never
open their inputs; the pass hands them the frames and the raw packets with their capture times), and writes
the messages the golden digests hold, whatever ``workers`` is and however many writers share the pass."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import golden_outputs
from conftest import REPO_ROOT, external

mcap_reader = pytest.importorskip("mcap.reader")

OS2 = ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json")

# the bytes a child process reads while it runs `lidarpkt ARGV` (its imports before excluded)
RCHAR_SCRIPT = """
import json, sys
def rchar():
    return int(next(l for l in open("/proc/self/io") if l.startswith("rchar:")).split()[1])
from lidarpkt.cli import main
before = rchar()
status = main(sys.argv[1:])
print(json.dumps({"status": status, "rchar": rchar() - before}))
"""


def _repeated_ouster_capture(out: Path, frames: int) -> dict:
    """``frames`` copies of the one-frame OS-2-128 capture as one stream: each copy's frame id and column
    timestamps moved on by one frame period, its capture times too. Returns what the copies were made of."""
    from lidarpkt.containers.pcap_reader import read_batches
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.vendors.ouster import decode_packets, encode_packets, load_metadata
    from lidarpkt.writers.pcap import write_pcap

    md = load_metadata(external(OS2[1]))
    lidar = [b for b in read_batches(external(OS2[0])) if b.payload_size == md.packet_size]  # the one frame
    payload = np.concatenate([b.payload for b in lidar])
    capture_ns = np.concatenate([b.timestamp_ns for b in lidar])
    fields = decode_packets(payload, md)
    period_ns = int(1e9 / (md.frequency_hz or 10))
    first_id = int(fields.frame_id[0])
    src, dst = Endpoint("127.0.0.1", 7502), Endpoint("127.0.0.1", md.lidar_port)
    hosts = [capture_ns + k * period_ns for k in range(frames)]
    payloads = []
    for k in range(frames):
        f = decode_packets(payload, md)
        f.header["frame_id"][:] = (first_id + k) % 65536
        f.timestamp_ns[:] = fields.timestamp_ns + np.uint64(k * period_ns)
        payloads.append(encode_packets(f, md))
    write_pcap(out, (Packet(int(hosts[k][i]), src, dst, payloads[k][i].tobytes())
                     for k in range(frames) for i in range(len(payload))), mtu=None)
    return {"hosts": np.concatenate(hosts), "payloads": np.concatenate(payloads), "period_ns": period_ns,
            "column_ns": fields.timestamp_ns.astype(np.int64), "packets_per_frame": len(payload)}


def _messages(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    """(log time, data) of every message, by topic, in file order."""
    out: dict[str, list[tuple[int, bytes]]] = {}
    with open(path, "rb") as fh:
        for _, channel, message in mcap_reader.make_reader(fh).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, bytes(message.data)))
    return out


def test_decode_to_mcap_reads_a_100_mb_capture_once_and_logs_each_message_at_its_capture_time(tmp_path):
    """A 102 MB capture (64 frames of an OS-2-128): the decode process reads at most 1.2x its bytes (it read
    3.07x when the MCAP writer read the capture again for the packets and a third time for the clocks).
    Every packet is a message at its capture time with its bytes; every frame a cloud logged when its last
    packet was received by the clock offset of the first packet (host - sensor time), inside the capture's
    span: arithmetic on the capture as built, not lidarpkt's."""
    from lidarpkt.vendors.ouster.ros import decode_packet_msg

    cap, out = tmp_path / "os2-x64.pcap", tmp_path / "x.mcap"
    built = _repeated_ouster_capture(cap, 64)
    size = cap.stat().st_size
    assert size >= 100e6
    run = subprocess.run([sys.executable, "-c", RCHAR_SCRIPT, "decode", str(cap), "-o", str(out), "-q",
                          "--metadata", str(external(OS2[1])), "--topics", "packets,points"],
                         capture_output=True, text=True, timeout=300, cwd=REPO_ROOT)
    assert run.returncode == 0, run.stderr
    result = json.loads(run.stdout.splitlines()[-1])
    assert result["status"] == 0
    assert result["rchar"] <= 1.2 * size, f"read {result['rchar'] / size:.2f}x the capture's bytes"

    messages = _messages(out)
    packets = messages["/ouster/lidar_packets"]
    hosts, payloads = built["hosts"], built["payloads"]
    assert [t for t, _ in packets] == hosts.tolist()
    assert all(decode_packet_msg(data) == payloads[i].tobytes() for i, (_, data) in enumerate(packets))
    start, end = int(hosts.min()), int(hosts.max())
    assert [t for t, _ in messages["/ouster/metadata"]] == [start]
    offset = int(hosts[0]) - int(built["column_ns"][0, 0])
    last_column = int(built["column_ns"].max())
    n = built["packets_per_frame"]
    expected = [min(end, max(start, last_column + k * built["period_ns"] + offset)) for k in range(len(hosts) // n)]
    assert sorted(t for t, _ in messages["/ouster/points"]) == expected
    assert expected[-1] == end  # the last frame is logged at the capture's end: it waited for it


@pytest.mark.parametrize("case", ["veloview-vlp16", "os1-64-fw20", "ouster-ros-bag"])
@pytest.mark.parametrize("workers", ["2", "3"])
def test_decode_to_mcap_with_workers_writes_the_golden_messages(tmp_path, case, workers):
    """Packets ride along in the threaded pipeline (``workers`` >= 2; segments would hand them out of order):
    the same messages and log times as ``workers=1``'s recorded digest."""
    name, files = golden_outputs.CASES[case]
    for path in (name, *files):
        external(path[4:])
    out = tmp_path / "x.mcap"
    golden_outputs._cli("decode", str(golden_outputs.resolve(name)), "-o", str(out), "-q", "--workers", workers,
                        *golden_outputs._sensor_args(files))
    assert golden_outputs._mcap_digest(out) == golden_outputs.load()[case]["mcap"]


def test_one_pass_feeds_several_writers_at_once(tmp_path):
    """write_captures hands one pass to an MCAP writer (packets and frames) and an NPZ writer (frames): each
    output is what its own ``lidarpkt decode`` writes (the recorded digests)."""
    from lidarpkt.writers import open_writer, write_captures

    case = "nebula-vlp16-dual"
    name, _ = golden_outputs.CASES[case]
    capture = external(name[4:])
    with open_writer("mcap", tmp_path / "x.mcap", capture=capture, topics=("packets", "points")) as mcap, \
            open_writer("npz", tmp_path / "x.npz") as npz:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            feed = write_captures([capture], [mcap, npz])
    stored = golden_outputs.load()[case]
    assert feed.frames == int(stored["frames.count"]) and mcap.frames_written == npz.frames_written == feed.frames
    assert golden_outputs._mcap_digest(tmp_path / "x.mcap") == stored["mcap"]
    assert golden_outputs._npz_digest(tmp_path / "x.npz") == stored["npz"]


def test_frames_waiting_for_the_span_spill_to_a_file_and_come_back_the_same(tmp_path, monkeypatch):
    """Hesai frames carry no clock offset: every one is logged at the capture's start, known only at its end,
    so every frame waits. With no memory allowed for waiting frames they go through the temporary file, and
    the MCAP is the recorded one; nothing is left beside it."""
    from lidarpkt.writers.mcap.frames import McapFrameWriter

    case = "hesai-xt32"
    name, files = golden_outputs.CASES[case]
    for path in (name, *files):
        external(path[4:])
    monkeypatch.setattr(McapFrameWriter, "pending_bytes", 0)
    out = tmp_path / "x.mcap"
    golden_outputs._cli("decode", str(golden_outputs.resolve(name)), "-o", str(out), "-q",
                        *golden_outputs._sensor_args(files))
    assert golden_outputs._mcap_digest(out) == golden_outputs.load()[case]["mcap"]
    assert [p.name for p in tmp_path.iterdir()] == ["x.mcap"]


def test_pending_frames_keep_what_memory_allows_and_spill_the_rest(tmp_path):
    from lidarpkt.writers.mcap.pending import PendingFrames
    from lidarpkt.vendors.ouster.ros import LIDAR_TOPIC as TOPIC

    pending = PendingFrames(tmp_path, memory_bytes=10)
    pending.add(5, "a", [(TOPIC, b"12345678")])
    pending.add(6, "b", [(TOPIC, b"abcdefgh")])  # beyond 10 bytes: to the file
    pending.add(7, None, [(TOPIC, b"xy")])
    assert len(pending) == 3
    assert [e[:2] for e in pending.take(lambda end_ns, source: source == "a")] == [(5, "a")]
    assert [(e[0], e[1], e[2][0][1]) for e in pending.drain()] == [(7, None, b"xy"), (6, "b", b"abcdefgh")]
    assert len(pending) == 0 and list(pending.drain()) == []
