"""Whole-image statistics and the §4.3 monitor against plain per-pixel reference loops, and the
monitor's ROC against scipy's Mann–Whitney U."""

import numpy as np
import pytest
from scipy import stats

from analysis.multireturn import evaluate_monitor, image_statistics, multireturn_map, spatial_gap_score
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
        import analysis.multireturn as mr

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
