"""Memory of the pcap reader under millions of orphan IPv4 fragments (datagrams that never complete).

Writes a classic pcap of ``--count`` first fragments (More Fragments set, offset 0), each of a
different datagram (IP ID and source address vary), with ``--fragment-bytes`` of data each, and a
complete 1206-byte UDP packet after every ``--good-every``-th; then reads it with
``lidarpkt.containers.pcap_reader.PcapReader`` (``--per-datagram K``: K fragments of each datagram at consecutive
offsets, the last never sent: the case where the reassembler's byte bound, not its datagram bound,
must hold memory; default bounds: 1024 pending datagrams, 64 MB) in a fresh process and
reports peak RSS, the peak of tracemalloc (``--tracemalloc``, slower), the time, the counts, and
whether every good packet came out.

    python benchmarks/bench_orphans.py --count 2000000 [--fragment-bytes 8] [--tracemalloc]

The file is built with NumPy (one template record, IDs and addresses filled in per row) in a
temporary folder and deleted afterwards (``--keep PATH`` keeps it).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))


def build(path: Path, count: int, frag_bytes: int, good_every: int, per_datagram: int = 1) -> int:
    """Write the capture; return the number of good packets in it."""
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.writers.framing import frames_for

    frag_bytes = max(8, frag_bytes // 8 * 8)
    eth = bytes.fromhex("020000000001607688000000") + b"\x08\x00"
    ip = bytearray(20)
    ip[0] = 0x45
    ip[2:4] = (20 + frag_bytes).to_bytes(2, "big")
    ip[6:8] = (0x2000).to_bytes(2, "big")  # More Fragments, offset 0
    ip[8], ip[9] = 64, 17
    ip[16:20] = bytes([10, 0, 0, 1])
    frame = eth + bytes(ip) + b"\x1d\x4e\x1d\x4e" + (frag_bytes + 1000).to_bytes(2, "big") + b"\x00\x00" + bytes(frag_bytes - 8)
    rec_len = 16 + len(frame)
    good = Packet(0, Endpoint("192.168.1.201", 2368), Endpoint("192.168.1.77", 2368), bytes(range(256)) * 4 + bytes(182))
    good_frame = frames_for(good, ident=1)[0]
    n_good = count // good_every
    with open(path, "wb") as fh:
        fh.write(np.array([0xA1B2C3D4], "<u4").tobytes() + np.array([2, 4], "<u2").tobytes()
                 + np.array([0, 0, 262144, 1], "<u4").tobytes())
        block = 200_000
        for start in range(0, count, block):
            k = np.arange(start, min(count, start + block), dtype=np.int64)
            rows = np.frombuffer((bytes(16) + frame) * len(k), np.uint8).reshape(len(k), rec_len).copy()
            ts = 1_600_000_000 * 1_000_000 + k * 10  # µs, 10 µs apart
            rows[:, 0:4] = (ts // 1_000_000).astype("<u4").view(np.uint8).reshape(-1, 4)
            rows[:, 4:8] = (ts % 1_000_000).astype("<u4").view(np.uint8).reshape(-1, 4)
            rows[:, 8:12] = np.full(len(k), len(frame), "<u4").view(np.uint8).reshape(-1, 4)
            rows[:, 12:16] = rows[:, 8:12]
            ipo = 16 + 14
            d = k // per_datagram  # datagram number
            off = (k % per_datagram) * (frag_bytes // 8)  # fragment offset, 8-byte units (never the last)
            rows[:, ipo + 4] = (d >> 8) & 0xFF  # IP ID
            rows[:, ipo + 5] = d & 0xFF
            rows[:, ipo + 6] = 0x20 | ((off >> 8) & 0x1F)  # More Fragments + offset
            rows[:, ipo + 7] = off & 0xFF
            rows[:, ipo + 12] = 10  # source 10.a.b.5, a.b from d >> 16
            rows[:, ipo + 13] = (d >> 24) & 0xFF
            rows[:, ipo + 14] = (d >> 16) & 0xFF
            rows[:, ipo + 15] = 5
            out = []
            for i0 in range(0, len(k), good_every):
                chunk = rows[i0 : i0 + good_every]
                out.append(chunk.tobytes())
                if len(chunk) == good_every:
                    t = int(ts[i0 + good_every - 1]) + 1
                    out.append(np.array([t // 1_000_000, t % 1_000_000, len(good_frame), len(good_frame)], "<u4").tobytes()
                               + good_frame)
            fh.write(b"".join(out))
    return n_good


def read(path: str, use_tracemalloc: bool) -> dict:
    import tracemalloc
    import warnings

    from lidarpkt.containers.pcap_reader import PcapReader

    if use_tracemalloc:
        tracemalloc.start()
    t0 = time.perf_counter()
    reader = PcapReader(path)
    good = 0
    worst = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, p in enumerate(reader.packets()):
            good += len(p.payload) == 1206
    elapsed = time.perf_counter() - t0
    out = {
        "seconds": round(elapsed, 2),
        "good_packets_read": good,
        "orphaned_fragments": reader.stats.orphaned_fragments,
        "fragments": reader.stats.fragments,
        "peak_rss_mb": round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
    }
    if use_tracemalloc:
        out["tracemalloc_peak_mb"] = round(tracemalloc.get_traced_memory()[1] / 1e6, 1)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=2_000_000)
    ap.add_argument("--fragment-bytes", type=int, default=8)
    ap.add_argument("--good-every", type=int, default=1000)
    ap.add_argument("--per-datagram", type=int, default=1,
                    help="fragments per datagram, at consecutive offsets, the last one never sent (<= 8192 * 8 / B)")
    ap.add_argument("--tracemalloc", action="store_true")
    ap.add_argument("--keep")
    ap.add_argument("--read", help=argparse.SUPPRESS)  # internal: read in a fresh process
    args = ap.parse_args()
    if args.read:
        print(json.dumps(read(args.read, args.tracemalloc)))
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="lidarpkt-orphans-"))
    path = Path(args.keep) if args.keep else tmp / "orphans.pcap"
    t0 = time.perf_counter()
    n_good = build(path, args.count, args.fragment_bytes, args.good_every, args.per_datagram)
    size = path.stat().st_size
    print(f"wrote {path} ({size / 1e6:.0f} MB): {args.count} orphan fragments of {args.fragment_bytes} B, "
          f"{n_good} good packets, in {time.perf_counter() - t0:.1f} s", flush=True)
    cmd = [sys.executable, __file__, "--read", str(path)] + (["--tracemalloc"] if args.tracemalloc else [])
    res = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
    res.update(count=args.count, fragment_bytes=args.fragment_bytes, per_datagram=args.per_datagram, file_mb=round(size / 1e6, 1), good_packets=n_good,
               all_good_read=res["good_packets_read"] == n_good)
    print(json.dumps(res, indent=2))
    if not args.keep:
        path.unlink()
        tmp.rmdir()
    return 0 if res["all_good_read"] else 1


if __name__ == "__main__":
    sys.exit(main())
