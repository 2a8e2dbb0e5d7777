"""Return-mode comparison: the two slots of a dual capture, or captures of one scene in different modes.

* Paired (:func:`compare_slots`, and :func:`compare_stacks` with ``paired=True``): frame k of
  one side and frame k of the other are the same firing. Per pixel: how often the two
  reports differ (a range that is not equal, or a return on one side only) and by how much
  (Δ = ``|r_a − r_b|`` over the frames where both returned and differ), with a histogram of Δ.
* Distributional (:func:`compare_stacks`): the frames of two captures are different firings,
  so per pixel the two temporal CDFs are compared: Kolmogorov–Smirnov distance sup_r |F_a − F_b|
  (vectorised over the image), difference of median ranges, difference of non-return fractions.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal, overload

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack

from .returns import resolve, sample_mask
from .stack import check_stack

_NO_SAMPLE = np.iinfo(np.int64).max
_KEY_CAP = np.int64(1) << 40  # above any range in mm; leaves room for the side bit of the KS sort keys

#: Default Δ histogram bin edges, metres: log-spaced from 2 mm (the VLP-16 range step) to 200 m.
DEFAULT_DELTA_EDGES_M = np.concatenate(([0.0], np.logspace(np.log10(0.002), np.log10(200.0), 51)))


@dataclass(frozen=True, eq=False)
class PairedComparison:
    """Frame-by-frame comparison of two reports of the same firings; per-pixel arrays are ``[H, W]``.

    Attributes:
        labels: the two sides (e.g. ``("last", "strongest")``).
        n_pairs: frames where both sides have a sample (column not lost on either).
        n_differ: pairs whose reports differ (unequal range, or a return on one side only).
        n_one_sided: pairs with a return on exactly one side.
        fraction_differ: n_differ / n_pairs (NaN without pairs).
        mean_delta_m, max_delta_m: of Δ over the pairs where both returned and differ (NaN if none).
        delta_edges_m, delta_counts: histogram of every such Δ over the image.
    """

    labels: tuple[str, str]
    n_pairs: np.ndarray
    n_differ: np.ndarray
    n_one_sided: np.ndarray
    fraction_differ: np.ndarray
    mean_delta_m: np.ndarray
    max_delta_m: np.ndarray
    delta_edges_m: np.ndarray
    delta_counts: np.ndarray

    def summary(self) -> dict:
        pairs = int(self.n_pairs.sum())
        differ = int(self.n_differ.sum())
        return {
            "labels": list(self.labels),
            "pairs": pairs,
            "pairs_differ": differ,
            "pairs_one_sided": int(self.n_one_sided.sum()),
            "fraction_identical": (pairs - differ) / pairs if pairs else None,
            "delta_histogram": {"edges_m": self.delta_edges_m.tolist(), "counts": self.delta_counts.tolist()},
        }


def _paired(ra, rb, va, vb, labels, edges) -> PairedComparison:
    """``ra, rb``: uint32 [K, H, W] (0 = non-return); ``va, vb``: bool [K, W] valid columns or
    [K, H, W] samples."""
    both_valid = _pixels(va) & _pixels(vb)
    ret_a, ret_b = ra > 0, rb > 0
    differ = both_valid & (ra != rb)
    one_sided = both_valid & (ret_a ^ ret_b)
    two_sided = differ & ret_a & ret_b
    delta = np.abs(ra.astype(np.int64) - rb.astype(np.int64)) / 1000.0
    n_pairs = np.broadcast_to(both_valid.sum(axis=0), ra.shape[1:]).astype(np.int64)
    n_two = two_sided.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_delta = np.where(n_two > 0, np.where(two_sided, delta, 0.0).sum(axis=0) / n_two, np.nan)
        frac = differ.sum(axis=0) / n_pairs
    max_delta = np.where(n_two > 0, np.where(two_sided, delta, -np.inf).max(axis=0), np.nan)
    edges = np.asarray(DEFAULT_DELTA_EDGES_M if edges is None else edges, np.float64)
    counts, _ = np.histogram(delta[two_sided], bins=edges)
    return PairedComparison(tuple(labels), n_pairs, differ.sum(axis=0).astype(np.int64), one_sided.sum(axis=0).astype(np.int64),
                            frac, mean_delta, max_delta, edges, counts.astype(np.int64))


def _pixels(valid: np.ndarray) -> np.ndarray:
    """A ``[K, W]`` column mask as ``[K, 1, W]``; a ``[K, H, W]`` sample mask as is."""
    return valid[:, None, :] if valid.ndim == 2 else valid


def compare_slots(stack: FrameStack, a: int | str = 0, b: int | str = 1, *, delta_edges_m: np.ndarray | None = None) -> PairedComparison:
    """Compare two returns of a dual capture frame by frame: slot indices or return kinds
    (``"last"``, ``"strongest"``..., selected per firing, see :mod:`analysis.returns`).

    Raises AnalysisError when the stack does not have both.
    """
    check_stack(stack)
    r = stack.range_mm.shape[1]
    from .returns import parse_return, select_returns

    a, b = parse_return(a), parse_return(b)
    if not (isinstance(a, int) and isinstance(b, int)):
        if a == b:
            raise AnalysisError(f"cannot compare return {a!r} with itself")
        stack, a, b = select_returns(stack, [a, b]), 0, 1
        r = 2
    if not (0 <= a < r and 0 <= b < r) or a == b:
        raise AnalysisError(
            f"cannot compare slots {a} and {b}: this capture has {r} return {'slot' if r == 1 else 'slots'} {list(stack.return_labels)}; "
            "slot comparison needs a dual-return capture (or give a second capture to compare modes)"
        )
    labels = (stack.return_labels[a], stack.return_labels[b])
    return _paired(stack.range_mm[:, a], stack.range_mm[:, b], sample_mask(stack, a), sample_mask(stack, b), labels, delta_edges_m)


@dataclass(frozen=True, eq=False)
class DistributionComparison:
    """Per-pixel comparison of the temporal CDFs of two captures; arrays are ``[H, W]``.

    Attributes:
        labels: the two sides.
        ks: ``sup_r |F_a(r) − F_b(r)|`` of the two temporal CDFs (non-returns in the denominators;
            NaN where a side has no sample).
        median_delta_m: median range of b minus median range of a (NaN where a side has no return).
        nonreturn_delta: non-return fraction of b minus that of a.
        n_samples_a, n_samples_b: samples per pixel on each side.
    """

    labels: tuple[str, str]
    ks: np.ndarray
    median_delta_m: np.ndarray
    nonreturn_delta: np.ndarray
    n_samples_a: np.ndarray
    n_samples_b: np.ndarray

    def summary(self) -> dict:
        finite = np.isfinite(self.ks)
        md = self.median_delta_m[np.isfinite(self.median_delta_m)]
        return {
            "labels": list(self.labels),
            "pixels_compared": int(finite.sum()),
            "ks_mean": float(self.ks[finite].mean()) if finite.any() else None,
            "ks_quantiles": {q: float(np.quantile(self.ks[finite], float(q))) for q in ("0.5", "0.9", "0.99")} if finite.any() else None,
            "fraction_median_differs": float(np.mean(md != 0)) if md.size else None,
            "median_delta_abs_m_quantiles": {q: float(np.quantile(np.abs(md), float(q))) for q in ("0.5", "0.9", "0.99")} if md.size else None,
        }


def _samples(range_mm: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """[K, H, W] uint32 + [K, W] columns or [K, H, W] samples → values int64 [K, H, W] (sentinel
    for non-return or missing) and n_samples [H, W]."""
    v = np.broadcast_to(_pixels(valid), range_mm.shape)
    vals = np.where(v & (range_mm > 0), range_mm.astype(np.int64), _NO_SAMPLE)
    return vals, v.sum(axis=0)


def ks_image(a_mm: np.ndarray, a_valid: np.ndarray, b_mm: np.ndarray, b_valid: np.ndarray) -> np.ndarray:
    """KS distance between the temporal CDFs of every pixel of two ``[K, H, W]`` range stacks
    (any K each), vectorised: ``float64[H, W]``, NaN where a side has no sample."""
    va, na = _samples(a_mm, a_valid)
    vb, nb = _samples(b_mm, b_valid)
    # One sort of keys 2·value + side (0 = a, 1 = b) instead of an argsort and two gathers.
    keys = np.concatenate([np.minimum(va, _KEY_CAP) * 2, np.minimum(vb, _KEY_CAP) * 2 + 1])
    keys.sort(axis=0)
    vals = keys >> 1
    from_b = (keys & 1).astype(bool)
    # integer counts, divided once: F_a − F_b without rounding drift along the cumulative sum
    cum_b = np.cumsum(from_b, axis=0)
    cum_a = np.arange(1, keys.shape[0] + 1).reshape((-1,) + (1,) * (keys.ndim - 1)) - cum_b
    with np.errstate(invalid="ignore", divide="ignore"):
        diff = cum_a / na - cum_b / nb
    # The step functions are compared after the last of equal values, below the non-returns.
    end_of_run = np.ones_like(vals, bool)
    end_of_run[:-1] = vals[1:] != vals[:-1]
    use = end_of_run & (vals != _KEY_CAP)
    ks = np.where(use, np.abs(diff), 0.0).max(axis=0)
    return np.where((na > 0) & (nb > 0), ks, np.nan)


@overload
def compare_stacks(a: FrameStack, b: FrameStack, slot_a: int | str = 0, slot_b: int | str = 0, *,
                   paired: Literal[False] = False, delta_edges_m: np.ndarray | None = None) -> DistributionComparison: ...
@overload
def compare_stacks(a: FrameStack, b: FrameStack, slot_a: int | str = 0, slot_b: int | str = 0, *,
                   paired: Literal[True], delta_edges_m: np.ndarray | None = None,
                   ) -> tuple[DistributionComparison, PairedComparison]: ...
@overload
def compare_stacks(a: FrameStack, b: FrameStack, slot_a: int | str = 0, slot_b: int | str = 0, *,
                   paired: bool, delta_edges_m: np.ndarray | None = None,
                   ) -> DistributionComparison | tuple[DistributionComparison, PairedComparison]: ...
def compare_stacks(
    a: FrameStack,
    b: FrameStack,
    slot_a: int | str = 0,
    slot_b: int | str = 0,
    *,
    paired: bool = False,
    delta_edges_m: np.ndarray | None = None,
) -> DistributionComparison | tuple[DistributionComparison, PairedComparison]:
    """Compare slot ``slot_a`` of capture ``a`` with slot ``slot_b`` of capture ``b`` (one scene,
    two modes) pixel by pixel. With ``paired=True`` (frame k of both is the same firing, as in
    captures generated from one seed) also return the frame-by-frame :class:`PairedComparison`.

    Raises AnalysisError when the images differ in size, a slot is missing, or paired stacks
    differ in frame count.
    """
    check_stack(a)
    check_stack(b)
    a, slot_a = resolve(a, slot_a)
    b, slot_b = resolve(b, slot_b)
    if a.range_mm.shape[2:] != b.range_mm.shape[2:]:
        (ha, wa), (hb, wb) = a.range_mm.shape[2:], b.range_mm.shape[2:]
        hint = (f"; put both on one grid with --grid {360.0 / min(wa, wb):g} (resolution_deg= of load_stack in Python)" if ha == hb
                else "; compare captures of one sensor")
        raise AnalysisError(f"the captures have different range images ({ha}x{wa} and {hb}x{wb}){hint}")
    for stack, slot, name in ((a, slot_a, "first"), (b, slot_b, "second")):
        if not 0 <= slot < stack.range_mm.shape[1]:
            raise AnalysisError(f"the {name} capture has no return slot {slot} (it has {list(stack.return_labels)})")
    ra, rb = a.range_mm[:, slot_a], b.range_mm[:, slot_b]
    labels = (a.return_labels[slot_a], b.return_labels[slot_b])
    ma, mb = sample_mask(a, slot_a), sample_mask(b, slot_b)
    ks = ks_image(ra, ma, rb, mb)
    va, na = _samples(ra, ma)
    vb, nb = _samples(rb, mb)

    def median_m(vals):
        f = np.where(vals != _NO_SAMPLE, vals, np.nan).astype(np.float64)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # pixels without a return give NaN, as documented
            return np.nanmedian(f, axis=0) / 1000.0

    with np.errstate(invalid="ignore", divide="ignore"):
        nr_a = (na - (va != _NO_SAMPLE).sum(axis=0)) / na
        nr_b = (nb - (vb != _NO_SAMPLE).sum(axis=0)) / nb
    dist = DistributionComparison(labels, ks, median_m(vb) - median_m(va), nr_b - nr_a, na, nb)
    if not paired:
        return dist
    if len(a) != len(b):
        raise AnalysisError(f"paired comparison needs the same number of frames ({len(a)} and {len(b)})")
    return dist, _paired(ra, rb, ma, mb, labels, delta_edges_m)

