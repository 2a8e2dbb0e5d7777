"""Whole-image multi-return statistics over a stack of frames, and the paper's multi-return
monitor (§4.3) with its evaluation.

Everything here is vectorised over the whole ``[K, R, H, W]`` stack: one sort along the frame
axis gives every pixel's sorted samples, and cluster boundaries are the gaps wider than
``gap_m`` between consecutive sorted returns (the rule of :func:`analysis.gmm.fit_auto`).

The monitor looks at a single frame: a raypath is flagged when the returns of its n × n
neighbourhood (its one-frame spatial CDF) hold a gap wider than a threshold, i.e. the
neighbourhood sees two surfaces. The paper's score takes the gap in the ranges themselves
(``method="gap"``, :func:`spatial_gap_score`); the default (``method="detrend"``,
:func:`detrended_gap_score`) takes it in the ranges about a local plane, so that ground and walls
at a shallow angle stop looking like two surfaces (see :func:`monitor_score` for the methods and
their measured precision and recall). It is scored against the temporal truth of the stack
(``n_clusters >= 2``) by precision, recall and a ROC curve over the threshold.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack

from .gmm import DEFAULT_GAP_M
from .returns import sample_mask
from .stack import check_stack, destagger, pixel_shift, restagger

_NO_SAMPLE = np.iinfo(np.uint32).max  # sorts after every real range


@dataclass(frozen=True, eq=False)
class ImageStatistics:
    """Per pixel and return slot statistics of a stack; every array is ``[R, H, W]``.

    Attributes:
        n_samples: frames with a sample (column not lost), returns + non-returns.
        n_returns: frames with a return.
        nonreturn_fraction: (n_samples − n_returns) / n_samples; NaN without samples.
        mean_m, std_m: mean and (population) standard deviation of the returned ranges, m; NaN without returns.
        n_clusters: clusters of returns (0 without returns).
        gap_m: largest gap between two consecutive clusters, m (0 for fewer than two clusters).
        gap_threshold_m: the gap that separates clusters.
        return_labels: label of each slot.
    """

    n_samples: np.ndarray
    n_returns: np.ndarray
    nonreturn_fraction: np.ndarray
    mean_m: np.ndarray
    std_m: np.ndarray
    n_clusters: np.ndarray
    gap_m: np.ndarray
    gap_threshold_m: float
    return_labels: tuple[str, ...] = ()

    @property
    def multi_return(self) -> np.ndarray:
        """``bool[R, H, W]``: more than one cluster over the stack."""
        return self.n_clusters >= 2


#: Temporaries of :func:`image_statistics` are bounded by working on blocks of rows of about this
#: many samples (K·R·rows·W): a long capture does not need several float64 copies of itself at once.
_BLOCK_SAMPLES = 1 << 22


def _block_statistics(rng: np.ndarray, valid: np.ndarray, gap_mm: float) -> tuple[np.ndarray, ...]:
    """Statistics of one block ``rng uint32[K, R, h, W]`` with samples ``valid bool[K, R, h, W]``."""
    k = rng.shape[0]
    present = (rng > 0) & valid
    srt = np.sort(np.where(present, rng, np.uint32(_NO_SAMPLE)), axis=0)
    is_ret = srt != _NO_SAMPLE  # returns sort first, then the non-returns and missing frames
    n_ret = is_ret.sum(axis=0)
    r_m = np.where(is_ret, srt, 0).astype(np.float64) / 1000.0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = r_m.sum(axis=0) / n_ret
        dev = np.where(is_ret, r_m - mean, 0.0)
        std = np.sqrt((dev * dev).sum(axis=0) / n_ret)
    if k > 1:
        step: np.ndarray = np.diff(srt.astype(np.int64), axis=0)  # int64 mm between consecutive sorted samples
        boundary = is_ret[1:] & (step > gap_mm)  # is_ret[1:] means both sides are returns
        n_clusters = (n_ret > 0).astype(np.int64) + boundary.sum(axis=0)
        gap = np.where(boundary, step, 0).max(axis=0) / 1000.0
    else:
        n_clusters = (n_ret > 0).astype(np.int64)
        gap = np.zeros(srt.shape[1:])
    return n_ret.astype(np.int64), mean, std, n_clusters, gap


def image_statistics(stack: FrameStack, *, gap_m: float = DEFAULT_GAP_M) -> ImageStatistics:
    """Whole-image statistics (number of returns, non-return fraction, std, clusters, largest
    gap Δ between clusters) for every pixel and slot, vectorised over the stack (in blocks of
    rows, to bound the memory of the temporaries).

    Raises AnalysisError for an empty stack or a non-positive gap.
    """
    if gap_m <= 0:
        raise AnalysisError(f"cluster gap {gap_m} m must be positive")
    check_stack(stack)
    k, r, h, w = stack.range_mm.shape
    rows_per_block = max(1, _BLOCK_SAMPLES // max(1, k * r * w))
    mask = sample_mask(stack)
    parts = [
        _block_statistics(stack.range_mm[:, :, a : a + rows_per_block], mask[:, :, a : a + rows_per_block], gap_m * 1000.0)
        for a in range(0, h, rows_per_block)  # blocks of rows, each vectorised over all its pixels
    ]
    n_ret, mean, std, n_clusters, gap = (np.concatenate(p, axis=1) for p in zip(*parts))
    n_samples = mask.sum(axis=0).astype(np.int64)
    with np.errstate(invalid="ignore", divide="ignore"):
        nonret = (n_samples - n_ret) / n_samples
    return ImageStatistics(
        n_samples=n_samples,
        n_returns=n_ret,
        nonreturn_fraction=nonret,
        mean_m=mean,
        std_m=std,
        n_clusters=n_clusters,
        gap_m=gap,
        gap_threshold_m=float(gap_m),
        return_labels=tuple(stack.return_labels),
    )


def spatial_gap_score(stack: FrameStack, *, frame: int = 0, n: int = 5, by_row: bool = False) -> np.ndarray:
    """The monitor's score: for every pixel and slot of one frame, the largest gap (m) between
    consecutive sorted returns of its n × n neighbourhood (rows clipped, azimuth wrapping,
    taken in the destaggered image). 0 where the neighbourhood has fewer than two returns.
    ``float64[R, H, W]``, in the stack's (staggered) pixel layout.

    ``by_row``: sort each row of the neighbourhood on its own and take the largest gap found in
    any of them. A surface seen at grazing incidence (ground, a hedge top) puts neighbouring
    beams metres apart, which the whole neighbourhood reads as two surfaces; within one row
    (one elevation, neighbouring azimuths) it stays one surface.
    """
    check_stack(stack)
    if n < 1 or n % 2 == 0:
        raise AnalysisError(f"neighbourhood size {n} must be an odd number >= 1")
    if not -len(stack) <= frame < len(stack):
        raise AnalysisError(f"frame {frame} is not in this stack of {len(stack)} frames")
    shift = pixel_shift(stack)
    rng = stack.range_mm[frame]
    present = (rng > 0) & sample_mask(stack)[frame]
    img = destagger(np.where(present, rng, np.uint32(_NO_SAMPLE)), shift)  # [R, H, W]
    r, h, w = img.shape
    half = n // 2
    padded = np.full((r, h + 2 * half, w), _NO_SAMPLE, dtype=np.uint32)
    padded[:, half : half + h] = img

    def largest_gap(neigh: np.ndarray) -> np.ndarray:
        neigh.sort(axis=0)
        step = np.diff(neigh.astype(np.int64), axis=0)
        return np.where(neigh[1:] != _NO_SAMPLE, step, 0).max(axis=0)

    if by_row:
        # the n azimuth neighbours of every pixel, then the largest gap over the n rows around it
        row_gap = largest_gap(np.stack([np.roll(padded, -dj, axis=2) for dj in range(-half, half + 1)]))
        score = np.stack([row_gap[:, half + di : half + di + h] for di in range(-half, half + 1)]).max(axis=0)
    else:
        # n·n shifted copies of the image: neighbour (di, dj) of every pixel at once.
        score = largest_gap(np.stack(
            [np.roll(padded[:, half + di : half + di + h], -dj, axis=2) for di in range(-half, half + 1) for dj in range(-half, half + 1)]
        ))
    return restagger(score / 1000.0, shift)


#: The monitor's scores (:func:`monitor_score`), the default first.
MONITOR_METHODS = ("detrend", "plane", "gap", "row")
DEFAULT_MONITOR_METHOD = "detrend"

#: A window of the ``detrend``/``plane`` scores with fewer returns than this says nothing (a plane
#: through three points fits them exactly); it is left out of the minimum over windows.
MIN_WINDOW_RETURNS = 5

#: Ridge on the plane's two slopes, relative to the number of returns: keeps the fit defined when
#: the returns of a window lie on one row or one column (the fitted values there are unchanged).
_SLOPE_RIDGE = 1e-9


def _neighbours(img: np.ndarray, n: int) -> np.ndarray:
    """``[R, H, W, n, n]``: neighbour (di, dj) of every pixel of ``img [R, H, W]`` at
    ``[..., di + n//2, dj + n//2]``, rows clipped (NaN beyond the top and bottom), azimuth wrapping."""
    r, h, w = img.shape
    half = n // 2
    padded = np.full((r, h + 2 * half, w + 2 * half), np.nan)
    padded[:, half : half + h, half : half + w] = img
    if half:
        padded[:, half : half + h, :half] = img[:, :, w - half :]  # azimuth wraps
        padded[:, half : half + h, half + w :] = img[:, :, :half]
    win = np.lib.stride_tricks.sliding_window_view(padded, (n, n), axis=(1, 2))  # [R, H, W, n, n], a view
    return win


def _window_gap(rng: np.ndarray, di: np.ndarray, dj: np.ndarray) -> np.ndarray:
    """Largest gap (m) of the residual CDF of each pixel's window of returns about its local plane.

    ``rng [..., k]``: the window's ranges in metres (NaN = no return); ``di``, ``dj`` ``[k]``: row
    and column offsets. The plane is fitted by least squares to the inverse range 1/r as a linear
    function of (di, dj): a flat surface seen from the sensor has 1/r = n·u / d, linear in the
    beam direction u, so ground at grazing incidence (whose range grows steeply from beam to
    beam) is a plane there and not a run of gaps. Residuals are r − 1/(fitted 1/r), in metres.
    NaN where the window holds fewer than :data:`MIN_WINDOW_RETURNS` returns."""
    ok = np.isfinite(rng)
    wgt = ok.astype(np.float64)
    with np.errstate(divide="ignore"):
        y = np.where(ok, 1.0 / np.where(ok, rng, 1.0), 0.0)
    x = np.stack([np.ones_like(di, dtype=np.float64), di - di.mean(), dj - dj.mean()])  # [3, k]
    a = (wgt @ (x[:, None, :] * x[None, :, :]).reshape(9, -1).T).reshape(wgt.shape[:-1] + (3, 3))  # XᵀWX per pixel
    count = wgt.sum(axis=-1)
    a[..., 1, 1] += _SLOPE_RIDGE * np.maximum(count, 1.0)
    a[..., 2, 2] += _SLOPE_RIDGE * np.maximum(count, 1.0)
    a[..., 0, 0] += count == 0  # no return at all: any plane (the window is left out below)
    b = y @ x.T  # XᵀWy (y is 0 where there is no return)
    coef = np.linalg.solve(a, b[..., None])[..., 0]
    fit = coef @ x  # [..., k] fitted 1/r
    with np.errstate(divide="ignore", invalid="ignore"):
        res = np.where(ok & (fit > 0), rng - 1.0 / fit, np.nan)
    res.sort(axis=-1)  # NaN last
    gap = np.diff(res, axis=-1)
    gap = np.where(np.isfinite(gap), gap, -np.inf).max(axis=-1)
    return np.where(count >= MIN_WINDOW_RETURNS, np.maximum(gap, 0.0), np.nan)


def detrended_gap_score(stack: FrameStack, *, frame: int = 0, n: int = 5, window_rows: int | None = None) -> np.ndarray:
    """The default monitor score: the largest gap (m) in the CDF of the neighbourhood's ranges
    *about their local plane*, for every pixel and slot of one frame. ``float64[R, H, W]``, in the
    stack's (staggered) pixel layout; 0 where no window has enough returns.

    The paper's score (:func:`spatial_gap_score`) reads any range difference inside the n × n
    neighbourhood as two surfaces, so ground and walls seen at a shallow angle, whose
    neighbouring beams are metres apart but on one smooth surface, are all flagged. Here a plane
    is removed first (:func:`_window_gap`: least squares on 1/r against the row and column
    offsets, one plane per window), and the gaps are looked for in what is left.

    ``window_rows``: windows of this many rows × n columns, every one that holds the pixel
    (n // 2 + 1 rows by default: for n = 5, the three 3 × 5 windows with the pixel in their
    top, middle and bottom row); the score is the *smallest* of their gaps. A crease or an
    occlusion edge along a row (wall above, ground below) then has a window on each side that
    is one plane, whereas a multi-return pixel has mixed ranges in every window. ``window_rows
    = n`` is one plane over the whole n × n neighbourhood (``method="plane"``).
    """
    check_stack(stack)
    if n < 1 or n % 2 == 0:
        raise AnalysisError(f"neighbourhood size {n} must be an odd number >= 1")
    if not -len(stack) <= frame < len(stack):
        raise AnalysisError(f"frame {frame} is not in this stack of {len(stack)} frames")
    if n > stack.range_mm.shape[3]:
        raise AnalysisError(f"neighbourhood {n} x {n} is wider than the image ({stack.range_mm.shape[3]} columns)")
    half = n // 2
    wr = half + 1 if window_rows is None else int(window_rows)
    if not 1 <= wr <= n:
        raise AnalysisError(f"window of {wr} rows does not fit the {n} x {n} neighbourhood")
    shift = pixel_shift(stack)
    rng = stack.range_mm[frame]
    present = (rng > 0) & sample_mask(stack)[frame]
    img = destagger(np.where(present, rng.astype(np.float64) / 1000.0, np.nan), shift)  # [R, H, W] m
    neigh = _neighbours(img, n)  # [R, H, W, n, n]
    r, h, w = img.shape
    cols = np.arange(-half, half + 1, dtype=np.float64)
    score = np.full((r, h, w), np.nan)
    for top in range(max(-half, 1 - wr), min(0, half - wr + 1) + 1):  # the windows holding row 0
        rows = np.arange(top, top + wr, dtype=np.float64)
        di, dj = np.repeat(rows, n), np.tile(cols, wr)
        win = neigh[:, :, :, top + half : top + half + wr, :].reshape(r, h, w, wr * n)
        gap = _window_gap(win, di, dj)
        score = np.fmin(score, gap)  # NaN (too few returns) only where no window has enough
    return restagger(np.nan_to_num(score, nan=0.0), shift)


def monitor_score(stack: FrameStack, *, frame: int = 0, n: int = 5, method: str = DEFAULT_MONITOR_METHOD) -> np.ndarray:
    """The multi-return monitor's score (m) of every pixel and slot of one frame, ``float64[R, H, W]``.

    Methods (:data:`MONITOR_METHODS`):

    - ``detrend`` (default): :func:`detrended_gap_score`, the smallest over the (n//2 + 1) × n
      windows holding the pixel of the largest gap about each window's local plane.
    - ``plane``: the same with one plane over the whole n × n neighbourhood.
    - ``gap``: the paper's score (§4.3), the largest gap of the n × n spatial CDF
      (:func:`spatial_gap_score`).
    - ``row``: the paper's score with each row of the neighbourhood sorted on its own.

    How the methods compare against the temporal truth, and on scan matching, is measured by
    ``benchmarks/monitor_methods.py`` (figures in the multi-return guide of the documentation).

    Raises AnalysisError for an unknown method, a bad n or frame.
    """
    if method == "detrend":
        return detrended_gap_score(stack, frame=frame, n=n)
    if method == "plane":
        return detrended_gap_score(stack, frame=frame, n=n, window_rows=n)
    if method in ("gap", "row"):
        return spatial_gap_score(stack, frame=frame, n=n, by_row=method == "row")
    raise AnalysisError(f"unknown monitor method {method!r}; choose one of {', '.join(MONITOR_METHODS)}")


@dataclass(frozen=True, eq=False)
class MonitorEvaluation:
    """The monitor scored against the temporal truth.

    Attributes:
        threshold_m: the operating threshold (flag when score > threshold).
        precision, recall: at that threshold (NaN when undefined).
        true_positive, false_positive, false_negative, true_negative: counts at that threshold.
        roc_threshold_m, roc_tpr, roc_fpr: the ROC curve, one point per distinct score
            (descending threshold), starting at (0, 0).
        auc: area under the ROC curve (NaN if only one class is present).
        n_pixels: pixels evaluated (those with a temporal return).
    """

    threshold_m: float
    precision: float
    recall: float
    true_positive: int
    false_positive: int
    false_negative: int
    true_negative: int
    roc_threshold_m: np.ndarray
    roc_tpr: np.ndarray
    roc_fpr: np.ndarray
    auc: float
    n_pixels: int

    def to_json(self) -> dict:
        return {
            "threshold_m": self.threshold_m,
            "precision": self.precision,
            "recall": self.recall,
            "true_positive": self.true_positive,
            "false_positive": self.false_positive,
            "false_negative": self.false_negative,
            "true_negative": self.true_negative,
            "auc": self.auc,
            "n_pixels": self.n_pixels,
            "roc": {"threshold_m": self.roc_threshold_m.tolist(), "tpr": self.roc_tpr.tolist(), "fpr": self.roc_fpr.tolist()},
        }


def evaluate_monitor(score: np.ndarray, truth: np.ndarray, threshold_m: float, mask: np.ndarray | None = None) -> MonitorEvaluation:
    """Precision, recall and ROC of ``score > threshold`` against boolean ``truth`` over ``mask``."""
    s = np.asarray(score, np.float64)
    t = np.asarray(truth, bool)
    m = np.ones_like(t) if mask is None else np.asarray(mask, bool)
    s, t = s[m], t[m]
    flag = s > threshold_m
    tp = int(np.count_nonzero(flag & t))
    fp = int(np.count_nonzero(flag & ~t))
    fn = int(np.count_nonzero(~flag & t))
    tn = int(np.count_nonzero(~flag & ~t))
    precision = tp / (tp + fp) if tp + fp else float("nan")
    recall = tp / (tp + fn) if tp + fn else float("nan")
    # ROC: thresholds just below each distinct score, from the highest down.
    order = np.argsort(-s, kind="stable")
    s_sorted, t_sorted = s[order], t[order]
    last_of_run = np.r_[np.flatnonzero(np.diff(s_sorted) != 0), s_sorted.size - 1] if s.size else np.zeros(0, int)
    cum_tp = np.cumsum(t_sorted)[last_of_run]
    cum_fp = np.cumsum(~t_sorted)[last_of_run]
    pos, neg = int(t.sum()), int((~t).sum())
    tpr = np.r_[0.0, cum_tp / pos] if pos else np.r_[0.0, np.full(cum_tp.size, np.nan)]
    fpr = np.r_[0.0, cum_fp / neg] if neg else np.r_[0.0, np.full(cum_fp.size, np.nan)]
    thr = np.r_[np.inf, s_sorted[last_of_run]]
    auc = float(np.sum(np.diff(fpr) * (tpr[1:] + tpr[:-1]) / 2.0)) if pos and neg else float("nan")
    return MonitorEvaluation(float(threshold_m), precision, recall, tp, fp, fn, tn, thr, tpr, fpr, auc, int(s.size))


@dataclass(frozen=True, eq=False)
class MultiReturnMap:
    """:func:`multireturn_map`'s result: the statistics, the monitor on one frame, its evaluation per slot."""

    stats: ImageStatistics
    monitor_score_m: np.ndarray  # float64[R, H, W]
    monitor_flags: np.ndarray  # bool[R, H, W]
    monitor_frame: int
    neighbourhood: int
    evaluation: list[MonitorEvaluation] = field(default_factory=list)  # one per slot
    method: str = DEFAULT_MONITOR_METHOD  # the monitor's score, one of MONITOR_METHODS

    @property
    def by_row(self) -> bool:
        """The monitor's score took each neighbourhood row on its own (``method == "row"``)."""
        return self.method == "row"

    def to_npz_dict(self) -> dict[str, np.ndarray]:
        """Arrays for ``numpy.savez`` (the file ``lidarpkt multireturn -o`` writes)."""
        s = self.stats
        out = {
            "n_samples": s.n_samples, "n_returns": s.n_returns, "nonreturn_fraction": s.nonreturn_fraction,
            "mean_m": s.mean_m, "std_m": s.std_m, "n_clusters": s.n_clusters, "gap_m": s.gap_m,
            "multi_return": s.multi_return, "gap_threshold_m": np.float64(s.gap_threshold_m),
            "return_labels": np.array(s.return_labels), "monitor_score_m": self.monitor_score_m,
            "monitor_flags": self.monitor_flags, "monitor_frame": np.int64(self.monitor_frame),
            "neighbourhood": np.int64(self.neighbourhood), "monitor_method": np.array(self.method),
            "monitor_by_row": np.bool_(self.by_row),
        }
        for i, ev in enumerate(self.evaluation):
            out[f"slot{i}_precision"] = np.float64(ev.precision)
            out[f"slot{i}_recall"] = np.float64(ev.recall)
            out[f"slot{i}_auc"] = np.float64(ev.auc)
            out[f"slot{i}_roc_threshold_m"] = ev.roc_threshold_m
            out[f"slot{i}_roc_tpr"] = ev.roc_tpr
            out[f"slot{i}_roc_fpr"] = ev.roc_fpr
        return out


def multireturn_map(
    stack: FrameStack,
    *,
    gap_m: float = DEFAULT_GAP_M,
    neighbourhood: int = 5,
    monitor_frame: int = 0,
    threshold_m: float | None = None,
    method: str | None = None,
    by_row: bool = False,
) -> MultiReturnMap:
    """The multi-return map of a scene: :func:`image_statistics`, the monitor's flags on frame
    ``monitor_frame`` (score > ``threshold_m``, default ``gap_m``: the neighbourhood shows two
    clusters), and the monitor evaluated per slot against ``n_clusters >= 2`` over the pixels
    with at least one return in the stack.

    ``method``: the monitor's score, see :func:`monitor_score` (default ``"detrend"``; ``"gap"``
    is the paper's). ``by_row=True`` is the older spelling of ``method="row"``.
    """
    if method is None:
        method = "row" if by_row else DEFAULT_MONITOR_METHOD
    elif by_row and method != "row":
        raise AnalysisError(f"by_row=True asks for method 'row', not {method!r}")
    if method not in MONITOR_METHODS:
        raise AnalysisError(f"unknown monitor method {method!r}; choose one of {', '.join(MONITOR_METHODS)}")
    stats = image_statistics(stack, gap_m=gap_m)
    score = monitor_score(stack, frame=monitor_frame, n=neighbourhood, method=method)
    thr = gap_m if threshold_m is None else float(threshold_m)
    evaluation = [
        evaluate_monitor(score[i], stats.multi_return[i], thr, mask=stats.n_returns[i] > 0) for i in range(score.shape[0])
    ]
    return MultiReturnMap(stats, score, score > thr, monitor_frame % len(stack), neighbourhood, evaluation, method)
