"""The plotted data read back from the figures (Line2D data, AxesImage arrays, bar heights) against
statistics recomputed here from the raw stack with plain NumPy, not with the analysis functions:
a figure that draws the wrong array (reversed, another slot, not destaggered) fails."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="plots need the `plot` extra (matplotlib)")

from lidarpkt.analysis import plots  # noqa: E402
from lidarpkt.analysis.compare import compare_slots  # noqa: E402
from lidarpkt.analysis.multireturn import multireturn_map  # noqa: E402
from lidarpkt.analysis.raypath import analyze_raypath  # noqa: E402
from test_analysis_plots import stack  # noqa: E402,F401 (the shared fixture)
from test_analysis_support import destaggered_by_definition, make_stack  # noqa: E402

ROW, COL = 4, 10


def samples_mm(st, row, col, slot):
    """The raypath's samples over the frames whose column arrived (0 = non-return)."""
    return st.range_mm[:, slot, row, col][st.column_valid[:, col]].astype(np.int64)


def empirical_cdf(samples):
    """(sorted return ranges in m, F at each = #samples ≤ r / #samples), non-returns in the denominator."""
    r = np.sort(samples[samples > 0]) / 1000.0
    return r, np.array([(samples[samples > 0] / 1000.0 <= x).sum() / samples.size for x in r])


def step_xy(line):
    return np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata(), float)


def test_temporal_cdf_curve_and_reflectivity_points(stack):  # noqa: F811
    ra = analyze_raypath(stack, ROW, COL, 0, gmm=None)
    fig = plots.plot_temporal_cdf(ra)
    ax, ax2 = fig.axes[:2]
    r, F = empirical_cdf(samples_mm(stack, ROW, COL, 0))
    assert len(r) > 5
    x, y = step_xy(ax.get_lines()[0])
    assert ax.get_lines()[0].get_drawstyle() == "steps-post"
    np.testing.assert_allclose(x[1 : 1 + len(r)], r)
    np.testing.assert_allclose(y[1 : 1 + len(r)], F)
    assert y[0] == 0 and y[-1] == pytest.approx(F[-1])
    # the dotted line at 1 − non-return fraction
    s = samples_mm(stack, ROW, COL, 0)
    assert ax.get_lines()[1].get_ydata()[0] == pytest.approx(np.count_nonzero(s) / s.size)
    # each reflectivity point is a (range, reflectivity) pair of one frame
    (pts,) = [ln for ln in ax2.get_lines() if ln.get_label() == "reflectivity"]
    px, py = step_xy(pts)
    keep = stack.column_valid[:, COL] & (stack.range_mm[:, 0, ROW, COL] > 0)
    truth = np.stack([stack.range_mm[keep, 0, ROW, COL] / 1000.0, stack.reflectivity[keep, 0, ROW, COL]], 1)
    got = np.stack([px, py], 1)
    np.testing.assert_allclose(got[np.lexsort(got.T[::-1])], truth[np.lexsort(truth.T[::-1])])


def test_temporal_vs_spatial_curves(stack):  # noqa: F811
    ra = analyze_raypath(stack, ROW, COL, 0, neighbourhood=3, gmm=None)
    lines = plots.plot_temporal_vs_spatial(ra).axes[0].get_lines()
    r, F = empirical_cdf(samples_mm(stack, ROW, COL, 0))
    x, y = step_xy(lines[0])
    np.testing.assert_allclose(x[1 : 1 + len(r)], r)
    np.testing.assert_allclose(y[1 : 1 + len(r)], F)
    first = stack.range_mm[0, 0, ROW - 1 : ROW + 2, COL - 1 : COL + 2].astype(np.int64).ravel()
    r, F = empirical_cdf(first)
    x, y = step_xy(lines[1])
    np.testing.assert_allclose(x[1 : 1 + len(r)], r)
    np.testing.assert_allclose(y[1 : 1 + len(r)], F)
    every = stack.range_mm[:, 0, ROW - 1 : ROW + 2, COL - 1 : COL + 2].astype(np.int64).ravel()
    r, F = empirical_cdf(every)
    x, y = step_xy(lines[2])
    np.testing.assert_allclose(x[1 : 1 + len(r)], r)
    np.testing.assert_allclose(y[1 : 1 + len(r)], F)


def test_gmm_model_curve_and_histogram(stack):  # noqa: F811
    from scipy.stats import norm

    ra = analyze_raypath(stack, ROW, COL, 0, gmm="auto")
    g = ra.gmm
    fig = plots.plot_gmm(ra)
    ax_pdf, ax_cdf = fig.axes[:2]
    (model,) = [ln for ln in ax_cdf.get_lines() if ln.get_label().startswith("model CDF")]
    x, y = step_xy(model)
    mixture = sum(w * norm.cdf(x, m, s) for w, m, s in zip(g.weights, g.means_m, g.sigmas_m))
    np.testing.assert_allclose(y, mixture, atol=1e-12)
    s = samples_mm(stack, ROW, COL, 0)
    assert sum(g.weights) == pytest.approx(np.count_nonzero(s) / s.size)  # the weights top out at 1 − non-returns
    (pdf,) = [ln for ln in ax_pdf.get_lines() if ln.get_label().startswith("GMM")]
    x, y = step_xy(pdf)
    density = sum(w * norm.pdf(x, m, s) for w, m, s in zip(g.weights, g.means_m, g.sigmas_m))
    np.testing.assert_allclose(y, density, rtol=1e-9, atol=1e-12)
    # bars: density over samples (non-returns included) of the raypath's returns
    bars = ax_pdf.patches
    left = np.array([b.get_x() for b in bars])
    width = np.array([b.get_width() for b in bars])
    edges = np.r_[left, left[-1] + width[-1]]
    counts, _ = np.histogram(s[s > 0] / 1000.0, bins=edges)
    np.testing.assert_allclose([b.get_height() for b in bars], counts / (s.size * width))
    assert sum(counts) == np.count_nonzero(s)


