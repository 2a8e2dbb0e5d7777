"""The analysis verbs of the ``lidarpkt`` command line: ``analyze``, ``multireturn``, ``compare-returns``.

Each reads a capture with :func:`lidarpkt.open` (pcap/pcapng, MCAP, ROS bag; ``--metadata`` for
Ouster pcaps), stacks its complete frames on one column grid, and reports. Errors are
:class:`lidarpkt.errors.AnalysisError` (or the decoder's own errors) with an actionable message.
"""

from __future__ import annotations

from lidarpkt.containers.magic import CAPTURES_TEXT

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.cli.console import count

if TYPE_CHECKING:
    from lidarpkt.core.sequence import FrameStack

# ---------------------------------------------------------------------------- helpers


def _check_outputs(args: argparse.Namespace, *, output_suffixes: tuple[str, ...] = ()) -> None:
    """Every input and output checked before any decoding (lidarpkt.cli.args' one rule for all verbs)."""
    from lidarpkt.cli import args as cliargs

    cliargs.check_inputs([p for p in (args.input, getattr(args, "input2", None)) if p])
    cliargs.sensor_options(args)
    cliargs.check_inputs(getattr(args, "metadata2", None) or (), "--metadata2")
    if output_suffixes:
        cliargs.check_output(args.output, "-o", output_suffixes)
    if hasattr(args, "json"):
        cliargs.check_json(args)
    if args.plot:
        _plots()  # matplotlib missing: said before the work, not after
        cliargs.check_folder(args.plot, "--plot")


def _status(args: argparse.Namespace, text: str) -> None:
    """A status line ("wrote ..."): on stderr, and none with -q."""
    import sys

    if not getattr(args, "quiet", False):
        print(text, file=sys.stderr)


def _say(args: argparse.Namespace):
    """print() for the text report: on stderr when the JSON document goes to stdout."""
    import functools
    import sys

    return functools.partial(print, file=sys.stderr if getattr(args, "json", False) else sys.stdout)


def _clean(obj: Any) -> Any:
    """JSON-safe: NaN/inf → None, NumPy scalars → Python."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _fmt(value: float | None, digits: int = 4) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _write_json(args: argparse.Namespace, doc: dict) -> None:
    """The document to stdout (``--json``) and/or its file (``-o REPORT.json``, checked before the work)."""
    from lidarpkt.cli import args as cliargs

    written = cliargs.emit_json(args, json.dumps(_clean(doc), allow_nan=False))
    if written:
        _status(args, f"wrote {written}")


def _load(path: str, args: argparse.Namespace, workers: int = 1, metadata: list[str] | None = None):
    """The stack of ``path`` with the verb's sensor options (``metadata``: IN2's own, ``--metadata2``),
    ``--frames`` and ``--grid``."""
    from lidarpkt.analysis.stack import load_stack, parse_frame_range

    from lidarpkt.cli import args as cliargs

    cliargs.check_inputs([path])
    options = cliargs.sensor_options(args)
    if metadata:
        options["metadata"] = metadata
    grid = args.grid  # its range checked as it was parsed (cliargs.NUMBERS)
    frames = getattr(args, "frames", None)
    rng = parse_frame_range(frames) if frames else None
    return load_stack(path, frames=rng, resolution_deg=grid, workers=workers, **options)


def _check_pixel(stack, row: int, col: int, slot: int) -> None:
    """:func:`analysis.stack.check_pixel`, its message in the CLI's words (the flag, then what to do)."""
    from lidarpkt.analysis.stack import check_pixel

    try:
        check_pixel(stack, row, col, slot)
    except AnalysisError as exc:
        _, r, h, w = stack.range_mm.shape
        if 0 <= slot < r:
            raise AnalysisError(f"--pixel {row},{col}: outside the {h} x {w} range image of this capture; use ROW in "
                                f"0..{h - 1} and COL in 0..{w - 1}") from None
        raise AnalysisError(f"--return: {exc}; choose one of its slots") from None


def _plots():
    try:
        from lidarpkt.analysis import plots
    except ImportError:  # pragma: no cover - depends on the install
        raise AnalysisError("--plot: needs matplotlib, which is not installed; pip install 'lidarpkt[plot]'") from None
    return plots


