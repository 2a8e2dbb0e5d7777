"""Whole-image statistics and the §4.3 monitor against plain per-pixel reference loops, and the
monitor's ROC against scipy's Mann–Whitney U."""

import numpy as np
import pytest
from scipy import stats

from lidarpkt.analysis.multireturn import (
    MIN_WINDOW_RETURNS,
    MONITOR_METHODS,
    detrended_gap_score,
    evaluate_monitor,
    image_statistics,
    monitor_score,
    multireturn_map,
    spatial_gap_score,
)
from lidarpkt.errors import AnalysisError
from test_analysis_support import destaggered_by_definition, make_stack


def random_stack(seed=0, k=12, r=2, h=5, w=9, shift=None):
    rng = np.random.default_rng(seed)
    # three surfaces per pixel (5, 5.05 and 9 m-ish) drawn at random, some non-returns, some lost columns
    surf = rng.choice([5000, 5050, 9000, 20000], size=(k, r, h, w), p=[0.5, 0.2, 0.2, 0.1])
    rngmm = (surf + rng.integers(-20, 21, size=surf.shape)).astype(np.uint32)
    rngmm[rng.random(rngmm.shape) < 0.15] = 0
    rngmm[:, :, 0, 0] = 7000  # a constant pixel
    rngmm[:, :, 1, 1] = 0  # a pixel that never returns
    valid = rng.random((k, w)) > 0.1
    valid[:, 2] = False  # a column that is always lost
    return make_stack(rngmm, valid=valid, shift=shift)


def reference_stats(stack, gap_m):
    k, r, h, w = stack.range_mm.shape
    out = {name: np.zeros((r, h, w)) for name in ("n_samples", "n_returns", "nonret", "std", "mean", "clusters", "gap")}
    for s in range(r):
        for i in range(h):
            for j in range(w):
                vals = [int(stack.range_mm[f, s, i, j]) for f in range(k) if stack.column_valid[f, j]]
                ret = sorted(v for v in vals if v > 0)
                out["n_samples"][s, i, j] = len(vals)
                out["n_returns"][s, i, j] = len(ret)
                out["nonret"][s, i, j] = (len(vals) - len(ret)) / len(vals) if vals else np.nan
                out["std"][s, i, j] = np.std(np.array(ret) / 1000) if ret else np.nan
                out["mean"][s, i, j] = np.mean(np.array(ret) / 1000) if ret else np.nan
                gaps = [(b - a) / 1000 for a, b in zip(ret, ret[1:]) if (b - a) / 1000 > gap_m]
                out["clusters"][s, i, j] = (1 + len(gaps)) if ret else 0
                out["gap"][s, i, j] = max(gaps, default=0.0)
    return out


@pytest.mark.parametrize("gap_m,block", [(0.1, None), (0.03, None), (0.1, 50)])
def test_image_statistics_match_a_per_pixel_loop(gap_m, block, monkeypatch):
    if block is not None:  # tiny blocks of rows: the blocked path must give the same result
        import lidarpkt.analysis.multireturn as mr

        monkeypatch.setattr(mr, "_BLOCK_SAMPLES", block)
    stack = random_stack()
    s = image_statistics(stack, gap_m=gap_m)
    ref = reference_stats(stack, gap_m)
    assert np.array_equal(s.n_samples, ref["n_samples"])
    assert np.array_equal(s.n_returns, ref["n_returns"])
    assert np.allclose(s.nonreturn_fraction, ref["nonret"], equal_nan=True)
    assert np.allclose(s.std_m, ref["std"], equal_nan=True, atol=1e-12)
    assert np.allclose(s.mean_m, ref["mean"], equal_nan=True)
    assert np.array_equal(s.n_clusters, ref["clusters"])
    assert np.allclose(s.gap_m, ref["gap"])
    # the fixed pixels: constant → 1 cluster, std 0; never returns → 0 clusters; always lost → no sample
    assert s.n_clusters[0, 0, 0] == 1 and s.std_m[0, 0, 0] == 0
    assert s.n_clusters[0, 1, 1] == 0 and s.nonreturn_fraction[0, 1, 1] == 1.0
    assert np.all(s.n_samples[:, :, 2] == 0) and np.all(np.isnan(s.nonreturn_fraction[:, :, 2]))
    assert np.array_equal(s.multi_return, ref["clusters"] >= 2)


def test_single_frame_statistics():
    stack = random_stack(k=1)
    s = image_statistics(stack)
    assert np.array_equal(s.n_clusters, (stack.range_mm[0] > 0) & stack.column_valid[0][None, None, :])
    assert np.all(s.gap_m == 0)


