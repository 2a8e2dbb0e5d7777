"""Precision, recall and ROC AUC of every multi-return monitor score (analysis.multireturn.monitor_score)
on the generated scenes and on VeloView's real 50-frame VLP-16 capture, and the scan-matching error
each method's monitor removes (analysis.registration, issue 17 §3).

    python benchmarks/monitor_methods.py [--neighbourhood N] [--frame K] [--markdown]
                                         [--registration-frames K | --no-registration]

Registration ranking: the first K frames (default 10) of each capture are registered by every
algorithm (point-to-point ICP, point-to-plane ICP, VGICP) to the first frame and to the map of all
frames, with every raypath and with the raypaths each method's one-frame monitor flags removed;
a method's *error reduction* is 1 − median translation error (monitor removed) / median
translation error (all), averaged over the algorithms and targets of a capture, then over the
captures. The default monitor method is the one with the largest mean reduction.

The truth is the temporal one of ``lidarpkt multireturn``: a raypath is multi-return when its
returns over the whole stack form two clusters or more (gap > 0.1 m); the monitor looks at one
frame and flags score > 0.1 m. Only raypaths with a return somewhere in the stack count. Slots
where every such raypath is multi-return (the OS1 dual's second-strongest slot: it only has
returns where there are two echoes) have no ROC and are left out.

The generated captures come from ``fixtures.ensure`` (seed 0, static, 50 VLP-16 / 30 OS1 frames);
VeloView's capture from ``$LIDARPKT_EXTERNAL_FIXTURES`` (default ``../shared/fixtures/external``),
skipped when it is not there. This measures quality, not speed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from lidarpkt.analysis.multireturn import MONITOR_METHODS, evaluate_monitor, image_statistics, monitor_score  # noqa: E402
from lidarpkt.analysis.stack import load_stack  # noqa: E402

GENERATED = ["vlp16-strongest", "vlp16-last", "vlp16-dual", "os1-64-legacy", "os1-64-dual"]
VELOVIEW = "veloview/vlp-16-test-90deg-1-50-frames.pcap"


def captures():
    from lidarpkt import fixtures

    for name in GENERATED:
        pcap = fixtures.ensure(name, aux=False)
        yield name, load_stack(pcap, metadata=fixtures.metadata_path(pcap))
    ext = Path(os.environ.get("LIDARPKT_EXTERNAL_FIXTURES") or ROOT.parent / "shared" / "fixtures" / "external")
    path = ext / VELOVIEW
    if path.exists():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield "veloview (real)", load_stack(path)
    else:
        print(f"({path} not found: VeloView's capture left out)", file=sys.stderr)


def precision_at_recall(ev, recall: float) -> float:
    """The best precision of any threshold on the ROC whose recall is at least ``recall``."""
    pos = ev.true_positive + ev.false_negative
    neg = ev.n_pixels - pos
    tp, fp = ev.roc_tpr * pos, ev.roc_fpr * neg
    ok = (ev.roc_tpr >= recall) & (tp + fp > 0)
    return float(np.max(tp[ok] / (tp[ok] + fp[ok]))) if ok.any() else float("nan")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--neighbourhood", type=int, default=5)
    p.add_argument("--frame", type=int, default=0)
    p.add_argument("--threshold", type=float, default=0.1)
    p.add_argument("--markdown", action="store_true", help="one markdown table instead of plain text")
    p.add_argument("--registration-frames", type=int, default=10, help="frames registered per capture (default 10)")
    p.add_argument("--no-registration", action="store_true", help="skip the registration ranking (needs small_gicp)")
    # P@R>=.5: the best precision over the ROC's thresholds at a recall of one half or more
    args = p.parse_args(argv)
    rows = []
    stacks = {}
    for name, stack in captures():
        stacks[name] = stack
        stats = image_statistics(stack)
        for method in MONITOR_METHODS:
            t0 = time.perf_counter()
            score = monitor_score(stack, frame=args.frame, n=args.neighbourhood, method=method)
            dt = time.perf_counter() - t0
            for slot, label in enumerate(stack.return_labels):
                mask = stats.n_returns[slot] > 0
                truth = stats.multi_return[slot]
                if truth[mask].all() or not truth[mask].any():
                    continue
                ev = evaluate_monitor(score[slot], truth, args.threshold, mask=mask)
                rows.append((f"{name} ({label})", method, ev, dt))
    if args.markdown:
        print("| capture (slot) | " + " | ".join(MONITOR_METHODS) + " |")
        print("|---|" + "---|" * len(MONITOR_METHODS))
        by_cap: dict[str, dict[str, object]] = {}
        for cap, method, ev, _ in rows:
            by_cap.setdefault(cap, {})[method] = ev
        for cap, evs in by_cap.items():
            cells = [f"P {e.precision:.2f} R {e.recall:.2f} AUC {e.auc:.3f}" for e in (evs[m] for m in MONITOR_METHODS)]
            print(f"| {cap} | " + " | ".join(cells) + " |")
    else:
        print_quality(rows)
    if not args.no_registration:
        registration_ranking(stacks, args.registration_frames, args.neighbourhood, args.threshold)
    return 0


REGISTRATION_CAPTURES = ["vlp16-strongest", "os1-64-legacy", "veloview (real)"]


def registration_ranking(stacks: dict, frames: int, n: int, threshold: float) -> dict[str, float]:
    """Print, per capture and method, the translation-error reduction of the monitor's removal,
    and the methods ranked by its mean. Returns {method: mean reduction}."""
    from lidarpkt.analysis.registration import registration_impact
    from lidarpkt.analysis.stack import select_frames

    reductions: dict[str, list[float]] = {m: [] for m in MONITOR_METHODS}
    print(f"\nregistration: median translation error (mm), first {frames} frames; "
          "reduction = 1 - monitor_removed / all, mean over 3 algorithms x 2 targets")
    print(f"{'capture':24s} {'all':>8s} " + " ".join(f"{m + ' (red.)':>22s}" for m in MONITOR_METHODS) + f" {'time':>7s}")
    for name in REGISTRATION_CAPTURES:
        if name not in stacks:
            continue
        t0 = time.perf_counter()
        st = select_frames(stacks[name], 0, frames)
        base = registration_impact(st, conditions=("all",))
        med_all = {(a, m): float(np.median(e["all"].translation_m)) for a, by in base.errors.items() for m, e in by.items()}
        cells = []
        for method in MONITOR_METHODS:
            r = registration_impact(st, monitor_method=method, neighbourhood=n, threshold_m=threshold,
                                    conditions=("monitor_removed",))
            red = [1.0 - float(np.median(e["monitor_removed"].translation_m)) / med_all[(a, m)]
                   for a, by in r.errors.items() for m, e in by.items()]
            reductions[method].append(float(np.mean(red)))
            removed = 100 * r.removed_fraction["monitor_removed"]
            cells.append(f"{np.mean(red):+6.1%} ({removed:4.1f}% removed)")
        print(f"{name:24s} {np.median(list(med_all.values())) * 1000:8.2f} " + " ".join(f"{c:>22s}" for c in cells)
              + f" {time.perf_counter() - t0:6.1f}s")
    mean = {m: float(np.mean(v)) for m, v in reductions.items() if v}
    ranked = sorted(mean, key=lambda m: -mean[m])
    print("ranked by mean error reduction: " + ", ".join(f"{m} {mean[m]:+.1%}" for m in ranked))
    return mean


def print_quality(rows) -> None:
    """The precision / recall table, one line per capture, slot and method."""
    if rows:
        print(f"{'capture (slot)':30s} {'method':8s} {'precision':>9s} {'recall':>7s} {'AUC':>6s} {'P@R>=.5':>7s} "
              f"{'flagged':>8s} {'multi':>6s} {'raypaths':>8s} {'time':>7s}")
        for cap, method, ev, dt in rows:
            print(f"{cap:30s} {method:8s} {ev.precision:9.3f} {ev.recall:7.3f} {ev.auc:6.3f} {precision_at_recall(ev, 0.5):7.3f} "
                  f"{ev.true_positive + ev.false_positive:8d} {ev.true_positive + ev.false_negative:6d} {ev.n_pixels:8d} {dt:6.2f}s")


if __name__ == "__main__":
    sys.exit(main())
