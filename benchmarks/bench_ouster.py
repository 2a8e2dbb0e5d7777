"""Ouster decoding throughput: lidarpkt against ouster-sdk on the same long capture, same run.

The long capture is one of the one-frame external captures repeated (default 500 frames), each
copy re-encoded with our encoder with the next frame id and timestamps moved on by one frame
period (CRC recomputed where the firmware writes one), written with ``lidarpkt.writers.pcap``
as unfragmented loopback datagrams like ouster-sdk's own recordings.

    python benchmarks/bench_ouster.py [--capture dual|legacy|single|ldr|ldr128] [--frames 500] [--repeat 3] [--keep PATH]

Prints, for each decoder, wall time, frames/s and MB/s of UDP payload, and the ratio. Both
decoders produce full frames (all channel fields); neither computes XYZ.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", ROOT.parent / "shared" / "fixtures" / "external"))

CAPTURES = {
    "dual": ("ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.pcap", "ouster-sdk/OS-0-32-U1_v2.2.0_1024x10.json"),
    "legacy": ("ouster-sdk/OS-1-64_1024x10_fw20.pcap", "ouster-sdk/OS-1-64_sensor_config_reduced.json"),
    "single": ("ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-2-128-U1_v2.3.0_1024x10.json"),
    "ldr": ("ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.pcap", "ouster-sdk/OS-0-128-U1_v2.3.0_1024x10.json"),
    "ldr128": ("ouster-sdk/OS-1-128_v2.3.0_1024x10_lb_n3.pcap", "ouster-sdk/OS-1-128_v2.3.0_1024x10.json"),
}


def build_capture(pcap: Path, meta: Path, frames: int, out: Path) -> tuple[int, int]:
    """Write ``frames`` copies of the frames of the capture's lidar packets (each copy's frame ids and times
    moved on by the frames it holds, so that the result reads as one stream); returns (packets, payload bytes)."""
    from lidarpkt.vendors.ouster import decode_packets, encode_packets, load_metadata
    from lidarpkt.core.packet import Endpoint, Packet
    from lidarpkt.containers.pcap_reader import read_batches
    from lidarpkt.writers.pcap import write_pcap

    md = load_metadata(meta)
    lidar = [b for b in read_batches(pcap) if b.payload_size == md.packet_size]
    payloads = np.concatenate([b.payload for b in lidar])
    capture_ns = np.concatenate([b.timestamp_ns for b in lidar])
    fields = decode_packets(payloads, md)
    period_ns = int(1e9 / (md.frequency_hz or 10))
    ids = (fields.column_frame_id[:, 0] if md.profile.legacy else fields.frame_id).astype(np.int64)
    first_id = int(ids[0])
    rel = (ids - first_id) % 65536  # each packet's frame among the capture's
    per_copy = int(rel.max()) + 1
    host_t0 = int(capture_ns[0])
    dt_host = capture_ns - host_t0
    src, dst = Endpoint("127.0.0.1", 7502), Endpoint("127.0.0.1", md.lidar_port)

    def packets():
        for k in range(frames):
            f = decode_packets(payloads, md)
            fid = (first_id + k * per_copy + rel) % 65536
            if md.profile.legacy:
                f.column_frame_id[:] = fid[:, None]
            else:
                f.header["frame_id"][:] = fid
            shift = k * per_copy * period_ns
            f.timestamp_ns[:] = fields.timestamp_ns + np.uint64(shift)
            payload = encode_packets(f, md)
            for i in range(len(payload)):
                yield Packet(host_t0 + shift + int(dt_host[i]), src, dst, payload[i].tobytes())

    write_pcap(out, packets(), mtu=None)
    return frames * len(payloads), frames * payloads.size


def bench_reader(path: Path) -> float:
    """The pcap reader alone (part of the lidarpkt time)."""
    from lidarpkt.containers.pcap_reader import read_batches

    t = time.perf_counter()
    for _ in read_batches(path):
        pass
    return time.perf_counter() - t


def bench_lidarpkt(path: Path, meta: Path) -> tuple[float, int]:
    import lidarpkt
    import lidarpkt.vendors.ouster  # noqa: F401  imports outside the timed part
    import lidarpkt.pipeline.reader  # noqa: F401

    t = time.perf_counter()
    n = sum(1 for _ in lidarpkt.open(path, metadata=meta))
    return time.perf_counter() - t, n


def bench_sdk(path: Path, meta: Path) -> tuple[float, int] | None:
    try:
        from ouster.sdk import pcap as sdk_pcap
    except ImportError:
        return None
    t = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        src = sdk_pcap.PcapFrameSetSource(str(path), meta=[str(meta)])
        n = sum(1 for fs in src if fs[0] is not None)
    return time.perf_counter() - t, n


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capture", choices=sorted(CAPTURES), default="dual")
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--keep", type=Path, help="write the long capture here and keep it")
    ap.add_argument("--repeat", type=int, default=3,
                    help="runs of each decoder, alternating; medians are printed (the first run of a process "
                         "also pays one-time costs: imports, first allocations)")
    args = ap.parse_args(argv)
    pcap, meta = (EXTERNAL / p for p in CAPTURES[args.capture])
    if not pcap.exists():
        print(f"external fixtures not found under {EXTERNAL}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        path = args.keep or Path(tmp) / f"ouster_{args.capture}_{args.frames}.pcap"
        t = time.perf_counter()
        n_packets, n_bytes = build_capture(pcap, meta, args.frames, path)
        print(f"capture: {args.capture} ({pcap.name}), {args.frames} frames, {n_packets} packets, "
              f"{n_bytes / 1e6:.0f} MB payload, {path.stat().st_size / 1e6:.0f} MB file, built in {time.perf_counter() - t:.1f} s")
        ours, sdks = [], []
        for _ in range(max(1, args.repeat)):
            ours.append(bench_lidarpkt(path, meta))
            sdk = bench_sdk(path, meta)
            if sdk is None:
                print("ouster-sdk : not installed (pip install ouster-sdk==1.0.1)")
                return 0
            sdks.append(sdk)
        ours_s, ours_n = statistics.median(t for t, _ in ours), ours[-1][1]
        sdk_s, sdk_n = statistics.median(t for t, _ in sdks), sdks[-1][1]
        reader_s = bench_reader(path)
        print(f"lidarpkt   : {ours_s:7.2f} s  {ours_n} frames  {ours_n / ours_s:8.1f} frames/s  {n_bytes / ours_s / 1e6:7.1f} MB/s"
              f"  (of which pcap reading {reader_s:.2f} s; median of {len(ours)}: {', '.join(f'{t:.2f}' for t, _ in ours)})")
        print(f"ouster-sdk : {sdk_s:7.2f} s  {sdk_n} frames  {sdk_n / sdk_s:8.1f} frames/s  {n_bytes / sdk_s / 1e6:7.1f} MB/s"
              f"  (median of {len(sdks)}: {', '.join(f'{t:.2f}' for t, _ in sdks)})")
        print(f"ratio lidarpkt/ouster-sdk throughput: {sdk_s / ours_s:.2f}  (>1 = lidarpkt faster)")
        if ours_n != sdk_n:
            print(f"WARNING: frame counts differ ({ours_n} vs {sdk_n})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