def reference_gap_score(stack, frame, n, shift=None, by_row=False):
    k, r, h, w = stack.range_mm.shape
    img = np.where(stack.column_valid[frame][None, None, :], stack.range_mm[frame].astype(np.int64), -1)  # -1 missing
    if shift is not None:
        img = destaggered_by_definition(img, shift)
    half = n // 2
    out = np.zeros((r, h, w))
    for s in range(r):
        for i in range(h):
            for j in range(w):
                groups = [
                    [img[s, ii, (j + dj) % w] for dj in range(-half, half + 1) if img[s, ii, (j + dj) % w] > 0]
                    for ii in range(max(0, i - half), min(h, i + half + 1))
                ]
                if not by_row:
                    groups = [[v for g in groups for v in g]]
                out[s, i, j] = max(
                    [(b - a) / 1000 for g in groups for a, b in zip(sorted(g), sorted(g)[1:])], default=0.0
                )
    if shift is not None:  # back to the staggered layout: staggered[u, c] = destaggered[u, (c + shift[u]) % W]
        out = np.stack([[np.roll(out[s, u], -shift[u]) for u in range(h)] for s in range(r)])
    return out


@pytest.mark.parametrize("by_row", [False, True])
@pytest.mark.parametrize("n", [3, 5])
def test_monitor_score_matches_a_per_pixel_loop(n, by_row):
    stack = random_stack(seed=1)
    got = spatial_gap_score(stack, frame=3, n=n, by_row=by_row)
    assert np.allclose(got, reference_gap_score(stack, 3, n, by_row=by_row))


@pytest.mark.parametrize("by_row", [False, True])
def test_monitor_score_uses_destaggered_neighbours(by_row):
    shift = np.array([4, 0, 7, 2, 5])
    stack = random_stack(seed=2, shift=shift)
    got = spatial_gap_score(stack, frame=0, n=3, by_row=by_row)
    assert np.allclose(got, reference_gap_score(stack, 0, 3, shift, by_row=by_row))


def reference_detrended_score(stack, frame, n, window_rows=None, shift=None):
    """The detrended score pixel by pixel: for every window of ``window_rows`` rows x n columns
    holding the pixel, a least-squares plane 1/r = a + b·di + c·dj (numpy.linalg.lstsq) through
    its returns, the largest gap between the sorted residuals r − 1/fit; the smallest over the
    windows with at least MIN_WINDOW_RETURNS returns; 0 when there is none."""
    k, r, h, w = stack.range_mm.shape
    img = np.where(stack.column_valid[frame][None, None, :], stack.range_mm[frame].astype(np.int64), 0)
    if shift is not None:
        img = destaggered_by_definition(img, shift)
    half = n // 2
    wr = half + 1 if window_rows is None else window_rows
    out = np.zeros((r, h, w))
    for s in range(r):
        for i in range(h):
            for j in range(w):
                pts = [(di, dj, img[s, i + di, (j + dj) % w] / 1000.0)
                       for di in range(-half, half + 1) for dj in range(-half, half + 1)
                       if 0 <= i + di < h and img[s, i + di, (j + dj) % w] > 0]
                best = None
                for top in range(-half, half + 1):
                    if not (top <= 0 <= top + wr - 1 and top + wr - 1 <= half):
                        continue
                    win = [(di, dj, rr) for di, dj, rr in pts if top <= di < top + wr]
                    if len(win) < MIN_WINDOW_RETURNS:
                        continue
                    x = np.array([[1.0, di, dj] for di, dj, _ in win])
                    rr = np.array([v for _, _, v in win])
                    coef = np.linalg.lstsq(x, 1.0 / rr, rcond=None)[0]
                    res = np.sort(rr - 1.0 / (x @ coef))
                    gap = float(np.max(np.diff(res))) if res.size > 1 else 0.0
                    best = gap if best is None else min(best, gap)
                out[s, i, j] = 0.0 if best is None else best
    if shift is not None:
        out = np.stack([[np.roll(out[s, u], -shift[u]) for u in range(h)] for s in range(r)])
    return out


@pytest.mark.parametrize("window_rows", [None, 2, 3])
@pytest.mark.parametrize("n", [3, 5])
def test_detrended_score_matches_a_per_pixel_loop(n, window_rows):
    if window_rows is not None and window_rows > n:
        pytest.skip("window taller than the neighbourhood")
    stack = random_stack(seed=4)
    got = detrended_gap_score(stack, frame=2, n=n, window_rows=window_rows)
    ref = reference_detrended_score(stack, 2, n, window_rows)
    assert np.allclose(got, ref, atol=1e-6)
    assert np.count_nonzero(ref > 0.1) > 10  # the random stack does hold gaps: the comparison is not 0 == 0


