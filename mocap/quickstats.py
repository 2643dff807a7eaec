"""Statistics of short 1-D arrays for per-frame and per-link hot paths, without numpy's per-call overhead."""

from __future__ import annotations

import numpy as np

__all__ = ["quick_median"]


def quick_median(values: np.ndarray) -> float:
    """``np.median`` of a short 1-D array (the mean of the middle two), the same number in ~1 us against ~10 us
    (one sort, none of np.median's argument handling)."""
    s = np.sort(values)
    return float(0.5 * (s[(s.size - 1) // 2] + s[s.size // 2]))
