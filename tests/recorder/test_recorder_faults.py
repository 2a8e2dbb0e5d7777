"""``lidarpkt record`` (a real subprocess, real loopback sockets) under faults: a burst above what it
can take (every datagram sent is either recorded or reported lost, exactly), and a sensor that stops
and restarts with its clock reset (recording goes on, the restart is reported, nothing is called lost).

SIGKILL and disk full are in tests/recorder/test_replay_record.py and tests/recorder/test_recorder_record.py.
"""

from __future__ import annotations

import json
import socket
import struct
import time

from conftest import external
from lidarpkt.recorder.replay import read_capture
from test_replay_record import Recorder, _free_ports, _messages, _recorded_payloads

PERIOD_US = 1327  # VLP-16 single-return packet period, rounded to the µs the packets carry


def _continuous_vlp16(n: int, start_us: int = 1_000_000_000) -> list[bytes]:
    """``n`` real VLP-16 data payloads (cycled) whose device timestamps advance by one packet period
    each, so that the recorder's gap counter sees one unbroken stream."""
    real = [p.payload for p in read_capture(str(external("veloview/vlp-16-test-90deg-1-50-frames.pcap")))
            if len(p.payload) == 1206]
    out = []
    for i in range(n):
        b = bytearray(real[i % len(real)])
        struct.pack_into("<I", b, 1200, (start_us + i * PERIOD_US) % 3_600_000_000)
        b[1204] = 0x37  # strongest: the period above
        out.append(bytes(b))
    return out


def _is_subsequence(sub: list[bytes], seq: list[bytes]) -> bool:
    it = iter(seq)
    return all(any(x == y for y in it) for x in sub)


def test_a_burst_above_the_sustainable_rate_is_recorded_or_reported_lost_exactly(tmp_path):
    """8000 VLP-16 packets sent back to back into a recorder with a ~4 KiB kernel buffer and a
    64 KiB queue: sent = recorded + kernel drops + queue overflow, exactly (the drops after the last
    datagram read included), what was recorded is in order, and lost_total says the same."""
    payloads = _continuous_vlp16(8000)
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "-q", "--rcvbuf", "0.004", "--queue", "0.0625", "--chunk-seconds", "0.1")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for p in payloads:
            tx.sendto(p, ("127.0.0.1", port))
    rec.wait_until_read()  # the kernel holds nothing more: every datagram was read or dropped
    rc = rec.stop()
    report = json.loads(rec.report.read_text())
    _, msgs = _messages(rec.out)
    got = _recorded_payloads(msgs)["/velodyne_packets"]
    local = report["kernel_drops"] + report["queue_overflow"]
    assert local > 0, "the burst was absorbed: nothing tested"
    assert len(got) == report["packets"] == report["datagrams_received"] - report["queue_overflow"]
    assert len(payloads) == len(got) + local, report
    assert _is_subsequence(got, payloads)
    assert report["lost_total"] == len(payloads) - len(got)  # loopback: nothing lost before this machine
    assert report["lost_gaps"] <= report["lost_total"]
    assert rc == 1  # recorded, with losses


def test_a_sensor_that_stops_and_restarts_is_reported_and_nothing_is_lost(tmp_path):
    """300 packets, 1.5 s of silence, then 300 more from a sensor whose clock restarted (its device
    timestamps jump back by minutes): the recorder keeps running, says the stream fell silent and came
    back, counts one interruption, reports no loss, and records all 600 packets in order."""
    before = _continuous_vlp16(300, start_us=2_000_000_000)
    after = _continuous_vlp16(300, start_us=1_000_000_000)
    (port,) = _free_ports(1)
    rec = Recorder(tmp_path, [port], "--chunk-seconds", "0.1")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for p in before:
            tx.sendto(p, ("127.0.0.1", port))
            time.sleep(0.0005)
        deadline = time.monotonic() + 60
        while "no packets for" not in rec.log.read_text():
            assert rec.proc.poll() is None and time.monotonic() < deadline, rec.log.read_text()
            time.sleep(0.05)
        for p in after:
            tx.sendto(p, ("127.0.0.1", port))
            time.sleep(0.0005)
    rec.wait_until_read()
    deadline = time.monotonic() + 60  # the recorder says so once it has taken them
    while "packets again after" not in rec.log.read_text():
        assert rec.proc.poll() is None and time.monotonic() < deadline, rec.log.read_text()
        time.sleep(0.05)
    assert rec.stop() == 0
    log = rec.log.read_text()
    assert "still listening" in log and "packets again after" in log
    assert "interrupted 1 time" in log
    report = json.loads(rec.report.read_text())
    assert report["interruptions"] == 1 and report["lost_total"] == 0 and report["lost_gaps"] == 0
    _, msgs = _messages(rec.out)
    assert _recorded_payloads(msgs)["/velodyne_packets"] == before + after
