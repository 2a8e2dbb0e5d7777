"""End to end: ``lidarpkt replay`` sends real and canned captures to loopback while ``lidarpkt
record`` (a real subprocess) writes them to MCAP; every packet must come back byte-identical,
in order, with nothing reported lost. Also SIGKILL mid-run and the replay pacing."""

from __future__ import annotations

import json
import os
import signal
import socket
from dataclasses import replace
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lidarpkt.core.packet import Packet
from lidarpkt.recorder.replay import read_capture, replay
from conftest import end_process, external, start_process

mcap_reader = pytest.importorskip("mcap.reader")

REPO = Path(__file__).resolve().parents[2]


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _unread_bytes(port: int) -> int | None:
    """Bytes of datagrams waiting in the receive queues of the UDP sockets bound to ``port`` (Linux
    /proc/net/udp, udp6), ``None`` where that is not readable."""
    total = None
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        try:
            rows = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        total = total or 0
        for row in rows:
            f = row.split()
            if int(f[1].rsplit(":", 1)[1], 16) == port:
                total += int(f[4].split(":")[1], 16)
    return total


def wait_until_read(ports: list[int], timeout_s: float = 60.0) -> None:
    """Until nothing sent to ``ports`` waits in their sockets any more (the receiver has read it all),
    at most ``timeout_s``: a condition, not a guess of how long a loaded machine takes. Without
    /proc it returns at once (the recorder still reads its backlog when stopped)."""
    deadline = time.monotonic() + timeout_s
    while any(_unread_bytes(p) for p in ports):
        if time.monotonic() > deadline:
            raise AssertionError(f"datagrams still unread on {ports} after {timeout_s} s")
        time.sleep(0.02)


def _receivers(ports: list[int], timeout_s: float | None = None) -> list[socket.socket]:
    """UDP sockets bound on 127.0.0.1 to ``ports``, with a 4 MiB receive buffer (the caller closes them)."""
    socks = []
    for port in ports:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        s.bind(("127.0.0.1", port))
        s.settimeout(timeout_s)
        socks.append(s)
    return socks


class Recorder:
    """``lidarpkt record`` in a subprocess, waited on until it listens.

    ``bind=None`` leaves ``--bind`` out (a multicast listener binds its group); ``out`` puts the MCAP
    elsewhere than ``tmp_path`` (a small tmpfs). As a context manager it kills the process on the
    way out if the test left it running, so that a failing test leaves no recorder behind.
    """

    def __init__(self, tmp_path: Path, ports: list[int], *extra: str, bind: str | None = "127.0.0.1",
                 out: Path | None = None) -> None:
        self.out = out or tmp_path / "rec.mcap"
        self.report = tmp_path / "rec.json"
        self.log = tmp_path / "rec.log"
        self.ports = list(ports)
        cmd = [sys.executable, "-m", "lidarpkt", "record", *(["--bind", bind] if bind else []), "-o", str(self.out),
               "--report", str(self.report), *extra]
        for p in ports:
            cmd += ["--port", str(p)]
        # faulthandler: if it ever fails to stop, SIGABRT makes it print every thread's stack to the log
        self.proc = start_process(cmd, stdout=subprocess.DEVNULL, stderr=self.log.open("w"), cwd=REPO,
                                  env=dict(os.environ, PYTHONFAULTHANDLER="1"))
        deadline = time.monotonic() + 60
        while "listening on" not in self.log.read_text():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                end_process(self.proc)
                raise AssertionError(f"record did not start: {self.log.read_text()}")
            time.sleep(0.02)

    def wait_until_read(self, timeout_s: float = 60.0) -> None:
        """Until the recorder has read every datagram sent to its ports (see :func:`wait_until_read`)."""
        wait_until_read(self.ports, timeout_s)

    def stop(self, sig=signal.SIGTERM) -> int:
        self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.send_signal(signal.SIGABRT)  # the stacks of where it hangs, for the failure message
            try:
                self.proc.wait(timeout=10)
            finally:
                if self.proc.poll() is None:
                    self.proc.kill()
            raise AssertionError(f"record did not stop within 60 s of {signal.Signals(sig).name}; its log, "
                                 f"with the stacks of its threads:\n{self.log.read_text()}") from None

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *_exc) -> None:
        end_process(self.proc)