def _source(path: str, stack) -> str:
    return f"{Path(path).name} ({stack.sensor.model}, {stack.sensor.return_mode})"


def _add_input(p: argparse.ArgumentParser, frames: bool = True) -> None:
    from lidarpkt.cli import args as cliargs

    cliargs.add_sensor_options(p)
    cliargs.add_quiet(p, "no status lines (\"wrote ...\"); the report itself is still printed")
    if frames:
        p.add_argument("--frames", metavar="A:B", help="analyse complete frames A..B-1 only (e.g. 0:30, 10:)")
    p.add_argument("--grid", metavar="DEG", type=cliargs.number("--grid"), default=None,
                   help="azimuth grid in degrees of sensors whose columns are firings (default: the sensor's, from "
                        "its firing rate, as decode -o x.npz and FrameStack.from_frames); frames whose columns are "
                        "their encoder's keep them")


# ---------------------------------------------------------------------------- analyze


def add_analyze_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", help=f"capture: {CAPTURES_TEXT}")
    from lidarpkt.cli import args as cliargs

    cliargs.add_workers(p)
    cliargs.add_pixel(p, required=True, help="raypath to analyse (row 0 = top beam; the column as the frame's: a "
                                             "measurement id where columns are the encoder's); repeatable")
    p.add_argument("--return", dest="slot", metavar="RETURN", default="0",
                   help="return: strongest, last or second_strongest, selected per firing as the sensor defines "
                        "them (a last+strongest dual mode: slot 1 holds the second strongest where the last was the "
                        "strongest), "
                        "or a raw slot index (0, 1); default 0")
    _add_input(p)
    p.add_argument("--neighbourhood", metavar="N", type=cliargs.number("--neighbourhood"), default=5, help="spatial CDF neighbourhood N×N, odd (default 5)")
    p.add_argument("--motion-compensation", action="store_true",
                   help="also compute the motion-compensated CDF (5×5 patch, ±2 px, against frame 0)")
    p.add_argument("--gmm", metavar="em|auto|THRESHOLDS", default="em",
                   help="Gaussian mixture: EM with BIC (default), auto gap thresholds, CDF thresholds like 0.14,0.38,0.68, or none")
    cliargs.add_json(p, "the results as one JSON document")
    cliargs.add_plot(p)


def run_analyze(args: argparse.Namespace) -> int:
    from lidarpkt.analysis.gmm import parse_method
    from lidarpkt.analysis.raypath import analyze_raypath
    from lidarpkt.analysis.returns import parse_return, resolve

    # options and outputs first: a typo should not cost a decode
    pixels = list(args.pixel)
    gmm = None if args.gmm in ("none", "off") else parse_method(args.gmm)
    if args.plot and args.plot.lower().endswith(".png"):
        raise AnalysisError(f"--plot {args.plot}: analyze writes several figures; give a folder")
    selection = parse_return(args.slot)
    _check_outputs(args)
    print = _say(args)  # noqa: A001 - the report's own print
    stack = _load(args.input, args, args.workers)
    stack, slot = resolve(stack, selection)
    for r, c in pixels:
        _check_pixel(stack, r, c, slot)
    results = [
        analyze_raypath(stack, r, c, slot, neighbourhood=args.neighbourhood,
                        motion_compensation=args.motion_compensation, gmm=gmm)
        for r, c in pixels
    ]
    source = _source(args.input, stack)
    print(f"{source}: {count(len(stack), 'frame')} of {stack.range_mm.shape[2]}x{stack.range_mm.shape[3]}, "
          f"return {stack.return_labels[slot]}")
    print(f"{'row':>4} {'col':>5} {'returns':>8} {'non-ret':>8} {'missing':>8} {'GMM':>5}  component means (m) [weights]")
    for ra in results:
        t = ra.temporal
        g = ra.gmm
        desc = "-" if g is None else "  ".join(f"{m:.3f} [{w:.2f}]" for m, w in zip(g.means_m, g.weights))
        print(f"{ra.row:>4} {ra.col:>5} {t.n_returns:>8} {t.n_nonreturn:>8} {t.n_missing:>8} "
              f"{'-' if g is None else g.n_components:>5}  {desc}")
        if ra.motion is not None:
            moved = int(np.count_nonzero(np.any(ra.motion.offsets != 0, axis=1)))
            print(f"{'':>4} motion compensation: {moved} of {count(len(stack), 'frame')} moved")
    _write_json(args, {"frames": len(stack), "pixels": [ra.to_json() for ra in results]})
    if args.plot:
        plots = _plots()
        out = Path(args.plot)
        written = [plots.save(plots.plot_range_image(stack, 0, slot, pixels, source), out / "range_image.png")]
        for ra in results:
            stem = f"r{ra.row}_c{ra.col}_{ra.label}"
            written.append(plots.save(plots.plot_temporal_cdf(ra, source), out / f"{stem}_temporal_cdf.png"))
            written.append(plots.save(plots.plot_temporal_vs_spatial(ra, source), out / f"{stem}_temporal_vs_spatial.png"))
            if ra.motion is not None:
                written.append(plots.save(plots.plot_motion_compensation(ra, source), out / f"{stem}_motion.png"))
            if ra.gmm is not None:
                written.append(plots.save(plots.plot_gmm(ra, source), out / f"{stem}_gmm.png"))
        _status(args, f"wrote {len(written)} figures to {out}")
    return 0


