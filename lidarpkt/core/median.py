"""The median of a 1-D array, as ``np.median`` gives it, without its cost: the decoders ask for a median per
batch and per frame (typical azimuth steps, packet periods, rotation rates), where ``np.median``'s
generality, and its first call's import of ``numpy.ma``, cost more than the work."""

from __future__ import annotations

import numpy as np


def median(values: np.ndarray) -> float:
    """``float(np.median(values))`` of a 1-D array: the middle value, or the mean of the two middle values
    of an even count; NaN when ``values`` is empty or holds a NaN (as ``np.median``, without its warning).

    One sort: on the decoders' arrays (a few distinct steps repeated) NumPy's sort is several times faster
    than its partition."""
    s = np.sort(np.asarray(values).reshape(-1))
    n = s.size
    if n == 0 or (s.dtype.kind == "f" and np.isnan(s[-1])):
        return float("nan")
    k = n // 2
    if n % 2:
        return float(s[k])
    if s.dtype.kind == "f":  # as np.mean of the two: in the array's precision
        return float((s[k - 1] + s[k]) / 2)
    return (float(s[k - 1]) + float(s[k])) / 2.0  # integers: np.mean's float64
