"""Statistics of short arrays for hot paths: the same numbers as numpy's."""

from __future__ import annotations

import numpy as np

from mocap.quickstats import quick_median


def test_short_median_is_numpys():
    rng = np.random.default_rng(2)
    for n in range(1, 9):
        v = rng.uniform(0.0, 0.3, n)
        assert quick_median(v) == float(np.median(v))
