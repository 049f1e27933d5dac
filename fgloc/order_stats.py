"""Order statistics without numpy's per-call overhead or copies: the median of an array,
partitioned in place, and the linear-interpolation quantile of a short list. Both give the
same floats as ``np.median`` / ``np.quantile`` (the tracker calls them per track and frame,
where numpy's calls cost 10-25 us each; the ALS reader on arrays of millions of heights)."""

from __future__ import annotations

import math

import numpy as np


def median_inplace(a: np.ndarray) -> float:
    """Median of a 1-D array (the middle value, or the mean of the middle two), partitioning
    it in place (no sorted copy of a large array)."""
    n = a.size
    k = n // 2
    a.partition(k)
    if n % 2:
        return float(a[k])
    return 0.5 * (float(a[k]) + float(a[:k].max()))


def linear_quantile(values: list[float], q: float) -> float:
    """The ``q`` (0..1) quantile of a short list of finite ``values`` with linear
    interpolation: the same number as ``np.quantile(values, q)`` (its default method, the
    same floating-point operations)."""
    s = sorted(values)
    at = (len(s) - 1) * q
    lo = math.floor(at)
    a, b = s[lo], s[min(lo + 1, len(s) - 1)]
    gamma, diff = at - lo, b - a
    return b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma
