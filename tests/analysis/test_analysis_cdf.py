"""Temporal (eq. 1) and spatial (eq. 3) CDFs on stacks whose answers are worked out by hand."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarpkt.analysis.cdf import RangeCDF, reflectivity_vs_range, spatial_cdf, temporal_cdf
from lidarpkt.errors import AnalysisError
from test_analysis_support import destaggered_by_definition, make_stack


def one_pixel_stack():
    # 8 frames of a 3 x 4 image; pixel (1, 2) sees 5, -, 7, 5, (lost), 6, -, 9 m.
    k, h, w = 8, 3, 4
    rng = np.full((k, 1, h, w), 1000, np.uint32)
    rng[:, 0, 1, 2] = [5000, 0, 7000, 5000, 4000, 6000, 0, 9000]
    refl = np.zeros_like(rng, np.uint8)
    refl[:, 0, 1, 2] = [10, 0, 70, 11, 99, 60, 0, 90]
    valid = np.ones((k, w), bool)
    valid[4, 2] = False  # frame 4 lost column 2: its 4000 is not a sample
    return make_stack(rng, valid=valid, reflectivity=refl)


def test_temporal_cdf_counts_nonreturns_and_leaves_out_missing_frames():
    cdf = temporal_cdf(one_pixel_stack(), 1, 2)
    # 7 samples (frame 4 missing), 5 returns, 2 non-returns.
    assert (cdf.n_samples, cdf.n_returns, cdf.n_nonreturn, cdf.n_missing) == (7, 5, 2, 1)
    assert cdf.range_m.tolist() == [5.0, 5.0, 6.0, 7.0, 9.0]
    # F(r) = #{samples <= r} / 7; the two 5 m samples share the value after both.
    assert cdf.F.tolist() == [2 / 7, 2 / 7, 3 / 7, 4 / 7, 5 / 7]
    assert cdf.nonreturn_fraction == pytest.approx(2 / 7)
    assert cdf.F[-1] == pytest.approx(1 - cdf.nonreturn_fraction)  # tops out below 1
    assert cdf.evaluate([4.999, 5.0, 6.5, 100.0]).tolist() == [0.0, 2 / 7, 3 / 7, 5 / 7]
    assert cdf.to_json() == {"range_m": [5.0, 5.0, 6.0, 7.0, 9.0], "F": [2 / 7, 2 / 7, 3 / 7, 4 / 7, 5 / 7]}


def test_reflectivity_is_aligned_with_the_sorted_ranges():
    r, refl = reflectivity_vs_range(one_pixel_stack(), 1, 2)
    assert r.tolist() == [5.0, 5.0, 6.0, 7.0, 9.0]
    assert refl.tolist() == [10, 11, 60, 70, 90]  # equal ranges keep frame order


def test_pixel_with_only_nonreturns_and_only_missing_frames():
    rng = np.zeros((3, 1, 2, 2), np.uint32)
    valid = np.ones((3, 2), bool)
    valid[:, 1] = False
    stack = make_stack(rng, valid=valid)
    cdf = temporal_cdf(stack, 0, 0)
    assert (cdf.n_samples, cdf.n_returns, cdf.n_nonreturn) == (3, 0, 3) and cdf.range_m.size == 0
    cdf = temporal_cdf(stack, 0, 1)
    assert (cdf.n_samples, cdf.n_missing) == (0, 3) and np.isnan(cdf.nonreturn_fraction)
    assert cdf.evaluate(5.0) == 0.0


def test_spatial_cdf_wraps_in_azimuth_and_clips_rows():
    # 1 frame, 4 rows x 6 columns, values 1000 * (10 * row + col + 1) so each pixel is recognisable.
    h, w = 4, 6
    img = (10 * np.arange(h)[:, None] + np.arange(w)[None, :] + 1) * 1000
    img[1, 5] = 0  # a non-return inside the neighbourhood
    valid = np.ones((1, w), bool)
    valid[0, 1] = False  # column 1 lost: its pixels are missing
    stack = make_stack(img[None, None], valid=valid)
    # 3 x 3 around (0, 0): rows 0..1 (row -1 clipped), columns 5, 0, 1 (wrap); column 1 missing.
    cdf = spatial_cdf(stack, 0, 0, n=3)
    expected = sorted(v for v in [img[0, 5], img[0, 0], img[1, 0]] if v)  # img[1, 5] is the non-return
    assert cdf.range_m.tolist() == [v / 1000 for v in expected]
    assert (cdf.n_samples, cdf.n_nonreturn, cdf.n_missing) == (4, 1, 2)
    assert cdf.F.tolist() == [1 / 4, 2 / 4, 3 / 4]
    # 5 x 5 around the bottom-right pixel (3, 5): rows 1..3, columns 3, 4, 5, 0, 1.
    cdf = spatial_cdf(stack, 3, 5, n=5)
    cols = [3, 4, 5, 0]
    samples = [img[r, c] for r in (1, 2, 3) for c in cols]
    assert cdf.n_samples == 12 and cdf.n_missing == 3
    assert cdf.range_m.tolist() == sorted(v / 1000 for v in samples if v)


def test_spatial_cdf_of_all_frames_superimposes_them():
    rng = np.random.default_rng(1).integers(0, 20000, size=(5, 1, 4, 7)).astype(np.uint32)
    rng[rng < 3000] = 0
    stack = make_stack(rng)
    every = spatial_cdf(stack, 2, 3, n=3, frame=None)
    parts = [spatial_cdf(stack, 2, 3, n=3, frame=f) for f in range(5)]
    assert every.n_samples == sum(p.n_samples for p in parts) == 45
    assert every.range_m.tolist() == sorted(np.concatenate([p.range_m for p in parts]).tolist())


def test_spatial_neighbourhood_is_taken_in_the_destaggered_image():
    h, w = 4, 8
    shift = np.array([3, 1, 6, 0])
    rng = np.random.default_rng(2)
    stag = rng.integers(1000, 50000, size=(h, w)).astype(np.uint32)
    stack = make_stack(stag[None, None], shift=shift)
    de = destaggered_by_definition(stag, shift)
    for row, col in [(0, 0), (2, 5), (3, 7)]:
        dcol = (col + shift[row]) % w
        assert de[row, dcol] == stag[row, col]
        expected = [de[r, (dcol + d) % w] for r in range(max(0, row - 1), min(h, row + 2)) for d in (-1, 0, 1)]
        got = spatial_cdf(stack, row, col, n=3)
        assert got.range_m.tolist() == sorted(v / 1000 for v in expected)


def test_bad_pixel_slot_frame_and_neighbourhood_raise_analysis_errors():
    stack = one_pixel_stack()
    with pytest.raises(AnalysisError, match=r"outside the 3 x 4 range image.*ROW in 0\.\.2 and COL in 0\.\.3"):
        temporal_cdf(stack, 3, 0)
    with pytest.raises(AnalysisError, match="outside"):
        temporal_cdf(stack, 0, -1)
    with pytest.raises(AnalysisError, match="slot 1 does not exist.*0=strongest"):
        temporal_cdf(stack, 0, 0, slot=1)
    with pytest.raises(AnalysisError, match="odd"):
        spatial_cdf(stack, 0, 0, n=4)
    with pytest.raises(AnalysisError, match="wider than the image"):
        spatial_cdf(stack, 0, 0, n=5)
    with pytest.raises(AnalysisError, match="frame 8 is not in this stack of 8"):
        spatial_cdf(stack, 0, 0, n=3, frame=8)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, 5000), min_size=0, max_size=40), st.integers(0, 5))
def test_cdf_matches_its_definition(samples, n_missing):
    cdf = RangeCDF.from_samples(np.array(samples, dtype=np.uint32), n_missing=n_missing)
    n = len(samples)
    returns = sorted(s for s in samples if s > 0)
    assert cdf.n_samples == n and cdf.n_returns == len(returns) and cdf.n_missing == n_missing
    assert cdf.range_m.tolist() == [s / 1000 for s in returns]
    for r, f in zip(cdf.range_m, cdf.F):
        assert f == sum(1 for s in returns if s / 1000 <= r) / n
