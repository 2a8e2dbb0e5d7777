"""Hesai Pandar decoding speed, per model, and against hydra4 (pure Python) on the XT32 bag.

For each of the seven nebula bags (``../shared/fixtures/external/nebula/hesai``): the bag's packets are
decoded once into fields, then re-encoded by lidarpkt's encoder ``--rotations`` times over (each copy
0.4 s later in the packets' own clock, a seamless stream of whole rotations), and pushed in batches of
8192 packets to a :class:`~lidarpkt.vendors.hesai.HesaiDecoder` with the model's calibration; every frame's
``xyz()`` is computed. Reports frames/s, returns (points)/s and packets/s.

hydra4 0.2.0 (PyPI, the only Python Hesai decoder; XT32 and OT128): ``Hydra(PandarXT32).to_pypcd4``
over the XT32 bag's four PandarScan messages, against lidarpkt on the same 2000 packets (decode,
frames, XYZ). hydra4 keeps one return of a dual-return firing, lidarpkt both: the ratio is of time for
the same packets.

    python benchmarks/bench_hesai.py [--rotations 50] [--repeat 3] [--models xt32 qt128 ...]
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))

from lidarpkt.vendors.hesai import (
    HesaiDecoder,
    decode_packets,
    detect_model,
    encode_packets,
    load_calibration,
)
from lidarpkt.core.packet import PacketBatch
from lidarpkt.containers.bags import BagReader
from lidarpkt.vendors.registry import bag_messages

FOLDERS = {"40p": "Pandar40P", "64": "Pandar64", "qt64": "PandarQT64", "qt128": "PandarQT128", "xt16": "PandarXT16",
           "xt32": "PandarXT32", "xt32m": "PandarXT32M"}
BATCH = 8192


def bag_packets(folder: str) -> PacketBatch:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return PacketBatch.concatenate(list(BagReader(glob.glob(f"{EXTERNAL}/nebula/hesai/{folder}/*/")[0], messages=bag_messages()).batches()))


def stream(batch: PacketBatch, rotations: int) -> tuple[np.ndarray, np.ndarray]:
    """The bag's packets ``rotations`` times over, re-encoded with times 0.4 s apart per copy."""
    model = detect_model(batch.payload)
    raw = decode_packets(batch.payload, model)
    raw = raw.select(raw.valid)
    n = len(raw)
    ts = raw.timestamp_ns
    span = int(ts[-1] - ts[0]) + int(np.median(np.diff(ts)))  # the next copy follows on
    out = np.empty((n * rotations, batch.payload_size), np.uint8)
    for k in range(rotations):
        out[k * n:(k + 1) * n] = encode_packets(
            model, azimuth_cdeg=raw.azimuth_cdeg, distance=raw.distance, reflectivity=raw.reflectivity,
            return_mode=raw.return_mode, timestamp_ns=raw.timestamp_ns + k * span, dis_unit_mm=int(raw.dis_unit_mm[0]),
            motor_speed_rpm=raw.motor_speed_rpm, mode_flag=raw.mode_flag, size=batch.payload_size,
            udp_sequence=None if raw.udp_sequence is None else raw.udp_sequence + np.uint32(k * n))
    host = np.arange(len(out), dtype=np.int64)
    return out, host


def run_lidarpkt(payload: np.ndarray, host: np.ndarray, calibration, xyz: bool = True) -> tuple[int, int]:
    dec = HesaiDecoder(calibration=calibration)
    frames = points = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = []
        for a in range(0, len(payload), BATCH):
            out += dec.push(PacketBatch.from_payloads(payload[a:a + BATCH], host[a:a + BATCH], first_index=a))
            for f in out:
                if xyz:
                    f.xyz()
                frames += 1
                points += int(np.count_nonzero(f.range_mm))
            out = []
        for f in dec.finish():
            if xyz:
                f.xyz()
            frames += 1
            points += int(np.count_nonzero(f.range_mm))
    return frames, points


def best_of(fn, repeat: int):
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def hydra4_vs_lidarpkt(repeat: int) -> None:
    try:
        from hydra4 import Hydra
        from hydra4.msgs import (
            pandar_msgs__msg__PandarPacket,
            pandar_msgs__msg__PandarScan,
        )
    except ImportError:
        print("hydra4 not installed: no comparison (pip install lidarpkt[crosscheck])")
        return
    batches = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        batches = list(BagReader(glob.glob(f"{EXTERNAL}/nebula/hesai/xt32/*/")[0], messages=bag_messages()).batches())
    msgs = [pandar_msgs__msg__PandarScan(header=None, packets=[
        pandar_msgs__msg__PandarPacket(stamp=None, data=row, size=len(row)) for row in b.payload]) for b in batches]
    csv = EXTERNAL / "nebula/hesai/PandarXT32.csv"

    def hydra():
        h = Hydra(Hydra.Model.PandarXT32, calibration_path=csv, min_distance=0.05, max_distance=120.0)
        clouds = [pc for m in msgs for pc in h.to_pypcd4(m)]
        return len(clouds), sum(len(pc.pc_data) for pc in clouds)

    batch = PacketBatch.concatenate(batches)
    cal = load_calibration(csv)
    t_h, (hf, hp) = best_of(hydra, repeat)
    t_l, (lf, lp) = best_of(lambda: run_lidarpkt(batch.payload, batch.timestamp_ns, cal), repeat)
    n = len(batch)
    print(f"XT32 bag, {n} packets:")
    print(f"  hydra4 0.2.0 : {t_h:8.4f} s  {n / t_h:10.0f} packets/s  {hf} clouds, {hp} points (one return per firing)")
    print(f"  lidarpkt     : {t_l:8.4f} s  {n / t_l:10.0f} packets/s  {lf} frames, {lp} returns (both returns), XYZ")
    print(f"  ratio (hydra4 time / lidarpkt time): {t_h / t_l:.1f}x")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rotations", type=int, default=50, help="copies of each bag's packets (4 rotations each)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each measurement; the best is reported")
    ap.add_argument("--models", nargs="*", default=list(FOLDERS), choices=list(FOLDERS))
    args = ap.parse_args()
    print(f"{'model':12s} {'packets':>8s} {'frames':>7s} {'s':>8s} {'frames/s':>9s} {'Mpoints/s':>10s} {'packets/s':>10s}"
          f" {'no-XYZ Mpoints/s':>17s}")
    for folder in args.models:
        name = FOLDERS[folder]
        batch = bag_packets(folder)
        payload, host = stream(batch, args.rotations)
        cal = load_calibration(EXTERNAL / "nebula/hesai" / f"{name}.csv")
        t, (frames, points) = best_of(lambda p=payload, h=host, c=cal: run_lidarpkt(p, h, c), args.repeat)
        t0, _ = best_of(lambda p=payload, h=host, c=cal: run_lidarpkt(p, h, c, xyz=False), args.repeat)
        print(f"{name:12s} {len(payload):8d} {frames:7d} {t:8.3f} {frames / t:9.1f} {points / t / 1e6:10.2f} "
              f"{len(payload) / t:10.0f} {points / t0 / 1e6:17.2f}")
    hydra4_vs_lidarpkt(args.repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
