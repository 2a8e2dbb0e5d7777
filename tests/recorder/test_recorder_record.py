"""``lidarpkt record`` options on real loopback traffic: --frames, rotation, multicast, unknown
streams, a non-legacy Ouster profile, and its errors."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time

import pytest

from lidarpkt.containers.udp import UdpSource
from lidarpkt.recorder.replay import read_capture, replay
from conftest import external
from test_replay_record import REPO, Recorder, _free_ports, _messages, _recorded_payloads


def test_frames_option_stops_after_that_many_rotations(tmp_path):
    pcap = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")  # 50 wraps at 20 Hz
    packets = [p for p in read_capture(str(pcap)) if len(p.payload) == 1206]
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "--frames", "5", "-q")
    replay(packets, "127.0.0.1", port, rate=10.0)
    assert rec.proc.wait(timeout=60) == 0
    report = json.loads(rec.report.read_text())
    assert report["stopped_by"] == "5 frames" and report["frames"] >= 5 and report["lost_total"] == 0
    _, msgs = _messages(rec.out)
    got = _recorded_payloads(msgs)["/velodyne_packets"]
    assert got == [p.payload for p in packets[: len(got)]] and len(got) == report["packets"]
    import lidarpkt  # the recording holds five whole rotations (the first wrap ends the one under way)

    whole = [f for f in lidarpkt.open(rec.out) if not f.partial]
    assert len(whole) >= 5, [f.frame_id for f in whole]


def test_rotation_by_size_splits_the_recording_without_losing_a_packet(tmp_path):
    pcap = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")
    packets = [p for p in read_capture(str(pcap)) if len(p.payload) == 1206]
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "--rotate-size", "0.1", "--chunk-seconds", "0.05", "-q")
    replay(packets, "127.0.0.1", port, rate=3.0)  # ~0.8 s: many 0.05 s chunks even on a loaded machine
    rec.wait_until_read()
    assert rec.stop() == 0
    report = json.loads(rec.report.read_text())
    files = report["files"]
    assert len(files) >= 3 and all(f.endswith(f"rec_{i:04d}.mcap") for i, f in enumerate(files))
    got = []
    for f in files:
        summary, msgs = _messages(f)
        assert summary is not None  # every file is complete on its own
        got += _recorded_payloads(msgs).get("/velodyne_packets", [])
    assert got == [p.payload for p in packets] and report["lost_total"] == 0


def test_unknown_datagrams_are_kept_on_their_own_topic(tmp_path):
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "-q")
    payloads = [bytes([i]) * (100 + i) for i in range(20)]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for p in payloads:
            tx.sendto(p, ("127.0.0.1", port))
    rec.wait_until_read()
    assert rec.stop() == 0
    _, msgs = _messages(rec.out)
    assert [bytes(m.data) for t, _, m in msgs if t == "/lidarpkt/other_packets"] == payloads
    report = json.loads(rec.report.read_text())
    assert {s["kind"] for s in report["streams"]} == {"other"} and report["packets"] == 20
    assert "kept on /lidarpkt/other_packets" in rec.log.read_text()


def test_non_legacy_ouster_needs_and_uses_the_metadata(tmp_path):
    pcap = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap")
    meta = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json")
    packets = list(read_capture(str(pcap)))
    lidar_port, imu_port = _free_ports(2)
    rec = Recorder(tmp_path, [lidar_port, imu_port], "--metadata", str(meta), "-q")
    from lidarpkt.vendors.ouster.metadata_json import load_metadata

    md = load_metadata(meta)
    replay(packets, "127.0.0.1", lidar_port, rate=10.0, port_map={md.imu_port: imu_port}, metadata=md)
    rec.wait_until_read()
    assert rec.stop() == 0
    _, msgs = _messages(rec.out)
    got = _recorded_payloads(msgs)
    assert got["/ouster/lidar_packets"] == [p.payload for p in packets if len(p.payload) == md.packet_size]
    assert got["/ouster/imu_packets"] == [p.payload for p in packets if len(p.payload) == 48]
    report = json.loads(rec.report.read_text())
    assert report["lost_total"] == 0


def test_multicast_group_on_loopback(tmp_path):
    (port,) = _free_ports(1)
    group = "239.255.76.16"
    try:
        UdpSource([port], multicast=group, interface="127.0.0.1").close()
    except Exception as exc:  # no multicast route on this machine
        pytest.skip(f"cannot join a multicast group on loopback here: {exc}")
    with Recorder(tmp_path, [port], "--multicast", group, "--interface", "lo", "-q", bind=None) as rec:
        payloads = [p.payload for p in read_capture(str(external("rust-lidar-utils/velodyne_example.pcap")))]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
            for p in payloads:
                tx.sendto(p, (group, port))
        rec.wait_until_read()
        assert rec.stop() == 0, rec.log.read_text()
    out, report = rec.out, rec.report
    summary = json.loads(report.read_text())
    assert summary["streams"][0]["dst"] == f"{group}:{port}" and summary["lost_total"] == 0
    _, msgs = _messages(out)
    assert _recorded_payloads(msgs)["/velodyne_packets"] == payloads


def _run_cli(*args, timeout=60):
    return subprocess.run([sys.executable, "-m", "lidarpkt", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def test_record_errors_are_clear_and_leave_no_traceback(tmp_path):
    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    port = holder.getsockname()[1]
    try:
        r = _run_cli("record", "--port", str(port), "--bind", "127.0.0.1", "-o", str(tmp_path / "x.mcap"))
    finally:
        holder.close()
    assert r.returncode == 2 and "already in use" in r.stderr and "Traceback" not in r.stderr
    r = _run_cli("record", "--port", str(_free_ports(1)[0]), "-o", str(tmp_path / "nodir" / "x.mcap"))
    assert r.returncode == 2 and "does not exist" in r.stderr and "Traceback" not in r.stderr
    r = _run_cli("record", "--port", str(_free_ports(1)[0]), "--gps", str(tmp_path / "ttyNONE"),
                 "-o", str(tmp_path / "g.mcap"))
    assert r.returncode == 2 and "--gps" in r.stderr and "no such file or directory" in r.stderr
    assert not (tmp_path / "g.mcap").exists()  # issue 14: it left an empty 307-byte MCAP
    r = _run_cli("record", "-o", str(tmp_path / "p.mcap"))
    assert r.returncode == 2 and "no UDP port to listen on" in r.stderr
    r = _run_cli("replay", str(external("rust-lidar-utils/velodyne_example.pcap")), "--to", "nohostport")
    assert r.returncode == 2 and "HOST:PORT" in r.stderr
    r = _run_cli("replay", str(external("ouster-sdk/empty_pcap.pcap")), "--to", "127.0.0.1:9")
    assert r.returncode == 2 and "no UDP packets to replay" in r.stderr
    r = _run_cli("replay", str(external("einride-vlp16-go/packet.bin")), "--to", "127.0.0.1:9")
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_duration_stop_with_status_lines_and_summary(tmp_path):
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "--duration", "2.2")
    payloads = [p.payload for p in read_capture(str(external("rust-lidar-utils/velodyne_example.pcap")))]
    replay([p for p in read_capture(str(external("rust-lidar-utils/velodyne_example.pcap")))],
           "127.0.0.1", port, rate=1.0)
    assert rec.proc.wait(timeout=60) == 0
    log = rec.log.read_text()
    status = [line for line in log.splitlines() if "pkt/s" in line]
    assert len(status) >= 2 and all("lost 0 (gaps) + 0 (kernel) + 0 (queue)" in s for s in status)
    assert "stopped by duration 2.2 s" in log and f"{len(payloads)} packets" in log
    assert "granted" in log.splitlines()[0]


def test_disk_full_while_recording_is_a_clear_error_and_the_file_stays_readable(tmp_path):
    import warnings

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages

    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)],
                      capture_output=True).returncode != 0:
        pytest.skip("cannot mount a small tmpfs here (needs root) to fill a disk")
    try:
        packets = [p for p in read_capture(str(external("veloview/vlp-16-test-90deg-1-50-frames.pcap")))
                   if len(p.payload) == 1206]
        span = packets[-1].timestamp_ns - packets[0].timestamp_ns + 1_327_000
        packets += [type(p)(p.timestamp_ns + span, p.src, p.dst, p.payload) for p in packets]  # ~1.7 MB zstd
        (port,) = _free_ports(1)
        out = mnt / "full.mcap"
        with Recorder(tmp_path, [port], "--chunk-seconds", "0.05", "-q", out=out) as rec:
            # a chunk closes every 0.05 s or 1 MiB raw (~0.4 MB zstd): several fit before the disk fills
            replay(packets, "127.0.0.1", port, rate=4.0)
            assert rec.proc.wait(timeout=60) == 2
        log = rec.log
        text = log.read_text()
        assert "no space left" in text and "readable up to its last complete chunk" in text
        assert "Traceback" not in text
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            got = [row.tobytes() for b in BagReader(out, messages=bag_messages()).batches() for row in b.payload]
        assert len(got) > 300 and got == [p.payload for p in packets[: len(got)]]
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


def test_a_silent_sensor_is_reported_and_the_recording_goes_on(tmp_path):
    (port,) = _free_ports(1)
    # the fixture first: a missing capture must not leave a recorder running
    payloads = [p.payload for p in read_capture(str(external("rust-lidar-utils/velodyne_example.pcap")))]
    with Recorder(tmp_path, [port], "-q") as rec, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for p in payloads[:40]:
            tx.sendto(p, ("127.0.0.1", port))
        deadline = time.monotonic() + 60
        while "no packets for" not in rec.log.read_text():
            assert time.monotonic() < deadline, rec.log.read_text()
            time.sleep(0.05)
        for p in payloads[40:]:
            tx.sendto(p, ("127.0.0.1", port))
        rec.wait_until_read()
        deadline = time.monotonic() + 60  # the recorder says so once it has taken them
        while "packets again after" not in rec.log.read_text():
            assert time.monotonic() < deadline, rec.log.read_text()
            time.sleep(0.05)
        assert rec.stop() == 0
    assert "packets again after" in rec.log.read_text()
    _, msgs = _messages(rec.out)
    assert _recorded_payloads(msgs)["/velodyne_packets"] == payloads
