"""Probabilistic raypath maps: a Gaussian mixture of every pixel's ranges over a stack .

The paper cites "explicitly probabilistic maps, which inherently represent each raypath as a
probabilistic CDF". :func:`fit_gmm_map` fits, for every pixel and return at once, the mixture
:func:`analysis.gmm.fit_em` fits to one raypath: EM on the returns for 1..L components from the
same two starts (the widest gaps, the quantiles), the better likelihood of the two, fits whose
means lie closer than the cluster gap rejected, the number of components by BIC. Vectorised in
NumPy over all pixels (the pixels still iterating, each EM step for all of them at once); a
number of components m is not tried for a pixel whose returns span less than (m − 1) × the
cluster gap, which no accepted fit could have anyway (EM means lie within the samples).

Files (:meth:`GmmMap.save`, :func:`load_gmm_map`): NPZ (arrays as below) or Parquet (one row per
pixel and return: ``return``, ``row``, ``col``, ``n_samples``, ``n_returns``, ``n_components``,
``weight_0..``, ``mean_m_0..``, ``sigma_m_0..``, and the settings in the schema metadata).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidarpkt.errors import AnalysisError
from lidarpkt.core.sequence import FrameStack

from .gmm import DEFAULT_EM_ITERATIONS, DEFAULT_EM_TOL, DEFAULT_GAP_M, DEFAULT_MIN_SIGMA_M
from .returns import sample_mask

_LOG_SQRT_2PI = 0.5 * np.log(2.0 * np.pi)


@dataclass(frozen=True, eq=False)
class GmmMap:
    """A mixture per pixel and return.

    Attributes:
        weights: ``float64[R, L, H, W]`` share of the samples (non-returns included) of each
            component, components by mean; 0 for unused components.
        means_m, sigmas_m: ``float64[R, L, H, W]``, metres; NaN for unused components.
        n_components: ``int64[R, H, W]`` (0 without a return).
        n_samples, n_returns: ``int64[R, H, W]``.
        return_labels: label of each return.
        max_components, min_separation_m, min_sigma_m: the fit's settings.
    """

    weights: np.ndarray
    means_m: np.ndarray
    sigmas_m: np.ndarray
    n_components: np.ndarray
    n_samples: np.ndarray
    n_returns: np.ndarray
    return_labels: tuple[str, ...]
    max_components: int
    min_separation_m: float
    min_sigma_m: float

    def map_range_mm(self, stack: FrameStack | None = None, ret: int | str = 0, min_weight: float = 0.05) -> np.ndarray:
        """``uint32[L, H, W]`` the component means of return ``ret`` in mm (0 where a component is
        unused or weighs less than ``min_weight``): the map :func:`analysis.registration.registration_impact`
        registers frames to. ``stack`` checks the image size. Raises AnalysisError."""
        i = ret if isinstance(ret, int) else (self.return_labels.index(ret) if ret in self.return_labels else -1)
        if not 0 <= i < len(self.return_labels):
            raise AnalysisError(f"the map has returns {list(self.return_labels)}, not {ret!r}")
        if stack is not None and stack.range_mm.shape[2:] != self.weights.shape[2:]:
            raise AnalysisError(f"the map is {self.weights.shape[2]}x{self.weights.shape[3]} pixels, the capture "
                                f"{stack.range_mm.shape[2]}x{stack.range_mm.shape[3]}: use a map of the same sensor")
        use = (self.weights[i] >= min_weight) & np.isfinite(self.means_m[i])
        return np.where(use, np.rint(np.nan_to_num(self.means_m[i]) * 1000.0), 0).astype(np.uint32)

    def save(self, path: str | Path) -> Path:
        """Write NPZ, or Parquet when the suffix is ``.parquet``. Raises AnalysisError."""
        path = Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            if path.suffix == ".parquet":
                _write_parquet(self, path)
            else:
                np.savez_compressed(path, **self._arrays())
        except OSError as exc:
            raise AnalysisError(f"--gmm-map {path}: cannot write ({exc.strerror or exc}); choose a writable path") from None
        return path

    def _arrays(self) -> dict:
        return {
            "weights": self.weights, "means_m": self.means_m, "sigmas_m": self.sigmas_m,
            "n_components": self.n_components, "n_samples": self.n_samples, "n_returns": self.n_returns,
            "return_labels": np.array(self.return_labels), "max_components": np.int64(self.max_components),
            "min_separation_m": np.float64(self.min_separation_m), "min_sigma_m": np.float64(self.min_sigma_m),
        }


def load_gmm_map(path: str | Path) -> GmmMap:
    """Read a map written by :meth:`GmmMap.save` (NPZ or Parquet). Raises AnalysisError."""
    path = Path(path)
    if not path.exists():
        raise AnalysisError(f"{path}: no such file")
    try:
        if path.suffix == ".parquet":
            return _read_parquet(path)
        with np.load(path) as z:
            return GmmMap(z["weights"], z["means_m"], z["sigmas_m"], z["n_components"], z["n_samples"], z["n_returns"],
                          tuple(str(s) for s in z["return_labels"]), int(z["max_components"]),
                          float(z["min_separation_m"]), float(z["min_sigma_m"]))
    except (KeyError, ValueError, OSError) as exc:
        raise AnalysisError(f"{path}: not a GMM map written by multireturn --gmm-map ({exc})") from None


def _write_parquet(m: GmmMap, path: Path) -> None:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:  # pragma: no cover - depends on the install
        raise AnalysisError("a Parquet GMM map needs pyarrow: pip install pyarrow, or write .npz") from None
    r, components, h, w = m.weights.shape
    ret, row, col = np.meshgrid(np.arange(r), np.arange(h), np.arange(w), indexing="ij")
    cols = {
        "return": pa.DictionaryArray.from_arrays(ret.ravel().astype(np.int32), pa.array(list(m.return_labels))),
        "row": pa.array(row.ravel().astype(np.int32)), "col": pa.array(col.ravel().astype(np.int32)),
        "n_samples": pa.array(m.n_samples.ravel()), "n_returns": pa.array(m.n_returns.ravel()),
        "n_components": pa.array(m.n_components.ravel()),
    }
    for name, arr in (("weight", m.weights), ("mean_m", m.means_m), ("sigma_m", m.sigmas_m)):
        for c in range(components):
            cols[f"{name}_{c}"] = pa.array(arr[:, c].ravel())
    meta = {"lidarpkt.gmm_map": json.dumps({
        "shape": [r, components, h, w], "return_labels": list(m.return_labels), "max_components": m.max_components,
        "min_separation_m": m.min_separation_m, "min_sigma_m": m.min_sigma_m})}
    pq.write_table(pa.table(cols).replace_schema_metadata(meta), path)


def _read_parquet(path: Path) -> GmmMap:
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    meta = json.loads((table.schema.metadata or {}).get(b"lidarpkt.gmm_map", b"null"))
    if not meta:
        raise AnalysisError(f"{path}: a Parquet file without lidarpkt's GMM map metadata")
    r, components, h, w = meta["shape"]

    def grid(name):
        return table.column(name).to_numpy().reshape(r, h, w)

    stacked = {n: np.stack([grid(f"{n}_{c}") for c in range(components)], axis=1) for n in ("weight", "mean_m", "sigma_m")}
    return GmmMap(stacked["weight"], stacked["mean_m"], stacked["sigma_m"], grid("n_components"), grid("n_samples"),
                  grid("n_returns"), tuple(meta["return_labels"]), int(meta["max_components"]),
                  float(meta["min_separation_m"]), float(meta["min_sigma_m"]))


def fit_gmm_map(
    stack: FrameStack,
    *,
    max_components: int = 4,
    min_separation_m: float = DEFAULT_GAP_M,
    min_sigma_m: float = DEFAULT_MIN_SIGMA_M,
    iterations: int = DEFAULT_EM_ITERATIONS,
    tol: float = DEFAULT_EM_TOL,
) -> GmmMap:
    """The mixture of every pixel and return slot of ``stack`` (module docstring), equal to
    :func:`analysis.gmm.fit_em` on each pixel's temporal CDF. Raises AnalysisError for bad settings."""
    if max_components < 1:
        raise AnalysisError(f"max_components {max_components} must be >= 1")
    if not min_separation_m > 0 or not min_sigma_m > 0:
        raise AnalysisError("the cluster gap and the smallest sigma must be positive")
    k, r, h, w = stack.range_mm.shape
    out_w = np.zeros((r, max_components, h, w))
    out_mu = np.full((r, max_components, h, w), np.nan)
    out_s = np.full((r, max_components, h, w), np.nan)
    n_comp = np.zeros((r, h, w), np.int64)
    mask = sample_mask(stack)
    n_samples = mask.sum(axis=0).astype(np.int64)
    n_returns = ((stack.range_mm > 0) & mask).sum(axis=0).astype(np.int64)
    for slot in range(r):
        present = (stack.range_mm[:, slot] > 0) & mask[:, slot]  # [K, H, W]
        x = np.where(present, stack.range_mm[:, slot], np.uint32(0xFFFFFFFF)).reshape(k, -1).T  # [P, K]
        x.sort(axis=1)  # returns first, ascending
        pix = np.flatnonzero(n_returns[slot].ravel() > 0)
        n = n_returns[slot].ravel()[pix]
        xs = np.where(np.arange(k)[None, :] < n[:, None], x[pix].astype(np.float64) / 1000.0, 0.0)
        w_, mu_, s_, m_ = _fit_pixels(xs, n, max_components, min_separation_m, min_sigma_m, iterations, tol)
        frac = n / n_samples[slot].ravel()[pix]
        flat = (slot, slice(None))
        ow, omu, osg = (a[flat].reshape(max_components, -1) for a in (out_w, out_mu, out_s))
        ow[:, pix], omu[:, pix], osg[:, pix] = (w_ * frac[:, None]).T, mu_.T, s_.T
        n_comp[slot].reshape(-1)[pix] = m_
    return GmmMap(out_w, out_mu, out_s, n_comp, n_samples, n_returns, tuple(stack.return_labels), max_components,
                  float(min_separation_m), float(min_sigma_m))


