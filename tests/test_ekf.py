"""Batched constant-acceleration EKFs against filterpy's ExtendedKalmanFilter, step by step."""

from __future__ import annotations

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import ExtendedKalmanFilter

from mocap import kernels
from mocap.ekf import (
    RunningError,
    ca_process_noise,
    ca_transition,
    init_state,
    position_jacobian,
    predict,
    update,
    update_position,
)
from mocap.geometry import reprojection_jacobians


@pytest.fixture(autouse=True, params=["numpy", "numba"])
def path(request, monkeypatch):
    """Every test on both paths: the numpy functions, and the compiled kernels they switch to."""
    if request.param == "numba" and not kernels.HAVE_NUMBA:
        pytest.skip(f"compiled kernels off: {kernels.REASON}")
    monkeypatch.setattr(kernels, "HAVE_NUMBA", request.param == "numba")
    return request.param


def _random_spd(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    A = rng.normal(size=(n, n))
    return (A @ A.T + n * np.eye(n)) * scale


def test_process_noise_is_filterpys_discrete_white_noise():
    for dims in (2, 3):
        Q = ca_process_noise(0.01, dims, 300.0)
        ref = Q_discrete_white_noise(3, dt=0.01, var=(300.0 * 0.01) ** 2, block_size=dims, order_by_dim=False)
        np.testing.assert_allclose(Q, ref, rtol=1e-12, atol=0)


def _filterpy_filters(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray, dims: int) -> list:
    """One filterpy ExtendedKalmanFilter per row of the batched state x (K, n), P (K, n, n)."""
    refs = []
    for xk, Pk in zip(x, P, strict=True):
        f = ExtendedKalmanFilter(dim_x=x.shape[1], dim_z=dims)
        f.x, f.P, f.F, f.Q = xk.copy(), Pk.copy(), F, Q
        refs.append(f)
    return refs


@pytest.mark.parametrize("dims", [2, 3])
def test_linear_position_filters_match_filterpy(dims):
    """The 2D image filter and the 3D world filter, K of them batched, equal K filterpy EKFs."""
    rng = np.random.default_rng(3)
    K, dt = 4, 1 / 120
    F, Q, H = ca_transition(dt, dims), ca_process_noise(dt, dims, 200.0), position_jacobian(dims)
    pos = rng.normal(size=(K, dims))
    R0 = np.stack([_random_spd(rng, dims, 1e-3) for _ in range(K)])
    x, P = init_state(pos, R0, rng.normal(size=(K, dims)), velocity_std=2.0, accel_std=30.0)
    refs = _filterpy_filters(x, P, F, Q, dims)
    for _ in range(30):
        x, P = predict(x, P, F, Q)
        z = rng.normal(size=(K, dims))
        R = np.stack([_random_spd(rng, dims, 1e-3) for _ in range(K)])
        x, P, y, S = update(x, P, z, x[:, :dims], H, R)
        for k, f in enumerate(refs):
            f.predict()
            f.update(z[k], lambda s: H, lambda s: s[:dims], R=R[k])
            np.testing.assert_allclose(x[k], f.x, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(P[k], f.P, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(y[k], f.y, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(S[k], f.S, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("dims", [2, 3])
def test_position_update_equals_the_general_update_and_filterpy(dims):
    """update_position (H = [I 0 0] as slices) gives the general update's numbers, and filterpy's, step by step."""
    rng = np.random.default_rng(11)
    K, dt = 5, 1 / 50
    F, Q, H = ca_transition(dt, dims, 0.5), ca_process_noise(dt, dims, 80.0), position_jacobian(dims)
    R0 = np.stack([_random_spd(rng, dims, 1e-2) for _ in range(K)])
    x, P = init_state(rng.normal(size=(K, dims)), R0, rng.normal(size=(K, dims)), velocity_std=3.0, accel_std=50.0)
    xg, Pg = x.copy(), P.copy()
    refs = _filterpy_filters(x, P, F, Q, dims)
    for _ in range(40):
        x, P = predict(x, P, F, Q)
        xg, Pg = predict(xg, Pg, F, Q)
        z = x[:, :dims] + rng.normal(scale=0.2, size=(K, dims))
        R = np.stack([_random_spd(rng, dims, 1e-2) for _ in range(K)])
        x, P, y, S = update_position(x, P, z, R)
        xg, Pg, yg, Sg = update(xg, Pg, z, xg[:, :dims], H, R)
        np.testing.assert_allclose(x, xg, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(P, Pg, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(y, yg, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(S, Sg, rtol=1e-12, atol=1e-14)
        for k, f in enumerate(refs):
            f.predict()
            f.update(z[k], lambda s: H, lambda s: s[:dims], R=R[k])
            np.testing.assert_allclose(x[k], f.x, rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(P[k], f.P, rtol=1e-10, atol=1e-12)
    assert not np.allclose(P[:, :dims, :dims], R, rtol=0.1)  # the filters did weigh prior and measurement


def test_world_filter_with_nonlinear_pair_measurement_matches_filterpy(rig):
    """A true EKF: the 3D state measured as its projections into a camera pair, z = (u1, v1, u2, v2)."""
    rng = np.random.default_rng(5)
    Ppair = rig.projection_matrices()[[0, 1]]
    dt = 1 / 50
    F, Q = ca_transition(dt, 3), ca_process_noise(dt, 3, 500.0)

    def hx(state: np.ndarray) -> np.ndarray:  # (K, 9) -> (K, 4)
        uv, _ = reprojection_jacobians(Ppair, state[:, :3])
        return uv.transpose(1, 0, 2).reshape(-1, 4)

    def jac(state: np.ndarray) -> np.ndarray:  # (K, 9) -> (K, 4, 9)
        _, J = reprojection_jacobians(Ppair, state[:, :3])
        H = np.zeros((len(state), 4, 9))
        H[:, :, :3] = J.transpose(1, 0, 2, 3).reshape(-1, 4, 3)
        return H

    K = 3
    x, P = init_state(rng.normal(scale=0.3, size=(K, 3)) + [0, 0, 1], np.eye(3)[None].repeat(K, 0) * 1e-4)
    refs = []
    for k in range(K):
        f = ExtendedKalmanFilter(dim_x=9, dim_z=4)
        f.x, f.P, f.F, f.Q = x[k].copy(), P[k].copy(), F, Q
        refs.append(f)
    truth = x[:, :3].copy()
    for _ in range(20):
        truth = truth + rng.normal(scale=0.01, size=truth.shape)
        x, P = predict(x, P, F, Q)
        z = hx(np.concatenate([truth, np.zeros((K, 6))], axis=1)) + rng.normal(scale=0.1, size=(K, 4))
        R = np.eye(4) * 0.01
        x, P, _, _ = update(x, P, z, hx(x), jac(x), R)
        for k, f in enumerate(refs):
            f.predict()
            f.update(z[k], lambda s: jac(s[None])[0], lambda s: hx(s[None])[0], R=R)
            np.testing.assert_allclose(x[k], f.x, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(P[k], f.P, rtol=1e-9, atol=1e-14)
    # and it tracks: the filtered positions are near the truth
    assert np.abs(x[:, :3] - truth).max() < 0.02


def test_constant_acceleration_prediction_is_exact_for_a_parabola():
    dt = 0.01
    F = ca_transition(dt, 3)
    p, v, a = np.array([1.0, 2.0, 3.0]), np.array([0.5, -1.0, 2.0]), np.array([0.0, 0.0, -9.81])
    x = np.concatenate([p, v, a])[None]
    x1, _ = predict(x, np.zeros((1, 9, 9)), F, np.zeros((9, 9)))
    np.testing.assert_allclose(x1[0, :3], p + v * dt + 0.5 * a * dt * dt, rtol=1e-14)
    np.testing.assert_allclose(x1[0, 3:6], v + a * dt, rtol=1e-14)


def test_running_error_smooths_and_widens_while_unseen():
    re = RunningError(alpha=0.5, scale=2.0)
    e = re.step(np.array([1.0]), np.array([3.0]))
    assert e[0] == pytest.approx(2.0)
    e_p, e_v, e_a = np.full(3, 0.01), np.full(3, 0.1), np.full(3, 1.0)
    r = re.radius(e_p, e_v, e_a, np.array([1, 2, 10]), 0.01, 0.005)
    assert r[0] == pytest.approx(2.0 * 0.01 + 0.005)  # next frame: the position error alone
    t = 9 * 0.01
    assert r[2] == pytest.approx(2.0 * (0.01 + 0.1 * t + 0.5 * t * t) + 0.005)
    assert r[0] < r[1] < r[2]
