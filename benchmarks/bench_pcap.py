"""Throughput of lidarpkt.containers.pcap_reader against a bare dpkt loop and ``cat FILE > /dev/null``.

Builds large captures with lidarpkt.writers.pcap from a real one (the VeloView VLP-16
capture, repeated with shifted times), then times, on each:

- ``cat FILE > /dev/null`` (the floor the issue names; GNU cat may not even copy the bytes
  when the output is /dev/null, so also:)
- ``python read``: ``readinto`` of the whole file in 8 MB pieces (the page-cache copy),
- a bare dpkt loop (``dpkt.pcap.Reader`` + ``Ethernet`` parse + UDP payload bytes per record),
- ``PcapReader.batches()`` (the decoders' path) and ``PcapReader.packets()``.

Captures: ``uniform`` (VLP-16 data packets only: the common case), ``mixed`` (data and
position packets interleaved as recorded), ``mixed-ng`` (the same as pcapng) and ``fragmented`` (Ouster 12608-B packets as
9 IPv4 fragments each, a tenth of the size).

    python benchmarks/bench_pcap.py --size-mb 200 [--repeat 3] [--keep DIR]

Prints packets/s and MB/s of each, and the ratios to dpkt and to cat.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from lidarpkt.containers.pcap_reader import PcapReader, read_packets  # noqa: E402
from lidarpkt.writers.framing import frames_for  # noqa: E402
from lidarpkt.writers.pcap import write_pcap_records, write_pcapng_records  # noqa: E402

EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))


def build(path: Path, source: Path, size_bytes: int, *, only_size: int | None = None, pcapng: bool = False) -> int:
    """Repeat the packets of ``source`` (shifting times) until the file holds about ``size_bytes``
    (a classic pcap, or pcapng with enhanced packet blocks)."""
    packets = [p for p in read_packets(source) if only_size is None or len(p.payload) == only_size]
    framed = [(p.timestamp_ns, frames_for(p, ident=i)) for i, p in enumerate(packets)]
    span = packets[-1].timestamp_ns - packets[0].timestamp_ns + 1_000_000
    per_round = sum(16 + len(f) for _, fs in framed for f in fs)
    rounds = max(1, size_bytes // per_round)

    def records():
        for r in range(rounds):
            shift = r * span
            for ts, fs in framed:
                for f in fs:
                    yield ts + shift, f

    if pcapng:
        write_pcapng_records(path, ((0, ts, f) for ts, f in records()))
    else:
        write_pcap_records(path, records())
    return rounds * len(packets)


def timed(fn, repeat: int) -> tuple[float, object]:
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def run_cat(path: Path) -> int:
    with open(os.devnull, "wb") as null:
        subprocess.run(["cat", str(path)], stdout=null, check=True)
    return 0


def run_read(path: Path) -> int:
    """Python reading the file in 8 MB pieces into one buffer (the page-cache copy every reader pays)."""
    buf = bytearray(8 << 20)
    with open(path, "rb", buffering=0) as fh:
        while fh.readinto(buf):
            pass
    return 0


def run_dpkt(path: Path) -> int:
    import dpkt

    n = 0
    with open(path, "rb") as fh:
        reader = dpkt.pcapng.Reader(fh) if path.suffix == ".pcapng" else dpkt.pcap.Reader(fh)
        for _ts, frame in reader:
            ip = dpkt.ethernet.Ethernet(frame).data
            udp = ip.data
            if isinstance(udp, dpkt.udp.UDP):
                _payload = bytes(udp.data)
                n += 1
    return n  # fragments count as records here: dpkt does not reassemble


def run_batches(path: Path) -> int:
    return sum(len(b) for b in PcapReader(path).batches())


def run_packets(path: Path) -> int:
    return sum(1 for _ in PcapReader(path).packets())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size-mb", type=float, default=200.0, help="size of the uniform and mixed captures")
    ap.add_argument("--repeat", type=int, default=1, help="runs per measurement (the best is kept)")
    ap.add_argument("--keep", type=Path, help="write the captures here and keep them (default: a temp dir)")
    ap.add_argument("--skip-packets", action="store_true", help="do not time packets() (slow on big files)")
    args = ap.parse_args(argv)

    velo = EXTERNAL / "veloview" / "vlp-16-test-90deg-1-50-frames.pcap"
    ouster = EXTERNAL / "ouster-sdk" / "OS-1-64_1024x10_fw20.pcap"
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="bench_pcap_"))
    workdir.mkdir(parents=True, exist_ok=True)
    size = int(args.size_mb * 1e6)
    try:
        files = {}
        t0 = time.perf_counter()
        files["uniform"] = (workdir / "uniform.pcap", build(workdir / "uniform.pcap", velo, size, only_size=1206))
        files["mixed"] = (workdir / "mixed.pcap", build(workdir / "mixed.pcap", velo, size))
        files["mixed-ng"] = (workdir / "mixed.pcapng", build(workdir / "mixed.pcapng", velo, size, pcapng=True))
        files["fragmented"] = (workdir / "fragmented.pcap", build(workdir / "fragmented.pcap", ouster, size // 10, only_size=12608))
        print(f"built captures in {time.perf_counter() - t0:.1f} s under {workdir}")
        print(f"{'capture':<11} {'MB':>7} {'packets':>9} | {'reader':<16} {'s':>7} {'kpkt/s':>9} {'MB/s':>8} | {'x dpkt':>7} {'x cat':>7}")
        for name, (path, n_packets) in files.items():
            mb = path.stat().st_size / 1e6
            runs = [("cat", run_cat), ("python read", run_read), ("dpkt loop", run_dpkt), ("lidarpkt batches", run_batches)]
            if not args.skip_packets:
                runs.append(("lidarpkt packets", run_packets))
            results = {}
            for label, fn in runs:
                seconds, count = timed(lambda: fn(path), args.repeat)
                results[label] = seconds
                if label.startswith("lidarpkt"):
                    assert count == n_packets, (label, count, n_packets)
            for label, seconds in results.items():
                ratio_dpkt = results["dpkt loop"] / seconds
                ratio_cat = results["cat"] / seconds
                print(
                    f"{name:<11} {mb:7.1f} {n_packets:9d} | {label:<16} {seconds:7.3f} {n_packets / seconds / 1e3:9.1f} "
                    f"{mb / seconds:8.1f} | {ratio_dpkt:7.2f} {ratio_cat:7.3f}"
                )
        print("x dpkt = speed-up over the dpkt loop; x cat = fraction of cat's speed (1 = as fast as reading the file)")
    finally:
        if args.keep is None:
            shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
