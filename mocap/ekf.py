"""Batched constant-acceleration extended Kalman filters (many filters at once, numpy).

State layout, per filter, for ``d`` spatial axes (d = 2 for an image filter in pixels, d = 3 for a
world filter in metres): ``(p_1..p_d, v_1..v_d, a_1..a_d)``, so n = 3 d. The motion model is the
paper's constant acceleration, ``p' = p + v dt + a dt^2 / 2``, ``v' = v + a dt``, ``a' = a``, with
the discrete Wiener-process acceleration noise (Bar-Shalom, Li & Kirubarajan, *Estimation with
Applications to Tracking and Navigation*, 2001, p. 274).

The filters are plain arrays owned by the caller: ``x`` (K, n), ``P`` (K, n, n). :func:`predict` and
:func:`update` return new arrays; the update takes any measurement function through its predicted
value ``hx`` (K, m) and Jacobian ``H`` (K, m, n) (or a shared (m, n)), i.e. it is a true EKF, and is
identical, step for step, to ``filterpy.kalman.ExtendedKalmanFilter`` (Joseph-form covariance update).
:func:`update_position` is the same update for the tracker's direct position measurement ``H = [I 0 0]``,
with the products by ``H`` done as slices (the same numbers, about half the matrix products).

:class:`RunningError` is the paper's search-region sizing: exponentially smoothed magnitudes of the
position, velocity and acceleration prediction errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap import kernels
from mocap.geometry import inv2x2, inv3x3

__all__ = [
    "ca_transition",
    "ca_process_noise",
    "predict",
    "update",
    "update_position",
    "position_jacobian",
    "init_state",
    "RunningError",
]


def ca_transition(dt: float, dims: int, damping: float = 1.0) -> np.ndarray:
    """(n, n) constant-acceleration transition matrix, n = 3 ``dims``; ``dt`` in seconds.

    With ``damping`` rho < 1 the acceleration decays by rho per step and only rho a drives the step
    (``p' = p + v dt + rho a dt^2/2``, ``v' = v + rho a dt``, ``a' = rho a``); rho = 0 is constant velocity.
    """
    r = damping
    block = np.array([[1.0, dt, 0.5 * r * dt * dt], [0.0, 1.0, r * dt], [0.0, 0.0, r]])
    return np.kron(block, np.eye(dims))


def ca_process_noise(dt: float, dims: int, jerk_std: float) -> np.ndarray:
    """(n, n) process noise: the acceleration changes by white N(0, (jerk_std dt)^2) every step.

    The discrete Wiener-process acceleration model, ``Q = G G^T (jerk_std dt)^2`` with
    ``G = (dt^2/2, dt, 1)`` per axis (Bar-Shalom, Li & Kirubarajan, p. 274; filterpy's
    ``Q_discrete_white_noise(3, dt, var, block_size=dims, order_by_dim=False)``). ``jerk_std`` in units/s^3.
    """
    g = np.array([0.5 * dt * dt, dt, 1.0])
    return np.kron(np.outer(g, g) * (jerk_std * dt) ** 2, np.eye(dims))


def position_jacobian(dims: int) -> np.ndarray:
    """(d, 3d) measurement Jacobian of a direct position measurement ``z = p``."""
    return np.eye(dims, 3 * dims)


def init_state(position: np.ndarray, position_var: np.ndarray, velocity: np.ndarray | None = None,
               velocity_std: float = 1.0, accel_std: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Start K filters at measured positions.

    Args:
        position: (K, d) positions.
        position_var: (K, d, d) their covariances.
        velocity: (K, d) initial velocities (default zero).
        velocity_std: prior std of the velocity, units/s.
        accel_std: prior std of the acceleration, units/s^2.

    Returns:
        ``x`` (K, 3d) and ``P`` (K, 3d, 3d).
    """
    K, d = position.shape
    x = np.zeros((K, 3 * d))
    x[:, :d] = position
    if velocity is not None:
        x[:, d:2 * d] = velocity
    P = np.zeros((K, 3 * d, 3 * d))
    P[:, :d, :d] = position_var
    eye = np.eye(d)
    P[:, d:2 * d, d:2 * d] = eye * velocity_std**2
    P[:, 2 * d:, 2 * d:] = eye * accel_std**2
    return x, P


def predict(x: np.ndarray, P: np.ndarray, F: np.ndarray, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prior of K filters: ``x' = F x``, ``P' = F P F^T + Q``.

    Args:
        x: (K, n) states.  P: (K, n, n) covariances.  F: (n, n) transition.  Q: (n, n) process noise.

    Returns:
        ``x'`` (K, n), ``P'`` (K, n, n).
    """
    K, n = x.shape
    if kernels.HAVE_NUMBA:
        c = kernels.contiguous
        return kernels.predict(c(x), c(P), c(F), c(Q.reshape(-1, n, n)))
    # Two plain (n, n) x (n, K n) products instead of 2 K tiny stacked ones (same sums, ~3x faster).
    FP = (F @ P.transpose(1, 0, 2).reshape(n, K * n)).reshape(n, K, n).transpose(1, 0, 2)
    return x @ F.T, (FP.reshape(K * n, n) @ F.T).reshape(K, n, n) + Q


def update(x: np.ndarray, P: np.ndarray, z: np.ndarray, hx: np.ndarray, H: np.ndarray, R: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """EKF measurement update of K filters (filterpy's equations, Joseph form).

    ``S = H P H^T + R``, ``K = P H^T S^-1``, ``x' = x + K (z - h(x))``,
    ``P' = (I - K H) P (I - K H)^T + K R K^T``.

    Args:
        x: (K, n) prior states.
        P: (K, n, n) prior covariances.
        z: (K, m) measurements.
        hx: (K, m) predicted measurements h(x).
        H: (K, m, n) or (m, n) Jacobians of h at x.
        R: (K, m, m) or (m, m) measurement covariances.

    Returns:
        ``x'`` (K, n), ``P'`` (K, n, n), innovation ``y`` (K, m) and its covariance ``S`` (K, m, m).
    """
    Ht = np.swapaxes(H, -1, -2)
    PHt = P @ Ht
    S = H @ PHt + R
    gain = PHt @ np.linalg.inv(S)
    y = z - hx
    x_new = x + (gain @ y[..., None])[..., 0]
    I_KH = np.eye(x.shape[1]) - gain @ H
    P_new = I_KH @ P @ np.swapaxes(I_KH, -1, -2) + gain @ R @ np.swapaxes(gain, -1, -2)
    return x_new, P_new, y, S


def update_position(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`update` for a direct position measurement (``h(x) = p``, ``H`` = :func:`position_jacobian`).

    With ``H = [I 0 0]``: ``P H^T`` is ``P[:, :, :d]`` and ``M = (I - K H) P = P - K P[:d]``, so the Joseph
    form ``M (I - K H)^T + K R K^T`` is ``M + (K R - M[:, :, :d]) K^T``: no n x n products.

    Args:
        x: (K, n) prior states, n = 3 d.  P: (K, n, n) prior covariances.
        z: (K, d) measured positions.  R: (K, d, d) or (d, d) their covariances.

    Returns:
        ``x'`` (K, n), ``P'`` (K, n, n), innovation ``y`` (K, d) and its covariance ``S`` (K, d, d).
    """
    d = z.shape[-1]
    if kernels.HAVE_NUMBA and d in (2, 3):
        c = kernels.contiguous
        return kernels.update_position(c(x), c(P), c(z), c(np.broadcast_to(R, z.shape + (d,))))
    PHt = P[:, :, :d]
    S = P[:, :d, :d] + R
    gain = PHt @ (inv2x2(S) if d == 2 else inv3x3(S) if d == 3 else np.linalg.inv(S))  # (K, n, d)
    gain_t = np.swapaxes(gain, -1, -2)
    y = z - x[:, :d]
    x_new = x + (gain @ y[..., None])[..., 0]
    M = P - gain @ P[:, :d, :]
    P_new = M + (gain @ R - M[:, :, :d]) @ gain_t
    return x_new, P_new, y, S


@dataclass
class RunningError:
    """Exponentially smoothed prediction-error magnitudes that size a search region (paper 004).

    For each filter: ``e_p`` the position error |measured - predicted|, ``e_v`` the error of the
    predicted velocity against the measured displacement per second, ``e_a`` that of the
    acceleration; each smoothed as ``e = alpha |err| + (1 - alpha) e``.

    The search radius ``m`` frames after the last measurement (m = 1: the next frame) is

        r = scale * (e_p + e_v t + e_a t^2 / 2) + floor,    t = (m - 1) dt

    so it widens while the marker is unseen, as the paper's variable threshold does.
    Arrays are (K,) and owned by the caller; the methods return new arrays.
    """

    alpha: float = 0.3
    scale: float = 3.0

    def step(self, e: np.ndarray, err: np.ndarray) -> np.ndarray:
        """Smooth the running error ``e`` (K,) with new error magnitudes ``err`` (K,)."""
        return self.alpha * err + (1.0 - self.alpha) * e

    def radius(self, e_p: np.ndarray, e_v: np.ndarray, e_a: np.ndarray, since: np.ndarray, dt: float,
               floor: float) -> np.ndarray:
        """(K,) search radius ``since`` (K,) frames after each filter's last measurement."""
        if np.ndim(since) == 0 and since <= 1:  # the next frame (t = 0): the same sums without the t arithmetic
            return self.scale * (e_p + e_v * 0.0 + e_a * 0.0) + floor
        t = np.maximum(since - 1, 0) * dt
        return self.scale * (e_p + e_v * t + 0.5 * e_a * t * t) + floor
