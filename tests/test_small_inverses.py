"""Closed-form 2x2 and 3x3 inverses against LAPACK (np.linalg.inv)."""

from __future__ import annotations

import numpy as np

from mocap.geometry import inv2x2, inv3x3


def test_closed_form_inverses_match_lapack_on_covariance_like_matrices():
    rng = np.random.default_rng(5)
    for d, inv in ((2, inv2x2), (3, inv3x3)):
        A = rng.normal(size=(4, 7, d, d))
        S = A @ np.swapaxes(A, -1, -2) * rng.uniform(1e-8, 1e6, size=(4, 7, 1, 1)) + 1e-3 * np.eye(d)  # SPD
        N = rng.normal(size=(5, d, d))  # general, non-symmetric
        for M in (S, N):
            got, ref = inv(M), np.linalg.inv(M)
            assert got.shape == M.shape
            np.testing.assert_allclose(got, ref, rtol=1e-9, atol=0)
            np.testing.assert_allclose(M @ got, np.broadcast_to(np.eye(d), M.shape), atol=1e-9)


def test_inv3x3_of_a_transposed_view_and_a_singular_matrix():
    A = np.arange(18.0).reshape(2, 3, 3) ** 1.5
    view = A.transpose(0, 2, 1)  # not contiguous
    np.testing.assert_allclose(inv3x3(view), np.linalg.inv(view), rtol=1e-9)
    with np.errstate(divide="ignore", invalid="ignore"):
        assert not np.isfinite(inv3x3(np.ones((1, 3, 3)))).all()  # no exception, no finite garbage
