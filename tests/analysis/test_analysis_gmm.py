"""Gaussian mixtures (eqs. 7–9): segmentation worked out by hand, EM against closed-form cluster
statistics, and the model CDF / KS distance against scipy.stats."""

import numpy as np
import pytest
from scipy import integrate, stats

from lidarpkt.analysis.cdf import RangeCDF
from lidarpkt.analysis.gmm import fit_auto, fit_em, fit_gmm, fit_thresholds, gap_thresholds, ks_distance
from lidarpkt.errors import AnalysisError

# 6 returns and 2 non-returns (n = 8): F = 1/8 ... 6/8 at the sorted returns.
HAND = RangeCDF.from_samples(np.array([1000, 0, 1040, 2000, 3000, 1020, 0, 2020]))


def test_threshold_segmentation_by_hand():
    g = fit_thresholds(HAND, [0.3, 0.5])
    # F = .125 .25 | .375 .5 | .625 .75  →  {1.00, 1.02} {1.04, 2.00} {2.02, 3.00}
    assert g.method == "thresholds"
    assert g.weights.tolist() == [2 / 8, 2 / 8, 2 / 8]
    assert g.means_m == pytest.approx([1.01, 1.52, 2.51])
    assert g.sigmas_m == pytest.approx([0.01, 0.48, 0.49])
    assert g.weights.sum() == pytest.approx(1 - HAND.nonreturn_fraction)


def test_automatic_gap_thresholds_by_hand():
    assert gap_thresholds(HAND, gap_m=0.1).tolist() == [3 / 8, 5 / 8]  # after 1.04 and after 2.02
    g = fit_auto(HAND, gap_m=0.1)
    assert g.method == "auto"
    assert g.weights.tolist() == [3 / 8, 2 / 8, 1 / 8]
    assert g.means_m == pytest.approx([1.02, 2.01, 3.0])
    assert g.sigmas_m == pytest.approx([np.std([1.0, 1.02, 1.04]), 0.01, 0.003])  # single sample: the floor


def test_paper_thresholds_on_four_clusters():
    rng = np.random.default_rng(4)
    centres = [8.0, 9.0, 10.0, 11.0]
    counts = [14, 24, 30, 32]  # cumulative 0.14, 0.38, 0.68, 1.0: the paper's thresholds fall in the gaps
    x = np.concatenate([c + rng.normal(0, 0.02, n) for c, n in zip(centres, counts)])
    cdf = RangeCDF.from_samples(np.round(x * 1000).astype(np.uint32))
    g = fit_gmm(cdf, "0.14,0.38,0.68")
    assert g.weights.tolist() == [0.14, 0.24, 0.30, 0.32]
    srt = np.sort(np.round(x * 1000) / 1000)
    bounds = np.cumsum([0] + counts)
    assert g.means_m == pytest.approx([srt[a:b].mean() for a, b in zip(bounds[:-1], bounds[1:])])


def test_em_finds_well_separated_clusters_and_their_sample_statistics():
    rng = np.random.default_rng(7)
    spec = [(5.0, 0.02, 180), (8.0, 0.05, 110), (12.5, 0.03, 70)]
    parts = [np.round((m + rng.normal(0, s, n)) * 1000) for m, s, n in spec]
    samples = np.concatenate(parts + [np.zeros(40)]).astype(np.uint32)  # + 40 non-returns
    cdf = RangeCDF.from_samples(rng.permutation(samples))
    g = fit_em(cdf)
    assert g.method == "em" and g.n_components == 3
    # For clusters this far apart the maximum-likelihood mixture is the clusters' own statistics.
    n = samples.size
    assert g.weights == pytest.approx([p.size / n for p in parts], abs=1e-6)
    assert g.means_m == pytest.approx([p.mean() / 1000 for p in parts], abs=1e-6)
    assert g.sigmas_m == pytest.approx([p.std() / 1000 for p in parts], rel=1e-4)
    assert g.bic is not None and g.ks < 0.05


