"""Velodyne decoding speed: lidarpkt against velodyne_decoder on the same long captures.

Writes a dual-return VLP-16 pcap of ``--seconds`` of sensor time (10 Hz, 1507 packets/s,
packets from lidarpkt's encoder framed by lidarpkt.writers.pcap), then times in the same run:

- lidarpkt: ``lidarpkt.open(path)`` → frames, and ``frame.xyz()`` of every frame (also without XYZ);
- velodyne_decoder 3.1.0: ``read_pcap(path, Config(model=VLP16), as_pcl_structs=True)``.

Both produce points for every return of the capture (lidarpkt: a dense [2, 16, W, 3] image
per frame; velodyne_decoder: its point list). Prints seconds, packets/s and the ratio.

``--models VLP-32C,VLS-128`` times the other models the same way, each on a capture of its own
(:func:`build_model`: the model's packets at 10 Hz from lidarpkt's encoder, the model read from the
factory byte by both decoders), and prints the ratio per model.

    python benchmarks/bench_velodyne.py [--seconds 60] [--repeat 1] [--keep DIR] [--models VLP-32C,VLS-128]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import lidarpkt  # noqa: E402
from lidarpkt.core.packet import Endpoint, Packet  # noqa: E402
from lidarpkt.writers.pcap import write_pcap  # noqa: E402
from lidarpkt.vendors.velodyne import encode_data_packets  # noqa: E402

PACKET_PERIOD_NS = {"strongest": 1_327_104, "dual": 663_552}  # 12 blocks of one firing pair, or 6 of two returns
START_NS = 1_700_000_000_000_000_000


def build(path: Path, seconds: float, seed: int = 0, mode: str = "dual") -> int:
    """A VLP-16 capture at 600 RPM of ``seconds`` of sensor time: a wall of range ~12 m with noise and
    5 % of firings without a return; in dual mode 10 % of firings have a second, nearer return."""
    period_ns = PACKET_PERIOD_NS[mode]
    n = int(seconds * 1e9 / period_ns)
    rng = np.random.default_rng(seed)
    t_ns = START_NS + np.arange(n, dtype=np.int64) * period_ns
    t_us = (t_ns // 1000) % 3_600_000_000
    azimuths = 12 if mode == "strongest" else 6  # dual: each azimuth's block repeated for the two returns
    first_t_us = np.arange(azimuths) * 2 * 55.296
    az = (np.rint((np.arange(n)[:, None] * period_ns / 1000 + first_t_us[None, :]) * 0.36) % 36000).astype(np.int64)
    az = np.repeat(az, 12 // azimuths, axis=1)
    src, dst = Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368)
    chunk = 20000

    def packets():
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            last = rng.integers(5000, 7000, size=(b - a, azimuths, 32))
            if mode == "strongest":
                last[rng.random(last.shape) < 0.05] = 0
                dist = last
            else:
                strong = np.where(rng.random(last.shape) < 0.1, last - rng.integers(100, 2000, size=last.shape), last)
                last[rng.random(last.shape) < 0.05] = 0
                dist = np.stack([last, strong], axis=2).reshape(b - a, 12, 32)
            refl = rng.integers(0, 120, size=(b - a, 12, 32))
            payload = encode_data_packets(az[a:b], dist, refl, t_us[a:b], mode)
            for i in range(b - a):
                yield Packet(int(t_ns[a + i]), src, dst, payload[i].tobytes())

    write_pcap(path, packets(), udp_checksum=False)
    return n


def build_model(path: Path, model_name: str, seconds: float, mode: str = "strongest", seed: int = 0) -> int:
    """A capture of ``model_name`` turning at 10 Hz in ``mode``: block azimuths from each block's firing time,
    a wall at ~12 m with noise, 5 % of firings without a return (dual: 10 % with a nearer strongest return)."""
    from lidarpkt.vendors.velodyne.layout import packet_layout
    from lidarpkt.vendors.velodyne.models import model_named

    model = model_named(model_name)
    lay = packet_layout(model, mode)
    period_ns = model.packet_period_ns(mode)
    n = int(seconds * 1e9 / period_ns)
    rng = np.random.default_rng(seed)
    t_ns = START_NS + np.arange(n, dtype=np.int64) * period_ns
    t_us = (t_ns // 1000) % 3_600_000_000
    ref_ns = lay.firing_ns[lay.azimuth_block[:, 0], 0] - lay.dt_s32[lay.azimuth_block[:, 0], 0] * 1e9
    flags = np.where(lay.flag == 0, 0xEEFF, lay.flag)
    unit = model.distance_resolution_m * 1000
    src, dst = Endpoint("192.168.1.201", 2368), Endpoint("255.255.255.255", 2368)
    chunk = 20000

    def packets():
        for a in range(0, n, chunk):
            b = min(n, a + chunk)
            az = (np.rint(((t_ns[a:b, None] - START_NS) + ref_ns[None, :]) * 1e-9 * 360000) % 36000).astype(np.int64)
            dist = rng.integers(int(11_000 / unit), int(13_000 / unit), size=(b - a, 12, 32))
            dist[rng.random(dist.shape) < 0.05] = 0
            if mode == "dual":
                flat = dist.reshape(b - a, -1)
                last, strong = lay.source[0].ravel(), lay.source[1].ravel()
                near = rng.random((b - a, last.size)) < 0.1
                flat[:, strong] = np.where(near, flat[:, last] // 2, flat[:, last])
            refl = rng.integers(0, 120, size=(b - a, 12, 32))
            payload = encode_data_packets(az, dist, refl, t_us[a:b], mode, model.product_ids[0],
                                          flag=np.broadcast_to(flags, (b - a, 12)))
            for i in range(b - a):
                yield Packet(int(t_ns[a + i]), src, dst, payload[i].tobytes())

    write_pcap(path, packets(), udp_checksum=False)
    return n


#: The real captures of the other models, as ``run_all.py`` repeats them: (name, capture under the external
#: fixtures, copies). The bags are exported to pcap first (``lidarpkt export --format pcap``).
REAL_CAPTURES = (
    ("VLP-32C", "nebula/vlp32/1713492677464078412", 150),
    ("VLS-128", "nebula/vls128/1614315746471294674", 25),
    ("HDL-32E", "rust-lidar-utils/velodyne_vlp32.pcap", 300),
)
HOUR_US = 3_600_000_000


def export_pcap(capture: Path, out: Path) -> Path:
    """``capture`` (a bag, or a pcap used as is) as a classic pcap, through ``lidarpkt export --format pcap``."""
    if capture.is_file() and capture.suffix == ".pcap":
        return capture
    import subprocess

    folder = out.with_suffix(".export")
    subprocess.run([sys.executable, "-m", "lidarpkt", "export", str(capture), "-o", str(folder), "--format", "pcap",
                    "--workers", "1", "-q"], check=True, cwd=REPO)
    return next(folder.glob("*.pcap"))


def build_repeated(source: Path, copies: int, out: Path) -> int:
    """``copies`` copies of the data packets (1206 B) of the pcap ``source``, one after the other: each copy's
    capture times and device times (the µs past the hour of each packet) moved on by the stream's span (first to
    last packet plus one median packet interval), so that the result reads as one stream. Position packets are
    left out (their NMEA times would not move). Returns the number of packets written."""
    from lidarpkt.containers.pcap_reader import read_batches

    batches = [b for b in read_batches(source) if b.payload_size == 1206]
    payload = np.concatenate([b.payload for b in batches])
    host_ns = np.concatenate([b.timestamp_ns for b in batches])
    order = np.argsort(np.concatenate([b.index for b in batches]), kind="stable")
    payload, host_ns = payload[order], host_ns[order]
    src, dst = batches[0].src, batches[0].dst
    device_us = payload[:, 1200:1204].copy().view("<u4")[:, 0].astype(np.int64)
    step_us = int(np.median(np.diff(device_us) % HOUR_US)) if len(device_us) > 1 else 0
    span_us = int((device_us[-1] - device_us[0]) % HOUR_US) + step_us

    def packets():
        for k in range(copies):
            copy = payload.copy()
            copy[:, 1200:1204] = ((device_us + k * span_us) % HOUR_US).astype("<u4").view(np.uint8).reshape(-1, 4)
            t = host_ns + k * span_us * 1000
            for i in range(len(copy)):
                yield Packet(int(t[i]), src, dst, copy[i].tobytes())

    write_pcap(out, packets(), udp_checksum=False)
    return copies * len(payload)


def real_capture(workdir: Path, name: str, external: Path) -> Path | None:
    """The repeated capture of model ``name`` (:data:`REAL_CAPTURES`) under ``workdir``, built once; None when
    the external fixtures are missing."""
    _, rel, copies = next(c for c in REAL_CAPTURES if c[0] == name)
    capture = external / rel
    if not capture.exists():
        return None
    out = workdir / f"{name.lower()}_real_x{copies}.pcap"
    if not out.exists():
        build_repeated(export_pcap(capture, out), copies, out)
    return out


def run_lidarpkt(path: Path, xyz: bool = True, workers: int = 1, read_ahead: bool | None = None) -> tuple[int, int]:
    frames = points = 0
    for f in lidarpkt.open(path, workers=workers, read_ahead=read_ahead):
        if xyz:
            f.xyz()
        frames += 1
        points += int(np.count_nonzero(f.range_mm))
    return frames, points


def run_lidarpkt_frames_only(path: Path) -> tuple[int, int]:
    return run_lidarpkt(path, xyz=False)


def run_velodyne_decoder(path: Path, vlp16: bool = True) -> tuple[int, int]:
    import velodyne_decoder as vd

    cfg = vd.Config(model=vd.Model.VLP16) if vlp16 else vd.Config()  # else: the model from the factory byte
    frames = points = 0
    for _, cloud in vd.read_pcap(str(path), cfg, as_pcl_structs=True):
        frames += 1
        points += len(cloud)
    return frames, points


def best_of(fn, path: Path, repeat: int):
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn(path)
        best = min(best, time.perf_counter() - t0)
    return best, result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="sensor time of the generated capture (default 60)")
    ap.add_argument("--repeat", type=int, default=1, help="runs of each decoder; the best is reported")
    ap.add_argument("--keep", type=Path, help="write the capture into this directory and keep it")
    ap.add_argument("--models", help="comma-separated other models to time instead of the VLP-16 (VLP-32C,VLS-128)")
    args = ap.parse_args()
    if args.models:
        return main_models(args)
    tmp = None
    if args.keep:
        args.keep.mkdir(parents=True, exist_ok=True)
        path = args.keep / f"vlp16_dual_{int(args.seconds)}s.pcap"
    else:
        tmp = tempfile.TemporaryDirectory()
        path = Path(tmp.name) / "vlp16_dual.pcap"
    t0 = time.perf_counter()
    n = build(path, args.seconds)
    print(f"capture: {path} — {n} dual-return packets, {args.seconds:.0f} s of sensor time, "
          f"{os.path.getsize(path) / 1e6:.1f} MB (written in {time.perf_counter() - t0:.1f} s)")
    t_ours, (frames, returns) = best_of(run_lidarpkt, path, args.repeat)
    print(f"lidarpkt          : {t_ours:7.2f} s  {n / t_ours:9.0f} packets/s  {frames} frames, {returns} returns, XYZ of every frame")
    t_frames, _ = best_of(run_lidarpkt_frames_only, path, args.repeat)
    print(f"lidarpkt (no XYZ) : {t_frames:7.2f} s  {n / t_frames:9.0f} packets/s  frames only")
    try:
        t_vd, (vframes, vpoints) = best_of(run_velodyne_decoder, path, args.repeat)
    except ImportError:
        print("velodyne_decoder not installed: no comparison (pip install lidarpkt[crosscheck])")
        return 0
    print(f"velodyne_decoder  : {t_vd:7.2f} s  {n / t_vd:9.0f} packets/s  {vframes} scans, {vpoints} points")
    print(f"ratio (velodyne_decoder time / lidarpkt time): {t_vd / t_ours:.2f}x")
    if tmp is not None:
        tmp.cleanup()
    return 0


def main_models(args) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for name in args.models.split(","):
            path = folder / f"{name.lower().replace(' ', '_')}_{int(args.seconds)}s.pcap"
            n = build_model(path, name, args.seconds)
            t_ours, (frames, returns) = best_of(run_lidarpkt, path, args.repeat)
            t_vd, (scans, points) = best_of(lambda p: run_velodyne_decoder(p, vlp16=False), path, args.repeat)
            print(f"{name:8s} lidarpkt {t_ours:6.2f} s ({frames} frames, {returns} returns, XYZ)  velodyne_decoder "
                  f"{t_vd:6.2f} s ({scans} scans, {points} points)  {n} packets  ratio {t_vd / t_ours:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