def _messages(path: Path):
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as fh:
        reader = mcap_reader.make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        msgs = [(ch.topic, m.log_time, d) for _, ch, m, d in reader.iter_decoded_messages(log_time_order=False)]
    return summary, msgs


def _recorded_payloads(msgs) -> dict[str, list[bytes]]:
    out: dict[str, list[bytes]] = {}
    for topic, _, m in msgs:
        if topic == "/velodyne_packets":
            out.setdefault(topic, []).extend(bytes(p.data) for p in m.packets)
        elif topic in ("/ouster/lidar_packets", "/ouster/imu_packets"):
            out.setdefault(topic, []).append(bytes(m.buf))
        elif topic == "/velodyne_position_packets":
            out.setdefault(topic, []).append(bytes(m.data))
    return out


def _by_size(packets: list[Packet]) -> dict[int, list[bytes]]:
    out: dict[int, list[bytes]] = {}
    for p in packets:
        out.setdefault(len(p.payload), []).append(p.payload)
    return out


def _replay_and_record(tmp_path, capture: Path, *, metadata: Path | None = None, via_cli: bool = False):
    lidar_port, aux_port = _free_ports(2)
    packets = list(read_capture(str(capture)))
    extra = ["--chunk-seconds", "0.2", "-q"] + (["--metadata", str(metadata)] if metadata else [])
    rec = Recorder(tmp_path, [lidar_port, aux_port], *extra)
    try:
        # lidar packets go to --to whatever their port; every other stream is mapped to aux_port
        aux_orig = {p.dst.port for p in packets if p.dst is not None}
        if via_cli:
            cmd = [sys.executable, "-m", "lidarpkt", "replay", str(capture), "--to", f"127.0.0.1:{lidar_port}",
                   "--rate", "10", "-q"]
            for orig in sorted(aux_orig | {8308, 7503}):
                cmd += ["--port-map", f"{orig}:{aux_port}"]
            assert subprocess.run(cmd, cwd=REPO, timeout=120).returncode == 0
        else:
            replay(packets, "127.0.0.1", lidar_port, rate=10.0,
                   port_map={p: aux_port for p in aux_orig | {8308, 7503}})
        rec.wait_until_read()  # the last datagrams are in the recorder before it is stopped
    finally:
        rc = rec.stop()
    report = json.loads(rec.report.read_text())
    return rc, report, packets, rec


def _check_lossless(rc, report, packets, rec, lidar_topic, aux_topic):
    summary, msgs = _messages(rec.out)  # a clean stop leaves a summary and an index
    assert summary is not None and summary.statistics.message_count == len(msgs) and summary.chunk_indexes
    got = _recorded_payloads(msgs)
    sizes = _by_size(packets)
    lidar_size = 1206 if lidar_topic == "/velodyne_packets" else max(sizes)
    assert got[lidar_topic] == sizes[lidar_size]  # byte-identical and in order
    aux = [p for s, ps in sizes.items() if s != lidar_size for p in ps]
    if aux:
        assert got[aux_topic] == aux
    assert report["datagrams_received"] == len(packets) == report["packets"]
    assert report["lost_total"] == 0 and report["out_of_order"] == 0, report
    assert report["stopped_by"] == "SIGTERM" and rc == 0, rec.log.read_text()
    return msgs


def test_vlp16_dual_canned_capture_through_the_replay_cli(tmp_path):
    from lidarpkt import fixtures

    pcap = fixtures.canned("vlp16-dual")
    rc, report, packets, rec = _replay_and_record(tmp_path, pcap, via_cli=True)
    assert {p.payload[1204] for p in packets if len(p.payload) == 1206} == {0x39}
    msgs = _check_lossless(rc, report, packets, rec, "/velodyne_packets", "/velodyne_position_packets")
    data_stream = next(s for s in report["streams"] if s["kind"] == "velodyne_data")
    assert data_stream["frames"] == sum(1 for t, _, _ in msgs if t == "/velodyne_packets") - 1


