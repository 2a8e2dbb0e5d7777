"""The largest sustained packet rate ``lidarpkt record`` keeps with zero loss on loopback.

For each sensor (``vlp16``: 1206-B data packets; ``os-128-dual``: 33024-B Ouster
RNG19_RFL8_SIG16_NIR16_DUAL packets of 128 beams, metadata ouster-sdk/empty_pcap.json), a real
``lidarpkt record`` subprocess listens on 127.0.0.1 and this script sends it packets at a fixed rate
for ``--seconds`` (paced every millisecond), then stops it with SIGTERM and reads its JSON report.
A step is *held* when every packet sent was recorded (report ``packets`` = sent) and the recorder
reported no loss (``lost_total`` = 0). The rate is stepped up (×1.5) until a step fails, then
bisected between the last held and the first failed rate.

The packets are one continuous stream (VLP-16 device timestamps advancing one period per packet;
Ouster frame and measurement ids in order), so the recorder's own gap counter would see any loss.
To keep the recorder's 256 MB queue from hiding a rate it cannot sustain over a short step, the
recorder runs with ``--queue 16`` (MB) unless ``--queue`` says otherwise; the kernel buffer is the
default 32 MiB.

    python benchmarks/bench_record_load.py [--sensor vlp16|os-128-dual|all] [--seconds 8] [--start RATE]

Prints one line per step (rate asked, rate sent, recorded, lost, recorder CPU) and the largest held
rate, in packets/s and MB/s. The sender is this Python process: when it cannot send at the asked
rate the step is marked "sender-limited" and the search stops there.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))


def vlp16_payloads(n: int) -> tuple[list[bytes], list[str]]:
    from lidarpkt.containers.pcap_reader import read_packets

    real = [p.payload for p in read_packets(EXTERNAL / "veloview/vlp-16-test-90deg-1-50-frames.pcap") if len(p.payload) == 1206]
    out = []
    for i in range(n):
        b = bytearray(real[i % len(real)])
        struct.pack_into("<I", b, 1200, (1_000_000_000 + i * 1327) % 3_600_000_000)
        b[1204] = 0x37
        out.append(bytes(b))
    return out, []


def ouster_payloads(n: int, meta: Path, low: int = 0) -> list[bytes]:
    """``n`` packets of a continuous synthetic stream of the sensor ``meta`` describes: measurement
    ids round the frame, 97.656 µs per column, frame ids counting up (in the packet header, or per
    column for LEGACY), random pixel values from ``low``. Shared by bench_record_view."""
    from lidarpkt.vendors.ouster import empty_fields, encode_packets, load_metadata

    md = load_metadata(meta)
    per = md.columns_per_frame // md.columns_per_packet
    f = empty_fields(md, n)
    rng = np.random.default_rng(0)
    mid = np.arange(n * md.columns_per_packet).reshape(n, md.columns_per_packet) % md.columns_per_frame
    f.measurement_id[:] = mid
    f.timestamp_ns[:] = 10**9 + np.arange(mid.size).reshape(mid.shape) * 97_656
    f.status[:] = 1
    frame_ids = (np.arange(n) // per) % 65536
    if "frame_id" in f.header:
        f.header["frame_id"][:] = frame_ids
    else:
        f.column_frame_id[:] = frame_ids[:, None]
    for bf in md.profile.pixel_fields:
        if bf.name in f.pixels:
            f.pixels[bf.name][:] = rng.integers(low, 1 << min(bf.width, 12), f.pixels[bf.name].shape) << bf.upshift
    return [r.tobytes() for r in encode_packets(f, md)]


def ouster_dual_128_payloads(n: int) -> tuple[list[bytes], list[str]]:
    meta = EXTERNAL / "ouster-sdk/empty_pcap.json"
    return ouster_payloads(n, meta), ["--metadata", str(meta)]


SENSORS = {"vlp16": vlp16_payloads, "os-128-dual": ouster_dual_128_payloads}


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def step(payloads: list[bytes], extra: list[str], rate: float, seconds: float, queue_mb: float, workdir: Path) -> dict:
    port = free_port()
    out, report, log = workdir / "load.mcap", workdir / "load.json", workdir / "load.log"
    for p in (out, report):
        if p.exists():
            p.unlink()
    cmd = [sys.executable, "-m", "lidarpkt", "record", "--bind", "127.0.0.1", "--port", str(port), "-o", str(out),
           "--report", str(report), "--queue", str(queue_mb), "-q", *extra]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=log.open("w"))
    try:
        deadline = time.monotonic() + 30
        while "listening on" not in log.read_text():
            if proc.poll() is not None or time.monotonic() > deadline:
                raise SystemExit(f"record did not start: {log.read_text()}")
            time.sleep(0.02)
        total = int(rate * seconds)
        sent = 0
        behind = 0.0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            tx.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8 << 20)
            send = tx.sendto
            dst = ("127.0.0.1", port)
            n = len(payloads)
            t0 = time.perf_counter()
            while sent < total:
                now = time.perf_counter()
                due = min(total, int((now - t0) * rate) + 1)
                while sent < due:
                    send(payloads[sent % n], dst)
                    sent += 1
                behind = max(behind, (now - t0) - sent / rate)
                ahead = sent / rate - (time.perf_counter() - t0)
                if ahead > 0.001:
                    time.sleep(ahead)
            elapsed = time.perf_counter() - t0
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=120)
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    finally:
        if proc.poll() is None:
            proc.kill()
    r = json.loads(report.read_text())
    return {
        "rate": rate,
        "sent": sent,
        "sent_rate": sent / elapsed,
        "recorded": r["packets"],
        "lost_total": r["lost_total"],
        "kernel_drops": r["kernel_drops"],
        "queue_overflow": r["queue_overflow"],
        "held": r["packets"] == sent and r["lost_total"] == 0,
        "sender_limited": sent / elapsed < 0.97 * rate,
        "children_cpu_s": ru.ru_utime + ru.ru_stime,
    }


def search(name: str, seconds: float, start: float, queue_mb: float, max_rate: float) -> dict:
    rates_needed = int(max_rate * seconds) + 1
    payloads, extra = SENSORS[name](min(rates_needed, 20_000 if name == "vlp16" else 4096))
    size = len(payloads[0])
    print(f"== {name}: {size}-byte packets, {seconds:g} s per step, recorder --queue {queue_mb:g} MB", flush=True)
    workdir = Path(tempfile.mkdtemp(prefix="lidarpkt-load-"))
    held, failed = None, None
    rate = start
    cpu_before = 0.0
    steps = []

    def run(rate):
        nonlocal cpu_before
        s = step(payloads, extra, rate, seconds, queue_mb, workdir)
        s["recorder_cpu_s"] = s["children_cpu_s"] - cpu_before
        cpu_before = s["children_cpu_s"]
        steps.append(s)
        print(f"  asked {rate:9.0f} pkt/s  sent {s['sent_rate']:9.0f} pkt/s ({s['sent_rate'] * size / 1e6:7.1f} MB/s)  "
              f"recorded {s['recorded']:7d}/{s['sent']:7d}  lost {s['lost_total']:6d} (kernel {s['kernel_drops']}, "
              f"queue {s['queue_overflow']})  recorder CPU {s['recorder_cpu_s']:5.1f} s  "
              f"{'HELD' if s['held'] else 'LOSS'}{'  sender-limited' if s['sender_limited'] else ''}", flush=True)
        return s

    while rate <= max_rate:
        s = run(rate)
        if s["held"]:
            held = s
            if s["sender_limited"]:
                break
            rate *= 1.5
        else:
            failed = s
            break
    if held is not None and failed is not None:
        lo, hi = held["rate"], failed["rate"]
        for _ in range(3):
            mid = (lo + hi) / 2
            s = run(mid)
            if s["held"]:
                lo, held = mid, s
            else:
                hi = mid
    for p in workdir.iterdir():
        p.unlink()
    workdir.rmdir()
    result = {"sensor": name, "packet_bytes": size, "held": held, "first_loss": failed, "steps": steps}
    if held:
        print(f"  largest rate held with zero loss: {held['sent_rate']:.0f} pkt/s = "
              f"{held['sent_rate'] * size / 1e6:.1f} MB/s", flush=True)
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sensor", default="all", choices=[*SENSORS, "all"])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--start", type=float, help="first rate (default 1000 pkt/s VLP-16, 500 Ouster)")
    ap.add_argument("--max-rate", type=float, default=200_000)
    ap.add_argument("--queue", type=float, default=16, help="recorder --queue, MB (16)")
    ap.add_argument("--json", help="write the steps as JSON here")
    args = ap.parse_args()
    results = []
    for name in (SENSORS if args.sensor == "all" else [args.sensor]):
        start = args.start or (1000 if name == "vlp16" else 500)
        results.append(search(name, args.seconds, start, args.queue, args.max_rate))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