def test_em_keeps_one_component_for_one_surface():
    rng = np.random.default_rng(8)
    cdf = RangeCDF.from_samples(np.round((6.0 + rng.normal(0, 0.02, 300)) * 1000).astype(np.uint32))
    g = fit_em(cdf)
    assert g.n_components == 1
    assert g.means_m[0] == pytest.approx(cdf.range_m.mean())


def test_em_finds_a_rare_cluster():
    # the window case: glass detected in 2 of 50 frames, far from the rest
    x = np.r_[[11200, 11204], 13000 + np.arange(-24, 25)[::2] * 2, 14800 + np.arange(-23, 24)[::2] * 3]
    cdf = RangeCDF.from_samples(x.astype(np.uint32))
    g = fit_em(cdf)
    assert g.n_components == 3
    assert g.weights[0] == pytest.approx(2 / x.size)
    assert g.means_m[0] == pytest.approx(11.202)


def test_model_cdf_pdf_and_ks_against_scipy():
    rng = np.random.default_rng(9)
    x = np.round(np.r_[rng.normal(4.0, 0.03, 120), rng.normal(4.6, 0.05, 80)] * 1000).astype(np.uint32)
    cdf = RangeCDF.from_samples(x)  # no non-returns: the model is a proper distribution
    g = fit_em(cdf)
    r = np.linspace(3.5, 5.0, 301)
    ref = sum(w * stats.norm.cdf(r, m, s) for w, m, s in zip(g.weights, g.means_m, g.sigmas_m))
    assert np.allclose(g.cdf(r), ref, atol=1e-12)
    assert np.allclose(g.pdf(r), sum(w * stats.norm.pdf(r, m, s) for w, m, s in zip(g.weights, g.means_m, g.sigmas_m)))
    assert integrate.quad(g.pdf, 3.0, 6.0, points=list(g.means_m), limit=200)[0] == pytest.approx(1.0, abs=1e-6)
    assert g.ks == pytest.approx(stats.kstest(cdf.range_m, g.cdf).statistic, abs=1e-12)


def test_ks_distance_with_nonreturns_matches_a_brute_force_sup():
    x = np.array([3000, 3010, 3020, 0, 0, 5000, 5004, 0, 5010, 3005], np.uint32)
    cdf = RangeCDF.from_samples(x)
    g = fit_auto(cdf)
    grid = np.sort(np.r_[np.linspace(2.9, 5.1, 20001), cdf.range_m, cdf.range_m - 1e-9])
    brute = np.max(np.abs(cdf.evaluate(grid) - g.cdf(grid)))
    assert ks_distance(g, cdf) == pytest.approx(brute, abs=1e-6)


def test_json_shape_and_errors():
    g = fit_gmm(HAND, "auto")
    assert set(g.to_json()) == {"method", "weights", "means_m", "sigmas_m", "ks"}
    empty = RangeCDF.from_samples(np.zeros(5, np.uint32))
    with pytest.raises(AnalysisError, match="no returns"):
        fit_em(empty)
    with pytest.raises(AnalysisError, match="no returns"):
        fit_thresholds(empty, [0.5])
    with pytest.raises(AnalysisError, match="increasing CDF values"):
        fit_gmm(HAND, "0.5,0.3")
    with pytest.raises(AnalysisError, match="increasing CDF values"):
        fit_gmm(HAND, [1.2])
    with pytest.raises(AnalysisError, match="expected em, auto, or CDF thresholds"):
        fit_gmm(HAND, "bic")


def test_em_does_not_split_one_surface_into_close_components():
    # 11 samples of one surface (sd 15 mm): BIC alone sometimes prefers two components ~2 cm apart
    rng = np.random.default_rng(0)
    draws = [RangeCDF.from_samples(np.round(rng.normal(15000, 15, 11)).astype(np.uint32)) for _ in range(30)]
    assert all(fit_em(c).n_components == 1 for c in draws)
    assert any(fit_em(c, min_separation_m=0.0).n_components > 1 for c in draws)  # what the rule prevents
