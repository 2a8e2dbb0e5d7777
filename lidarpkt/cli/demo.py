"""``lidarpkt demo``: the whole pipeline on the bundled synthetic scene, end to end.

For each of the five fixture captures (VLP-16 strongest, last and dual; OS1-64 legacy and
dual; see ``fixtures/README.md``) it

1. generates the full-length capture once (deterministic, cached; about 5 s for all five),
2. decodes it to MCAP with the ``decode`` verb (raw packet topics + PointCloud2),
3. stacks its frames and analyses every named raypath of the scene in every return slot
   (temporal CDF, GMM by EM/BIC) and the whole image (multi-return map),

then prints one table (raypath, capture, slot, returns, clusters, GMM means) and writes the
paper's figures and a ``summary.json`` into ``-o DIR``.

The CLI sits at the top of the stack, so this module may import ``recorder``, ``analysis``
and ``fixtures`` (lazily, inside :func:`run`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from lidarpkt.errors import UsageError

# Raypaths whose figures are drawn (all are analysed and tabulated).
FIGURE_RAYPATHS = ("window", "foliage")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import args as cliargs

    parser.add_argument("-o", "--output", dest="output", default="demo-out", metavar="DIR",
                        help="folder for MCAP files, figures, summary (demo-out)")
    parser.add_argument("--frames", type=int, metavar="N",
                        help="frames per capture (default: the fixtures' full length)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene's per-firing draws (0)")
    parser.add_argument("--no-plots", action="store_true", help="skip the figures (no matplotlib needed)")
    parser.add_argument("--no-mcap", action="store_true", help="skip writing MCAP files")
    cliargs.add_quiet(parser, "no progress bar")


def run(args: argparse.Namespace) -> int:
    from lidarpkt import fixtures
    from lidarpkt.analysis import analyze_raypath, available_returns, load_stack, multireturn_map, select_returns

    from . import args as cliargs

    if args.frames is not None and args.frames < 1:
        raise UsageError(f"--frames {args.frames}: not a whole number >= 1; give e.g. --frames 20")
    out = cliargs.check_folder(args.output, "-o")  # checked (and made) before minutes of work
    plots = None if args.no_plots else _plots_module()
    progress = cliargs.Progress(getattr(args, "quiet", False), total=len(fixtures.CAPTURES), unit="capture",
                                desc="demo")
    started = time.monotonic()
    rows: list[dict[str, Any]] = []
    captures: dict[str, Any] = {}
    stacks = {}

    for name in fixtures.CAPTURES:
        t0 = time.monotonic()
        pcap = fixtures.ensure(name, frames=args.frames, seed=args.seed)
        truth = fixtures.load_truth(pcap)
        metadata = fixtures.metadata_path(pcap)
        mcap_path = None
        if not args.no_mcap:
            mcap_path = out / f"{name}.mcap"
            _decode_to_mcap(pcap, mcap_path, metadata)
        stack = load_stack(pcap, metadata=metadata)
        # the returns as the sensor defines them (a VLP-16 dual: last, strongest, second strongest)
        stack = select_returns(stack, available_returns(stack))
        stacks[name] = stack
        mr = multireturn_map(stack)
        for raypath, info in truth["raypaths"].items():
            row, col = info["pixel"][0]
            for slot, label in enumerate(stack.return_labels):
                ra = analyze_raypath(stack, row, col, slot, gmm="em")
                rows.append({
                    "raypath": raypath, "capture": name, "slot": label, "row": row, "col": col,
                    "frames": ra.temporal.n_samples, "returns": ra.temporal.n_returns,
                    "clusters": int(mr.stats.n_clusters[slot, row, col]),
                    "gmm_means_m": [] if ra.gmm is None else [round(float(m), 3) for m in ra.gmm.means_m],
                    "gmm_weights": [] if ra.gmm is None else [round(float(w), 3) for w in ra.gmm.weights],
                    "ks": None if ra.gmm is None else round(float(ra.gmm.ks), 4),
                })
                if plots is not None and raypath in FIGURE_RAYPATHS and ra.temporal.n_returns:
                    stem = out / f"{name}-{raypath}-{label}"
                    plots.save(plots.plot_temporal_cdf(ra, name), f"{stem}-temporal-cdf.png")
                    plots.save(plots.plot_temporal_vs_spatial(ra, name), f"{stem}-temporal-vs-spatial.png")
                    if ra.gmm is not None:
                        plots.save(plots.plot_gmm(ra, name), f"{stem}-gmm.png")
        if plots is not None:
            pixels = [tuple(info["pixel"][0]) for info in truth["raypaths"].values()]
            plots.save(plots.plot_range_image(stack, 0, 0, pixels, name), out / f"{name}-range-image.png")
            plots.save(plots.plot_multireturn_map(mr, stack, 0, name), out / f"{name}-multireturn-map.png")
        captures[name] = {
            "pcap": str(pcap), "mcap": None if mcap_path is None else str(mcap_path),
            "frames": len(stack), "return_labels": list(stack.return_labels),
            "monitor": [{"slot": stack.return_labels[i], "precision": ev.precision, "recall": ev.recall, "auc": ev.auc}
                        for i, ev in enumerate(mr.evaluation)],
            "seconds": round(time.monotonic() - t0, 2),
        }
        progress.update(len(captures), name)
    progress.close()

    if plots is not None:
        _mode_comparison_figures(plots, stacks, fixtures, out, args)

    _print_table(rows)
    summary = {"captures": captures, "raypaths": rows, "seconds": round(time.monotonic() - started, 2)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=_json_default) + "\n")
    n_png = len(list(out.glob("*.png")))
    print(f"\n{len(fixtures.CAPTURES)} captures analysed in {summary['seconds']:.1f} s; "
          f"{'MCAP files, ' if not args.no_mcap else ''}{n_png} figures and summary.json in {out}/")
    return 0


def _decode_to_mcap(pcap: Path, mcap_path: Path, metadata: Path | None) -> None:
    """The ``decode`` verb itself, so the demo exercises what a user runs."""
    from lidarpkt.cli import main

    argv = ["decode", str(pcap), "-o", str(mcap_path), "-q"]
    if metadata is not None:
        argv += ["--metadata", str(metadata)]
    status = main(argv)
    if status:
        from lidarpkt.errors import RecorderError

        raise RecorderError(f"{pcap}: decoding to {mcap_path} failed (exit status {status}, error above); run lidarpkt decode on it to see why")


def _mode_comparison_figures(plots, stacks, fixtures, out: Path, args) -> None:
    """Strongest vs last temporal CDFs of the figure raypaths, from the captures of one sensor in each return
    mode (:data:`lidarpkt.fixtures.MODE_CAPTURES`): how the mode changes what a raypath reports."""
    from lidarpkt.analysis import temporal_cdf

    modes = fixtures.MODE_CAPTURES
    truth = fixtures.load_truth(fixtures.ensure(modes["strongest"], frames=args.frames, seed=args.seed))
    model = stacks[modes["strongest"]].sensor.model
    for raypath in FIGURE_RAYPATHS:
        row, col = truth["raypaths"][raypath]["pixel"][0]
        cdfs = {
            "strongest": temporal_cdf(stacks[modes["strongest"]], row, col, 0),
            "last": temporal_cdf(stacks[modes["last"]], row, col, 0),
            "dual: last": temporal_cdf(stacks[modes["dual"]], row, col, 0),
            "dual: strongest": temporal_cdf(stacks[modes["dual"]], row, col, 1),
        }
        fig = plots.plot_mode_cdfs(cdfs, row, col, f"{model} {raypath}")
        plots.save(fig, out / f"{fixtures.MODE_FIGURE_PREFIX}-{raypath}-modes.png")


def _print_table(rows: list[dict[str, Any]]) -> None:
    head = f"{'raypath':<9} {'capture':<16} {'slot':<17} {'pixel':>11} {'returns':>9} {'clusters':>8}  GMM means (m)"
    print(head)
    print("-" * len(head))
    for r in rows:
        means = ", ".join(f"{m:.3f}" for m in r["gmm_means_m"]) or "-"
        pixel = f"({r['row']},{r['col']})"
        print(f"{r['raypath']:<9} {r['capture']:<16} {r['slot']:<17} {pixel:>11} "
              f"{r['returns']:>4}/{r['frames']:<4} {r['clusters']:>8}  {means}")


def _plots_module():
    try:
        from lidarpkt.analysis import plots
    except ImportError as exc:  # matplotlib missing: the `plot` extra
        print(f"lidarpkt demo: no figures ({exc}); install the plot extra: pip install 'lidarpkt[plot]'",
              file=sys.stderr)
        return None
    return plots


def _json_default(obj: Any) -> Any:
    try:
        return obj.item()  # NumPy scalars
    except AttributeError:
        return str(obj)
