"""The rotation arithmetic every azimuth-cut vendor shares (:mod:`lidarpkt.core.rotation`): its fast paths give
NumPy's own values."""

from __future__ import annotations

import numpy as np
import pytest

from lidarpkt.core.rotation import modulo_turn

RNG = np.random.default_rng(7)


@pytest.mark.parametrize("values", [
    RNG.uniform(-36000, 36000, 4001),  # azimuths less a cut angle, differences of azimuths: the fast path
    RNG.uniform(-1e6, 1e6, 4001),  # further than a turn: np.remainder itself
    np.diff(RNG.integers(0, 36000, 500).astype(np.uint16)),  # unsigned differences that wrapped at 65536
    RNG.integers(-36000, 36000, 500).astype(np.int32),
    np.array([0.0, 35999.999, 36000.0, -36000.0, -1e-9]),
    np.array([1.0, np.nan, -2.0]),
    np.array([]),
], ids=["within-a-turn", "far", "uint16-diff", "int32", "edges", "nan", "empty"])
def test_modulo_turn_is_numpy_remainder(values):
    got = modulo_turn(values)
    want = np.remainder(np.asarray(values, np.float64), 36000.0)
    assert got.dtype == want.dtype == np.float64
    np.testing.assert_array_equal(got, want)


def test_modulo_turn_leaves_its_argument():
    values = np.array([-5.0, 10.0])
    modulo_turn(values)
    assert values.tolist() == [-5.0, 10.0]