def _fit_pixels(x, n, max_m, min_sep, min_sigma, iters, tol):
    """Per pixel (rows of ``x [P, K]``, the first ``n[p]`` sorted returns in m): the BIC-chosen fit.
    Returns weights (of the returns), means, sigmas ``[P, max_m]`` (by mean, NaN/0 unused) and M ``[P]``."""
    p, k = x.shape
    ok = np.arange(k)[None, :] < n[:, None]
    big = np.where(ok, x, np.inf)
    uniq = 1 + np.sum(ok[:, 1:] & (np.diff(np.where(ok, x, np.nan), axis=1) != 0), axis=1)
    span = np.where(ok, x, -np.inf).max(axis=1) - big.min(axis=1)
    mean = np.where(ok, x, 0.0).sum(axis=1) / n
    spread = np.maximum(np.sqrt(np.where(ok, (x - mean[:, None]) ** 2, 0.0).sum(axis=1) / n), min_sigma)
    best_bic = np.full(p, np.inf)
    best_w, best_mu, best_s = np.zeros((p, max_m)), np.full((p, max_m), np.nan), np.full((p, max_m), np.nan)
    best_m = np.zeros(p, np.int64)
    for m in range(1, max_m + 1):
        # m components: only where the returns have m distinct values and span the gaps m means need
        todo = np.flatnonzero((uniq >= m) & ((m == 1) | (span >= (m - 1) * min_sep)))
        if not todo.size:
            continue
        xt, okt, nt = x[todo], ok[todo], n[todo]
        starts = [mean[todo, None]] if m == 1 else [_gap_start(xt, nt, m), _quantile_start(xt, nt, m)]
        fit_ll = np.full(todo.size, -np.inf)
        fit = [np.zeros((todo.size, m)) for _ in range(3)]
        for mu0 in starts:
            s0 = np.maximum(np.repeat((spread[todo] / m)[:, None], m, axis=1), min_sigma)
            ll, w_, mu_, s_ = _em_batch(xt, okt, nt, mu0, s0, np.full((todo.size, m), 1.0 / m), min_sigma, iters, tol)
            better = ll > fit_ll  # the first start wins ties, like max() in fit_em
            fit_ll = np.where(better, ll, fit_ll)
            for dst, src in zip(fit, (w_, mu_, s_)):
                dst[better] = src[better]
        w_, mu_, s_ = fit
        ok_fit = np.isfinite(fit_ll)
        if m > 1:
            ok_fit &= np.min(np.diff(np.sort(mu_, axis=1), axis=1), axis=1) >= min_sep
        bic = -2.0 * fit_ll + (3 * m - 1) * np.log(nt)
        win = ok_fit & (bic < best_bic[todo])
        idx = todo[win]
        order = np.argsort(mu_[win], axis=1, kind="stable")
        best_bic[idx] = bic[win]
        best_m[idx] = m
        best_w[idx], best_mu[idx], best_s[idx] = 0.0, np.nan, np.nan
        best_w[idx, :m] = np.take_along_axis(w_[win], order, 1)
        best_mu[idx, :m] = np.take_along_axis(mu_[win], order, 1)
        best_s[idx, :m] = np.take_along_axis(s_[win], order, 1)
    return best_w, best_mu, best_s, best_m