# ---------------------------------------------------------------------------- multireturn


def add_multireturn_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", nargs="+", help=f"capture: {CAPTURES_TEXT}; several captures "
                   "or a folder (or --workers/--scheduler): -o is a folder of maps and summary.csv "
                   "(lidarpkt.archive.multireturn_maps)")
    from lidarpkt.cli import args as cliargs

    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="one capture: the statistics and monitor flags, MAP.npz; several: a folder")
    p.set_defaults(_output_suffixes=(".npz",))
    p.add_argument("--workers", type=cliargs.number("--workers"), default=None, metavar="N",
                   help="use N CPU cores (several captures: N processes of a local Dask cluster; default: every core)")
    p.add_argument("--scheduler", metavar="ADDR", help="several captures: an existing Dask cluster (tcp://HOST:8786)")
    cliargs.add_plot(p, "write the multi-return map and the monitor's ROC (PNG) into this folder")
    _add_input(p)
    p.add_argument("--gap", metavar="M", type=cliargs.number("--gap"), default=None, help="range gap that separates clusters, metres (default 0.1)")
    p.add_argument("--neighbourhood", metavar="N", type=cliargs.number("--neighbourhood"), default=5, help="monitor neighbourhood N×N, odd (default 5)")
    p.add_argument("--monitor-frame", metavar="K", type=cliargs.number("--monitor-frame"), default=0, help="frame the monitor looks at (default 0)")
    p.add_argument("--threshold", metavar="M", type=cliargs.number("--threshold"), default=None, help="monitor flag threshold, metres (default: the gap)")
    from lidarpkt.analysis.multireturn import MONITOR_METHODS

    p.add_argument("--method", choices=MONITOR_METHODS, default=None,
                   help="monitor score: detrend (default) = largest gap of the neighbourhood's ranges about a local "
                        "plane, the smallest over the windows of N//2+1 rows holding the pixel (ground and walls at "
                        "a shallow angle are one surface, not two); plane = one plane over the whole N×N; gap = the "
                        "paper's §4.3 score, largest gap of the N×N spatial CDF; row = gap within each row of the "
                        "neighbourhood")
    p.add_argument("--gmm-map", metavar="OUT", help="also fit a Gaussian mixture per pixel and return (a probabilistic "
                   "raypath map) and write it: NPZ, or Parquet when OUT ends in .parquet")
    p.add_argument("--gmm-components", metavar="L", type=cliargs.number("--gmm-components"), default=4, help="most mixture components per pixel (default 4)")
    p.add_argument("--return", dest="slot", metavar="RETURN", default="0",
                   help="return shown in the plot: a kind (strongest, last, second_strongest) or an index into the "
                        "map's returns (a last+strongest dual map has last, strongest, second_strongest); default 0")


