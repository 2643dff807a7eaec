"""Multi-view geometry on ideal (undistorted) pixels: epipolar geometry and triangulation.

All functions are pure and vectorised. References: Hartley & Zisserman, *Multiple View
Geometry*, 2nd ed. (H&Z).
"""

from __future__ import annotations

import numpy as np

from mocap.camera import Camera

__all__ = [
    "skew",
    "fundamental_from_cameras",
    "epipolar_lines",
    "point_line_distance",
    "epipolar_distance_matrix",
    "triangulate_dlt",
    "triangulate_weighted",
    "reprojection_jacobians",
    "project_ideal",
    "inv2x2",
    "inv3x3",
]


def skew(t: np.ndarray) -> np.ndarray:
    """(3,) vector -> (3, 3) cross-product matrix ``[t]x`` with ``[t]x @ v == t x v``."""
    t = np.asarray(t, dtype=np.float64).reshape(3)
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def fundamental_from_cameras(cam1: Camera, cam2: Camera) -> np.ndarray:
    """Fundamental matrix of a calibrated pair, ideal pixels (H&Z eq. 9.2, p. 244).

    ``F = K2^-T [t]x R K1^-1`` with ``R, t`` the pose of camera 2 relative to camera 1,
    so that ``x2^T F x1 = 0`` for homogeneous ideal pixels of one world point, and
    ``F @ x1`` is the epipolar line of ``x1`` in image 2. Normalised to unit Frobenius norm.

    Returns:
        (3, 3) rank-2 fundamental matrix.
    """
    R1, R2 = cam1.R, cam2.R
    R = R2 @ R1.T
    t = cam2.translation - R @ cam1.translation
    F = np.linalg.inv(cam2.matrix).T @ skew(t) @ R @ np.linalg.inv(cam1.matrix)
    return F / np.linalg.norm(F)


