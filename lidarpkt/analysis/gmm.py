"""Gaussian mixtures of a raypath's range samples (paper eqs. 7–9), and their fit to the empirical CDF.

The model is a mixture over *samples*, non-returns included, so that it can be laid over the
temporal CDF directly:

    p(r) = Σ_m w_m N(r; μ_m, σ_m²),   G(r) = Σ_m w_m Φ((r − μ_m) / σ_m),   Σ_m w_m = 1 − (non-return fraction).

Three ways to get the components:

* ``thresholds``: segment the sorted samples where the empirical CDF crosses given values
  (the paper's 0.14, 0.38, 0.68 for its ROI 4); each segment gives one component: its share
  of the samples, its mean and standard deviation.
* ``auto``: the same, with thresholds placed at the gaps in the sorted ranges wider than
  ``gap_m`` (the CDF value of the last sample before each gap).
* ``em``: expectation maximisation on the returns for 1..``max_components`` components, the
  number chosen by the Bayesian information criterion BIC = −2 ln L + (3M − 1) ln n.

The Kolmogorov–Smirnov distance ``sup_r |G(r) − F(r)|`` says how well the model follows the
empirical CDF F.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.special import erf

from lidarpkt.errors import AnalysisError

from .cdf import RangeCDF

#: Range gap (m) that separates two clusters, used by ``auto`` and by the whole-image statistics.
DEFAULT_GAP_M = 0.1
#: Smallest component standard deviation (m): above the VLP-16's 2 mm range step, so that a
#: component cannot collapse onto one repeated quantised value.
DEFAULT_MIN_SIGMA_M = 0.003

#: EM stops after this many iterations, or when the log-likelihood gains less than this share
#: (see :func:`fit_em`); the per-pixel maps of :mod:`analysis.gmm_map` use the same.
DEFAULT_EM_ITERATIONS = 300
DEFAULT_EM_TOL = 1e-6

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


@dataclass(frozen=True, eq=False)
class GaussianMixture:
    """A 1-D Gaussian mixture of ranges.

    Attributes:
        method: ``"thresholds"``, ``"auto"`` or ``"em"``.
        weights: ``float64[M]`` share of the samples (non-returns included) in each component.
        means_m, sigmas_m: ``float64[M]`` component means and standard deviations, metres, by mean.
        ks: Kolmogorov–Smirnov distance to the empirical CDF the model was fitted to.
        thresholds: ``float64[M-1]`` CDF thresholds that cut the segments (thresholds/auto), else None.
        bic: BIC of the chosen model (em), else None.
    """

    method: str
    weights: np.ndarray
    means_m: np.ndarray
    sigmas_m: np.ndarray
    ks: float
    thresholds: np.ndarray | None = None
    bic: float | None = None

    @property
    def n_components(self) -> int:
        return int(self.weights.size)

    def pdf(self, r_m: np.ndarray | float) -> np.ndarray:
        """Model density at ranges ``r_m`` (metres), in 1/m."""
        r = np.asarray(r_m, dtype=np.float64)[..., None]
        z = (r - self.means_m) / self.sigmas_m
        return np.sum(self.weights * np.exp(-0.5 * z * z - _LOG_SQRT_2PI) / self.sigmas_m, axis=-1)

    def cdf(self, r_m: np.ndarray | float) -> np.ndarray:
        """Model CDF at ranges ``r_m`` (metres); tops out at Σ weights = 1 − non-return fraction."""
        r = np.asarray(r_m, dtype=np.float64)[..., None]
        z = (r - self.means_m) / (self.sigmas_m * np.sqrt(2.0))
        return np.sum(self.weights * 0.5 * (1.0 + erf(z)), axis=-1)

    def to_json(self) -> dict:
        """``{"method", "weights", "means_m", "sigmas_m", "ks"}`` as ``analyze --json`` writes it."""
        return {
            "method": self.method,
            "weights": self.weights.tolist(),
            "means_m": self.means_m.tolist(),
            "sigmas_m": self.sigmas_m.tolist(),
            "ks": float(self.ks),
        }


def ks_distance(model: GaussianMixture, cdf: RangeCDF) -> float:
    """``sup_r |G(r) − F(r)|`` between a model CDF G and an empirical CDF F (both over the same samples).

    F is a step function, so the supremum is reached at a sample, on one side of its step.
    """
    if cdf.n_returns == 0:
        return float(np.sum(model.weights)) if model.weights.size else 0.0
    values, counts = np.unique(cdf.range_m, return_counts=True)
    after = np.cumsum(counts) / cdf.n_samples  # F at each distinct value
    before = np.concatenate(([0.0], after[:-1]))  # F just below it
    g = model.cdf(values)
    return float(max(np.max(np.abs(after - g)), np.max(np.abs(before - g))))


def _finish(method: str, cdf: RangeCDF, w, mu, sigma, **extra) -> GaussianMixture:
    order = np.argsort(mu, kind="stable")
    model = GaussianMixture(method, np.asarray(w, float)[order], np.asarray(mu, float)[order],
                            np.asarray(sigma, float)[order], 0.0, **extra)
    return GaussianMixture(**{**model.__dict__, "ks": ks_distance(model, cdf)})


def fit_thresholds(
    cdf: RangeCDF, thresholds: Sequence[float] | np.ndarray, *, min_sigma_m: float = DEFAULT_MIN_SIGMA_M, method: str = "thresholds"
) -> GaussianMixture:
    """Mixture from segmenting the sorted samples at CDF thresholds (eq. 7).

    Sample i (sorted) goes to segment #{t in thresholds : t < F_i}; empty segments are dropped.
    Raises AnalysisError if the thresholds are not increasing values in (0, 1) or there is no return.
    """
    t = np.asarray(list(thresholds), dtype=np.float64)
    if t.ndim != 1 or np.any((t <= 0) | (t >= 1)) or np.any(np.diff(t) <= 0):
        raise AnalysisError(f"GMM thresholds {t.tolist()} must be increasing CDF values strictly between 0 and 1 (e.g. 0.14,0.38,0.68)")
    if cdf.n_returns == 0:
        raise AnalysisError("no returns on this raypath: nothing to fit a Gaussian mixture to")
    seg = np.searchsorted(t, cdf.F, side="left")
    counts = np.bincount(seg, minlength=t.size + 1).astype(np.float64)
    used = counts > 0
    sums = np.bincount(seg, weights=cdf.range_m, minlength=t.size + 1)
    mu = np.divide(sums, counts, out=np.zeros_like(sums), where=used)
    sq = np.bincount(seg, weights=(cdf.range_m - mu[seg]) ** 2, minlength=t.size + 1)
    sigma = np.sqrt(np.divide(sq, counts, out=np.zeros_like(sq), where=used))
    sigma = np.maximum(sigma, min_sigma_m)
    return _finish(method, cdf, counts[used] / cdf.n_samples, mu[used], sigma[used], thresholds=t)


def gap_thresholds(cdf: RangeCDF, *, gap_m: float = DEFAULT_GAP_M) -> np.ndarray:
    """CDF thresholds at the gaps wider than ``gap_m`` between consecutive sorted ranges:
    the CDF value of the last sample before each gap. ``float64[G]``."""
    if gap_m <= 0:
        raise AnalysisError(f"gap {gap_m} m must be positive")
    gaps = np.flatnonzero(np.diff(cdf.range_m) > gap_m)
    return cdf.F[gaps]


def fit_auto(cdf: RangeCDF, *, gap_m: float = DEFAULT_GAP_M, min_sigma_m: float = DEFAULT_MIN_SIGMA_M) -> GaussianMixture:
    """Mixture from segmenting at the gaps wider than ``gap_m`` (see :func:`gap_thresholds`)."""
    return fit_thresholds(cdf, gap_thresholds(cdf, gap_m=gap_m), min_sigma_m=min_sigma_m, method="auto")


def _logsumexp_rows(a: np.ndarray) -> np.ndarray:
    """log Σ_j exp(a[i, j]) per row (plain NumPy: scipy's version costs more than the EM step here)."""
    top = a.max(axis=1)
    return top + np.log(np.exp(a - top[:, None]).sum(axis=1))


def _em(x: np.ndarray, mu: np.ndarray, sigma: np.ndarray, w: np.ndarray, min_sigma: float, iters: int, tol: float):
    n = x.size
    prev = -np.inf
    for _ in range(iters):  # iterations, not samples: each step is vectorised over samples × components
        z = (x[:, None] - mu) / sigma
        logp = np.log(w) - 0.5 * z * z - np.log(sigma) - _LOG_SQRT_2PI  # [n, M]
        norm = _logsumexp_rows(logp)
        ll = float(norm.sum())
        resp = np.exp(logp - norm[:, None])
        nk = resp.sum(axis=0)
        if np.any(nk < 1e-9):  # a component lost all its samples: this start failed
            return None
        w = nk / n
        mu = (resp * x[:, None]).sum(axis=0) / nk
        sigma = np.sqrt(np.maximum((resp * (x[:, None] - mu) ** 2).sum(axis=0) / nk, min_sigma**2))
        if ll - prev <= tol * max(1.0, abs(ll)):
            break
        prev = ll
    z = (x[:, None] - mu) / sigma
    ll = float(_logsumexp_rows(np.log(w) - 0.5 * z * z - np.log(sigma) - _LOG_SQRT_2PI).sum())
    return ll, w, mu, sigma


def fit_em(
    cdf: RangeCDF,
    *,
    max_components: int = 4,
    min_sigma_m: float = DEFAULT_MIN_SIGMA_M,
    min_separation_m: float = DEFAULT_GAP_M,
    iterations: int = DEFAULT_EM_ITERATIONS,
    tol: float = DEFAULT_EM_TOL,
) -> GaussianMixture:
    """Mixture by expectation maximisation on the returns, the number of components (1..max_components)
    chosen by BIC (eqs. 8–9). Deterministic: each M starts from the M − 1 widest gaps and from
    the quantiles of the samples, and the better likelihood wins.

    A fit whose component means lie closer than ``min_separation_m`` (the cluster gap of the
    multi-return map) is not a candidate: with a few dozen samples BIC alone sometimes splits
    one surface's Gaussian noise into two components a couple of centimetres apart.

    EM stops when the log-likelihood gains less than ``tol`` (relative): at 1e-6 the means are
    within 0.02 mm of those at 1e-9 (measured on the generated VLP-16 and OS1-64 scenes, 300
    raypaths with spread), a hundredth of the range step, for a third of the iterations.

    Raises AnalysisError if there is no return or max_components < 1.
    """
    if max_components < 1:
        raise AnalysisError(f"max_components {max_components} must be >= 1")
    if cdf.n_returns == 0:
        raise AnalysisError("no returns on this raypath: nothing to fit a Gaussian mixture to")
    x = cdf.range_m
    n = x.size
    return_fraction = n / cdf.n_samples
    best: tuple[float, np.ndarray, np.ndarray, np.ndarray] | None = None  # (BIC, weights, means, sigmas)
    spread = max(float(np.std(x)), min_sigma_m)
    for m in range(1, min(max_components, np.unique(x).size) + 1):
        starts = []
        if m == 1:
            starts.append(np.array([x.mean()]))
        else:
            # the widest gaps; among equal gaps the first (a stable order, which the per-pixel
            # maps of analysis.gmm_map reproduce)
            cuts = np.sort(np.argsort(-np.diff(x), kind="stable")[: m - 1]) + 1
            starts.append(np.array([seg.mean() for seg in np.split(x, cuts)]))
            starts.append(np.quantile(x, (np.arange(m) + 0.5) / m))
        fits = []
        for mu0 in starts:
            sigma0 = np.full(m, spread / m)
            fit = _em(x, mu0.astype(float), np.maximum(sigma0, min_sigma_m), np.full(m, 1.0 / m), min_sigma_m, iterations, tol)
            if fit is not None:
                fits.append(fit)
        if not fits:
            continue
        ll, w, mu, sigma = max(fits, key=lambda f: f[0])
        if m > 1 and np.min(np.diff(np.sort(mu))) < min_separation_m:
            continue
        bic = -2.0 * ll + (3 * m - 1) * np.log(n)
        if best is None or bic < best[0]:
            best = (bic, w, mu, sigma)
    if best is None:  # m = 1 always converges
        raise AnalysisError(f"EM found no Gaussian mixture of {n} returns")
    bic, w, mu, sigma = best
    return _finish("em", cdf, w * return_fraction, mu, sigma, bic=float(bic))


def parse_method(method: str | Sequence[float] | np.ndarray) -> str | np.ndarray:
    """``"em"``/``"auto"``, or CDF thresholds (a sequence or a string like ``"0.14,0.38,0.68"``)
    checked to be increasing values in (0, 1). Raises AnalysisError otherwise."""
    if isinstance(method, str):
        if method in ("em", "auto"):
            return method
        try:
            method = [float(v) for v in method.split(",") if v.strip()]
        except ValueError:
            raise AnalysisError(f"--gmm {method!r}: expected em, auto, or CDF thresholds like 0.14,0.38,0.68") from None
        if not method:
            raise AnalysisError("--gmm: give em, auto, or at least one CDF threshold")
    t = np.asarray(list(method), dtype=np.float64)
    if t.ndim != 1 or np.any((t <= 0) | (t >= 1)) or np.any(np.diff(t) <= 0):
        raise AnalysisError(f"GMM thresholds {t.tolist()} must be increasing CDF values strictly between 0 and 1 (e.g. 0.14,0.38,0.68)")
    return t


def fit_gmm(cdf: RangeCDF, method: str | Sequence[float] | np.ndarray = "em", **options) -> GaussianMixture:
    """``method``: ``"em"``, ``"auto"``, a sequence of CDF thresholds, or a string of them
    (``"0.14,0.38,0.68"``, as ``--gmm`` takes it). Options go to the fitting function."""
    method = parse_method(method)
    if isinstance(method, str):
        return fit_em(cdf, **options) if method == "em" else fit_auto(cdf, **options)
    return fit_thresholds(cdf, method, **options)
