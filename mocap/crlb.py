"""Cramér–Rao lower bound on the 3D position of a marker seen by several cameras.

Each camera c that sees the marker measures its blob centroid ``u_c = pi_c(X) + n_c`` with
``n_c ~ N(0, sigma_c^2 I_2)`` (distorted pixels). The Fisher information about ``X`` is

    I(X) = sum_c J_c^T J_c / sigma_c^2,     J_c = d pi_c / dX  (2x3, pixels per metre),

and any unbiased estimator has covariance >= I(X)^-1 (Kay, *Fundamentals of Statistical
Signal Processing* I, sec. 3.7; Hartley & Zisserman sec. 5.2.3 for the projective case).
The bound is what an ideal triangulation of the true centroids' noise would reach.
"""

from __future__ import annotations

import numpy as np

from mocap.camera import Rig

__all__ = ["crlb_covariance"]


def crlb_covariance(rig: Rig, points: np.ndarray, visible: np.ndarray, sigma_px: np.ndarray) -> np.ndarray:
    """Cramér–Rao covariance of each point's 3D position.

    Args:
        rig: the cameras, in the order of the ``visible`` / ``sigma_px`` columns.
        points: (N, 3) true world positions, metres.
        visible: (N, C) bool: camera c measured point n.
        sigma_px: (N, C) std (pixels, per axis) of that measurement; ignored where not visible.

    Returns:
        (N, 3, 3) covariance bound, m^2; NaN where the information is singular (fewer than two
        informative cameras, or cameras in line with the point).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    visible = np.asarray(visible, dtype=bool)
    sigma = np.asarray(sigma_px, dtype=np.float64)
    n = len(points)
    if visible.shape != (n, len(rig)) or sigma.shape != visible.shape:
        raise ValueError(f"visible and sigma_px must have shape {(n, len(rig))}, got {visible.shape}, {sigma.shape}")
    with np.errstate(divide="ignore", invalid="ignore"):
        weight = np.where(visible & (sigma > 0) & np.isfinite(sigma), 1.0 / sigma**2, 0.0)  # (N, C)
    info = np.zeros((n, 3, 3))
    for c, cam in enumerate(rig.cameras):
        used = weight[:, c] > 0
        if used.any():
            jac = cam.projection_jacobian(points[used])  # (n_used, 2, 3)
            info[used] += np.einsum("nki,nkj->nij", jac, jac) * weight[used, c, None, None]
    cov = np.full((n, 3, 3), np.nan)
    # A rank-deficient information matrix has no inverse: use the condition number as the test.
    ok = np.isfinite(info).all(axis=(1, 2))
    if ok.any():
        with np.errstate(divide="ignore", invalid="ignore"):
            ok[ok] = np.linalg.cond(info[ok]) < 1e12
    cov[ok] = np.linalg.inv(info[ok])
    return cov
