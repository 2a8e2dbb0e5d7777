"""What bounds ``lidarpkt.open(path, workers=2)``: the CPU time of each stage of its pipeline, alone.

    python benchmarks/bench_stages.py CAPTURE [--metadata M.json] [--work none|xyz|xyz32|vlp] [--repeat 5]

The pipeline of ``workers=2`` runs three stages side by side: reading (pcap → packet batches, the
read-ahead thread), assembling (batches → frames, the decode thread) and the caller's own work on each
frame (``--work``: nothing, ``xyz()``, ``xyz(numpy.float32)``, or ``vlp`` = ``xyz()`` and a count of
returns, as ``run_all.py``'s VLP-16 rows). Each stage is timed alone in one thread (median CPU time of
``--repeat`` runs; the caller's work on the first 100 frames, scaled to all of them); a pipeline is at
best as fast as its slowest stage, so ``one thread / slowest stage`` is the ceiling of ``workers=2``
against ``workers=1, read_ahead=False`` before the threads cost each other anything.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import lidarpkt  # noqa: E402
from lidarpkt.containers.pcap_reader import PcapReader  # noqa: E402

WORK = {
    "none": lambda f: None,
    "xyz": lambda f: f.xyz(),
    "xyz32": lambda f: f.xyz(np.float32),
    "vlp": lambda f: (f.xyz(), np.count_nonzero(f.range_mm)),
}


def cpu_median(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return statistics.median(times)


def stages(path: Path, metadata: str | None, work: str, repeat: int) -> dict[str, float]:
    """CPU seconds of each stage over the whole capture: read, assemble, work, and the one-thread total."""
    read = cpu_median(lambda: sum(len(b) for b in PcapReader(path).batches()), repeat)
    decode = cpu_median(lambda: sum(1 for _ in lidarpkt.open(path, metadata=metadata, read_ahead=False)), repeat)
    sample, n = [], 0
    for n, frame in enumerate(lidarpkt.open(path, metadata=metadata, read_ahead=False), 1):
        if len(sample) < 100:
            sample.append(frame)
    each = WORK[work]
    caller = cpu_median(lambda: [each(f) for f in sample], repeat) * n / max(1, len(sample))
    return {"read": read, "assemble": decode - read, "work": caller, "one thread": decode + caller, "frames": n}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("capture", type=Path)
    ap.add_argument("--metadata")
    ap.add_argument("--work", choices=sorted(WORK), default="none")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    s = stages(args.capture, args.metadata, args.work, args.repeat)
    slowest = max(s["read"], s["assemble"], s["work"])
    print(f"{args.capture.name} ({s['frames']} frames, work: {args.work}): read {s['read']:.3f} s, "
          f"assemble {s['assemble']:.3f} s, work {s['work']:.3f} s; one thread {s['one thread']:.3f} s; "
          f"workers=2 at best {s['one thread'] / slowest:.2f}x faster")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
