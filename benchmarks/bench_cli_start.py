"""How fast the CLI starts (issue 16's "CLI start" target: at most 0.3 s each).

    python benchmarks/bench_cli_start.py [--repeat 7] [--capture PCAP]

Times ``lidarpkt --help``, ``lidarpkt --version`` and ``lidarpkt info`` on a 100-packet capture
(``rust-lidar-utils/velodyne_vlp16.pcap``: 84 data + 16 position packets) as whole processes
(``python -m lidarpkt``), the median wall and CPU (children's user + system) time of ``--repeat``
runs each. CPU time is the steadier figure on a shared machine. What each imports is checked by
``tests/cli/test_one_grid.py``; ``python -X importtime -m lidarpkt ...`` shows where the time goes.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TARGET_S = 0.3


def _external(relpath: str) -> Path:
    root = os.environ.get("LIDARPKT_EXTERNAL_FIXTURES") or str(REPO.parent / "shared" / "fixtures" / "external")
    return Path(root) / relpath


def time_command(argv: list[str], repeat: int) -> tuple[float, float]:
    """(median wall s, median CPU s) of ``python -m lidarpkt ARGV`` run ``repeat`` times (after one warm-up)."""
    env = dict(os.environ, PYTHONPATH=str(REPO))
    walls, cpus = [], []
    for i in range(repeat + 1):
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "lidarpkt", *argv], stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, env=env, check=False)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if i:  # the first run warms the page cache and the .pyc files
            walls.append(wall)
            cpus.append((after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime))
    return statistics.median(walls), statistics.median(cpus)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--capture", default=str(_external("rust-lidar-utils/velodyne_vlp16.pcap")))
    args = parser.parse_args(argv)
    print(f"{'command':<32} {'wall s':>8} {'cpu s':>8}  target {TARGET_S} s")
    for cmd in (["--help"], ["--version"], ["info", args.capture]):
        wall, cpu = time_command(cmd, args.repeat)
        shown = " ".join(cmd if cmd[0] != "info" else ["info", Path(cmd[1]).name])
        print(f"lidarpkt {shown:<23} {wall:8.3f} {cpu:8.3f}  {'ok' if wall <= TARGET_S else 'over (wall)'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