def test_detrended_score_uses_destaggered_neighbours():
    shift = np.array([4, 0, 7, 2, 5])
    stack = random_stack(seed=6, shift=shift)
    got = detrended_gap_score(stack, frame=1, n=5)
    assert np.allclose(got, reference_detrended_score(stack, 1, 5, shift=shift), atol=1e-6)


def tilted_ground(h=16, w=120, seed=0, noise_mm=8.0):
    """Ranges (mm) of a sloping ground plane seen from 1.8 m up, beams from -4° to -19° and 0.2°
    apart in azimuth: 1/r = n·u / d. Neighbouring beams are metres apart (the farthest rows) and
    the range also changes along each row (the ground slopes sideways). Not a full rotation: the
    first and last columns are not neighbours in the world, only in the image (azimuth wraps)."""
    el = np.radians(np.linspace(-4.0, -19.0, h))[:, None]
    az = np.radians(30.0 + 0.2 * np.arange(w))[None, :]
    u = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el) * np.ones_like(az)])
    normal = np.array([0.06, -0.04, 1.0])
    normal /= np.linalg.norm(normal)
    r_m = -1.8 / np.einsum("i,i...->...", normal, u)
    assert np.all(r_m > 0)
    noise = np.random.default_rng(seed).normal(0.0, noise_mm, r_m.shape)
    return np.rint(r_m * 1000.0 + noise)


def test_a_tilted_ground_plane_is_not_flagged_but_the_paper_score_flags_it():
    rng = tilted_ground()
    jumps = np.abs(np.diff(rng, axis=0)) / 1000.0
    assert jumps.max() > 3.0  # metres between neighbouring beams: what the paper's score reads as two surfaces
    stack = make_stack(rng[None, None])
    inner = np.s_[0, :, 2:-2]  # leave out the columns whose 5 x 5 neighbourhood wraps to the other end
    detrend = monitor_score(stack, method="detrend")[inner]
    gap = monitor_score(stack, method="gap")[inner]
    assert np.mean(gap > 0.1) > 0.5
    assert detrend.max() < 0.1
    assert np.array_equal(monitor_score(stack), monitor_score(stack, method="detrend"))  # the default


def test_a_two_surface_patch_is_flagged_and_its_surroundings_are_not():
    """A window-like patch on the tilted ground: in this frame each of its pixels sees either a
    near surface or the one 1.2 m behind it (a checkerboard, so every window through the patch
    holds both). Every patch pixel is flagged; pixels three columns or more clear of the patch,
    and the rows above and below it, are not."""
    rng = tilted_ground(h=16, w=60, seed=1)
    r0, c0 = 8, 30
    rows, cols = np.arange(r0 - 1, r0 + 2), np.arange(c0 - 3, c0 + 4)
    board = (rows[:, None] + cols[None, :]) % 2 == 0
    patch = rng[np.ix_(rows, cols)]
    rng[np.ix_(rows, cols)] = np.where(board, patch - 1200.0, patch)  # the near surface on the black squares
    stack = make_stack(rng[None, None])
    score = detrended_gap_score(stack)[0]
    assert np.all(score[np.ix_(rows, cols)] > 0.1)
    clear = np.ones_like(score, bool)
    clear[rows[0] : rows[-1] + 1, cols[0] - 2 : cols[-1] + 3] = False  # the patch and two columns either side
    clear[:, :2] = clear[:, -2:] = False  # wrap seam of this synthetic (not 360°) image
    assert score[clear].max() < 0.1
    # and through the map: flagged where the score says so, with the method recorded
    mr = multireturn_map(stack)
    assert mr.method == "detrend" and mr.monitor_flags[0, r0, c0] and not mr.monitor_flags[0][clear].any()


def test_monitor_methods_and_their_errors():
    stack = random_stack(seed=5)
    assert MONITOR_METHODS[0] == "detrend"
    assert np.array_equal(monitor_score(stack, method="gap", n=3), spatial_gap_score(stack, n=3))
    assert np.array_equal(monitor_score(stack, method="row", n=3), spatial_gap_score(stack, n=3, by_row=True))
    assert np.array_equal(monitor_score(stack, method="plane", n=3), detrended_gap_score(stack, n=3, window_rows=3))
    with pytest.raises(AnalysisError, match="unknown monitor method 'median'"):
        monitor_score(stack, method="median")
    with pytest.raises(AnalysisError, match="odd"):
        detrended_gap_score(stack, n=4)
    with pytest.raises(AnalysisError, match="wider than the image"):
        detrended_gap_score(stack, n=11)
    with pytest.raises(AnalysisError, match="frame 40"):
        detrended_gap_score(stack, frame=40)
    with pytest.raises(AnalysisError, match="does not fit"):
        detrended_gap_score(stack, n=3, window_rows=4)
    with pytest.raises(AnalysisError, match="by_row"):
        multireturn_map(stack, method="plane", by_row=True)
    assert multireturn_map(stack, by_row=True, neighbourhood=3).method == "row"


