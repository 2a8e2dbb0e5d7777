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


def _is_whole_by_modulo(az, cut, **kw):
    """rotation_is_whole as written before its fast path (every key through modulo_turn): the reference."""
    from lidarpkt.core.median import median
    from lidarpkt.core.rotation import GAP_STEPS

    if kw.get("lost_columns"):
        return False
    key = modulo_turn(np.asarray(az, np.float64) - cut)
    step = median(modulo_turn(np.diff(az))) if len(key) >= 2 else 0.0
    by_block = kw.get("by_block", False)
    if step > 0 and len(key) >= 2 and float(np.diff(key).max()) > GAP_STEPS * (2 * step if by_block else step):
        return False
    check_start, check_end = kw["check_start"], kw["check_end"]
    if not (check_start or check_end):
        return True
    if len(key) < 2:
        if not kw.get("fallback_step_cdeg"):
            return False
        step = kw["fallback_step_cdeg"]
    if by_block:
        key[1::2] = key[0::2]
        step *= 2
    if check_start and not key[0] < step:
        return False
    return not check_end or key[-1] >= 36000.0 - step


def _outcome(fn, az, cut, kw):
    """The answer, or the type of what was raised (by-block frames of an odd width cannot pair their columns)."""
    try:
        return fn(az, cut, **kw)
    except ValueError as exc:
        return type(exc)


def test_rotation_is_whole_fast_path_gives_the_rule():
    """Frames of every shape the decoders make (whole, cut short at either end, a gap, a wrap inside, one column,
    NaN, out-of-turn values, uint16 azimuths), with and without a cut angle and by block: the same answer as
    the rule written with modulo_turn throughout, and the argument left as it was."""
    from lidarpkt.core.rotation import rotation_is_whole

    gen = np.random.default_rng(3)
    cases = []
    for width in (1, 2, 3, 1808, 2170):
        step = 36000 / max(width, 1)
        start = gen.uniform(0, 36000)
        whole = (np.arange(width) * step + gen.uniform(0, step)) % 36000
        shifted = (np.arange(width) * step + start) % 36000
        gap = whole.copy()
        if width > 10:
            gap[width // 2:] = (gap[width // 2:] + 5 * step) % 36000
        cases += [whole, shifted, gap, whole[: max(1, width // 2)], whole[width // 3:], np.round(whole)]
    cases += [np.array([1.0, np.nan, 3.0]), np.array([-5.0, 100.0, 200.0]), np.array([35990.0, 36010.0, 50.0]),
              np.array([35990, 10, 30], np.uint16), np.array([100.0, 100.0, 100.0]),
              np.cumsum([50.0, 10, 10, 10, 17, 10, 10]), np.cumsum([50.0, 10, 10, 10, 16, 10, 10]),  # 1.6 steps apart
              np.cumsum([50.0, 10, 10, 10, 17, 17, 17, 17]),  # the largest within GAP_STEPS of the median, not the least
              np.cumsum([100.0] + [20.0] * 907 + [17920.0]) % 36000,  # half a rotation missing (nebula's VLP-32C)
              np.cumsum([100.0, 10, 10, 10, 33, 33, 33]),  # a gap by the median, not beyond twice the mean
              np.cumsum([100.0, 10, 10, 32.0, 10]), np.cumsum([100.0, 10, 10, 32.000001, 10]),  # at GAP_STEPS exactly
              np.array([35000.0, 35500.0, 36500.0]), np.array([-10.0, 5.0, 20.0]),  # rising, past either end of the turn
              np.array([0.0, 18000.0, 35999.0])]  # rising across the whole turn
    for az in cases:
        before = np.array(az, copy=True)
        for cut in (0.0, 9000.0):
            for by_block in (False, True):
                for check_start in (False, True):
                    for check_end in (False, True):
                        kw = dict(check_start=check_start, check_end=check_end, by_block=by_block,
                                  fallback_step_cdeg=20.0)
                        assert _outcome(rotation_is_whole, az, cut, kw) == _outcome(
                            _is_whole_by_modulo, np.array(az, copy=True), cut, kw)
        np.testing.assert_array_equal(az, before)
