"""``record --view --points`` at 10× real time: does the view or the point decoding cost the file a packet?

    python benchmarks/bench_record_view.py [--seconds 3] [--rate 10] [--sensor vlp16-dual|os1-64-legacy|all]

For each sensor a continuous synthetic stream (device timestamps / frame and measurement ids in
order, so that the recorder's own gap counters would see any loss) is replayed over loopback at
``--rate`` × real time for about ``--seconds`` of wall time, to a real ``lidarpkt record`` subprocess,
twice: alone, then with ``--view --points`` and a Foxglove WebSocket client (tests/view_client.py)
subscribed to every channel. Reported per run: packets sent and recorded, ``lost_total`` (the
recorder's loss accounting), frames decoded off the receive path, point-cloud frames written,
frames dropped for the view, packets not decoded, frames the client received, and the recorder's
CPU (all threads, % of one core, from /proc while the replay ran and 1 s after).

* ``vlp16-dual``: ``bench_velodyne.build(mode="dual")``, 600 RPM, 1508 packets/s of 1206 B;
* ``os1-64-legacy``: OS1-64 LEGACY 1024×10 (fixtures/canned/os1-64-legacy.json), 640 packets/s
  of 12608 B, encoded with lidarpkt.vendors.ouster.encode_packets.

The numbers depend on the machine and what else runs on it; nothing is asserted here (the
zero-loss property is asserted by tests/view/test_view_record.py).
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path


REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))
sys.path.insert(0, str(REPO / "benchmarks"))

from lidarpkt.core.packet import Packet  # noqa: E402
from bench_record import _cpu_seconds, _free_port  # noqa: E402
from lidarpkt.recorder.replay import read_capture, replay  # noqa: E402

OUSTER_METADATA = REPO / "fixtures" / "canned" / "os1-64-legacy.json"


def vlp16_dual(seconds_of_sensor_time: float, tmp: Path) -> tuple[list[Packet], list[str]]:
    from bench_velodyne import build

    path = tmp / "vlp16-dual.pcap"
    build(path, seconds_of_sensor_time, mode="dual")
    return list(read_capture(str(path))), []


def os1_64_legacy(seconds_of_sensor_time: float, tmp: Path) -> tuple[list[Packet], list[str]]:
    from bench_record_load import ouster_payloads
    from lidarpkt.vendors.ouster import load_metadata

    md = load_metadata(OUSTER_METADATA)
    per_frame = md.columns_per_frame // md.columns_per_packet
    payloads = ouster_payloads(int(seconds_of_sensor_time * 10 * per_frame), OUSTER_METADATA, low=1)
    period_ns = 100_000_000 // per_frame
    t0 = time.time_ns()
    return [Packet(t0 + i * period_ns, None, None, p) for i, p in enumerate(payloads)], \
        ["--metadata", str(OUSTER_METADATA)]


SENSORS = {"vlp16-dual": vlp16_dual, "os1-64-legacy": os1_64_legacy}


def run_one(name: str, packets: list[Packet], extra: list[str], rate: float, view: bool, tmp: Path) -> dict:
    port = _free_port()
    tag = f"{name}-{'view' if view else 'alone'}"
    out, report, log = tmp / f"{tag}.mcap", tmp / f"{tag}.json", tmp / f"{tag}.log"
    args = ["--view", "--points", "--ws", "127.0.0.1:0"] if view else []
    proc = subprocess.Popen([sys.executable, "-m", "lidarpkt", "record", "--port", str(port), "--bind", "127.0.0.1",
                             "-o", str(out), "--report", str(report), "-q", *extra, *args],
                            stderr=log.open("w"), cwd=REPO)
    client = None
    try:
        while "listening on" not in log.read_text():
            if proc.poll() is not None:
                raise SystemExit(log.read_text())
            time.sleep(0.02)
        if view:
            import re

            from view_client import FoxgloveClient

            ws = int(re.search(r"serving ws://[^:]+:(\d+)", log.read_text()).group(1))
            client = FoxgloveClient(f"ws://127.0.0.1:{ws}")
        cpu0, t0 = _cpu_seconds(proc.pid), time.perf_counter()
        stats = replay(packets, "127.0.0.1", port, rate=rate)
        time.sleep(1.0)
        cpu, wall = _cpu_seconds(proc.pid) - cpu0, time.perf_counter() - t0
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=300)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(60)
        if client is not None:
            client.close()
    rep = json.loads(report.read_text())
    seen = len([m for m in client.messages if "/points/" in m.topic]) if client is not None else None
    return {
        "sensor": name, "view+points": view, "rate": rate, "sent": stats.packets,
        "send_pkt_per_s": round(stats.packets / stats.seconds), "recorded": rep["packets"],
        "lost_total": rep["lost_total"], "frames_decoded": rep.get("frames_decoded"),
        "points_frames_written": rep.get("points_frames_written"),
        "view_frames_dropped": rep.get("view_frames_dropped"), "packets_not_decoded": rep.get("packets_not_decoded"),
        "client_point_clouds": seen, "recorder_cpu_pct": round(100 * cpu / wall, 1),
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="wall seconds of replay per run (3)")
    ap.add_argument("--rate", type=float, default=10.0, help="replay speed, × real time (10)")
    ap.add_argument("--sensor", choices=[*SENSORS, "all"], default="all")
    ap.add_argument("--json", metavar="FILE", help="also write the rows as JSON")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        for name in (SENSORS if args.sensor == "all" else [args.sensor]):
            packets, extra = SENSORS[name](args.seconds * args.rate, tmp)
            for view in (False, True):
                row = run_one(name, packets, extra, args.rate, view, tmp)
                rows.append(row)
                print(json.dumps(row), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