def test_detrended_score_scores_a_64_by_1024_frame_without_a_python_loop_per_pixel(monkeypatch):
    """Vectorised: the plane fits are solved for all pixels in a few NumPy calls, whatever the
    image size (counted, not timed)."""
    import lidarpkt.analysis.multireturn as m

    calls = []
    real = m._window_gap
    monkeypatch.setattr(m, "_window_gap", lambda *a: calls.append(a[0].shape) or real(*a))
    rng = np.random.default_rng(0).integers(1000, 30000, size=(1, 2, 64, 1024)).astype(np.uint32)
    score = m.detrended_gap_score(make_stack(rng), n=5)
    assert score.shape == (2, 64, 1024)
    assert calls == [(2, 64, 1024, 15)] * 3  # one call per window position (3 for n = 5), all pixels at once


def test_monitor_evaluation_by_hand_and_auc_against_mann_whitney():
    score = np.array([0.0, 0.05, 0.2, 0.3, 1.5, 0.2, 2.0, 0.0])
    truth = np.array([False, False, True, False, True, True, True, False])
    ev = evaluate_monitor(score, truth, threshold_m=0.1)
    # flagged: 0.2(T) 0.3(F) 1.5(T) 0.2(T) 2.0(T) → TP 4, FP 1, FN 0, TN 3
    assert (ev.true_positive, ev.false_positive, ev.false_negative, ev.true_negative) == (4, 1, 0, 3)
    assert ev.precision == 4 / 5 and ev.recall == 1.0
    u = stats.mannwhitneyu(score[truth], score[~truth]).statistic
    assert ev.auc == pytest.approx(u / (truth.sum() * (~truth).sum()))
    assert ev.roc_tpr[0] == 0 and ev.roc_fpr[0] == 0 and ev.roc_tpr[-1] == 1 and ev.roc_fpr[-1] == 1
    assert np.all(np.diff(ev.roc_tpr) >= 0) and np.all(np.diff(ev.roc_fpr) >= 0)


def test_monitor_roc_on_random_scores_matches_mann_whitney():
    rng = np.random.default_rng(5)
    truth = rng.random(500) < 0.3
    score = np.round(rng.normal(truth * 0.4, 0.5), 1)  # rounded: many ties
    ev = evaluate_monitor(score, truth, threshold_m=0.2)
    u = stats.mannwhitneyu(score[truth], score[~truth]).statistic
    assert ev.auc == pytest.approx(u / (truth.sum() * (~truth).sum()))


def test_multireturn_map_and_its_npz(tmp_path):
    stack = random_stack(seed=3)
    mr = multireturn_map(stack, neighbourhood=3, monitor_frame=1)
    assert mr.monitor_flags.shape == stack.range_mm.shape[1:]
    assert np.array_equal(mr.monitor_flags, mr.monitor_score_m > 0.1)
    assert len(mr.evaluation) == 2
    path = tmp_path / "map.npz"
    np.savez_compressed(path, **mr.to_npz_dict())
    with np.load(path) as z:
        assert np.array_equal(z["n_clusters"], mr.stats.n_clusters)
        assert z["return_labels"].tolist() == ["last", "strongest"]
        assert str(z["monitor_method"]) == "detrend" and not bool(z["monitor_by_row"])
        assert np.array_equal(z["monitor_score_m"], detrended_gap_score(stack, frame=1, n=3))
        assert float(z["slot0_auc"]) == pytest.approx(mr.evaluation[0].auc, nan_ok=True)


def test_errors():
    stack = random_stack()
    with pytest.raises(AnalysisError, match="positive"):
        image_statistics(stack, gap_m=0)
    with pytest.raises(AnalysisError, match="odd"):
        spatial_gap_score(stack, n=2)
    with pytest.raises(AnalysisError, match="frame 40"):
        spatial_gap_score(stack, frame=40)
    with pytest.raises(AnalysisError, match="empty"):
        image_statistics(make_stack(np.zeros((0, 1, 2, 2), np.uint32), valid=np.zeros((0, 2), bool)))