def epipolar_lines(F: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Epipolar lines ``l = F x`` of (N, 2) ideal pixels -> (N, 3) lines ``(a, b, c)``.

    For lines in image 1 of points in image 2 pass ``F.T``.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    return points @ F[:, :2].T + F[:, 2]


def point_line_distance(lines: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distances, pixels, of every point to every line: ``|a u + b v + c| / sqrt(a^2 + b^2)``.

    Args:
        lines: (N, 3) lines.
        points: (M, 2) points.

    Returns:
        (N, M) distances.
    """
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 3)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    norm = np.hypot(lines[:, 0], lines[:, 1])[:, None]
    return np.abs(lines[:, :2] @ points.T + lines[:, 2:3]) / norm


def epipolar_distance_matrix(F: np.ndarray, points1: np.ndarray, points2: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance between every pair, pixels.

    ``d(i, j) = max(dist(x2_j, F x1_i), dist(x1_i, F^T x2_j))``: the larger of the two
    point-to-line distances, so that a pair is accepted only if it fits in both images.

    Args:
        F: (3, 3) fundamental matrix from image 1 to image 2.
        points1: (N, 2) ideal pixels in image 1.
        points2: (M, 2) ideal pixels in image 2.

    Returns:
        (N, M) distances.
    """
    d12 = point_line_distance(epipolar_lines(F, points1), points2)
    d21 = point_line_distance(epipolar_lines(F.T, points2), points1)
    return np.maximum(d12, d21.T)


def triangulate_dlt(projections: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of many points at once (H&Z sec. 12.2, p. 312).

    Args:
        projections: (C, 3, 4) ideal-pixel projection matrices.
        points: (C, N, 2) ideal pixels; NaN where camera c did not see point n.

    Returns:
        (N, 3) points, metres; NaN where fewer than two cameras saw the point.
    """
    P = np.asarray(projections, dtype=np.float64)
    uv = np.asarray(points, dtype=np.float64)
    C, N = uv.shape[:2]
    seen = np.isfinite(uv).all(axis=2)  # (C, N)
    uvz = np.where(seen[..., None], uv, 0.0)
    # Rows u*P3 - P1 and v*P3 - P2 per camera; zero rows for unseen cameras.
    rows_u = uvz[..., 0:1] * P[:, None, 2, :] - P[:, None, 0, :]  # (C, N, 4)
    rows_v = uvz[..., 1:2] * P[:, None, 2, :] - P[:, None, 1, :]
    A = np.concatenate([rows_u, rows_v], axis=0) * np.concatenate([seen, seen], axis=0)[..., None]
    A = np.transpose(A, (1, 0, 2))  # (N, 2C, 4)
    # Row scaling improves conditioning without changing the solution.
    scale = np.linalg.norm(A, axis=2, keepdims=True)
    A = A / np.where(scale > 0, scale, 1.0)
    _, _, vt = np.linalg.svd(A)
    X = vt[:, -1, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        out = X[:, :3] / X[:, 3:4]
    out[seen.sum(axis=0) < 2] = np.nan
    return out


def inv2x2(S: np.ndarray) -> np.ndarray:
    """Inverses of (..., 2, 2) matrices in closed form (adjugate / determinant).

    Same values as ``np.linalg.inv`` to rounding, ~10x faster on a few hundred small matrices.
    """
    flat = (S if S.dtype.kind == "f" else S.astype(np.float64)).reshape(-1, 4)
    out = flat[:, [3, 1, 2, 0]]  # (d, b, c, a): a new array, negated and divided in place
    out[:, 1:3] *= -1.0
    out /= (flat[:, 0] * flat[:, 3] - flat[:, 1] * flat[:, 2])[:, None]
    return out.reshape(S.shape)


def _adjugate_index() -> np.ndarray:
    """(4, 9) flat indices: ``adj(A)[i, j] = A[a] A[b] - A[c] A[d]`` (cofactor of ``A[j, i]``), row-major (i, j)."""
    idx = np.empty((4, 9), dtype=np.intp)
    for i in range(3):
        for j in range(3):
            j1, j2, i1, i2 = (j + 1) % 3, (j + 2) % 3, (i + 1) % 3, (i + 2) % 3
            idx[:, 3 * i + j] = [3 * j1 + i1, 3 * j2 + i2, 3 * j1 + i2, 3 * j2 + i1]
    return idx


_ADJ3 = _adjugate_index()


def inv3x3(S: np.ndarray) -> np.ndarray:
    """Inverses of (..., 3, 3) matrices in closed form (adjugate / determinant).

    Same values as ``np.linalg.inv`` to rounding (1e-15 relative on the tracker's covariances), ~2x faster
    on a few dozen small matrices; a singular matrix gives inf/NaN instead of an exception.
    """
    flat = S.reshape(-1, 9)
    a = flat[:, _ADJ3]  # (M, 4, 9)
    adj = a[:, 0] * a[:, 1] - a[:, 2] * a[:, 3]  # (M, 9)
    det = flat[:, 0] * adj[:, 0] + flat[:, 1] * adj[:, 3] + flat[:, 2] * adj[:, 6]  # first row . first column
    return (adj / det[:, None]).reshape(S.shape)


def project_ideal(projections: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ideal pixels ``uv`` (C, N, 2) of world points ``X`` (N, 3) in every camera, and their depths (C, N), m.

    The depth is the third homogeneous coordinate ``P2 . Xh`` (metres for ``K [R | t]`` matrices).
    """
    P = np.asarray(projections, dtype=np.float64)
    proj = X @ P[:, :, :3].transpose(0, 2, 1) + P[:, None, :, 3]  # (C, N, 3); a matmul beats einsum here
    w = proj[..., 2]
    return proj[..., :2] / w[..., None], w


def reprojection_jacobians(projections: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ideal-pixel projections and their Jacobians for every camera and point.

    ``u = (P0 . Xh) / (P2 . Xh)``, so ``du/dX = (P0[:3] - u P2[:3]) / (P2 . Xh)``.

    Args:
        projections: (C, 3, 4) projection matrices.
        X: (N, 3) world points.

    Returns:
        ``uv`` (C, N, 2) projected ideal pixels and ``J`` (C, N, 2, 3) pixels per metre.
    """
    P = np.asarray(projections, dtype=np.float64)
    uv, w = project_ideal(P, X)
    J = (P[:, None, :2, :3] - uv[..., None] * P[:, None, 2:3, :3]) / w[..., None, None]
    return uv, J


def _well_conditioned(H: np.ndarray) -> np.ndarray:
    """(N,) bool: the (N, 3, 3) symmetric positive semi-definite normal matrices ``H`` are finite and invertible
    to working precision: det(H) (the product of the eigenvalues) above 1e-12 x (trace / 3)^3 (no SVD per point)."""
    with np.errstate(invalid="ignore", over="ignore"):
        scale = (np.trace(H, axis1=1, axis2=2) / 3.0) ** 3
        return np.isfinite(H).all(axis=(1, 2)) & (np.linalg.det(H) > 1e-12 * scale) & (scale > 0)


def triangulate_weighted(
    projections: np.ndarray,
    points: np.ndarray,
    covariances: np.ndarray | None = None,
    iterations: int = 3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Covariance-weighted multi-view least squares (Gauss-Newton from the DLT).

    Minimises ``sum_c r_c^T S_c^-1 r_c`` with ``r_c`` the reprojection error in camera
    c and ``S_c`` its 2D centroid covariance. The returned 3D covariance is the inverse
    Fisher information ``(sum_c J_c^T S_c^-1 J_c)^-1`` (first-order propagation).

    Args:
        projections: (C, 3, 4) ideal-pixel projection matrices.
        points: (C, N, 2) ideal pixels; NaN where unseen.
        covariances: (C, N, 2, 2) pixel^2 centroid covariances, or None for identity.
        iterations: Gauss-Newton steps.

    Returns:
        ``X`` (N, 3) metres, ``cov`` (N, 3, 3) m^2, ``rms`` (N,) RMS reprojection error
        in pixels over the cameras that saw the point. NaN where < 2 cameras.
    """
    P = np.asarray(projections, dtype=np.float64)
    uv = np.asarray(points, dtype=np.float64)
    C, N = uv.shape[:2]
    seen = np.isfinite(uv).all(axis=2)
    if covariances is None:
        W = np.broadcast_to(np.eye(2), (C, N, 2, 2)).copy()
    else:
        cov = np.asarray(covariances, dtype=np.float64)
        cov = np.where(seen[..., None, None], cov, np.eye(2))
        W = np.linalg.inv(cov)
    W = W * seen[..., None, None]
    X = triangulate_dlt(P, uv)
    good = np.isfinite(X).all(axis=1)
    Xg = np.where(good[:, None], X, 0.0)
    uvz = np.where(seen[..., None], uv, 0.0)
    for _ in range(iterations):
        proj, J = reprojection_jacobians(P, Xg)
        r = np.where(seen[..., None], uvz - proj, 0.0)  # (C, N, 2)
        JtW = np.einsum("cnki,cnkl->cnil", J, W)  # (C, N, 3, 2)
        H = np.einsum("cnil,cnlj->nij", JtW, J)
        g = np.einsum("cnil,cnl->ni", JtW, r)
        good &= _well_conditioned(H)  # (views with near-infinite covariances leave the depth undetermined)
        H[~good] = np.eye(3)
        g[~good] = 0.0
        Xg = Xg + np.linalg.solve(H, g[..., None])[..., 0]
    proj, J = reprojection_jacobians(P, Xg)
    JtW = np.einsum("cnki,cnkl->cnil", J, W)
    H = np.einsum("cnil,cnlj->nij", JtW, J)
    good &= _well_conditioned(H)
    H[~good] = np.eye(3)
    cov3 = np.linalg.inv(H)
    r2 = np.where(seen, ((uvz - proj) ** 2).sum(axis=2), 0.0).sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(r2 / seen.sum(axis=0))
    Xg[~good] = np.nan
    cov3[~good] = np.nan
    rms[~good] = np.nan
    return Xg, cov3, rms