def test_range_image_is_the_destaggered_frame():
    shift = np.array([0, 6, 12, 18])
    rng = np.random.default_rng(5)
    r = rng.integers(3000, 9000, size=(2, 2, 4, 32)).astype(np.uint32)
    r[rng.random(r.shape) < 0.1] = 0
    valid = np.ones((2, 32), bool)
    valid[1, 7] = False
    st = make_stack(r, valid=valid, shift=shift, labels=("strongest", "second_strongest"))
    for frame, slot in ((0, 1), (1, 0)):
        img = plots.plot_range_image(st, frame, slot).axes[0].get_images()[0].get_array()
        truth = np.where(r[frame, slot] > 0, r[frame, slot] / 1000.0, np.nan)
        truth[:, ~valid[frame]] = np.nan
        truth = destaggered_by_definition(truth, shift)
        np.testing.assert_array_equal(np.ma.filled(img, np.nan), truth)


def test_multireturn_map_images_and_roc(stack):  # noqa: F811
    mr = multireturn_map(stack, neighbourhood=3)
    fig = plots.plot_multireturn_map(mr, stack, 0)
    images = [ax.get_images()[0] for ax in fig.axes if ax.get_images()]
    # panel 2: non-return fraction per pixel over the frames whose column arrived
    valid = stack.column_valid[:, None, :]
    n = valid.sum(axis=0)
    nonret = ((stack.range_mm[:, 0] == 0) & valid).sum(axis=0) / n
    np.testing.assert_allclose(np.ma.filled(images[1].get_array(), np.nan), nonret)
    # panel 4: flags + 2·truth
    code = mr.monitor_flags[0].astype(float) + 2 * mr.stats.multi_return[0]
    np.testing.assert_array_equal(np.ma.filled(images[3].get_array(), np.nan), code)

    ev = mr.evaluation[0]
    ax = plots.plot_roc(ev).axes[0]
    curve, diagonal, point = ax.get_lines()[:3]
    # the ROC by brute force: one point per distinct score, flag when score ≥ it
    mask = mr.stats.n_returns[0] > 0
    score, truth = mr.monitor_score_m[0][mask], mr.stats.multi_return[0][mask]
    levels = np.unique(score)[::-1]
    tpr = [0.0] + [(truth & (score >= t)).sum() / truth.sum() for t in levels]
    fpr = [0.0] + [(~truth & (score >= t)).sum() / (~truth).sum() for t in levels]
    np.testing.assert_allclose(curve.get_xdata(), fpr)
    np.testing.assert_allclose(curve.get_ydata(), tpr)
    flag = score > ev.threshold_m
    assert point.get_xdata()[0] == pytest.approx((flag & ~truth).sum() / (~truth).sum())
    assert point.get_ydata()[0] == pytest.approx((flag & truth).sum() / truth.sum())


def test_delta_histogram_counts(stack):  # noqa: F811
    pc = compare_slots(stack)
    ax = plots.plot_delta_histogram(pc).axes[0]
    (stairs,) = [p for p in ax.patches]
    values, edges = stairs.get_data().values, stairs.get_data().edges
    a, b = stack.range_mm[:, 0].astype(np.int64), stack.range_mm[:, 1].astype(np.int64)
    both = (a > 0) & (b > 0) & (a != b) & stack.column_valid[:, None, :]
    delta = np.abs(a - b)[both] / 1000.0
    counts, _ = np.histogram(delta, bins=pc.delta_edges_m)
    np.testing.assert_array_equal(edges, pc.delta_edges_m[1:])
    np.testing.assert_array_equal(values, counts[1:])
    assert values.sum() > 100


def test_mode_cdf_curves():
    r = np.random.default_rng(1).integers(3000, 9000, size=(6, 1, 4, 32)).astype(np.uint32)
    r[::3, 0, 1, 3] = 0
    st = make_stack(r)
    from lidarpkt.analysis.cdf import temporal_cdf

    lines = plots.plot_mode_cdfs({"strongest": temporal_cdf(st, 1, 3), "last": temporal_cdf(st, 1, 4)}, 1, 3).axes[0].get_lines()
    for line, col in zip(lines, (3, 4)):
        rr, F = empirical_cdf(samples_mm(st, 1, col, 0))
        x, y = step_xy(line)
        np.testing.assert_allclose(x[1 : 1 + len(rr)], rr)
        np.testing.assert_allclose(y[1 : 1 + len(rr)], F)
