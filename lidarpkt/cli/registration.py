"""``lidarpkt registration-impact CAPTURE``: the pose error multi-return raypaths cause in scan
matching, with and without the raypaths the monitor flags (:mod:`analysis.registration`)."""

from __future__ import annotations

from lidarpkt.containers.magic import CAPTURES_TEXT

import argparse
import json
from pathlib import Path

from lidarpkt.errors import AnalysisError
from lidarpkt.cli.console import count


def add_arguments(p: argparse.ArgumentParser) -> None:
    from lidarpkt.analysis.multireturn import MONITOR_METHODS
    from lidarpkt.analysis.registration import ALGORITHMS, MODES

    p.add_argument("input", metavar="CAPTURE", help=f"capture of a stationary sensor: {CAPTURES_TEXT}")
    from lidarpkt.cli import args as cliargs

    cliargs.add_sensor_options(p)
    p.add_argument("--frames", metavar="A:B", help="use complete frames A..B-1 only (e.g. 0:20)")
    p.add_argument("--grid", metavar="DEG", type=cliargs.number("--grid"), default=None, help="azimuth grid in degrees of sensors whose columns are firings (default: the sensor's)")
    p.add_argument("--return", dest="slot", metavar="RETURN", default="0",
                   help="return to register: strongest, last, second_strongest or a slot index (default 0)")
    cliargs.add_json(p, "the results as one JSON document")
    cliargs.add_plot(p, "write the error CDF figures (PNG) into this folder")
    p.add_argument("--algorithm", action="append", choices=tuple(ALGORITHMS), help="registration algorithm; repeatable (default all)")
    p.add_argument("--mode", action="append", choices=MODES, help="target: each frame to the first, or to a map of all frames; repeatable (default both)")
    p.add_argument("--map", metavar="GMM", help="a probabilistic raypath map (multireturn --gmm-map) as the scan-to-map target")
    p.add_argument("--method", choices=MONITOR_METHODS, default=None, help="the monitor's score (default detrend)")
    p.add_argument("--gap", metavar="M", type=cliargs.number("--gap"), default=None, help="range gap that separates clusters, metres (default 0.1)")
    p.add_argument("--neighbourhood", metavar="N", type=cliargs.number("--neighbourhood"), default=5, help="monitor neighbourhood N×N, odd (default 5)")
    p.add_argument("--threshold", metavar="M", type=cliargs.number("--threshold"), default=None, help="monitor flag threshold, metres (default: the gap)")
    p.add_argument("--downsample", metavar="M", type=cliargs.number("--downsample"), default=0.25, help="voxel-grid downsampling of every cloud, metres (default 0.25)")
    p.add_argument("--max-correspondence", metavar="M", type=cliargs.number("--max-correspondence"), default=1.0, help="largest correspondence distance, metres (default 1)")
    p.add_argument("--voxel", metavar="M", type=cliargs.number("--voxel"), default=1.0, help="VGICP voxel size, metres (default 1)")
    p.add_argument("--workers", metavar="N", type=cliargs.number("--workers"), default=1,
                   help="use N CPU cores (default 1): the threads of the scan matching (small_gicp)")
    cliargs.add_quiet(p, "no table and no status lines")


def run(args: argparse.Namespace) -> int:
    from lidarpkt.cli import args as cliargs

    from lidarpkt.cli.analysis import _check_outputs, _clean, _load, _plots, _source, _status
    from lidarpkt.analysis.gmm import DEFAULT_GAP_M
    from lidarpkt.analysis.multireturn import DEFAULT_MONITOR_METHOD
    from lidarpkt.analysis.registration import ALGORITHMS, MODES, RegistrationSettings, registration_impact
    from lidarpkt.analysis.returns import parse_return

    # options first: a typo should not cost a decode
    selection = parse_return(args.slot)
    gap = DEFAULT_GAP_M if args.gap is None else args.gap  # the flags' ranges checked as parsed (cliargs.NUMBERS)
    if args.map:
        cliargs.check_inputs([args.map], "--map")
    if args.plot and args.plot.lower().endswith(".png"):
        raise AnalysisError(f"--plot {args.plot}: registration-impact writes two figures; give a folder")
    _check_outputs(args)
    settings = RegistrationSettings(downsampling_m=args.downsample, max_correspondence_m=args.max_correspondence,
                                    voxel_m=args.voxel, threads=args.workers)
    gmm_map = None
    if args.map:
        from lidarpkt.analysis.gmm_map import load_gmm_map

        gmm_map = load_gmm_map(args.map)
    stack = _load(args.input, args)
    map_range = None
    if gmm_map is not None:
        map_range = gmm_map.map_range_mm(stack)
    impact = registration_impact(
        stack, slot=selection, algorithms=args.algorithm or tuple(ALGORITHMS), modes=args.mode or MODES,
        monitor_method=args.method or DEFAULT_MONITOR_METHOD, gap_m=gap, neighbourhood=args.neighbourhood,
        threshold_m=args.threshold, settings=settings, map_range_mm=map_range,
    )
    doc = {"input": args.input, **impact.to_json()}
    if not args.quiet and not args.json:  # with --json stdout is the document alone
        print_table(impact, _source(args.input, stack))
    written = cliargs.emit_json(args, json.dumps(_clean(doc), allow_nan=False))
    if written:
        _status(args, f"wrote {written}")
    if args.plot:
        plots = _plots()
        out = Path(args.plot)
        src = Path(args.input).name
        for q, name in (("translation_m", "registration_translation_cdf.png"), ("rotation_deg", "registration_rotation_cdf.png")):
            plots.save(plots.plot_registration_cdfs(impact, q, src), out / name)
        _status(args, f"wrote 2 figures to {out}")
    return 0


def print_table(impact, source: str) -> None:
    """Median / 95th percentile of the translation (mm) and rotation (deg) errors per condition."""
    from lidarpkt.analysis.registration import CONDITIONS

    rf = impact.removed_fraction
    print(f"{source}: {count(impact.frames, 'frame')}, {impact.points_per_frame:.0f} returns per frame ({impact.label} return); "
          f"monitor ({impact.monitor_method}) removes {100 * rf['monitor_removed']:.1f} %, "
          f"multi-return raypaths {100 * rf['multireturn_removed']:.1f} % of the returns")
    head = f"{'algorithm':<20} {'target':<13}" + "".join(f" {c:>24}" for c in CONDITIONS)
    print(head)
    print(f"{'':<34}" + "".join(f" {'median/p95 mm, deg':>24}" for _ in CONDITIONS))
    for alg, by_mode in impact.errors.items():
        for mode, by_cond in by_mode.items():
            cells = []
            for c in CONDITIONS:
                s = by_cond[c].summary()
                t, r = s["translation_m"], s["rotation_deg"]
                cells.append("n/a" if t["median"] is None else
                             f"{1000 * t['median']:.2f}/{1000 * t['p95']:.2f}, {r['median']:.3f}")
            print(f"{alg:<20} {mode:<13}" + "".join(f" {c:>24}" for c in cells))
