"""Motion-compensated temporal CDF (paper eqs. 4–6).

A hand-held or vibrating sensor moves the scene across the range image by a pixel or two
between frames, which smears the temporal CDF of a raypath. For each frame k the patch of
the range image around the raypath is compared with the same patch of the reference frame
(frame 0) at every offset δ = (Δrow, Δcol) within ±``search`` pixels; the offset with the
lowest patch cost J is taken, and the frame's sample is read at (row + Δrow, col + Δcol).

Patch cost, over the pairs p of the patch where both pixels are samples (rows inside the
image, columns not lost):

    J_k(δ) = (1 / |P|) Σ_p ρ(r_k(p + δ), r_0(p)),
    ρ(a, b) = min(|a − b|, c)²   both returns,
              c²                 exactly one is a non-return,
              0                  both are non-returns,

with c = ``cap_m`` (1 m by default). The cap keeps one multi-return pixel in the patch from
outweighing the rest (a plain sum of squares would let a 10 m jump decide the match), and a
return/non-return mismatch costs as much as the largest range mismatch. Equal costs go to the
smallest |δ|, so a still frame keeps δ = 0. Offsets move in the destaggered image (adjacent
azimuths), and columns wrap in azimuth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack

from .cdf import RangeCDF
from .stack import check_pixel, neighbour_columns


@dataclass(frozen=True, eq=False)
class MotionCompensation:
    """Result of :func:`motion_compensated_cdf`.

    Attributes:
        offsets: ``int64[K, 2]`` chosen (Δrow, Δcol) per frame: the pixel of frame k that sees
            what (row, col) saw in the reference frame is (row + Δrow, col + Δcol) (Δcol in
            destaggered columns, i.e. azimuth steps).
        cost_m2: ``float64[K]`` the patch cost J at the chosen offset, m² (inf: nothing to compare).
        range_mm: ``uint32[K]`` the compensated samples (0 = non-return or missing; see ``sample_valid``).
        sample_valid: ``bool[K]`` False where the chosen pixel's column was lost.
        cdf: temporal CDF of the compensated samples.
    """

    offsets: np.ndarray
    cost_m2: np.ndarray
    range_mm: np.ndarray
    sample_valid: np.ndarray
    cdf: RangeCDF

    def to_json(self) -> dict:
        """``{"offsets": [[drow, dcol], ...], "range_m": [...], "F": [...]}``."""
        return {"offsets": self.offsets.tolist(), **self.cdf.to_json()}


def motion_compensated_cdf(
    stack: FrameStack,
    row: int,
    col: int,
    slot: int = 0,
    *,
    patch: int = 5,
    search: int = 2,
    reference: int = 0,
    cap_m: float = 1.0,
    offsets: np.ndarray | None = None,
) -> MotionCompensation:
    """Motion-compensated temporal CDF of pixel (row, col) (eqs. 4–6), vectorised over frames and offsets.

    Args:
        patch: odd patch size (5 in the paper).
        search: offsets searched in each direction, pixels (2 in the paper).
        reference: stack index of the reference frame (frame 0 in the paper).
        cap_m: the cost cap c in metres (see the module docstring).
        offsets: ``int[K, 2]`` per-frame offsets to use instead of searching the patch (e.g. the
            whole-image ones of :func:`estimate_frame_offsets`); ``cost_m2`` is then the patch
            cost at those offsets, and they must lie within ±``search``.

    Raises:
        AnalysisError: bad pixel/slot/patch/search/reference.
    """
    from .returns import resolve, sample_mask

    stack, slot = resolve(stack, slot)
    check_pixel(stack, row, col, slot)
    if patch < 1 or patch % 2 == 0:
        raise AnalysisError(f"patch size {patch} must be an odd number >= 1 (the paper uses 5)")
    if search < 0:
        raise AnalysisError(f"search radius {search} must be >= 0 pixels")
    k, _, h, w = stack.range_mm.shape
    if not -k <= reference < k:
        raise AnalysisError(f"reference frame {reference} is not in this stack of {k} frames")
    half = patch // 2
    reach = half + search
    if 2 * reach + 1 > w:
        raise AnalysisError(f"patch {patch} with search ±{search} is wider than the image ({w} columns)")

    # Window of all pixels any candidate patch can touch: [K, 2·reach+1, 2·reach+1].
    rows = np.arange(row - reach, row + reach + 1)
    row_in = (rows >= 0) & (rows < h)
    rows_c = np.clip(rows, 0, h - 1)
    cols = neighbour_columns(stack, row, col, rows_c, np.arange(-reach, reach + 1))  # [2r+1, 2r+1]
    win_mm = stack.range_mm[:, slot, rows_c[:, None], cols].astype(np.float64)
    win_ok = sample_mask(stack, slot)[:, rows_c[:, None], cols] & row_in[None, :, None]
    win_m = np.where(win_mm > 0, win_mm / 1000.0, np.nan)  # NaN = non-return

    ref_m = win_m[reference, search : search + patch, search : search + patch]  # [P, P]
    ref_ok = win_ok[reference, search : search + patch, search : search + patch]
    # cand[k, a, b] is frame k's patch moved by (a - search, b - search): [K, S, S, P, P]
    cand_m = sliding_window_view(win_m, (patch, patch), axis=(1, 2))
    cand_ok = sliding_window_view(win_ok, (patch, patch), axis=(1, 2))

    ref_ret = ~np.isnan(ref_m)
    cand_ret = ~np.isnan(cand_m)
    both = ref_ret & cand_ret
    diff = np.minimum(np.abs(np.nan_to_num(cand_m) - np.nan_to_num(ref_m)), cap_m)
    rho = np.where(both, diff * diff, np.where(ref_ret ^ cand_ret, cap_m * cap_m, 0.0))
    pair = cand_ok & ref_ok
    n_pairs = pair.sum(axis=(3, 4))
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = np.where(n_pairs > 0, (rho * pair).sum(axis=(3, 4)) / n_pairs, np.inf)  # [K, S, S]

    # Try offsets in order of growing |δ| so that argmin's first-minimum rule prefers small moves.
    side = np.arange(-search, search + 1)
    d_row, d_col = np.meshgrid(side, side, indexing="ij")
    order = np.lexsort((d_col.ravel(), d_row.ravel(), d_row.ravel() ** 2 + d_col.ravel() ** 2))
    if offsets is None:
        flat_cost = cost.reshape(k, -1)[:, order]
        best = order[np.argmin(flat_cost, axis=1)]
        offsets = np.stack([d_row.ravel()[best], d_col.ravel()[best]], axis=1).astype(np.int64)
    else:
        offsets = np.asarray(offsets, dtype=np.int64)
        if offsets.shape != (k, 2) or np.any(np.abs(offsets) > search):
            raise AnalysisError(f"offsets must be int[{k}, 2] within ±{search} pixels, got shape {offsets.shape}")
        best = (offsets[:, 0] + search) * (2 * search + 1) + (offsets[:, 1] + search)
    best_cost = cost.reshape(k, -1)[np.arange(k), best]

    pick_r = reach + offsets[:, 0]
    pick_c = reach + offsets[:, 1]
    frames = np.arange(k)
    sample_ok = win_ok[frames, pick_r, pick_c]
    sample_mm = np.where(sample_ok, win_mm[frames, pick_r, pick_c], 0).astype(np.uint32)
    cdf = RangeCDF.from_samples(sample_mm[sample_ok], n_missing=int(k - np.count_nonzero(sample_ok)))
    return MotionCompensation(offsets, best_cost, sample_mm, sample_ok, cdf)


def estimate_frame_offsets(
    stack: FrameStack, slot: int = 0, *, search: int = 2, reference: int = 0, cap_m: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Whole-frame motion: the offset of every frame against the reference frame, with the cost J
    of the module docstring taken over the whole image instead of one 5 × 5 patch.

    A patch on a surface wider than itself cannot tell a one-pixel yaw from none (every offset
    sees the same surface); the whole image can, when the sensor moved as a whole (hand-held
    jitter). Vectorised over pixels, one pass per frame and offset.

    Returns:
        ``(offsets int64[K, 2], cost_m2 float64[K])``: (Δrow, Δcol) with the meaning of
        :attr:`MotionCompensation.offsets`, and the cost at the chosen offset.
    """
    from .returns import resolve, sample_mask
    from .stack import check_stack, destagger, pixel_shift

    check_stack(stack)
    stack, slot = resolve(stack, slot)
    k, r, h, w = stack.range_mm.shape
    if not 0 <= slot < r:
        raise AnalysisError(f"return slot {slot} does not exist: this capture has {r} slot(s)")
    if search < 0 or 2 * search + 1 > min(h, w):
        raise AnalysisError(f"search radius {search} does not fit a {h} x {w} image")
    if not -k <= reference < k:
        raise AnalysisError(f"reference frame {reference} is not in this stack of {k} frames")
    shift = pixel_shift(stack)
    valid = sample_mask(stack, slot)
    img = destagger(np.where(valid, stack.range_mm[:, slot] / 1000.0, -1.0), shift)  # -1 = missing
    ref = img[reference]
    side = np.arange(-search, search + 1)
    d_row, d_col = np.meshgrid(side, side, indexing="ij")
    order = np.lexsort((d_col.ravel(), d_row.ravel(), d_row.ravel() ** 2 + d_col.ravel() ** 2))
    cost = np.full((k, d_row.size), np.inf)
    for i in order:  # 25 offsets; each one vectorised over frames and pixels
        dr, dc = int(d_row.ravel()[i]), int(d_col.ravel()[i])
        lo, hi = max(0, -dr), min(h, h - dr)  # reference rows whose moved row is inside the image
        cand = np.roll(img[:, lo + dr : hi + dr], -dc, axis=2)
        base = ref[lo:hi]
        ok = (cand >= 0) & (base >= 0)
        a_ret, b_ret = cand > 0, base > 0
        diff = np.minimum(np.abs(cand - base), cap_m)
        rho = np.where(a_ret & b_ret, diff * diff, np.where(a_ret ^ b_ret, cap_m * cap_m, 0.0))
        n = ok.sum(axis=(1, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            cost[:, i] = np.where(n > 0, np.where(ok, rho, 0.0).sum(axis=(1, 2)) / n, np.inf)
    best = order[np.argmin(cost[:, order], axis=1)]
    offsets = np.stack([d_row.ravel()[best], d_col.ravel()[best]], axis=1).astype(np.int64)
    return offsets, cost[np.arange(k), best]
