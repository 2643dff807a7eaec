"""Bundle adjustment of camera poses (optionally focal length and k1) and wand poses.

Unknowns: every camera's pose (Rodrigues vector and translation, world -> camera) except the
reference camera's, which fixes the world frame; optionally a focal-length factor and a k1 change
per camera; and per frame the wand as a rigid rod: the position ``p`` of marker 0 and the unit
direction ``d``, so marker k sits at ``p + offset_k d``. The wand's length is thereby a hard
constraint and gives the scale. ``d`` is parametrised locally, ``d = normalise(d0 + a e1 + b e2)``
with ``e1, e2`` orthogonal to the starting direction ``d0`` (no singularity, 2 parameters).

Residuals: reprojection errors in distorted pixels through the full lens model
(:meth:`mocap.camera.Camera.project`), each divided by its blob's centroid standard deviation,
under a robust loss (``soft_l1``). ``scipy.optimize.least_squares`` (trust-region reflective)
with a sparse Jacobian pattern (``jac_sparsity``): each residual depends on one camera and one
frame, so finite differences need only a few grouped evaluations and the normal equations stay
sparse (Triggs et al., *Bundle Adjustment — A Modern Synthesis*, 2000).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import coo_matrix

from mocap.camera import Camera, Rig

__all__ = ["BundleOptions", "BundleResult", "bundle_adjust", "wand_points"]


@dataclass
class BundleOptions:
    """Settings of :func:`bundle_adjust`.

    Attributes:
        refine_focal: also estimate a focal-length factor per camera (fx and fy together).
        refine_k1: also estimate a change of the radial coefficient k1 per camera.
        loss: robust loss of ``least_squares``.
        f_scale: where the loss turns robust, in standard deviations of the residuals.
        max_nfev: most function evaluations per solve.
    """

    refine_focal: bool = False
    refine_k1: bool = False
    loss: str = "soft_l1"
    f_scale: float = 3.0
    max_nfev: int = 200


@dataclass
class BundleResult:
    """Outcome of :func:`bundle_adjust`.

    Attributes:
        rig: the refined cameras.
        points: (F, K, 3) wand markers, metres (NaN for frames with no observation).
        residuals: (F, C, K, 2) reprojection error (projection - observation), pixels; NaN where unused.
        success: the solver reported convergence.
        message: the solver's message.
        nfev: function evaluations.
    """

    rig: Rig
    points: np.ndarray
    residuals: np.ndarray
    success: bool
    message: str
    nfev: int


def wand_points(p0: np.ndarray, direction: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(F, 3) marker-0 positions and (F, 3) unit directions -> (F, K, 3) marker positions."""
    return p0[:, None, :] + offsets[None, :, None] * direction[:, None, :]