def test_vlp16_dual_real_nebula_bag(tmp_path):
    bag = external("nebula/vlp16/1673400471837873222")
    rc, report, packets, rec = _replay_and_record(tmp_path, bag)
    assert len(packets) == 603  # SOURCES.md: 151 + 151 + 151 + 150
    _check_lossless(rc, report, packets, rec, "/velodyne_packets", None)


def test_ouster_os1_64_legacy_real_capture(tmp_path):
    pcap = external("ouster-sdk/OS-1-64_1024x10_fw20.pcap")
    rc, report, packets, rec = _replay_and_record(
        tmp_path, pcap, metadata=external("ouster-sdk/OS-1-64_sensor_config_reduced.json"), via_cli=True)
    assert {len(p.payload) for p in packets} == {12608, 48}
    msgs = _check_lossless(rc, report, packets, rec, "/ouster/lidar_packets", "/ouster/imu_packets")
    assert [t for t, _, _ in msgs].count("/ouster/metadata") == 1


def test_ouster_os1_64_legacy_canned_two_frames(tmp_path):
    from lidarpkt import fixtures

    pcap = fixtures.canned("os1-64-legacy")
    rc, report, packets, rec = _replay_and_record(tmp_path, pcap, metadata=fixtures.metadata_path(pcap))
    _check_lossless(rc, report, packets, rec, "/ouster/lidar_packets", "/ouster/imu_packets")
    lidar = next(s for s in report["streams"] if s["kind"] == "ouster_lidar")
    # two whole frames (fixtures.CANNED_FRAMES): the recorder counts frame-id changes ("rotations"), one here
    assert lidar["frames"] == 1


def test_frames_from_the_recording_equal_frames_from_the_capture(tmp_path):
    import lidarpkt

    pcap = external("rust-lidar-utils/velodyne_example.pcap")
    rc, report, packets, rec = _replay_and_record(tmp_path, pcap)
    direct = list(lidarpkt.open(pcap))
    again = list(lidarpkt.open(rec.out))
    assert len(direct) == len(again) > 0
    for a, b in zip(direct, again):
        # host times differ (a new capture), the sensor's own data must not
        assert np.array_equal(a.range_mm, b.range_mm) and np.array_equal(a.azimuth_deg, b.azimuth_deg)
        assert np.array_equal(a.reflectivity, b.reflectivity)


def test_sigkill_leaves_the_packets_before_the_last_chunk_readable(tmp_path):
    import warnings

    from lidarpkt.containers.bags import BagReader

    from lidarpkt.vendors.registry import bag_messages

    pcap = external("veloview/vlp-16-test-90deg-1-50-frames.pcap")  # about 2.5 s, 20 Hz
    packets = [p for p in read_capture(str(pcap)) if len(p.payload) == 1206]
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "--chunk-seconds", "0.2", "-q")

    def send():
        replay(packets, "127.0.0.1", port, rate=1.0)

    def on_disk() -> list[bytes]:
        """The packets a reader finds in the file as it is now (mid-write: cut at its end)."""
        from lidarpkt.errors import LidarpktError

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                return [row.tobytes() for b in BagReader(rec.out, messages=bag_messages()).batches() for row in b.payload]
            except (LidarpktError, FileNotFoundError):
                return []

    t = threading.Thread(target=send)
    t.start()
    # killed once chunks are on disk while the sender goes on (a condition, not a guess of how far a
    # loaded machine gets in some time): what was readable then must still be after the SIGKILL
    deadline = time.monotonic() + 60
    while len(before := on_disk()) < 100:
        assert time.monotonic() < deadline, "the recorder wrote no chunk"
        time.sleep(0.05)
    rec.proc.send_signal(signal.SIGKILL)
    rec.proc.wait(timeout=30)
    t.join(timeout=60)
    got = on_disk()
    # what is in the file is exactly the start of what was sent, with all that was there before the kill
    assert got == [p.payload for p in packets[: len(got)]]
    assert len(got) >= len(before) >= 100
    # the official reader, read as a stream (the file has no summary), sees the same packets
    from mcap.reader import NonSeekingReader
    from mcap_ros2.decoder import DecoderFactory

    official = []
    with open(rec.out, "rb") as fh:
        it = NonSeekingReader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(log_time_order=False)
        try:
            for _, ch, _, m in it:
                official += [bytes(p.data) for p in m.packets]
        except Exception:  # the cut at the end of the file
            pass
    assert official == got