def _gap_start(x, n, m):
    """Means of the segments between the m − 1 widest gaps (the first of equal gaps)."""
    k = x.shape[1]
    d = np.diff(x, axis=1)
    d = np.where(np.arange(1, k)[None, :] < n[:, None], d, -np.inf)  # gaps between returns only
    cuts = np.argsort(-d, axis=1, kind="stable")[:, : m - 1] + 1
    seg = np.zeros(x.shape, np.int64)
    np.put_along_axis(seg, cuts, 1, axis=1)
    seg = np.cumsum(seg, axis=1)
    ok = np.arange(k)[None, :] < n[:, None]
    onehot = (seg[:, :, None] == np.arange(m)[None, None, :]) & ok[:, :, None]
    return (onehot * x[:, :, None]).sum(axis=1) / onehot.sum(axis=1)


def _quantile_start(x, n, m):
    """np.quantile(x[:n], (i + 0.5) / m) per pixel (linear interpolation)."""
    q = (np.arange(m) + 0.5) / m
    pos = q[None, :] * (n[:, None] - 1)
    lo = np.floor(pos).astype(np.int64)
    hi = np.minimum(lo + 1, n[:, None] - 1)
    frac = pos - lo
    a, b = np.take_along_axis(x, lo, 1), np.take_along_axis(x, hi, 1)
    return a + (b - a) * frac