def run_multireturn(args: argparse.Namespace) -> int:
    from lidarpkt.containers.magic import is_capture_folder

    folder = Path(args.input[0]).is_dir() and not is_capture_folder(args.input[0])  # a bag folder is one capture
    if len(args.input) > 1 or folder or args.workers is not None or args.scheduler:
        # an archive: one map per capture, in parallel
        from lidarpkt.cli.archive import run_multireturn_archive

        return run_multireturn_archive(args)
    args.input = args.input[0]
    from lidarpkt.analysis.gmm import DEFAULT_GAP_M
    from lidarpkt.analysis.multireturn import multireturn_map
    from lidarpkt.analysis.returns import parse_return, sensor_returns

    gap = DEFAULT_GAP_M if args.gap is None else args.gap  # the flags' ranges checked as parsed (cliargs.NUMBERS)
    method = args.method
    shown = parse_return(args.slot)
    _check_outputs(args, output_suffixes=(".npz",))
    if args.gmm_map:
        from lidarpkt.cli import args as cliargs

        cliargs.check_output(args.gmm_map, "--gmm-map", (".npz", ".parquet"))
    stack = _load(args.input, args)
    stack = sensor_returns(stack)  # the returns as the sensor defines them
    mr = multireturn_map(stack, gap_m=gap, neighbourhood=args.neighbourhood, monitor_frame=args.monitor_frame,
                         threshold_m=args.threshold, method=method)
    out = Path(args.output)
    try:
        np.savez_compressed(out, allow_pickle=False, **mr.to_npz_dict(), frame_id=stack.frame_id)
    except OSError as exc:
        raise AnalysisError(f"-o {out}: cannot write ({exc.strerror or exc}); choose a writable path") from None
    s = mr.stats
    slot = shown if isinstance(shown, int) else (s.return_labels.index(shown) if shown in s.return_labels else -1)
    if not 0 <= slot < len(s.return_labels):
        raise AnalysisError(f"--return {args.slot}: no such slot; this capture has slots {list(s.return_labels)}")
    print(f"{_source(args.input, stack)}: {count(len(stack), 'frame')} of {stack.range_mm.shape[2]}x{stack.range_mm.shape[3]}")
    for i, label in enumerate(s.return_labels):
        with_ret = int(np.count_nonzero(s.n_returns[i]))
        multi = int(np.count_nonzero(s.multi_return[i]))
        ev = mr.evaluation[i]
        print(f"slot {i} ({label}): {with_ret} raypaths with returns, {multi} multi-return "
              f"(>= 2 clusters, gap > {gap:g} m); monitor ({mr.method}) on frame {mr.monitor_frame}: "
              f"{int(np.count_nonzero(mr.monitor_flags[i]))} flagged, precision {_fmt(ev.precision, 3)}, "
              f"recall {_fmt(ev.recall, 3)}, ROC AUC {_fmt(ev.auc, 3)}")
    _status(args, f"wrote {out}")
    if args.gmm_map:
        _status(args, _write_gmm_map(stack, args.gmm_map, args.gmm_components, gap))
    if args.plot:
        plots = _plots()
        figure, roc = Path(args.plot) / "multireturn_map.png", Path(args.plot) / "multireturn_roc.png"
        plots.save(plots.plot_multireturn_map(mr, stack, slot, _source(args.input, stack)), figure)
        ev = mr.evaluation[slot]
        plots.save(plots.plot_roc(ev, f"Multi-return monitor ({mr.method}) ROC, {s.return_labels[slot]} return\n"
                                      f"{ev.n_pixels} raypaths, {Path(args.input).name}"), roc)
        _status(args, f"wrote {figure} and {roc}")
    return 0


def _write_gmm_map(stack, path: str, components: int, gap_m: float) -> str:
    from lidarpkt.analysis.gmm_map import fit_gmm_map

    gm = fit_gmm_map(stack, max_components=components, min_separation_m=gap_m)
    gm.save(path)
    counts = np.bincount(gm.n_components.ravel(), minlength=components + 1)
    return (f"wrote {path}: mixtures of up to {components} components per pixel "
            f"({', '.join(f'{n} with {m}' for m, n in enumerate(counts) if n)})")