def test_replay_paces_by_capture_time_over_rate():
    """Pacing with a fake clock: the sender sleeps until each packet's capture time / rate."""
    now = [0.0]
    sleeps: list[float] = []

    def sleep(s):
        sleeps.append(s)
        now[0] += s

    pk = [Packet(1_000_000_000 + i * 10_000_000, None, None, bytes(1206)) for i in range(101)]  # 1 s
    (port,) = _free_ports(1)
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", port))
    receiver.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    try:
        stats = replay(pk, "127.0.0.1", port, rate=4.0, clock=lambda: now[0], sleep=sleep)
        assert stats.packets == 101 and stats.per_port == {port: 101}
        assert sum(sleeps) == pytest.approx(0.25)  # 1 s of capture at 4x
        assert all(s > 0.001 for s in sleeps)
        stats = replay(pk, "127.0.0.1", port, rate=None, clock=lambda: now[0], sleep=sleep)
        assert len(sleeps) == 100  # --max: no more sleeping
    finally:
        receiver.close()


def test_a_recorded_mcap_replays_like_the_pcap_it_came_from(tmp_path):
    """pcap → ``decode`` MCAP → ``replay`` MCAP → ``record`` MCAP: the same packets again. MCAP keeps
    no ports, so the position packets go to 8308, mapped here to the recorder's second port."""
    pcap = external("rust-lidar-utils/velodyne_vlp16.pcap")  # data + position
    first = tmp_path / "first.mcap"
    r = subprocess.run([sys.executable, "-m", "lidarpkt", "decode", str(pcap), "-o", str(first), "--topics", "packets",
                        "-q"], cwd=REPO, timeout=120)
    assert r.returncode == 0
    lidar_port, aux_port = _free_ports(2)
    rec = Recorder(tmp_path, [lidar_port, aux_port], "-q")
    try:
        cmd = [sys.executable, "-m", "lidarpkt", "replay", str(first), "--to", f"127.0.0.1:{lidar_port}", "--rate", "10",
               "--port-map", f"8308:{aux_port}", "-q"]
        assert subprocess.run(cmd, cwd=REPO, timeout=120).returncode == 0
        rec.wait_until_read()
    finally:
        assert rec.stop() == 0
    _, msgs = _messages(rec.out)
    got = _recorded_payloads(msgs)
    sizes = _by_size(list(read_capture(str(pcap))))
    assert got["/velodyne_packets"] == sizes[1206] and got["/velodyne_position_packets"] == sizes[512]


def test_replay_loop_repeats_until_interrupted():
    pcap = external("rust-lidar-utils/velodyne_example.pcap")  # 84 packets
    (port,) = _free_ports(1)
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 << 20)
    rx.bind(("127.0.0.1", port))
    rx.settimeout(0.2)
    proc = start_process([sys.executable, "-m", "lidarpkt", "replay", str(pcap), "--to", f"127.0.0.1:{port}",
                          "--max", "--loop"], stderr=subprocess.PIPE, text=True, cwd=REPO)
    first = []
    deadline = time.monotonic() + 60
    try:
        while len(first) < 3 * 84 and time.monotonic() < deadline:
            try:
                first.append(rx.recv(65535))
            except socket.timeout:  # the replay process is still starting
                continue
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl-C: start_process gave it SIGINT's default, whatever pytest inherited
        try:
            _, err = proc.communicate(timeout=60)
        finally:
            end_process(proc)
            rx.close()
    assert proc.returncode == 0 and "sent" in err
    payloads = [p.payload for p in read_capture(str(pcap))]
    assert first == payloads * 3


