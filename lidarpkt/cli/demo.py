"""``lidarpkt demo``: the whole pipeline on the bundled synthetic scene, end to end
(:func:`lidarpkt.analysis.demo.run_demo`).

For each of the five fixture captures it generates the full-length capture once (deterministic,
cached), decodes it to MCAP with the ``decode`` verb (raw packet topics + PointCloud2), and analyses
every named raypath of the scene in every return slot and the whole image; then it prints one table
(raypath, capture, slot, returns, clusters, GMM means) and writes the paper's figures and a
``summary.json`` into ``-o DIR``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lidarpkt.errors import UsageError

from lidarpkt.fixtures.captures import CAPTURES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from . import args as cliargs

    parser.add_argument("-o", "--output", dest="output", default="demo-out", metavar="DIR",
                        help="folder for MCAP files, figures, summary (demo-out)")
    parser.add_argument("--frames", type=cliargs.number("--frames"), metavar="N",
                        help="frames per capture (default: the fixtures' full length)")
    parser.add_argument("--seed", type=cliargs.number("--seed"), default=0, help="seed of the scene's per-firing draws (0)")
    parser.add_argument("--no-plots", action="store_true", help="skip the figures (no matplotlib needed)")
    parser.add_argument("--no-mcap", action="store_true", help="skip writing MCAP files")
    cliargs.add_quiet(parser, "no progress bar")


def run(args: argparse.Namespace) -> int:
    from lidarpkt.analysis.demo import format_table, run_demo

    from . import args as cliargs
    from .console import Progress

    if args.frames is not None and args.frames < 1:
        raise UsageError(f"--frames {args.frames}: not a whole number >= 1; give e.g. --frames 20")
    out = cliargs.check_folder(args.output, "-o")  # checked (and made) before minutes of work
    plots = None if args.no_plots else _plots_module()
    progress = Progress(getattr(args, "quiet", False), total=len(CAPTURES), unit="capture", desc="demo")
    try:
        summary = run_demo(out, frames=args.frames, seed=args.seed, plots=plots,
                           write_mcap=None if args.no_mcap else _decode_to_mcap, progress=progress.update)
    finally:
        progress.close()
    print(format_table(summary["raypaths"]))
    n_png = len(list(out.glob("*.png")))
    print(f"\n{len(CAPTURES)} captures analysed in {summary['seconds']:.1f} s; "
          f"{'MCAP files, ' if not args.no_mcap else ''}{n_png} figures and summary.json in {out}/")
    return 0


def _decode_to_mcap(pcap: Path, mcap_path: Path, metadata: Path | None) -> None:
    """The ``decode`` verb itself, so the demo exercises what a user runs."""
    from lidarpkt.errors import LidarpktError, RecorderError

    from .decode import decode_captures

    try:
        decode_captures([pcap], mcap_path, metadata=[metadata] if metadata is not None else None)
    except LidarpktError as exc:
        raise RecorderError(f"{pcap}: decoding to {mcap_path} failed ({exc}); run lidarpkt decode on it to see "
                            "why") from exc


def _plots_module():
    try:
        from lidarpkt.analysis import plots
    except ImportError as exc:  # matplotlib missing: the `plot` extra
        print(f"lidarpkt demo: no figures ({exc}); install the plot extra: pip install 'lidarpkt[plot]'",
              file=sys.stderr)
        return None
    return plots
