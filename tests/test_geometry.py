"""Epipolar geometry and triangulation against OpenCV and invariants."""

from __future__ import annotations

import cv2
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from mocap.geometry import (
    epipolar_distance_matrix,
    fundamental_from_cameras,
    inv2x2,
    project_ideal,
    reprojection_jacobians,
    triangulate_dlt,
    triangulate_weighted,
)
from tests.conftest import ring_rig

RIG = ring_rig()


def _ideal(rig, X):
    return np.stack([c.undistort(c.project(X)) for c in rig])


@settings(max_examples=50, deadline=None)
@given(X=arrays(np.float64, (20, 3), elements=st.floats(-1.0, 1.0)), i=st.integers(0, 5), j=st.integers(0, 5))
def test_fundamental_epipolar_constraint(X, i, j):
    if i == j:
        return
    X = X + [0.0, 0.0, 1.0]
    F = fundamental_from_cameras(RIG[i], RIG[j])
    u1, u2 = RIG[i].undistort(RIG[i].project(X)), RIG[j].undistort(RIG[j].project(X))
    assert np.linalg.matrix_rank(F, tol=1e-9) == 2
    d = np.diag(epipolar_distance_matrix(F, u1, u2))
    assert np.all(d < 1e-6)


def test_fundamental_matches_opencv_estimate():
    rng = np.random.default_rng(3)
    X = rng.uniform(-1, 1, (100, 3)) + [0, 0, 1]
    u1, u2 = RIG[0].undistort(RIG[0].project(X)), RIG[1].undistort(RIG[1].project(X))
    F_cv, _ = cv2.findFundamentalMat(u1, u2, cv2.FM_8POINT)
    F = fundamental_from_cameras(RIG[0], RIG[1])
    F_cv = F_cv / np.linalg.norm(F_cv) * np.sign(F_cv.ravel() @ F.ravel())
    np.testing.assert_allclose(F, F_cv, atol=1e-6)


def test_dlt_matches_opencv_and_truth():
    rng = np.random.default_rng(4)
    X = rng.uniform(-1, 1, (200, 3)) + [0, 0, 1]
    uv = _ideal(RIG, X)
    P = RIG.projection_matrices()
    got = triangulate_dlt(P[:2], uv[:2])
    ref = cv2.triangulatePoints(P[0], P[1], uv[0].T, uv[1].T)
    np.testing.assert_allclose(got, (ref[:3] / ref[3]).T, atol=1e-9)
    np.testing.assert_allclose(triangulate_dlt(P, uv), X, atol=1e-9)


def test_dlt_with_missing_views():
    X = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, 1.5], [-0.3, 0.2, 0.4]])
    uv = _ideal(RIG, X)
    uv[:5, 1] = np.nan  # point 1 seen by one camera only
    uv[:4, 2] = np.nan  # point 2 seen by two cameras
    got = triangulate_dlt(RIG.projection_matrices(), uv)
    np.testing.assert_allclose(got[[0, 2]], X[[0, 2]], atol=1e-9)
    assert np.isnan(got[1]).all()


def test_weighted_triangulation_covariance_is_calibrated():
    """The empirical scatter of the estimate matches its predicted covariance."""
    rng = np.random.default_rng(5)
    X = np.array([[0.2, -0.1, 1.2]])
    P = RIG.projection_matrices()
    clean = _ideal(RIG, X)
    sigmas = np.array([0.1, 0.1, 0.3, 0.3, 0.2, 0.5])
    cov2 = (sigmas**2)[:, None, None, None] * np.eye(2)
    trials = 2000
    noisy = clean[:, None, 0, :] + rng.normal(size=(6, trials, 2)) * sigmas[:, None, None]
    est, cov, rms = triangulate_weighted(P, noisy, np.broadcast_to(cov2, (6, trials, 2, 2)))
    emp = np.cov((est - X).T)
    np.testing.assert_allclose(np.diag(emp), np.diag(cov[0]), rtol=0.12)
    assert np.linalg.norm(est.mean(axis=0) - X[0]) < 3e-5
    # Weighting beats the unweighted DLT when cameras differ in noise.
    dlt = triangulate_dlt(P, noisy)
    assert ((est - X) ** 2).sum(1).mean() < ((dlt - X) ** 2).sum(1).mean()
    assert np.all(rms > 0)


def test_weighted_triangulation_of_views_with_no_information_is_nan_not_an_error():
    """Two views, one with a covariance of 1e24 px^2 (a centroid that carries nothing): the depth is undetermined.
    The point is NaN, its neighbour in the batch is unaffected, and nothing raises."""
    X = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, 1.5]])
    uv = _ideal(RIG, X)
    uv[2:, :] = np.nan  # both points seen by cameras 0 and 1 only
    cov = np.broadcast_to(np.eye(2) * 1e-4, (6, 2, 2, 2)).copy()
    cov[1, 0] = np.eye(2) * 1e24
    got, cov3, rms = triangulate_weighted(RIG.projection_matrices(), uv, cov)
    assert np.isnan(got[0]).all() and np.isnan(cov3[0]).all() and np.isnan(rms[0])
    np.testing.assert_allclose(got[1], X[1], atol=1e-9)


def test_reprojection_jacobians_match_opencv_and_finite_differences():
    """Ideal-pixel projections equal cv2.projectPoints without distortion, depths the camera-frame z; Jacobians
    equal central differences."""
    rng = np.random.default_rng(8)
    X = rng.uniform(-0.8, 0.8, size=(25, 3)) + [0.0, 0.0, 1.0]
    P = RIG.projection_matrices()
    uv, J = reprojection_jacobians(P, X)
    uv2, depth = project_ideal(P, X)
    np.testing.assert_array_equal(uv2, uv)
    for c, cam in enumerate(RIG):
        ref, _ = cv2.projectPoints(X, cam.rotation, cam.translation, cam.matrix, None)
        np.testing.assert_allclose(uv[c], ref[:, 0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(depth[c], cam.world_to_camera(X)[:, 2], rtol=1e-12)
    step = 1e-6
    for axis in range(3):
        d = np.zeros(3)
        d[axis] = step
        num = (reprojection_jacobians(P, X + d)[0] - reprojection_jacobians(P, X - d)[0]) / (2 * step)
        np.testing.assert_allclose(J[..., axis], num, rtol=1e-6, atol=1e-3)


def test_inv2x2_equals_numpy_inverse():
    rng = np.random.default_rng(9)
    A = rng.normal(size=(7, 5, 2, 2))
    S = A @ A.swapaxes(-1, -2) + 0.1 * np.eye(2)  # covariances, as the tracker passes them
    np.testing.assert_allclose(inv2x2(S), np.linalg.inv(S), rtol=1e-12, atol=1e-12)
    M = rng.normal(size=(9, 2, 2))  # and any invertible matrix
    np.testing.assert_allclose(inv2x2(M) @ M, np.broadcast_to(np.eye(2), M.shape), atol=1e-10)