def test_replay_without_metadata_sends_ouster_lidar_to_the_lidar_port_as_info_recognises_it():
    """Issue 14: without --metadata the non-legacy lidar packets went to 7502 (mapped), not --to,
    although `lidarpkt info` calls the stream Ouster lidar; now both recognise it by its header."""
    pcap = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap")  # non-legacy
    from lidarpkt.vendors.ouster.metadata_json import load_metadata

    md = load_metadata(external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"))
    lidar, other = _free_ports(2)
    socks = _receivers([lidar, other])
    try:
        packets = list(read_capture(str(pcap)))
        blind = replay(packets, "127.0.0.1", lidar, rate=None, port_map={7502: other, 7503: other})
        assert blind.unknown == 0 and blind.per_port == {lidar: 64, other: 10}
        noise = [replace(p, payload=bytes(len(p.payload))) for p in packets if len(p.payload) != 48]
        zeros = replay(noise, "127.0.0.1", lidar, rate=None, port_map={7502: other})
        assert zeros.unknown == 64 and zeros.per_port == {other: 64}  # the size alone is not enough
        told = replay(packets, "127.0.0.1", lidar, rate=None, port_map={7503: other}, metadata=md)
        assert told.unknown == 0 and told.per_port == {lidar: 64, other: 10}
    finally:
        for s in socks:
            s.close()


def test_replay_of_an_mcap_uses_the_metadata_recorded_in_it(tmp_path):
    pcap = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap")
    meta = external("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json")
    mcap = tmp_path / "os2.mcap"
    assert subprocess.run([sys.executable, "-m", "lidarpkt", "decode", str(pcap), "--metadata", str(meta), "-o",
                           str(mcap), "--topics", "packets", "-q"], cwd=REPO, timeout=120).returncode == 0
    lidar, other = _free_ports(2)
    socks = _receivers([lidar, other], timeout_s=5)
    try:
        r = subprocess.run([sys.executable, "-m", "lidarpkt", "replay", str(mcap), "--to", f"127.0.0.1:{lidar}",
                            "--max", "--port-map", f"7503:{other}"], cwd=REPO, timeout=120, capture_output=True,
                           text=True)
        assert r.returncode == 0 and "no known stream" not in r.stderr, r.stderr
        got_lidar = [socks[0].recv(65535) for _ in range(64)]
        got_imu = [socks[1].recv(65535) for _ in range(10)]
    finally:
        for s in socks:
            s.close()
    packets = list(read_capture(str(pcap)))
    assert got_lidar == [p.payload for p in packets if len(p.payload) > 48]
    assert got_imu == [p.payload for p in packets if len(p.payload) == 48]


def test_live_recording_of_the_ouster_capture_decodes_to_the_same_frame(tmp_path):
    import lidarpkt

    pcap = external("ouster-sdk/OS-1-64_1024x10_fw20.pcap")
    meta = external("ouster-sdk/OS-1-64_sensor_config_reduced.json")
    rc, report, packets, rec = _replay_and_record(tmp_path, pcap, metadata=meta)
    assert rc == 0 and report["lost_total"] == 0
    direct = list(lidarpkt.open(pcap, metadata=meta))
    again = list(lidarpkt.open(rec.out))  # no metadata given: the recording carries it
    assert len(direct) == len(again) == 1  # SOURCES.md: exactly one frame
    a, b = direct[0], again[0]
    assert a.frame_id == b.frame_id == 189
    for name in ("range_mm", "reflectivity", "signal", "near_ir", "column_timestamp_ns", "measurement_id",
                 "status", "column_valid"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    np.testing.assert_array_equal(a.xyz(), b.xyz())
