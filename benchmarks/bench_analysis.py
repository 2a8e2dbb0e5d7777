"""Time the analysis stage on a synthetic 64 × 1024 × 30-frame stack (target: whole-image statistics < 2 s;
the per-pixel mixture map, analysis.gmm_map.fit_gmm_map, < 10 s).

    python benchmarks/bench_analysis.py [--frames 30] [--rows 64] [--cols 1024] [--slots 1] [--repeat 3] [--no-gmm-map]

The stack mixes single surfaces, two- and three-cluster raypaths, non-returns and a few lost
columns, so that every branch of the computation does work. Reports the best of ``--repeat``
runs of each step (wall-clock, this machine) and the peak size of the input.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from lidarpkt.analysis.compare import compare_slots, ks_image  # noqa: E402
from lidarpkt.analysis.gmm_map import fit_gmm_map  # noqa: E402
from lidarpkt.analysis.motion import estimate_frame_offsets, motion_compensated_cdf  # noqa: E402
from lidarpkt.analysis.multireturn import detrended_gap_score, image_statistics, multireturn_map, spatial_gap_score  # noqa: E402
from lidarpkt.analysis.raypath import analyze_raypath  # noqa: E402
from lidarpkt.core.sequence import FrameStack  # noqa: E402
from lidarpkt.core.sensor import SensorInfo


def synthetic_stack(k: int, r: int, h: int, w: int, seed: int = 0) -> FrameStack:
    rng = np.random.default_rng(seed)
    base = rng.uniform(2000, 60000, size=(h, w))
    second = base + rng.uniform(500, 5000, size=(h, w))
    third = second + rng.uniform(500, 5000, size=(h, w))
    kind = rng.choice(3, size=(h, w), p=[0.8, 0.15, 0.05])  # clusters per raypath
    pick = rng.integers(0, 3, size=(k, r, h, w)) % (kind + 1)
    ranges = np.choose(pick, [base, second, third]) + rng.normal(0, 20, size=(k, r, h, w))
    ranges[rng.random(ranges.shape) < 0.05] = 0
    valid = rng.random((k, w)) > 0.002
    labels = ("strongest",) if r == 1 else ("strongest", "second_strongest")
    sensor = SensorInfo(
        vendor="ouster", model="bench", rows=h, columns_per_frame=w, return_mode="single" if r == 1 else "dual",
        return_labels=labels, beam_altitude_deg=np.zeros(h), beam_azimuth_deg=np.zeros(h),
        pixel_shift_by_row=np.tile([18, 12, 6, 0], h // 4 + 1)[:h],
    )
    return FrameStack(
        sensor=sensor, return_labels=labels, frame_id=np.arange(k), range_mm=np.round(ranges).astype(np.uint32),
        reflectivity=rng.integers(0, 255, size=(k, r, h, w), dtype=np.uint8), column_valid=valid,
        column_timestamp_ns=np.zeros((k, w), np.int64), azimuth_deg=np.zeros((k, w)),
    )


def best_of(repeat: int, fn, *args, **kwargs) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn(*args, **kwargs)
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--rows", type=int, default=64)
    p.add_argument("--cols", type=int, default=1024)
    p.add_argument("--slots", type=int, default=1, choices=(1, 2))
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--no-gmm-map", action="store_true", help="skip the per-pixel mixture map (the slowest step)")
    args = p.parse_args(argv)
    stack = synthetic_stack(args.frames, args.slots, args.rows, args.cols)
    shape = "x".join(map(str, stack.range_mm.shape))
    print(f"stack [K, R, H, W] = {shape}, range_mm {stack.range_mm.nbytes / 1e6:.1f} MB")
    steps = [
        ("image_statistics (whole image, every pixel and slot)", image_statistics, (stack,), {}),
        ("spatial_gap_score (paper's monitor, 5x5, one frame)", spatial_gap_score, (stack,), {}),
        ("detrended_gap_score (default monitor, 5x5, one frame)", detrended_gap_score, (stack,), {}),
        ("multireturn_map (statistics + monitor + ROC)", multireturn_map, (stack,), {}),
        ("estimate_frame_offsets (whole-image registration)", estimate_frame_offsets, (stack,), {}),
        ("motion_compensated_cdf (one raypath, 5x5 patch, ±2 px)", motion_compensated_cdf, (stack, 30, 500), {}),
        ("analyze_raypath (CDFs + motion + EM GMM, one raypath)", analyze_raypath, (stack, 30, 500),
         {"motion_compensation": True}),
        ("ks_image (KS distance of every pixel, two stacks)", ks_image,
         (stack.range_mm[:, 0], stack.column_valid, stack.range_mm[:, 0], stack.column_valid), {}),
    ]
    if args.slots == 2:
        steps.append(("compare_slots (dual, every pixel)", compare_slots, (stack,), {}))
    for name, fn, a, kw in steps:
        t, _ = best_of(args.repeat, fn, *a, **kw)
        print(f"{t * 1000:9.1f} ms  {name}")
    if not args.no_gmm_map:
        # once: it is the slowest step; CPU time too, since a loaded machine stretches the wall clock
        cpu0, t0 = time.process_time(), time.perf_counter()
        gm = fit_gmm_map(stack, max_components=4)
        wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
        counts = np.bincount(gm.n_components.ravel(), minlength=5)
        print(f"{wall * 1000:9.1f} ms  fit_gmm_map (EM + BIC per pixel, up to 4 components; CPU {cpu:.1f} s; "
              f"pixels with 0..4 components: {counts.tolist()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
