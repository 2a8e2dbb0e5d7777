"""OSF files: ``lidarpkt.open`` → frames (every stored field) against ouster-sdk's ``OsfFrameSetSource``.

    python benchmarks/bench_osf.py [--repeat 5] [FILE.osf ...]     # default: the good OSF files of the ouster-sdk fixtures

Each file is read by both alternately ``--repeat`` times in one process (warm page cache); prints the median
wall time per frame of each and the ratio. ouster-sdk decodes a frame's fields in a thread pool; lidarpkt in
the caller's thread (``workers=2`` decodes ahead of the caller).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
EXTERNAL = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES", REPO.parent / "shared" / "fixtures" / "external"))
FILES = ["OS-1-128_v2.3.0_1024x10_lb_n3.osf", "OS-0-128_v3.0.1_1024x10_20241017_141645.osf", "single_scan_016.osf",
         "osf_fw_3.2_10scans.osf", "single_frame_zm.osf"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="*", help="OSF files (default: the ouster-sdk fixtures')")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)

    import lidarpkt
    from lidarpkt.errors import LidarpktError
    from ouster.sdk import osf

    paths = [Path(f) for f in args.files] or [EXTERNAL / "ouster-sdk" / f for f in FILES]
    for path in paths:
        ours, theirs, n = [], [], 0
        try:
            for _ in range(args.repeat):
                t0 = time.perf_counter()
                n = sum(1 for _ in lidarpkt.open(path))
                ours.append(time.perf_counter() - t0)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    t0 = time.perf_counter()
                    m = sum(1 for fs in osf.OsfFrameSetSource(str(path)) for f in fs if f is not None)
                    theirs.append(time.perf_counter() - t0)
        except LidarpktError as exc:
            print(f"{path.name}: not read ({exc})")
            continue
        a, b = statistics.median(ours) / max(n, 1) * 1e3, statistics.median(theirs) / max(m, 1) * 1e3
        print(f"{path.name}: {n} frames; lidarpkt {a:.1f} ms/frame, ouster-sdk {b:.1f} ms/frame ({a / b:.2f}x)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