# ---------------------------------------------------------------------------- compare-returns


def add_compare_returns_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", metavar="IN", help="a dual-return capture, or the first of two captures of one scene")
    p.add_argument("input2", metavar="IN2", nargs="?", help="a capture of the same scene in another return mode")
    from lidarpkt.cli import args as cliargs

    cliargs.add_workers(p)
    cliargs.add_json(p, "the comparison as one JSON document")
    cliargs.add_plot(p)
    _add_input(p)
    p.add_argument("--metadata2", action="append", metavar="FILE", help="a sensor's file of IN2 (default: --metadata)")
    cliargs.add_pixel(p, required=False, help="raypath whose temporal CDFs to compare in detail; repeatable")
    p.add_argument("--return", dest="slot", metavar="RETURN", default=None,
                   help="with IN2: the return of IN to compare: strongest, last, second_strongest (per firing, as "
                        "the sensor defines them) or a raw slot index (default: a return kind both captures report)")
    p.add_argument("--return2", dest="slot2", metavar="RETURN", default=None,
                   help="with IN2: the return of IN2 to compare (default: the same kind as --return)")
    p.add_argument("--paired", action="store_true",
                   help="with IN2: frame k of both captures is the same firing (captures generated from one seed); "
                        "also compare them frame by frame")


def _pair_returns(a, b, sel_a, sel_b):
    """The returns of two captures to compare: given ones, else the same kind on both sides
    (``compare-returns STRONGEST.pcap DUAL.pcap`` pairs strongest with strongest)."""
    from lidarpkt.analysis.returns import available_returns

    if sel_a is None and sel_b is None:
        common = [k for k in available_returns(a) if k in available_returns(b)]
        if not common:  # two modes with nothing in common (strongest vs last): their own returns
            return available_returns(a)[0], available_returns(b)[0]
        return common[0], common[0]
    if sel_b is None:
        return sel_a, sel_a if isinstance(sel_a, str) else 0
    if sel_a is None:
        return (sel_b if isinstance(sel_b, str) else 0), sel_b
    return sel_a, sel_b


