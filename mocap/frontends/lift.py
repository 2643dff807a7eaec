"""Per-camera labelled 2D tracks -> labelled 3D trajectories through the calibrated multi-view stage.

For every label and frame: undistort each camera's point; reject outlying cameras by consensus (every
camera pair proposes a 3D point, the proposal that most cameras reproject to within ``max_error_px`` wins,
so up to C - 2 cameras that lost the target are voted out); triangulate the agreeing cameras with
:func:`mocap.geometry.triangulate_weighted`. A point seen by two cameras that disagree is dropped (two
views cannot tell which one is wrong). Everything is vectorised over frames x labels.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from mocap.camera import Rig
from mocap.geometry import reprojection_jacobians, triangulate_dlt, triangulate_weighted
from mocap.trajectories import Trajectories

__all__ = ["lift_tracks"]


def lift_tracks(rig: Rig, tracks: np.ndarray, labels: list[str], fps: float, sigma_px: np.ndarray | None = None,
                max_error_px: float = 4.0, metadata: dict | None = None) -> Trajectories:
    """Triangulate labelled 2D tracks from every camera of ``rig``.

    Args:
        rig: the calibration; camera c produced ``tracks[c]``.
        tracks: (C, F, L, 2) distorted pixels per camera, frame and label; NaN where not tracked.
        labels: (L,) label names (e.g. "head", or finger names).
        fps: frame rate, Hz.
        sigma_px: (C, F, L) 2D standard deviations, px (isotropic), or None for 1 px everywhere.
        max_error_px: reprojection-error gate of the outlier rejection, px.
        metadata: written into the trajectories.

    Returns:
        Trajectories: positions (F, L, 3) m, residuals = RMS reprojection error back-projected to the
        point's depth (mm), camera masks of the cameras kept.
    """
    tracks = np.asarray(tracks, dtype=np.float64)
    C, F, L = tracks.shape[:3]
    if C != len(rig) or tracks.shape[3] != 2 or len(labels) != L:
        raise ValueError(f"tracks {tracks.shape} do not fit {len(rig)} cameras and {len(labels)} labels")
    flat = tracks.reshape(C, F * L, 2)
    uv = np.stack([cam.undistort(flat[c]) for c, cam in enumerate(rig.cameras)])
    if sigma_px is None:
        cov = None
    else:
        s2 = np.asarray(sigma_px, dtype=np.float64).reshape(C, F * L) ** 2
        cov = s2[..., None, None] * np.eye(2)
    P = rig.projection_matrices()
    uv = _consensus(P, uv, max_error_px)
    X, _, rms = triangulate_weighted(P, uv, cov)
    seen = np.isfinite(uv).all(axis=2) & np.isfinite(X).all(axis=1)
    depth = np.stack([cam.world_to_camera(np.nan_to_num(X))[:, 2] / cam.matrix[0, 0] for cam in rig.cameras])
    metres_per_px = np.where(seen, depth, 0.0).sum(axis=0) / np.maximum(seen.sum(axis=0), 1)
    residual_mm = rms * metres_per_px * 1000.0
    masks = (seen.astype(np.uint32) << np.arange(C, dtype=np.uint32)[:, None]).sum(axis=0, dtype=np.uint32)
    return Trajectories(list(labels), fps, X.reshape(F, L, 3), residual_mm.reshape(F, L), masks.reshape(F, L),
                        rig.names, 0, dict(metadata or {}))


def _consensus(P: np.ndarray, uv: np.ndarray, gate: float) -> np.ndarray:
    """Keep, per point, the largest set of cameras that agree within ``gate`` px; NaN out the others.

    Every camera pair proposes a point (DLT); the proposal with the most cameras within the gate wins (ties:
    the smaller summed error). A point seen by two cameras only is kept when they agree.

    Args:
        P: (C, 3, 4) projection matrices.
        uv: (C, N, 2) ideal pixels, NaN where unseen.
        gate: reprojection-error gate, px.

    Returns:
        (C, N, 2) ideal pixels with the outlying cameras set to NaN.
    """
    C, N = uv.shape[:2]
    seen = np.isfinite(uv).all(axis=2)
    best_count = np.zeros(N, dtype=int)
    best_cost = np.full(N, np.inf)
    best_inliers = np.zeros((C, N), dtype=bool)
    for i, j in combinations(range(C), 2):
        X = triangulate_dlt(P[[i, j]], uv[[i, j]])
        ok = np.isfinite(X).all(axis=1)
        proj, _ = reprojection_jacobians(P, np.where(ok[:, None], X, 0.0))
        err = np.where(seen & ok, np.hypot(*(proj - uv).transpose(2, 0, 1)), np.inf)  # (C, N)
        inliers = err <= gate
        count = inliers.sum(axis=0)
        cost = np.where(inliers, err, 0.0).sum(axis=0)
        better = (count >= 2) & ((count > best_count) | ((count == best_count) & (cost < best_cost)))
        best_count = np.where(better, count, best_count)
        best_cost = np.where(better, cost, best_cost)
        best_inliers[:, better] = inliers[:, better]
    return np.where(best_inliers[..., None], uv, np.nan)
