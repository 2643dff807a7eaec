"""Statistics of short arrays for hot paths: the same numbers as numpy's."""

from __future__ import annotations

import warnings

import numpy as np

from mocap.quickstats import nanmedian_columns, quick_median


def test_short_median_is_numpys():
    rng = np.random.default_rng(2)
    for n in range(1, 9):
        v = rng.uniform(0.0, 0.3, n)
        assert quick_median(v) == float(np.median(v))


def test_column_nanmedian_is_numpys_with_empty_and_unseen_columns():
    rng = np.random.default_rng(4)
    for n in (0, 1, 2, 7, 120):
        v = rng.uniform(0.0, 0.3, (n, 6))
        v[rng.random(v.shape) < 0.4] = np.nan
        v[:, 0] = np.nan  # a column never seen
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            expected = np.nanmedian(v, axis=0) if n else np.full(6, np.nan)
        np.testing.assert_array_equal(nanmedian_columns(v), expected)