def run_compare_returns(args: argparse.Namespace) -> int:
    from lidarpkt.analysis.cdf import temporal_cdf
    from lidarpkt.analysis.compare import PairedComparison, compare_slots, compare_stacks, ks_image
    from lidarpkt.analysis.returns import available_returns, parse_return, resolve, sample_mask, select_returns

    pixels = list(args.pixel)
    sel_a = None if args.slot is None else parse_return(args.slot)
    sel_b = None if args.slot2 is None else parse_return(args.slot2)
    if args.plot and args.plot.lower().endswith(".png"):
        raise AnalysisError(f"--plot {args.plot}: compare-returns writes several figures; give a folder")
    _check_outputs(args)
    print = _say(args)  # noqa: A001 - the report's own print
    a = _load(args.input, args, args.workers)
    for r, c in pixels:  # before any heavy work
        _check_pixel(a, r, c, 0)
    src_a = _source(args.input, a)
    doc: dict[str, Any] = {"inputs": [args.input]}
    plots = _plots() if args.plot else None
    figs = []
    pc: PairedComparison | None
    pairs: list[tuple[FrameStack, int, FrameStack, int]]  # (stack, slot) pairs compared raypath by raypath
    if args.input2 is None:
        if a.range_mm.shape[1] < 2:
            raise AnalysisError(
                f"{args.input} has one return slot ({a.return_labels[0]}): give a dual-return capture, "
                "or a second capture of the same scene (IN2) to compare modes"
            )
        a = select_returns(a, available_returns(a)[:2])  # VLP-16 dual: last vs strongest, per firing
        pc = compare_slots(a, 0, 1)
        pairs = [(a, 0, a, 1)]
        doc["frames"] = len(a)
        doc["slots"] = pc.summary()
        s = pc.summary()
        print(f"{src_a}: {count(len(a), 'frame')}, {s['labels'][0]} vs {s['labels'][1]}: {s['pairs']} pairs, "
              f"{_fmt(s['fraction_identical'])} identical, {s['pairs_one_sided']} with a return on one side only")
        if plots:
            figs.append((plots.plot_delta_histogram(pc, src_a), "delta_histogram.png"))
            with np.errstate(invalid="ignore", divide="ignore"):
                two = (pc.n_differ - pc.n_one_sided) / pc.n_pairs  # both slots returned, at different ranges
            figs.append((plots.plot_pixel_map(two, f"Frames where {pc.labels[0]} and {pc.labels[1]} are two different "
                                              f"returns, per raypath — {src_a}", "fraction of frames", a, vmax=1.0),
                         "two_returns.png"))
    else:
        b = _load(args.input2, args, args.workers, metadata=args.metadata2)
        doc["inputs"].append(args.input2)
        doc["frames"] = [len(a), len(b)]
        sel_a, sel_b = _pair_returns(a, b, sel_a, sel_b)
        a, sa_i = resolve(a, sel_a)
        b, sb_i = resolve(b, sel_b)
        if args.paired:
            dist, pc = compare_stacks(a, b, sa_i, sb_i, paired=True)
        else:
            dist, pc = compare_stacks(a, b, sa_i, sb_i), None
        doc["modes"] = dist.summary()
        if plots:
            figs.append((plots.plot_pixel_map(dist.ks, f"KS distance between the temporal CDFs, {dist.labels[0]} "
                                              f"({Path(args.input).name}) vs {dist.labels[1]} ({Path(args.input2).name})",
                                              "KS distance", a, vmax=1.0), "ks_map.png"))
        s = doc["modes"]
        ksq = s["ks_quantiles"] or {}
        print(f"{src_a} vs {_source(args.input2, b)}: {s['pixels_compared']} raypaths compared; "
              f"KS distance between temporal CDFs: median {_fmt(ksq.get('0.5'), 3)}, 90% {_fmt(ksq.get('0.9'), 3)}")
        if pc is not None:
            doc["paired"] = pc.summary()
            print(f"paired by frame: {_fmt(pc.summary()['fraction_identical'])} of pairs identical")
            if plots:
                figs.append((plots.plot_delta_histogram(pc, f"{Path(args.input).name} vs {Path(args.input2).name}"),
                             "delta_histogram.png"))
        pairs = [(a, sa_i, b, sb_i)]
    raypaths = []
    for r, c in pixels:
        for sa, ia, sb, ib in pairs:
            _check_pixel(sa, r, c, ia)
            _check_pixel(sb, r, c, ib)
            ca, cb = temporal_cdf(sa, r, c, ia), temporal_cdf(sb, r, c, ib)

            ks = float(ks_image(sa.range_mm[:, ia, r:r + 1, c:c + 1], sample_mask(sa, ia)[:, r:r + 1, c:c + 1],
                                sb.range_mm[:, ib, r:r + 1, c:c + 1], sample_mask(sb, ib)[:, r:r + 1, c:c + 1])[0, 0])
            la, lb = sa.return_labels[ia], sb.return_labels[ib]
            if la == lb:
                la, lb = f"{la} ({Path(args.input).name})", f"{lb} ({Path(args.input2).name})"
            raypaths.append({"row": r, "col": c, "labels": [la, lb], "ks": ks,
                             "cdfs": [ca.to_json(), cb.to_json()],
                             "n_nonreturn": [ca.n_nonreturn, cb.n_nonreturn], "n_samples": [ca.n_samples, cb.n_samples]})
            print(f"raypath ({r}, {c}): {la} {ca.n_returns}/{ca.n_samples} returns, {lb} {cb.n_returns}/{cb.n_samples}, "
                  f"KS distance {ks:.3f}")
            if plots:
                figs.append((plots.plot_mode_cdfs({la: ca, lb: cb}, r, c, src_a, ks), f"r{r}_c{c}_modes.png"))
    doc["raypaths"] = raypaths
    _write_json(args, doc)
    if plots:
        for fig, name in figs:
            plots.save(fig, Path(args.plot) / name)
        _status(args, f"wrote {len(figs)} figures to {args.plot}")
    return 0
