"""RoboSense decoding speed: frames and XYZ of the RS-Helios bag, repeated into a stream of 30 MB or more.

The bag (``../shared/fixtures/external/nebula/robosense/helios16p``, 751 packets: 750 MSOP and a DIFOP) is
read through the vendor registry (as ``lidarpkt.open`` reads it), its MSOP packets decoded once into
fields and re-encoded by lidarpkt's encoder ``--copies`` times over (each copy later in the packets'
own clock by the bag's span, the header's packet counter running on: one seamless stream of whole
rotations, as the sensor would send it), the DIFOP first. The stream is pushed in batches of 8192
packets to a :class:`~lidarpkt.vendors.robosense.RobosenseDecoder` (model, return mode and calibration
from the packets and the DIFOP) and every frame's ``xyz()`` is computed. Reports frames/s, returns
(points)/s, packets/s and MB/s, with and without XYZ.

    python benchmarks/bench_robosense.py [--copies 34] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))

from lidarpkt.core.packet import PacketBatch
from lidarpkt.vendors.registry import open_packets
from lidarpkt.vendors.robosense import RobosenseDecoder, decode_packets, detect_model, encode_packets
from lidarpkt.vendors.robosense.detect import is_difop
from bench_hesai import best_of

BAG = EXTERNAL / "nebula/robosense/helios16p/rosbag2_2023_08_03-11_02_46"
BATCH = 8192


def bag_packets() -> np.ndarray:
    return np.concatenate([batch.payload for batch in open_packets(BAG).batches()])


def stream(payload: np.ndarray, copies: int) -> tuple[np.ndarray, np.ndarray]:
    """The DIFOP, then the bag's MSOP packets ``copies`` times over, re-encoded as one stream."""
    difop = payload[is_difop(payload)][:1]
    msop = payload[~is_difop(payload)]
    model = detect_model(msop)
    raw = decode_packets(msop, model)
    ts = raw.timestamp_ns
    n = len(raw)
    span = int(ts[-1] - ts[0]) + int(np.median(np.diff(ts)))  # the next copy follows on
    out = np.empty((1 + n * copies, payload.shape[1]), np.uint8)
    out[0] = difop[0]
    for k in range(copies):
        out[1 + k * n:1 + (k + 1) * n] = encode_packets(
            model, azimuth_cdeg=raw.azimuth_cdeg, distance=raw.distance, reflectivity=raw.reflectivity,
            timestamp_ns=ts + k * span, distance_unit_um=int(raw.distance_unit_um[0]),
            packet_count=None if raw.packet_count is None else raw.packet_count + k * n)
    host = np.concatenate([[ts[0]], (ts[None, :] + span * np.arange(copies)[:, None]).reshape(-1)])
    return out, host


def run(payload: np.ndarray, host: np.ndarray, xyz: bool = True) -> tuple[int, int]:
    decoder = RobosenseDecoder()
    frames = points = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for a in range(0, len(payload) + 1, BATCH):
            out = decoder.push(PacketBatch.from_payloads(payload[a:a + BATCH], host[a:a + BATCH], first_index=a)) \
                if a < len(payload) else decoder.finish()
            for f in out:
                if xyz:
                    f.xyz()
                frames += 1
                points += int(np.count_nonzero(f.range_mm))
    return frames, points


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--copies", type=int, default=34, help="copies of the bag's 750 MSOP packets (34: 31.8 MB)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each measurement; the best is reported")
    args = ap.parse_args()
    payload, host = stream(bag_packets(), args.copies)
    megabytes = payload.nbytes / 1e6
    t, (frames, points) = best_of(lambda: run(payload, host), args.repeat)
    t0, _ = best_of(lambda: run(payload, host, xyz=False), args.repeat)
    print(f"RS-Helios bag x{args.copies}: {len(payload)} packets, {megabytes:.1f} MB, {frames} frames, {points} returns")
    print(f"  frames + XYZ : {t:7.3f} s  {frames / t:7.1f} frames/s  {points / t / 1e6:6.2f} Mpoints/s  "
          f"{len(payload) / t:8.0f} packets/s  {megabytes / t:6.1f} MB/s")
    print(f"  frames only  : {t0:7.3f} s  {frames / t0:7.1f} frames/s  {points / t0 / 1e6:6.2f} Mpoints/s  "
          f"{len(payload) / t0:8.0f} packets/s  {megabytes / t0:6.1f} MB/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
