"""The plot of the documentation's Performance page: lidarpkt's speed over the reference decoders'.

The figures are those of the latest published runs (``docs/performance.md`` gives the command, the date
and the machine; ``docs/performance-history.md`` every earlier run): per comparison, the ratio of each
``benchmarks/run_all.py`` run (whole processes; each run's ratio is itself over the medians of its paired
rounds), their median and the target. After new runs, update ``RUNS`` and the page, then
``python benchmarks/plot_ratios.py`` (needs matplotlib, the ``plot`` extra) rewrites
``docs/figures/benchmark-ratios.png``.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

#: comparison -> (ratio of each of the latest runs, target): lidarpkt's speed / the reference's
#: (higher is faster), whole processes
RUNS: dict[str, tuple[tuple[float, ...], float]] = {
    "VLP-16 strongest 60 s\nframes+XYZ vs velodyne_decoder": ((3.45, 3.32, 3.50), 4.0),
    "VLP-16 dual 60 s\nframes+XYZ vs velodyne_decoder": ((4.82, 5.11, 4.86), 4.0),
    "VLP-32C × 150\nframes+XYZ vs velodyne_decoder": ((4.15, 3.91, 3.52), 4.0),
    "VLS-128 × 25\nframes+XYZ vs velodyne_decoder": ((3.87, 4.04, 3.82), 4.0),
    "HDL-32E × 300\nframes+XYZ vs velodyne_decoder": ((3.00, 2.94, 2.91), 4.0),
    "OS-2-128 single (RNG19)\nframes vs ouster-sdk": ((1.41, 1.32, 1.32), 1.5),
    "OS-0-32 dual (RNG19)\nframes vs ouster-sdk": ((1.77, 1.68, 1.44), 1.5),
    "OS-0-128 (RNG15)\nframes vs ouster-sdk": ((1.47, 1.49, 1.13), 1.5),
    "OS-1-64 legacy\nframes vs ouster-sdk": ((1.49, 1.36, 1.13), 1.5),
    "OS-1-128 (RNG15)\nframes vs ouster-sdk": ((1.50, 1.50, 1.06), 1.5),
}
RUN_DATE = "2026-11-27 19:41-19:48 UTC, 3 runs, load 1.5-2.1"
OUT = Path(__file__).resolve().parents[1] / "docs" / "figures" / "benchmark-ratios.png"


def plot(out: Path = OUT) -> Path:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(RUNS)
    fig, ax = plt.subplots(figsize=(9, 5.6), dpi=110)
    for i, name in enumerate(names):
        ratios, target = RUNS[name]
        ax.barh(i, statistics.median(ratios), color="#4c72b0", height=0.6, label="median of the runs" if i == 0 else None)
        ax.plot(ratios, [i] * len(ratios), "o", color="#222222", markersize=4, label="each run" if i == 0 else None)
        ax.plot([target, target], [i - 0.38, i + 0.38], color="#c44e52", lw=2, label="target" if i == 0 else None)
    ax.axvline(1.0, color="#888888", lw=1, ls="--")
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xscale("log")
    ax.set_xlim(0.25, 8)
    ax.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
    ax.set_xticks([0.25, 0.5, 1, 2, 4, 8], ["0.25×", "0.5×", "1×", "2×", "4×", "8×"])
    ax.set_xlabel("lidarpkt's speed over the reference decoder's (wall time ratio; > 1: lidarpkt is faster)")
    ax.set_title(f"Decoding speed against the reference decoders\n2 vCPUs, {RUN_DATE}", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", type=Path, default=OUT, help="the PNG to write")
    print(plot(parser.parse_args().output))


if __name__ == "__main__":
    main()
