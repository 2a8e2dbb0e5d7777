"""A bag keeps no UDP ports, and nebula's ``RobosenseScan`` carries the DIFOP among the MSOP packets: ``export --format
pcap`` and ``replay`` of the bag send each kind to its factory port (MSOP 6699, DIFOP 7788, rs_driver's
``msop_port`` and ``difop_port``), where RoboSense's own driver listens for them. The pcap is read by dpkt, the
replayed datagrams by sockets bound to the two ports; packets are told apart by their identifiers here, not by
lidarpkt."""

from __future__ import annotations

import json
import re
import selectors
import socket
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import lidarpkt
from archive_cases import lidarpkt_cli
from conftest import end_process, external, start_process
from robosense_bag import BAG, all_packets, batches

dpkt = pytest.importorskip("dpkt")

REPO = Path(__file__).resolve().parents[2]
DIFOP_ID = bytes.fromhex("a5ff005a11115555")  # a DIFOP packet's first 8 bytes (the manuals' identifier)
MSOP_PORT, DIFOP_PORT = 6699, 7788  # the manuals' factory ports, rs_driver's defaults
SENSOR, HOST = "192.168.1.200", "192.168.1.102"


def _frames(path) -> list:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return list(lidarpkt.open(path))


def _udp_datagrams(pcap: Path) -> list[tuple[str, str, int, int, bytes]]:
    """(source address, destination address, source port, destination port, payload) of every record, by dpkt."""
    out = []
    with open(pcap, "rb") as fh:
        for _, frame in dpkt.pcap.UniversalReader(fh):
            ip = dpkt.ethernet.Ethernet(frame).data
            assert isinstance(ip, dpkt.ip.IP) and not ip.mf and ip.offset == 0  # 1248 B: never fragmented
            udp = ip.data
            assert isinstance(udp, dpkt.udp.UDP) and udp.ulen == 8 + len(udp.data)
            out.append((socket.inet_ntoa(ip.src), socket.inet_ntoa(ip.dst), udp.sport, udp.dport, bytes(udp.data)))
    return out


def test_the_record_parts_a_scan_by_kind():
    """The vendor record's ``split``, through the registry: each message of the bag (one batch, as rosbags reads
    it) parted into its MSOP and its DIFOP, every packet once, the parts in the order of their first packet."""
    from lidarpkt.vendors import registry

    kinds = []
    for batch in batches():
        match = registry.classify(batch)
        parts = registry.by_kind(batch, match)
        np.testing.assert_array_equal(np.sort(np.concatenate([p.index for _, p in parts])), batch.index)
        assert [int(p.index[0]) for _, p in parts] == sorted(int(p.index[0]) for _, p in parts)
        for m, p in parts:
            difop = [row[:8].tobytes() == DIFOP_ID for row in p.payload]
            assert all(difop) if m.kind == "difop" else not any(difop)
            assert registry.vendor(m.vendor).endpoints(m)[1].port == (DIFOP_PORT if m.kind == "difop" else MSOP_PORT)
        kinds.append([m.kind for m, _ in parts])
    assert sorted(kinds) == [["msop"]] * 4 + [["msop", "difop"]]  # one message carries the DIFOP among its MSOP


def test_export_pcap_sends_msop_to_6699_and_difop_to_7788(tmp_path):
    bag = external(BAG)
    run = lidarpkt_cli("export", str(bag), "--format", "pcap", "-o", str(tmp_path / "pcap"), "-q")
    assert run.returncode == 0, run.stderr
    (pcap,) = (tmp_path / "pcap").rglob("*.pcap")
    datagrams = _udp_datagrams(pcap)
    payload, _ = all_packets()  # the bag read by rosbags
    assert [d[4] for d in datagrams] == [row.tobytes() for row in payload]  # every packet, in order
    difop = [d for d in datagrams if d[4][:8] == DIFOP_ID]
    msop = [d for d in datagrams if d[4][:8] != DIFOP_ID]
    assert len(difop) == 1 and len(msop) == 750
    assert {d[:4] for d in difop} == {(SENSOR, HOST, DIFOP_PORT, DIFOP_PORT)}
    assert {d[:4] for d in msop} == {(SENSOR, HOST, MSOP_PORT, MSOP_PORT)}
    doc = json.loads(lidarpkt_cli("info", "--json", str(pcap)).stdout)
    kinds = {s["dst_port"]: s["stream_kind"] for s in doc["streams"]}
    assert kinds == {MSOP_PORT: "robosense_msop", DIFOP_PORT: "robosense_difop"}
    again, direct = _frames(pcap), _frames(bag)
    assert len(again) == len(direct) > 0
    for a, b in zip(again, direct):
        assert (a.frame_id, a.timestamp_ns, a.sensor.model, a.return_labels) == \
            (b.frame_id, b.timestamp_ns, b.sensor.model, b.return_labels)
        for name in ("range_mm", "reflectivity", "azimuth_deg", "column_timestamp_ns", "column_valid"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        np.testing.assert_array_equal(a.xyz(), b.xyz())


def _receive(socks: list[socket.socket], proc: subprocess.Popen, quiet_s: float = 1.0,
             timeout_s: float = 120.0) -> list[list[bytes]]:
    """The datagrams each socket receives while ``proc`` runs and until they stay quiet ``quiet_s`` after it ends."""
    got: list[list[bytes]] = [[] for _ in socks]
    with selectors.DefaultSelector() as sel:
        for i, s in enumerate(socks):
            sel.register(s, selectors.EVENT_READ, i)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            events = sel.select(timeout=quiet_s)
            if not events and proc.poll() is not None:
                break
            for key, _ in events:
                got[key.data].append(key.fileobj.recv(65535))
    return got


def test_replay_of_the_bag_sends_the_difop_to_the_difop_port():
    from test_replay_record import _free_ports, _receivers

    bag = external(BAG)
    msop_port, difop_port = _free_ports(2)
    socks = _receivers([msop_port, difop_port])
    proc = None
    try:
        proc = start_process([sys.executable, "-m", "lidarpkt", "replay", str(bag), "--to", f"127.0.0.1:{msop_port}",
                              "--port-map", f"{DIFOP_PORT}:{difop_port}", "--max"],
                             cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        on_msop, on_difop = _receive(socks, proc)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 0, err
    finally:
        for s in socks:
            s.close()
        if proc is not None:
            end_process(proc)
    assert re.search(rf"\b750 to port {msop_port}\b", err) and re.search(rf"\b1 to port {difop_port}\b", err), err
    payload, _ = all_packets()
    rows = [row.tobytes() for row in payload]
    assert on_difop == [r for r in rows if r[:8] == DIFOP_ID]  # the one DIFOP, where rs_driver listens for it
    assert on_msop == [r for r in rows if r[:8] != DIFOP_ID]  # the 750 MSOP in order, no DIFOP among them