def _perpendicular_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) unit vectors -> two (F, 3) unit vectors spanning the plane orthogonal to each."""
    helper = np.where(np.abs(d[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    return e1, np.cross(d, e1)


class _Problem:
    """Parameter packing, residuals and Jacobian pattern of one bundle adjustment."""

    def __init__(self, rig: Rig, obs: np.ndarray, sigma: np.ndarray, offsets: np.ndarray, fixed: int,
                 points: np.ndarray, options: BundleOptions) -> None:
        self.rig = rig
        self.offsets = offsets
        self.fixed = fixed
        F, C, K = obs.shape[:3]
        used = np.isfinite(obs).all(axis=3) & np.isfinite(points).all(axis=2)[:, None, :]
        self.frames_used = np.flatnonzero(used.any(axis=(1, 2)))
        frame_slot = np.full(F, -1)
        frame_slot[self.frames_used] = np.arange(len(self.frames_used))
        f, c, k = np.nonzero(used)
        self.obs_index = (f, c, k)
        self.slot = frame_slot[f]
        self.cam = c
        self.marker = k
        self.uv = obs[f, c, k]
        self.weight = 1.0 / sigma[f, c, k]
        self.by_camera = [np.flatnonzero(c == j) for j in range(C)]
        self.n_intr = int(options.refine_focal) + int(options.refine_k1)
        self.options = options
        self.pose_cams = [j for j in range(C) if j != fixed]
        self.n_cam_params = 6 * len(self.pose_cams) + self.n_intr * C
        p = points[self.frames_used]
        d = p[:, -1] - p[:, 0]
        self.d0 = d / np.linalg.norm(d, axis=1, keepdims=True)
        self.e1, self.e2 = _perpendicular_basis(self.d0)
        self.p0 = p[:, 0]

    def x0(self) -> np.ndarray:
        cams = []
        for j in self.pose_cams:
            cams += [self.rig[j].rotation, self.rig[j].translation]
        intr = np.zeros(self.n_intr * len(self.rig))
        frames = np.column_stack([self.p0, np.zeros((len(self.p0), 2))]).ravel()
        return np.concatenate([*cams, intr, frames])

    def unpack(self, x: np.ndarray) -> tuple[list[Camera], np.ndarray]:
        """Parameters -> (cameras, (F_used, K, 3) marker positions)."""
        cams = list(self.rig.cameras)
        for n, j in enumerate(self.pose_cams):
            cams[j] = cams[j].with_pose(x[6 * n : 6 * n + 3], x[6 * n + 3 : 6 * n + 6])
        intr = x[6 * len(self.pose_cams) : self.n_cam_params].reshape(len(self.rig), self.n_intr)
        if self.n_intr:
            for j, cam in enumerate(cams):
                K = cam.matrix.copy()
                dist = cam.distortions.copy()
                col = 0
                if self.options.refine_focal:
                    K[0, 0] *= 1 + intr[j, col]
                    K[1, 1] *= 1 + intr[j, col]
                    col += 1
                if self.options.refine_k1:
                    dist[0] += intr[j, col]
                cams[j] = Camera(cam.name, cam.size, K, dist, cam.rotation, cam.translation, cam.fisheye)
        fr = x[self.n_cam_params :].reshape(-1, 5)
        d = self.d0 + fr[:, 3:4] * self.e1 + fr[:, 4:5] * self.e2
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return cams, wand_points(fr[:, :3], d, self.offsets)

    def project(self, x: np.ndarray) -> np.ndarray:
        """(N_obs, 2) projections of the observed markers."""
        cams, X = self.unpack(x)
        out = np.empty_like(self.uv)
        for j, idx in enumerate(self.by_camera):
            if idx.size:
                out[idx] = cams[j].project(X[self.slot[idx], self.marker[idx]])
        return out

    def residuals(self, x: np.ndarray) -> np.ndarray:
        r = (self.project(x) - self.uv) * self.weight[:, None]
        return np.nan_to_num(r, nan=1e6).ravel()

    def sparsity(self) -> coo_matrix:
        """(2 N_obs, N_params) 0/1 pattern: each residual depends on its camera's and its frame's parameters."""
        n_obs = len(self.uv)
        C = len(self.rig)
        pose_col = np.full(C, -1)
        pose_col[self.pose_cams] = 6 * np.arange(len(self.pose_cams))
        blocks = [self.n_cam_params + 5 * self.slot[:, None] + np.arange(5)]
        has_pose = pose_col[self.cam] >= 0
        blocks.append(np.where(has_pose[:, None], pose_col[self.cam][:, None] + np.arange(6), -1))
        if self.n_intr:
            base = 6 * len(self.pose_cams)
            blocks.append(base + self.n_intr * self.cam[:, None] + np.arange(self.n_intr))
        cols = np.concatenate(blocks, axis=1)  # (N_obs, P) with -1 = none
        rows = np.broadcast_to(np.arange(n_obs)[:, None], cols.shape)
        keep = cols >= 0
        r = np.concatenate([2 * rows[keep], 2 * rows[keep] + 1])
        c = np.concatenate([cols[keep], cols[keep]])
        shape = (2 * n_obs, self.n_cam_params + 5 * len(self.frames_used))
        return coo_matrix((np.ones(len(r), dtype=np.int8), (r, c)), shape=shape)


def bundle_adjust(rig: Rig, obs: np.ndarray, points: np.ndarray, offsets: np.ndarray, fixed: int,
                  sigma: np.ndarray | None = None, options: BundleOptions | None = None) -> BundleResult:
    """Refine camera poses (and optionally focal, k1) and wand poses.

    Args:
        rig: starting cameras; camera ``fixed`` keeps its pose (it defines the world frame).
        obs: (F, C, K, 2) wand markers, distorted pixels; NaN where unseen or rejected.
        points: (F, K, 3) starting wand markers, metres (only marker 0 and the direction are used).
        offsets: (K,) marker positions along the wand, metres.
        fixed: index of the reference camera.
        sigma: (F, C, K) centroid standard deviation of each observation, pixels (None: all 1).
        options: settings.

    Returns:
        The refined rig, wand points and residuals.
    """
    options = options or BundleOptions()
    sigma = np.ones(obs.shape[:3]) if sigma is None else np.where(np.isfinite(sigma) & (sigma > 0), sigma, 1.0)
    problem = _Problem(rig, obs, sigma, np.asarray(offsets, dtype=np.float64), fixed, points, options)
    x0 = problem.x0()
    scale = float(np.median(np.abs(problem.residuals(x0)))) / 0.6745
    f_scale = options.f_scale * max(scale, 1e-12) if options.loss != "linear" else 1.0
    sol = least_squares(problem.residuals, x0, jac_sparsity=problem.sparsity(), loss=options.loss,
                        f_scale=min(f_scale, options.f_scale * 1e3), x_scale="jac", method="trf",
                        tr_solver="lsmr", max_nfev=options.max_nfev, xtol=1e-10, ftol=1e-9, gtol=1e-10)
    cams, X = problem.unpack(sol.x)
    F, C, K = obs.shape[:3]
    all_points = np.full((F, K, 3), np.nan)
    all_points[problem.frames_used] = X
    residuals = np.full(obs.shape, np.nan)
    residuals[problem.obs_index] = problem.project(sol.x) - problem.uv
    return BundleResult(Rig(cams, dict(rig.metadata), dict(rig.extra_tables)), all_points, residuals,
                        bool(sol.success), str(sol.message), int(sol.nfev))
