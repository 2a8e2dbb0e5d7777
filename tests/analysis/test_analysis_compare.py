"""Return-mode comparison: dual slots by hand, the vectorised KS image against scipy's ks_2samp,
and the real VLP-16 dual capture (nebula bag) against what its provenance note states."""

import numpy as np
import pytest
from scipy import stats

from lidarpkt.analysis.compare import compare_slots, compare_stacks, ks_image
from lidarpkt.errors import AnalysisError
from test_analysis_support import make_stack


def test_dual_slots_by_hand():
    # 4 frames, 1 x 3 pixels, slots (last, strongest)
    last = np.array([[5000, 7000, 0], [5000, 7100, 0], [6000, 0, 3000], [5000, 7000, 0]])
    strongest = np.array([[5000, 7000, 0], [4000, 7000, 0], [6000, 0, 3000], [5000, 9000, 2000]])
    rng = np.stack([last, strongest], axis=1)[:, :, None, :]  # [K, R, 1, W]
    valid = np.ones((4, 3), bool)
    valid[3, 0] = False  # frame 3 of pixel 0 is missing (its values do not count)
    pc = compare_slots(make_stack(rng, valid=valid))
    assert pc.labels == ("last", "strongest")
    assert pc.n_pairs[0].tolist() == [3, 4, 4]
    assert pc.n_differ[0].tolist() == [1, 2, 1]
    assert pc.n_one_sided[0].tolist() == [0, 0, 1]
    assert pc.fraction_differ[0].tolist() == [1 / 3, 2 / 4, 1 / 4]
    assert pc.mean_delta_m[0, :2].tolist() == [1.0, (0.1 + 2.0) / 2] and np.isnan(pc.mean_delta_m[0, 2])
    assert pc.max_delta_m[0, :2].tolist() == [1.0, 2.0]
    assert pc.delta_counts.sum() == 3  # Δ = 1.0, 0.1, 2.0
    assert np.histogram([1.0, 0.1, 2.0], bins=pc.delta_edges_m)[0].tolist() == pc.delta_counts.tolist()
    s = pc.summary()
    assert s["pairs"] == 11 and s["pairs_differ"] == 4 and s["fraction_identical"] == pytest.approx(7 / 11)


def test_ks_image_equals_scipy_ks_2samp_without_nonreturns():
    rng = np.random.default_rng(11)
    a = rng.integers(4000, 4100, size=(30, 3, 4)).astype(np.uint32)  # coarse: many ties, also across sides
    b = (rng.integers(4000, 4100, size=(17, 3, 4)) + rng.integers(0, 30, size=(1, 3, 4))).astype(np.uint32)
    ks = ks_image(a, np.ones((30, 4), bool), b, np.ones((17, 4), bool))
    for i in range(3):
        for j in range(4):
            assert ks[i, j] == pytest.approx(stats.ks_2samp(a[:, i, j], b[:, i, j]).statistic, abs=1e-12)


def test_ks_image_with_nonreturns_and_missing_matches_a_brute_force_sup():
    rng = np.random.default_rng(12)
    a = rng.choice([0, 5000, 5100, 8000], size=(20, 2, 3)).astype(np.uint32)
    b = rng.choice([0, 0, 5000, 8000, 9000], size=(25, 2, 3)).astype(np.uint32)
    va = rng.random((20, 3)) > 0.2
    vb = rng.random((25, 3)) > 0.2
    ks = ks_image(a, va, b, vb)
    grid = np.arange(0, 10001)
    for i in range(2):
        for j in range(3):
            sa, sb = a[va[:, j], i, j], b[vb[:, j], i, j]
            fa = ((sa[None, :] > 0) & (sa[None, :] <= grid[:, None])).sum(axis=1) / sa.size
            fb = ((sb[None, :] > 0) & (sb[None, :] <= grid[:, None])).sum(axis=1) / sb.size
            assert ks[i, j] == pytest.approx(np.max(np.abs(fa - fb)))


def test_compare_stacks_distributional_and_paired():
    rng = np.random.default_rng(13)
    a = make_stack(rng.integers(5000, 5050, size=(10, 1, 2, 3)).astype(np.uint32), labels=("strongest",))
    b_r = a.range_mm.copy()
    b_r[:, 0, 0, 0] += 2000  # the last return sees a wall 2 m behind at pixel (0, 0)
    b_r[::2, 0, 1, 2] = 0
    b = make_stack(b_r, labels=("last",))
    dist, pc = compare_stacks(a, b, paired=True)
    assert dist.labels == ("strongest", "last")
    assert dist.ks[0, 0] == 1.0 and dist.median_delta_m[0, 0] == pytest.approx(2.0)
    assert dist.ks[1, 2] == 0.5 and dist.nonreturn_delta[1, 2] == 0.5
    assert dist.ks[0, 1] == 0.0 and dist.median_delta_m[0, 1] == 0.0
    assert pc.n_differ[0, 0] == 10 and pc.mean_delta_m[0, 0] == pytest.approx(2.0)
    assert pc.n_one_sided[1, 2] == 5
    assert compare_stacks(a, b).summary()["pixels_compared"] == 6


def test_comparison_errors():
    single = make_stack(np.ones((2, 1, 2, 3), np.uint32))
    with pytest.raises(AnalysisError, match="needs a dual-return capture"):
        compare_slots(single)
    with pytest.raises(AnalysisError, match="different range images"):
        compare_stacks(single, make_stack(np.ones((2, 1, 2, 4), np.uint32)))
    with pytest.raises(AnalysisError, match="same number of frames"):
        compare_stacks(single, make_stack(np.ones((3, 1, 2, 3), np.uint32)), paired=True)
    with pytest.raises(AnalysisError, match="slot 1 does not exist"):
        compare_stacks(single, single, slot_b=1)


def test_real_vlp16_dual_capture_slots_mostly_identical(ext):
    """SOURCES.md: in the nebula VLP-16 dual bag about 98% of return pairs are identical."""
    from lidarpkt.analysis.stack import load_stack

    stack = load_stack(ext("nebula/vlp16/1673400471837873222/1673400471837873222_0.db3"))
    assert stack.return_labels == ("last", "strongest")
    pc = compare_slots(stack)
    s = pc.summary()
    assert s["pairs"] > 50_000
    assert 0.95 < s["fraction_identical"] < 0.995
    # where the slots differ in range, the last return is never nearer than the strongest one
    last, strongest = stack.range_mm[:, 0], stack.range_mm[:, 1]
    both = (last > 0) & (strongest > 0) & stack.column_valid[:, None, :]
    assert np.all(last[both] >= strongest[both])
