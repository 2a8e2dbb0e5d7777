"""Recorder throughput: the packet rate ``lidarpkt record`` keeps on loopback, and decode → MCAP speed.

    python benchmarks/bench_record.py [--seconds S] [--rates 10,30,100,max] [--quick]

For each capture (VLP-16 strongest, Ouster OS1-64 legacy) and each replay rate, a real
``lidarpkt record`` subprocess listens on a loopback port while this process replays the
capture's lidar packets (repeated to last about ``--seconds`` at that rate). Reported per
run: packets sent, packets/s and MB/s achieved by the sender, what the recorder received,
and its loss counters (kernel drops, queue overflow). Then ``lidarpkt decode`` of the
VeloView capture to MCAP (packets + points) is timed.

The numbers depend on the machine and on what else runs on it; nothing here is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lidarpkt.core.packet import Packet  # noqa: E402
from lidarpkt.recorder.replay import read_capture, replay  # noqa: E402

EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))
CAPTURES = {
    "vlp16": (EXTERNAL / "veloview" / "vlp-16-test-90deg-1-50-frames.pcap", 1206),
    "os1-64-legacy": (EXTERNAL / "ouster-sdk" / "OS-1-64_1024x10_fw20.pcap", 12608),
}


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _packets(path: Path, size: int, seconds: float, rate: float | None) -> list[Packet]:
    base = [p for p in read_capture(str(path)) if len(p.payload) == size]
    span = base[-1].timestamp_ns - base[0].timestamp_ns + (base[1].timestamp_ns - base[0].timestamp_ns)
    real_s = seconds * (rate or 100.0)
    out: list[Packet] = []
    k = 0
    while (k * span) / 1e9 < real_s:
        out += [Packet(p.timestamp_ns + k * span, None, None, p.payload) for p in base]
        k += 1
    return out


def run_one(name: str, rate: float | None, seconds: float, tmp: Path) -> dict:
    path, size = CAPTURES[name]
    packets = _packets(path, size, seconds, rate)
    port = _free_port()
    out, report, log = tmp / f"{name}.mcap", tmp / f"{name}.json", tmp / f"{name}.log"
    proc = subprocess.Popen([sys.executable, "-m", "lidarpkt", "record", "--port", str(port), "--bind", "127.0.0.1",
                             "-o", str(out), "--report", str(report), "-q"], stderr=log.open("w"), cwd=REPO)
    while "listening on" not in log.read_text():
        if proc.poll() is not None:
            raise SystemExit(log.read_text())
        time.sleep(0.02)
    cpu0, t0 = _cpu_seconds(proc.pid), time.perf_counter()
    stats = replay(packets, "127.0.0.1", port, rate=rate)
    time.sleep(1.0)
    cpu, wall = _cpu_seconds(proc.pid) - cpu0, time.perf_counter() - t0
    proc.send_signal(signal.SIGTERM)
    proc.wait(timeout=120)
    rep = json.loads(report.read_text())
    return {
        "capture": name, "rate": "max" if rate is None else rate, "sent": stats.packets,
        "send_pkt_per_s": round(stats.packets / stats.seconds), "send_MB_per_s": round(stats.bytes / stats.seconds / 1e6, 1),
        "received": rep["datagrams_received"], "kernel_drops": rep["kernel_drops"],
        "queue_overflow": rep["queue_overflow"], "file_MB": round(rep["bytes_written"] / 1e6, 1),
        # CPU of the recorder process (all its threads) while the replay ran and 1 s after, % of one core
        "recorder_cpu_s": round(cpu, 2), "recorder_cpu_pct": round(100 * cpu / wall, 1),
    }


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a live process (Linux /proc), seconds."""
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def bench_decode(tmp: Path) -> list[dict]:
    """``decode`` of the VeloView capture to MCAP, timed in this process (start-up excluded)."""
    import argparse as _argparse

    from lidarpkt.cli import decode

    pcap = CAPTURES["vlp16"][0]
    out = []
    for i, topics in enumerate(("packets", "packets", "packets,points", "packets,points,images")):
        parser = _argparse.ArgumentParser()
        decode.add_arguments(parser)
        args = parser.parse_args([str(pcap), "-o", str(tmp / "decode.mcap"), "--topics", topics, "-q"])
        t0 = time.perf_counter()
        decode.run(args)
        dt = time.perf_counter() - t0
        if i == 0:  # a warm-up run: imports, type store, first-touch of the file
            continue
        out.append({"decode_topics": topics, "seconds": round(dt, 3), "input_MB": round(pcap.stat().st_size / 1e6, 2),
                    "input_MB_per_s": round(pcap.stat().st_size / 1e6 / dt, 1),
                    "output_MB": round((tmp / "decode.mcap").stat().st_size / 1e6, 2)})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=3.0, help="wall-clock length of each run (3)")
    ap.add_argument("--rates", default="10,30,100,max", help="replay rates to try (10,30,100,max)")
    ap.add_argument("--quick", action="store_true", help="one short run per capture at 10x")
    args = ap.parse_args()
    rates = ["10"] if args.quick else args.rates.split(",")
    seconds = 1.0 if args.quick else args.seconds
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for name in CAPTURES:
            for r in rates:
                print(json.dumps(run_one(name, None if r == "max" else float(r), seconds, tmp)), flush=True)
        for row in bench_decode(tmp):
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
