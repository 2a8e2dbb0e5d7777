"""The paper's figure types (matplotlib, the ``plot`` extra).

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot (no global
state, no display needed); :func:`save` writes it as PNG. Ranges are in metres, CDFs are the
samples' CDF (non-returns in the denominator, so a curve tops out at 1 − non-return fraction).
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack

from .cdf import RangeCDF
from .compare import PairedComparison
from .multireturn import MonitorEvaluation, MultiReturnMap
from .raypath import RaypathAnalysis
from .stack import destagger, pixel_shift


def _figure(*args, **kwargs):
    try:
        from matplotlib.figure import Figure
    except ImportError:  # pragma: no cover - depends on the install
        raise AnalysisError("plots need matplotlib: pip install 'lidarpkt[plot]'") from None
    return Figure(*args, **kwargs)


def save(fig, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` as PNG to ``path`` (parent folders created). Returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, format="png")
    return path


def _name(ra: RaypathAnalysis, source: str) -> str:
    where = f"raypath (row {ra.row}, col {ra.col}), {ra.label} return"
    return f"{where}\n{source}" if source else where


def _step(ax, cdf: RangeCDF, x_right: float | None = None, **kw):
    """Draw an empirical CDF as a step function from 0 up to its top (1 − non-return fraction)."""
    if cdf.n_returns == 0:
        return ax.plot([], [], **kw)
    x = np.r_[cdf.range_m[0], cdf.range_m]
    y = np.r_[0.0, cdf.F]
    if x_right is not None and x_right > x[-1]:
        x, y = np.r_[x, x_right], np.r_[y, y[-1]]
    return ax.step(x, y, where="post", **kw)


def _range_limits(*cdfs: RangeCDF, pad: float = 0.05) -> tuple[float, float]:
    vals = np.concatenate([c.range_m for c in cdfs if c.n_returns] or [np.array([0.0, 1.0])])
    lo, hi = float(vals.min()), float(vals.max())
    margin = max((hi - lo) * pad, 0.05)
    return lo - margin, hi + margin


def _cdf_axes(ax, ylabel: str = "CDF F(r)"):
    ax.set_xlabel("range r (m)")
    ax.set_ylabel(ylabel)
    ax.set_ylim(-0.02, 1.02)
    ax.grid(True, alpha=0.3)


def plot_temporal_cdf(ra: RaypathAnalysis, source: str = ""):
    """Fig. 7: temporal CDF of a raypath, with the reflectivity of each return on a second axis."""
    t = ra.temporal
    fig = _figure(figsize=(7.5, 4.5), layout="constrained")
    ax = fig.add_subplot()
    lo, hi = _range_limits(t)
    _step(ax, t, hi, color="C0", lw=1.8, label="temporal CDF")
    if t.n_samples:
        ax.axhline(1 - t.nonreturn_fraction, color="C0", ls=":", lw=1,
                   label=f"1 − non-return fraction = {1 - t.nonreturn_fraction:.2f}")
    ax.set_xlim(lo, hi)
    _cdf_axes(ax)
    ax2 = ax.twinx()
    ax2.plot(t.range_m, ra.reflectivity, "o", ms=3.5, color="C3", alpha=0.6, label="reflectivity")
    ax2.set_ylabel("reflectivity (sensor units, 0–255)", color="C3")
    ax2.tick_params(axis="y", colors="C3")
    top = max(110, int(ra.reflectivity.max()) + 10) if ra.reflectivity.size else 110
    ax2.set_ylim(0, min(top, 265))
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], loc="upper left", fontsize=8)
    ax.set_title(
        f"Temporal CDF, {_name(ra, source)}\n{t.n_returns} returns, {t.n_nonreturn} non-returns, "
        f"{t.n_missing} missing of {ra.n_frames} frames",
        fontsize=10,
    )
    return fig


def plot_temporal_vs_spatial(ra: RaypathAnalysis, source: str = ""):
    """Figs. 8–9: temporal CDF against the spatial CDF of the first frame and of all frames superimposed."""
    fig = _figure(figsize=(7.5, 4.5), layout="constrained")
    ax = fig.add_subplot()
    lo, hi = _range_limits(ra.temporal, ra.spatial, ra.spatial_all)
    n = ra.neighbourhood
    _step(ax, ra.temporal, hi, color="C0", lw=2.0, label=f"temporal ({ra.temporal.n_samples} frames)")
    _step(ax, ra.spatial, hi, color="C1", lw=1.5, ls="--", label=f"spatial {n}×{n}, first frame")
    _step(ax, ra.spatial_all, hi, color="C2", lw=1.2, ls="-.", label=f"spatial {n}×{n}, all frames superimposed")
    ax.set_xlim(lo, hi)
    _cdf_axes(ax)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"Temporal vs spatial CDF, {_name(ra, source)}", fontsize=10)
    return fig


def plot_motion_compensation(ra: RaypathAnalysis, source: str = ""):
    """Fig. 10: temporal CDF before and after motion compensation, and the chosen offsets per frame."""
    if ra.motion is None:
        raise AnalysisError("this raypath was analysed without motion compensation (use --motion-compensation)")
    m = ra.motion
    fig = _figure(figsize=(7.5, 6.0), layout="constrained")
    ax, ax_off = fig.subplots(2, 1, height_ratios=[2.2, 1])
    lo, hi = _range_limits(ra.temporal, m.cdf)
    _step(ax, ra.temporal, hi, color="C0", lw=1.6, label="before (raw temporal CDF)")
    _step(ax, m.cdf, hi, color="C3", lw=1.6, ls="--", label="after motion compensation")
    ax.set_xlim(lo, hi)
    _cdf_axes(ax)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"Motion compensation (5×5 patch, ±2 px, vs frame 0), {_name(ra, source)}", fontsize=10)
    k = np.arange(m.offsets.shape[0])
    ax_off.step(k, m.offsets[:, 0], where="mid", color="C4", label="Δrow")
    ax_off.step(k, m.offsets[:, 1], where="mid", color="C5", ls="--", label="Δcol")
    ax_off.set_xlabel("frame (stack index)")
    ax_off.set_ylabel("chosen offset (pixels)")
    ax_off.set_yticks(np.arange(-2, 3))
    ax_off.grid(True, alpha=0.3)
    ax_off.legend(loc="upper right", fontsize=8, ncol=2)
    return fig


def plot_gmm(ra: RaypathAnalysis, source: str = ""):
    """Fig. 11: GMM density above (with the samples' histogram), model vs empirical CDF below."""
    if ra.gmm is None:
        raise AnalysisError(f"no Gaussian mixture for raypath ({ra.row}, {ra.col}): it has no returns or --gmm was off")
    g = ra.gmm
    cdf = ra.motion.cdf if ra.motion is not None else ra.temporal
    fig = _figure(figsize=(7.5, 6.5), layout="constrained")
    ax_pdf, ax_cdf = fig.subplots(2, 1, sharex=True)
    lo, hi = _range_limits(cdf)
    lo = min(lo, float(np.min(g.means_m - 3 * g.sigmas_m)))
    hi = max(hi, float(np.max(g.means_m + 3 * g.sigmas_m)))
    r = np.linspace(lo, hi, 2000)
    # Histogram as a density over *samples* (non-returns included), so that it matches the model's scale.
    bins = np.linspace(lo, hi, 81)
    counts, _ = np.histogram(cdf.range_m, bins=bins)
    ax_pdf.bar(bins[:-1], counts / (cdf.n_samples * np.diff(bins)), width=np.diff(bins), align="edge",
               color="0.75", label="samples (histogram)")
    ax_pdf.plot(r, g.pdf(r), color="C3", lw=1.6, label=f"GMM ({g.method}, {g.n_components} components)")
    ax_pdf.set_ylabel("density p(r) (1/m)")
    ax_pdf.grid(True, alpha=0.3)
    ax_pdf.legend(loc="upper left", fontsize=8)
    terms = [f"{w:.2f}·N({m:.3f} m, {s * 100:.1f} cm)" for w, m, s in zip(g.weights, g.means_m, g.sigmas_m)]
    comp = "\n".join(", ".join(terms[i : i + 3]) for i in range(0, len(terms), 3))  # 3 components a line
    ax_pdf.set_title(f"Gaussian mixture, {_name(ra, source)}\n{comp}", fontsize=9)
    _step(ax_cdf, cdf, hi, color="C0", lw=1.6, label="empirical CDF")
    ax_cdf.plot(r, g.cdf(r), color="C3", lw=1.4, ls="--", label=f"model CDF (KS distance {g.ks:.3f})")
    ax_cdf.set_xlim(lo, hi)
    _cdf_axes(ax_cdf)
    ax_cdf.legend(loc="upper left", fontsize=8)
    return fig


def plot_range_image(
    stack: FrameStack, frame: int = 0, slot: int = 0, pixels: Sequence[tuple[int, int]] = (), source: str = ""
):
    """Figs. 2–3: the range image of one frame (destaggered for display) with raypaths marked.

    Marked pixels are given in the stack's (staggered) coordinates and drawn where they appear
    in the destaggered image. Black: non-return; grey: no sample (the column's packet was lost),
    as the colour bar says. Labels of nearby marks are stacked so that none hides another.
    """
    from matplotlib import colormaps

    shift = pixel_shift(stack)
    rng = stack.range_mm[frame, slot].astype(np.float64) / 1000.0
    from .returns import sample_mask

    valid = sample_mask(stack, slot)[frame]
    img = np.where(valid & (rng > 0), rng, np.nan)
    img = destagger(img, shift)
    missing = destagger(~valid, shift)
    h, w = img.shape
    cmap = colormaps["viridis"].with_extremes(bad="black")
    fig = _figure(figsize=(12, max(2.8, min(8.0, 1.2 + 12 * h / w * 3))), layout="constrained")
    ax = fig.add_subplot()
    finite = img[np.isfinite(img)]
    vmax = float(np.quantile(finite, 0.98)) if finite.size else 1.0
    im = ax.imshow(img, aspect="auto", interpolation="nearest", cmap=cmap, vmin=0, vmax=vmax)
    if missing.any():
        ax.imshow(np.where(missing, 1.0, np.nan), aspect="auto", interpolation="nearest", cmap="Greys", vmin=0, vmax=2)
    placed: list[tuple[int, int]] = []
    for r, c in pixels:
        dc = (c + shift[r]) % w
        ax.plot(dc, r, marker="s", ms=9, mfc="none", mec="red", mew=1.8)
        right = dc > 0.85 * w  # keep the label inside the image near the right edge
        # a label ~8 characters wide covers ~10% of a 12-inch image: stack those of nearby marks
        level = sum(1 for pr, pc in placed if abs(pc - dc) < 0.12 * w and abs(pr - r) <= max(2, h // 8))
        placed.append((r, dc))
        dy = (-6, 9, -21, 24, -36, 39)[level % 6]
        ax.annotate(f"({r}, {c})", (dc, r), xytext=(-8 if right else 6, dy), textcoords="offset points",
                    ha="right" if right else "left", color="red", fontsize=8,
                    bbox=dict(boxstyle="round,pad=0.15", fc="white", alpha=0.7, lw=0))
    ax.set_xlabel("column (azimuth step" + (", destaggered" if np.any(shift) else "") + ")")
    ax.set_ylabel("row (beam, 0 = top)")
    ax.yaxis.get_major_locator().set_params(integer=True)
    cb = fig.colorbar(im, ax=ax, pad=0.01)
    cb.set_label("range (m)\nblack: no return, grey: no sample", fontsize=8)  # two short lines: never cut off
    label = stack.return_labels[slot]
    src = f" — {source}" if source else ""
    ax.set_title(f"Range image, frame id {int(stack.frame_id[frame])}, {label} return, {stack.sensor.model}{src}", fontsize=10)
    return fig


def plot_multireturn_map(mr: MultiReturnMap, stack: FrameStack | None = None, slot: int = 0, source: str = ""):
    """The multi-return map: clusters per pixel, non-return fraction, largest gap Δ, monitor flags."""
    from matplotlib import colormaps
    from matplotlib.colors import BoundaryNorm, ListedColormap

    s = mr.stats
    shift = pixel_shift(stack) if stack is not None else np.zeros(s.n_clusters.shape[1], np.int64)
    show = lambda a: destagger(a, shift)  # noqa: E731 - display only
    label = s.return_labels[slot] if s.return_labels else f"slot {slot}"
    h, w = s.n_clusters.shape[1:]
    fig = _figure(figsize=(12, max(6.0, min(12.0, 4 * (0.9 + 12 * h / w * 2)))), layout="constrained")
    axes = fig.subplots(4, 1, sharex=True)
    ncl = np.minimum(s.n_clusters[slot], 4)
    cmap = ListedColormap(["black", "#d9d9d9", "#fdae61", "#d7191c", "#7b3294"])
    im = axes[0].imshow(show(ncl), aspect="auto", interpolation="nearest", cmap=cmap,
                        norm=BoundaryNorm(np.arange(-0.5, 5.5), 5))
    cb = fig.colorbar(im, ax=axes[0], ticks=range(5), pad=0.01)
    cb.ax.set_yticklabels(["0 (no return)", "1", "2", "3", "≥4"])
    cb.set_label("clusters")
    axes[0].set_title(f"Clusters per raypath over {int(s.n_samples[slot].max())} frames (gap > {s.gap_threshold_m * 100:.0f} cm)")
    im = axes[1].imshow(show(s.nonreturn_fraction[slot]), aspect="auto", interpolation="nearest",
                        cmap=colormaps["magma"].with_extremes(bad="0.6"), vmin=0, vmax=1)
    fig.colorbar(im, ax=axes[1], pad=0.01).set_label("fraction")
    axes[1].set_title("Non-return fraction (grey: no sample)")
    gap = np.where(s.n_clusters[slot] >= 2, s.gap_m[slot], np.nan)
    finite = gap[np.isfinite(gap)]
    im = axes[2].imshow(show(gap), aspect="auto", interpolation="nearest",
                        cmap=colormaps["viridis"].with_extremes(bad="0.9"), vmin=0,
                        vmax=float(np.quantile(finite, 0.98)) if finite.size else 1.0)
    fig.colorbar(im, ax=axes[2], pad=0.01).set_label("Δ (m)")
    axes[2].set_title("Largest gap Δ between clusters (grey: single cluster or none)")
    ev = mr.evaluation[slot] if mr.evaluation else None
    flags = mr.monitor_flags[slot].astype(float)
    truth = s.multi_return[slot]
    # 0 neither, 1 flagged only (false alarm), 2 missed, 3 both
    code = flags + 2 * truth
    im = axes[3].imshow(show(code), aspect="auto", interpolation="nearest",
                        cmap=ListedColormap(["#f0f0f0", "#fdae61", "#2c7bb6", "#d7191c"]),
                        norm=BoundaryNorm(np.arange(-0.5, 4.5), 4))
    cb = fig.colorbar(im, ax=axes[3], ticks=range(4), pad=0.01)
    # short lines: a long tick label ("flagged & multi…") was cut off at the figure's edge
    cb.ax.set_yticklabels(["neither", "flagged\nonly", "missed", "flagged &\nmulti-return"], fontsize=8)
    n = mr.neighbourhood
    what = {
        "detrend": f"{n}×{n}, gap about local planes",
        "plane": f"{n}×{n}, gap about one plane",
        "gap": f"{n}×{n} spatial CDF gap, the paper's",
        "row": f"{n}×{n} spatial CDF gap per row",
    }.get(mr.method, f"{n}×{n}")
    title = f"Monitor '{mr.method}' ({what}) on frame {mr.monitor_frame}"
    if ev is not None:
        title += (f", flagged > {ev.threshold_m * 100:.0f} cm: precision {ev.precision:.2f}, "
                  f"recall {ev.recall:.2f}, ROC AUC {ev.auc:.2f}")
    axes[3].set_title(title)
    for ax in axes:
        ax.set_ylabel("row")
        ax.yaxis.get_major_locator().set_params(integer=True)
    axes[3].set_xlabel("column (azimuth step" + (", destaggered" if np.any(shift) else "") + ")")
    src = f" — {source}" if source else ""
    fig.suptitle(f"Multi-return map, {label} return{src}", fontsize=11)
    return fig


def plot_roc(ev: MonitorEvaluation, title: str = ""):
    """ROC curve of the multi-return monitor over its gap threshold, the operating point marked."""
    fig = _figure(figsize=(5, 5), layout="constrained")
    ax = fig.add_subplot()
    ax.plot(ev.roc_fpr, ev.roc_tpr, color="C0", lw=1.6, label=f"ROC (AUC {ev.auc:.2f})")
    ax.plot([0, 1], [0, 1], color="0.6", ls=":", lw=1)
    pos = ev.true_positive + ev.false_negative
    neg = ev.false_positive + ev.true_negative
    if pos and neg:
        ax.plot(ev.false_positive / neg, ev.true_positive / pos, "o", color="C3",
                label=f"threshold {ev.threshold_m * 100:.0f} cm: precision {ev.precision:.2f}, recall {ev.recall:.2f}")
    ax.set_xlabel("false-positive rate")
    ax.set_ylabel("true-positive rate (recall)")
    ax.set_xlim(-0.01, 1.01)
    ax.set_ylim(-0.01, 1.01)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="lower right", fontsize=8)
    ax.set_title(title or f"Multi-return monitor ROC ({ev.n_pixels} raypaths)", fontsize=10)
    return fig


def plot_delta_histogram(pc: PairedComparison, source: str = ""):
    """Histogram of Δ = ``|r_a − r_b|`` over the frame pairs whose two returns differ."""
    fig = _figure(figsize=(7.5, 4.2), layout="constrained")
    ax = fig.add_subplot()
    e = pc.delta_edges_m
    lo = max(e[1], 1e-3)
    ax.stairs(pc.delta_counts[1:], e[1:], fill=True, color="C0", alpha=0.7)
    ax.set_xscale("log")
    ax.set_xlim(lo, e[-1])
    ax.set_xlabel(f"Δ = |r({pc.labels[0]}) − r({pc.labels[1]})| (m, log scale)")
    ax.set_ylabel("pairs of returns")
    ax.grid(True, alpha=0.3, which="both")
    s = pc.summary()
    ident = s["fraction_identical"]
    ident_txt = f"{ident:.3f}" if ident is not None else "n/a"
    src = f" — {source}" if source else ""
    ax.set_title(
        f"{pc.labels[0]} vs {pc.labels[1]}{src}\n{s['pairs']} pairs: {ident_txt} identical, "
        f"{s['pairs_differ'] - s['pairs_one_sided']} differ in range, {s['pairs_one_sided']} return on one side only",
        fontsize=9,
    )
    return fig


def plot_mode_cdfs(cdfs: Mapping[str, RangeCDF], row: int, col: int, source: str = "", ks: float | None = None):
    """Temporal CDFs of one raypath in several modes (e.g. strongest vs last), on one axis."""
    fig = _figure(figsize=(7.5, 4.5), layout="constrained")
    ax = fig.add_subplot()
    lo, hi = _range_limits(*cdfs.values())
    styles = ["-", "--", "-.", ":"]
    for i, (label, cdf) in enumerate(cdfs.items()):
        _step(ax, cdf, hi, lw=1.8 - 0.2 * i, ls=styles[i % 4], label=f"{label} ({cdf.n_returns}/{cdf.n_samples} returns)")
    ax.set_xlim(lo, hi)
    _cdf_axes(ax)
    ax.legend(loc="upper left", fontsize=8)
    ks_txt = f", KS distance {ks:.3f}" if ks is not None and np.isfinite(ks) else ""
    src = f" — {source}" if source else ""
    ax.set_title(f"Temporal CDF by return mode, raypath (row {row}, col {col}){ks_txt}{src}", fontsize=10)
    return fig


def plot_pixel_map(values: np.ndarray, title: str, label: str, stack: FrameStack | None = None,
                   vmin: float | None = 0.0, vmax: float | None = None):
    """A per-pixel ``[H, W]`` quantity as an image (destaggered for display when ``stack`` has a
    stagger), NaN (no sample) in grey: e.g. how often two modes differ, or their KS distance."""
    from matplotlib import colormaps

    shift = pixel_shift(stack) if stack is not None else np.zeros(values.shape[0], np.int64)
    img = destagger(np.asarray(values, dtype=np.float64), shift)
    h, w = img.shape
    fig = _figure(figsize=(12, max(2.8, min(8.0, 1.2 + 12 * h / w * 3))), layout="constrained")
    ax = fig.add_subplot()
    finite = img[np.isfinite(img)]
    if vmax is None:
        vmax = float(np.quantile(finite, 0.99)) if finite.size else 1.0
    im = ax.imshow(img, aspect="auto", interpolation="nearest", cmap=colormaps["viridis"].with_extremes(bad="0.6"),
                   vmin=vmin, vmax=vmax)
    fig.colorbar(im, ax=ax, pad=0.01).set_label(label)
    ax.set_xlabel("column (azimuth step" + (", destaggered" if np.any(shift) else "") + ")")
    ax.set_ylabel("row (beam, 0 = top)")
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_title(title + " (grey: no sample)", fontsize=10)
    return fig


# ---------------------------------------------------------------------------- registration impact


def plot_registration_cdfs(impact, quantity: str = "translation_m", source: str = ""):
    """Empirical CDFs of the pose error (``quantity``: ``"translation_m"``, drawn in mm, or
    ``"rotation_deg"``) per condition, one panel per algorithm (columns) and target (rows),
    in the style of the paper's range CDFs. ``impact``: :class:`analysis.registration.RegistrationImpact`."""
    from .registration import CONDITIONS

    algs = list(impact.errors)
    modes = list(next(iter(impact.errors.values()))) if algs else []
    scale, unit = (1000.0, "mm") if quantity == "translation_m" else (1.0, "deg")
    what = "translation error" if quantity == "translation_m" else "rotation error"
    fig = _figure(figsize=(4.0 * max(1, len(algs)), 3.2 * max(1, len(modes)) + 0.6), layout="constrained")
    axes = fig.subplots(max(1, len(modes)), max(1, len(algs)), squeeze=False)
    styles = {"all": "-", "monitor_removed": "--", "multireturn_removed": "-."}
    for j, alg in enumerate(algs):
        for i, mode in enumerate(modes):
            ax = axes[i][j]
            for cond in CONDITIONS:
                e = impact.errors[alg][mode].get(cond)
                if e is None or not e.frame.size:
                    continue
                x = np.sort(getattr(e, quantity) * scale)
                y = np.arange(1, x.size + 1) / x.size
                ax.step(np.r_[0.0, x], np.r_[0.0, y], where="post", ls=styles[cond], lw=1.6,
                        label=f"{cond} (median {np.median(x):.3g} {unit})")
            ax.set_title(f"{alg.replace('_', ' ')}, {mode.replace('_', ' ')}", fontsize=9)
            ax.set_xlabel(f"{what} ({unit})")
            ax.set_ylabel("CDF")
            ax.set_ylim(-0.02, 1.02)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="lower right", fontsize=7)
    src = f" — {source}" if source else ""
    fig.suptitle(f"Pose {what} of a stationary sensor ({impact.frames} frames, {impact.label} return){src}", fontsize=10)
    return fig
