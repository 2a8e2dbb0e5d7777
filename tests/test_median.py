"""The decoders' median (:func:`lidarpkt.core.median.median`) gives ``np.median``'s own values, dtype by dtype."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lidarpkt.core.median import median

RNG = np.random.default_rng(11)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 1092, 1800, 1801])
@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.int64, np.int32, np.uint16, np.uint8])
def test_median_is_numpy_median(n, dtype):
    for values in (RNG.integers(0, 250, n).astype(dtype),  # few distinct values, as azimuth steps
                   (RNG.normal(size=n) * 1000).astype(dtype) if np.dtype(dtype).kind == "f" else
                   RNG.integers(0, np.iinfo(dtype).max, n, dtype=np.int64).astype(dtype)):
        want = np.median(values)
        got = median(values)
        assert isinstance(got, float)
        assert got == float(want)


def test_float32_mean_of_the_middle_pair_in_float32():
    values = np.array([16777217.0, 1.0, 16777219.0, 3.0], np.float32)  # sums beyond float32's exact integers
    assert median(values) == float(np.median(values))


def test_nan_and_empty_give_nan_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(median(np.array([1.0, np.nan, -2.0, 5.0])))
        assert np.isnan(median(np.array([], np.float64)))


def test_leaves_its_argument():
    values = np.array([3, 1, 2])
    median(values)
    assert values.tolist() == [3, 1, 2]
