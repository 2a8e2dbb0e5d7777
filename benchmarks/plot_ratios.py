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
from pathlib import Path

#: comparison -> (ratio of each of the latest runs, target): lidarpkt's speed / the reference's
#: (higher is faster), whole processes
RUNS: dict[str, tuple[tuple[float, ...], float]] = {
    "VLP-16 strongest 60 s\nframes+XYZ vs velodyne_decoder": ((3.46, 3.50, 3.51), 4.0),
    "VLP-16 dual 60 s\nframes+XYZ vs velodyne_decoder": ((4.72, 4.68, 4.65), 4.0),
    "VLP-32C × 150\nframes+XYZ vs velodyne_decoder": ((3.99, 3.62, 3.96), 4.0),
    "VLS-128 × 25\nframes+XYZ vs velodyne_decoder": ((3.73, 3.69, 3.77), 4.0),
    "HDL-32E × 300\nframes+XYZ vs velodyne_decoder": ((2.56, 2.75, 2.84), 4.0),
    "OS-2-128 single (RNG19)\nframes vs ouster-sdk": ((1.48, 1.47, 1.48), 1.5),
    "OS-0-32 dual (RNG19)\nframes vs ouster-sdk": ((1.54, 1.71, 1.81), 1.5),
    "OS-0-128 (RNG15)\nframes vs ouster-sdk": ((1.30, 1.48, 1.43), 1.5),
    "OS-1-64 legacy\nframes vs ouster-sdk": ((1.52, 1.58, 1.68), 1.5),
    "OS-1-128 (RNG15)\nframes vs ouster-sdk": ((1.46, 1.40, 1.44), 1.5),
}
RUN_DATE = "2026-11-27 14:27-14:33 UTC, 3 runs, load 1.5-1.6"
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
        ax.barh(i, sorted(ratios)[1], color="#4c72b0", height=0.6, label="median of the runs" if i == 0 else None)
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
    ax.set_title(f"Decoding speed against the reference decoders, 2 vCPUs, {RUN_DATE}", fontsize=10)
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