def _em_batch(x, ok, n, mu, sigma, w, min_sigma, iters, tol):
    """EM of :func:`analysis.gmm._em` for many pixels at once; each pixel stops on its own.
    Returns (log-likelihood ``[P]``, -inf where a start failed; w, mu, sigma ``[P, M]``).

    Arrays are laid out ``[pixels, components, samples]`` so that the sums over samples run on
    contiguous memory; the pixels still iterating are gathered once per step."""
    mu, sigma, w = mu.astype(float).copy(), sigma.astype(float).copy(), w.astype(float).copy()
    p = x.shape[0]
    failed = np.zeros(p, bool)
    prev = np.full(p, -np.inf)
    active = np.arange(p)
    xa, oka, na = x[:, None, :], ok.astype(float), n.astype(float)
    for _ in range(iters):  # iterations; each one vectorised over the pixels still iterating
        if not active.size:
            break
        ma, sa = mu[active][:, :, None], sigma[active][:, :, None]
        z = (xa - ma) / sa
        logp = (np.log(w[active]) - np.log(sigma[active]) - _LOG_SQRT_2PI)[:, :, None] - 0.5 * z * z  # [A, M, K]
        top = logp.max(axis=1, keepdims=True)
        e = np.exp(logp - top)
        tot = e.sum(axis=1, keepdims=True)
        ll = ((top[:, 0] + np.log(tot[:, 0])) * oka).sum(axis=1)
        resp = e * (oka[:, None, :] / tot)
        nk = resp.sum(axis=2)
        bad = np.any(nk < 1e-9, axis=1)
        failed[active[bad]] = True
        nk = np.where(bad[:, None], 1.0, nk)
        new_mu = (resp * xa).sum(axis=2) / nk
        dev = xa - new_mu[:, :, None]
        new_s = np.sqrt(np.maximum((resp * dev * dev).sum(axis=2) / nk, min_sigma**2))
        good = ~bad
        ga = active[good]
        w[ga], mu[ga], sigma[ga] = nk[good] / na[good][:, None], new_mu[good], new_s[good]
        conv = ll - prev[active] <= tol * np.maximum(1.0, np.abs(ll))
        prev[active] = ll
        keep = good & ~conv
        active, xa, oka, na = active[keep], xa[keep], oka[keep], na[keep]
    z = (x[:, None, :] - mu[:, :, None]) / sigma[:, :, None]
    logp = (np.log(w) - np.log(sigma) - _LOG_SQRT_2PI)[:, :, None] - 0.5 * z * z
    top = logp.max(axis=1)
    ll = np.where(ok, top + np.log(np.exp(logp - top[:, None, :]).sum(axis=1)), 0.0).sum(axis=1)
    return np.where(failed, -np.inf, ll), w, mu, sigma
