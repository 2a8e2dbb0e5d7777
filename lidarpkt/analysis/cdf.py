"""Empirical range CDFs of a raypath: temporal (paper eq. 1) and spatial (eq. 3).

Both follow one rule: every *sample* counts in the denominator, a sample being a firing
that the sensor reported on, with or without a return. A non-return is a sample whose
range is infinite, so the CDF tops out at 1 − (non-return fraction), as in the paper's
figures. A pixel whose column was lost (``column_valid`` False) is **missing**: it is not a
sample, it is left out and counted separately.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack

from .returns import resolve, sample_mask
from .stack import check_pixel, neighbour_columns


@dataclass(frozen=True, eq=False)
class RangeCDF:
    """An empirical range CDF.

    Attributes:
        range_m: ``float64[n_returns]`` the returned ranges in metres, sorted ascending.
        F: ``float64[n_returns]`` the CDF at each of them: #{samples ≤ range_m[i]} / n_samples
            (ties share the value of the last of them).
        n_samples: the denominator, returns + non-returns.
        n_returns, n_nonreturn: samples with and without a return.
        n_missing: pixels left out because their column was lost.
    """

    range_m: np.ndarray
    F: np.ndarray
    n_samples: int
    n_returns: int
    n_nonreturn: int
    n_missing: int

    @classmethod
    def from_samples(cls, range_mm: np.ndarray, n_missing: int = 0) -> "RangeCDF":
        """CDF of samples given in millimetres, 0 = non-return (missing pixels already removed)."""
        r = np.asarray(range_mm).ravel()
        returns = np.sort(r[r > 0]).astype(np.float64) / 1000.0
        n = int(r.size)
        f = np.searchsorted(returns, returns, side="right") / n if n else np.zeros(0)
        return cls(returns, f, n, int(returns.size), n - int(returns.size), int(n_missing))

    @property
    def nonreturn_fraction(self) -> float:
        """Non-returns / samples (NaN when there is no sample)."""
        return self.n_nonreturn / self.n_samples if self.n_samples else float("nan")

    def evaluate(self, r_m: np.ndarray | float) -> np.ndarray:
        """F(r) at any ranges ``r_m`` (metres); a right-continuous step function."""
        if not self.n_samples:
            return np.zeros_like(np.asarray(r_m, dtype=np.float64))
        return np.searchsorted(self.range_m, np.asarray(r_m, dtype=np.float64), side="right") / self.n_samples

    def to_json(self) -> dict:
        """``{"range_m": [...], "F": [...]}``, the shape ``analyze --json`` writes."""
        return {"range_m": self.range_m.tolist(), "F": self.F.tolist()}


def pixel_samples(stack: FrameStack, row: int, col: int, slot: int | str = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples of one raypath over the stack.

    ``slot``: a slot index or a return kind (``"strongest"``, ``"last"``, ``"second_strongest"``,
    selected per firing: see :mod:`analysis.returns`).

    Returns:
        ``(frames int64[n], range_mm uint32[n], reflectivity uint8[n])`` for the n frames with a
        sample (column valid and the return reported), in frame order; range 0 = non-return.

    Raises:
        AnalysisError: pixel or slot out of range, a return the capture does not report, empty stack.
    """
    stack, slot = resolve(stack, slot)
    check_pixel(stack, row, col, slot)
    frames = np.flatnonzero(sample_mask(stack, slot)[:, row, col])
    return frames, stack.range_mm[frames, slot, row, col], stack.reflectivity[frames, slot, row, col]


def temporal_cdf(stack: FrameStack, row: int, col: int, slot: int | str = 0) -> RangeCDF:
    """Temporal CDF (eq. 1) of pixel (row, col), return slot ``slot``, over the K frames of the stack.

    Non-returns count in the denominator; frames without a sample (column lost, or a return the
    sensor did not report in that firing) are left out and counted in ``n_missing``. Raises
    AnalysisError for a pixel or slot out of range.
    """
    frames, rng, _ = pixel_samples(stack, row, col, slot)
    return RangeCDF.from_samples(rng, n_missing=len(stack) - frames.size)


def reflectivity_vs_range(stack: FrameStack, row: int, col: int, slot: int | str = 0) -> tuple[np.ndarray, np.ndarray]:
    """Reflectivity against range for the returns of a raypath.

    Returns ``(range_m float64[n], reflectivity uint8[n])`` sorted by range (stable: frame
    order among equal ranges), i.e. aligned with :func:`temporal_cdf`'s ``range_m``.
    """
    _, rng, refl = pixel_samples(stack, row, col, slot)
    keep = rng > 0
    rng, refl = rng[keep], refl[keep]
    order = np.argsort(rng, kind="stable")
    return rng[order].astype(np.float64) / 1000.0, refl[order]


def neighbourhood(stack: FrameStack, row: int, col: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``int64[m]`` and columns ``int64[m, n]`` of the n × n neighbourhood of (row, col).

    Rows are clipped at the top and bottom of the image (so m ≤ n); columns wrap in azimuth and
    are taken in the destaggered image (see :func:`analysis.stack.neighbour_columns`).
    """
    if n < 1 or n % 2 == 0:
        raise AnalysisError(f"neighbourhood size {n} must be an odd number >= 1 (the paper uses 3 and 5)")
    h, w = stack.range_mm.shape[2:]
    if n > w:
        raise AnalysisError(f"neighbourhood {n} x {n} is wider than the image ({w} columns)")
    half = n // 2
    rows = np.arange(max(0, row - half), min(h, row + half + 1))
    return rows, neighbour_columns(stack, row, col, rows, np.arange(-half, half + 1))


def spatial_cdf(
    stack: FrameStack, row: int, col: int, slot: int | str = 0, *, n: int = 5, frame: int | None = 0
) -> RangeCDF:
    """Spatial CDF (eq. 3) over the n × n neighbourhood of pixel (row, col).

    Args:
        n: odd neighbourhood size (5 and 3 in the paper); rows clipped at the image edges,
            columns wrapping in azimuth.
        frame: stack index of the one frame to use, or ``None`` for all frames superimposed
            (the paper's Fig. 9).

    Neighbourhood pixels in lost columns are missing (counted in ``n_missing``); non-returns
    count in the denominator. Raises AnalysisError for bad pixel, slot, frame or n.
    """
    stack, slot = resolve(stack, slot)
    check_pixel(stack, row, col, slot)
    rows, cols = neighbourhood(stack, row, col, n)
    if frame is None:
        frames = np.arange(len(stack))
    else:
        if not -len(stack) <= frame < len(stack):
            raise AnalysisError(f"frame {frame} is not in this stack of {len(stack)} frames; give one of 0-{len(stack) - 1} "
                                "(--monitor-frame)")
        frames = np.array([frame % len(stack)])
    ranges = stack.range_mm[frames[:, None, None], slot, rows[None, :, None], cols[None, :, :]]
    valid = sample_mask(stack, slot)[frames[:, None, None], rows[None, :, None], cols[None, :, :]]
    return RangeCDF.from_samples(ranges[valid], n_missing=int(valid.size - np.count_nonzero(valid)))
