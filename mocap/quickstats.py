"""Statistics of short 1-D arrays for per-frame and per-link hot paths, without numpy's per-call overhead."""

from __future__ import annotations

import numpy as np

__all__ = ["nanmedian_columns", "quick_median"]


def quick_median(values: np.ndarray) -> float:
    """``np.median`` of a short 1-D array (the mean of the middle two), the same number in ~1 us against ~10 us
    (one sort, none of np.median's argument handling)."""
    s = np.sort(values)
    return float(0.5 * (s[(s.size - 1) // 2] + s[s.size // 2]))


def nanmedian_columns(values: np.ndarray) -> np.ndarray:
    """``np.nanmedian(values, axis=0)`` of an (n, R) array: (R,), NaN where a column has no finite value; one sort
    (NaNs sort last), without the masked arrays np.nanmedian takes for small inputs (~10x faster at n ~ 100)."""
    if len(values) == 0:
        return np.full(values.shape[1], np.nan)
    s = np.sort(values, axis=0)
    count = np.isfinite(values).sum(axis=0)  # (R,)
    lo, hi = np.maximum(count - 1, 0) // 2, count // 2
    columns = np.arange(values.shape[1])
    median = 0.5 * (s[lo, columns] + s[hi, columns])
    return np.where(count > 0, median, np.nan)
