"""The multi-return analysis of the bundled synthetic scene, end to end (what ``lidarpkt demo`` runs).

For each of the five fixture captures (VLP-16 strongest, last and dual; OS1-64 legacy and dual; see
``fixtures/README.md``) :func:`run_demo` generates the full-length capture once (deterministic, cached),
writes it as MCAP when asked (``write_mcap``), stacks its frames and analyses every named raypath of the
scene in every return slot (temporal CDF, GMM by EM/BIC) and the whole image (multi-return map), then
draws the paper's figures and writes a ``summary.json`` into the output folder.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

from lidarpkt.fixtures import CAPTURES

__all__ = ["CAPTURES", "FIGURE_RAYPATHS", "format_table", "run_demo"]

#: Raypaths whose figures are drawn (all are analysed and tabulated).
FIGURE_RAYPATHS = ("window", "foliage")


def run_demo(out: str | Path, *, frames: int | None = None, seed: int = 0, plots: Any = None,
             write_mcap: Callable[[Path, Path, Path | None], None] | None = None,
             progress: Callable[[int, str], None] | None = None) -> dict[str, Any]:
    """Analyse every fixture capture and write the results into the folder ``out`` (it must exist).

    Args:
        out: the output folder: figures, ``summary.json``, and the MCAP files ``write_mcap`` writes.
        frames: frames per capture (default: the fixtures' full length); seed: of the scene's draws.
        plots: :mod:`lidarpkt.analysis.plots` to draw the figures, or None for none.
        write_mcap: ``write_mcap(pcap, mcap_path, metadata_path_or_None)`` writes a capture as MCAP; None: no MCAP.
        progress: ``progress(captures_done, name)`` after each capture.

    Returns:
        the summary written to ``summary.json``: ``captures`` (per capture: pcap, mcap, frames, return labels,
        the monitor's precision/recall/AUC per slot, seconds), ``raypaths`` (the rows of :func:`format_table`)
        and ``seconds``.

    Raises:
        lidarpkt.errors.LidarpktError: what generating, decoding or analysing raises.
    """
    from lidarpkt import fixtures

    from .multireturn import multireturn_map
    from .raypath import analyze_raypath
    from .returns import available_returns, select_returns
    from .stack import load_stack

    out = Path(out)
    started = time.monotonic()
    rows: list[dict[str, Any]] = []
    captures: dict[str, Any] = {}
    stacks = {}

    for name in CAPTURES:
        t0 = time.monotonic()
        pcap = fixtures.ensure(name, frames=frames, seed=seed)
        truth = fixtures.load_truth(pcap)
        metadata = fixtures.metadata_path(pcap)
        mcap_path = None
        if write_mcap is not None:
            mcap_path = out / f"{name}.mcap"
            write_mcap(pcap, mcap_path, metadata)
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
        if progress is not None:
            progress(len(captures), name)

    if plots is not None:
        _mode_comparison_figures(plots, stacks, out, frames, seed)
    summary = {"captures": captures, "raypaths": rows, "seconds": round(time.monotonic() - started, 2)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=_json_default) + "\n")
    return summary


def _mode_comparison_figures(plots, stacks, out: Path, frames: int | None, seed: int) -> None:
    """Strongest vs last temporal CDFs of the figure raypaths, from the captures of one sensor in each return
    mode (:data:`lidarpkt.fixtures.captures.MODE_CAPTURES`): how the mode changes what a raypath reports."""
    from lidarpkt import fixtures
    from lidarpkt.fixtures.captures import MODE_CAPTURES, MODE_FIGURE_PREFIX

    from .cdf import temporal_cdf

    truth = fixtures.load_truth(fixtures.ensure(MODE_CAPTURES["strongest"], frames=frames, seed=seed))
    model = stacks[MODE_CAPTURES["strongest"]].sensor.model
    for raypath in FIGURE_RAYPATHS:
        row, col = truth["raypaths"][raypath]["pixel"][0]
        cdfs = {
            "strongest": temporal_cdf(stacks[MODE_CAPTURES["strongest"]], row, col, 0),
            "last": temporal_cdf(stacks[MODE_CAPTURES["last"]], row, col, 0),
            "dual: last": temporal_cdf(stacks[MODE_CAPTURES["dual"]], row, col, 0),
            "dual: strongest": temporal_cdf(stacks[MODE_CAPTURES["dual"]], row, col, 1),
        }
        fig = plots.plot_mode_cdfs(cdfs, row, col, f"{model} {raypath}")
        plots.save(fig, out / f"{MODE_FIGURE_PREFIX}-{raypath}-modes.png")


def format_table(rows: list[dict[str, Any]]) -> str:
    """The demo's table: one line per raypath, capture and return slot (returns, clusters, GMM means)."""
    head = f"{'raypath':<9} {'capture':<16} {'slot':<17} {'pixel':>11} {'returns':>9} {'clusters':>8}  GMM means (m)"
    lines = [head, "-" * len(head)]
    for r in rows:
        means = ", ".join(f"{m:.3f}" for m in r["gmm_means_m"]) or "-"
        pixel = f"({r['row']},{r['col']})"
        lines.append(f"{r['raypath']:<9} {r['capture']:<16} {r['slot']:<17} {pixel:>11} "
                     f"{r['returns']:>4}/{r['frames']:<4} {r['clusters']:>8}  {means}")
    return "\n".join(lines)


def _json_default(obj: Any) -> Any:
    try:
        return obj.item()  # NumPy scalars
    except AttributeError:
        return str(obj)
