"""A first estimate of the rig from wand observations: pairwise geometry and a view graph.

1. Every camera pair that saw the wand together in enough frames gets its relative pose from the
   essential matrix (``cv2.findEssentialMat`` with MAGSAC++ on normalised coordinates, then
   ``cv2.recoverPose``, which picks the one of four (R, t) that puts the points in front of both
   cameras: the cheirality test, H&Z sec. 9.6.3) and its scale from the wand: the median
   triangulated end-to-end distance must equal the wand's length.
2. The view graph joins cameras by those pairs; its maximum spanning tree, weighted by the number
   of inlier points, links every camera to the best-connected one (the reference, identity pose)
   through the strongest pairs. Poses are chained along the tree.

Bundle adjustment (:mod:`calibration.bundle`) then refines everything jointly.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from calibration.wand import Wand
from mocap.camera import Rig
from mocap.errors import MocapError
from mocap.geometry import triangulate_dlt

__all__ = ["PairPose", "normalised_observations", "pair_poses", "spanning_tree", "initial_rig",
           "order_two_marker_wand", "MIN_PAIR_FRAMES"]

MIN_PAIR_FRAMES = 15


@dataclass
class PairPose:
    """Pose of camera j relative to camera i (``X_j = R X_i + t``, metres) and its support."""

    R: np.ndarray
    t: np.ndarray
    inliers: int
    frames: int


def normalised_observations(rig: Rig, obs: np.ndarray) -> np.ndarray:
    """(F, C, K, 2) distorted pixels -> (F, C, K, 2) normalised image coordinates ``K^-1 x`` (undistorted)."""
    out = np.full(obs.shape, np.nan)
    for c, cam in enumerate(rig):
        ideal = cam.undistort(obs[:, c].reshape(-1, 2))
        Kinv = np.linalg.inv(cam.matrix)
        out[:, c] = (ideal @ Kinv[:2, :2].T + Kinv[:2, 2]).reshape(obs[:, c].shape)
    return out


def _pair_pose(x1: np.ndarray, x2: np.ndarray, wand: Wand, threshold: float) -> PairPose | None:
    """Relative pose from normalised (N, K, 2) wand observations of two cameras, or None."""
    p1 = x1.reshape(-1, 2)
    p2 = x2.reshape(-1, 2)
    E, mask = cv2.findEssentialMat(p1, p2, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.999, threshold=threshold)
    if E is None or E.shape != (3, 3):
        return None
    n_in, R, t, mask = cv2.recoverPose(E, p1, p2, np.eye(3), mask=mask)
    if n_in < 8 * wand.n_markers:
        return None
    P = np.stack([np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([R, t])])
    X = triangulate_dlt(P, np.stack([p1, p2])).reshape(len(x1), wand.n_markers, 3)
    length = np.linalg.norm(X[:, -1] - X[:, 0], axis=1)
    length = length[np.isfinite(length) & (length > 0)]
    if length.size == 0:
        return None
    scale = wand.length / float(np.median(length))
    return PairPose(R, t.ravel() * scale, int(n_in), len(x1))


def pair_poses(norm_obs: np.ndarray, wand: Wand, threshold: float = 1e-3,
               min_frames: int = MIN_PAIR_FRAMES) -> dict[tuple[int, int], PairPose]:
    """Relative poses of every camera pair (i < j) that saw the wand together in ``min_frames`` frames.

    Args:
        norm_obs: (F, C, K, 2) normalised coordinates, NaN where unseen.
        wand: the wand (its length sets each pair's scale).
        threshold: inlier threshold of the essential-matrix estimator, normalised units
            (about pixels / focal length).
        min_frames: fewest common frames to try a pair.
    """
    seen = np.isfinite(norm_obs).all(axis=(2, 3))  # (F, C)
    C = seen.shape[1]
    out: dict[tuple[int, int], PairPose] = {}
    for i in range(C):
        for j in range(i + 1, C):
            both = seen[:, i] & seen[:, j]
            if both.sum() < min_frames:
                continue
            pose = _pair_pose(norm_obs[both, i], norm_obs[both, j], wand, threshold)
            if pose is not None:
                out[(i, j)] = pose
    return out


def spanning_tree(pairs: dict[tuple[int, int], PairPose], names: list[str]) -> tuple[int, np.ndarray]:
    """The reference camera and each camera's parent in the maximum spanning tree of the view graph.

    Returns:
        ``(root, parent)``: ``parent[c]`` is the camera c's pose is chained from (-9999 for the root).

    Raises:
        MocapError: naming the cameras that no pair links to the others.
    """
    C = len(names)
    weight = np.zeros((C, C))
    for (i, j), p in pairs.items():
        weight[i, j] = weight[j, i] = p.inliers
    n_comp, label = connected_components(csr_matrix(weight > 0), directed=False)
    if n_comp > 1:
        sizes = np.bincount(label)
        main = int(np.argmax(sizes))
        lost = [names[c] for c in range(C) if label[c] != main]
        raise MocapError(
            f"camera(s) {', '.join(lost)} never saw the wand together with the other cameras often enough "
            f"(at least {MIN_PAIR_FRAMES} common frames are needed to link a camera): wave the wand where "
            "they overlap with their neighbours"
        )
    root = int(np.argmax(weight.sum(axis=1)))
    # Maximum spanning tree = minimum spanning tree of inverted weights.
    inv = np.where(weight > 0, 1.0 / np.maximum(weight, 1), 0.0)
    tree = minimum_spanning_tree(csr_matrix(inv))
    tree = tree + tree.T
    _, parent = breadth_first_order(tree, root, directed=False, return_predecessors=True)
    return root, parent


def initial_rig(rig: Rig, norm_obs: np.ndarray, wand: Wand) -> tuple[Rig, dict[tuple[int, int], PairPose], int]:
    """Chain pairwise poses along the view graph's spanning tree.

    Args:
        rig: cameras with their intrinsics (poses ignored).
        norm_obs: (F, C, K, 2) normalised wand observations.
        wand: the wand.

    Returns:
        ``(rig with first poses (reference camera at the origin), pair poses, reference camera index)``.
    """
    pairs = pair_poses(norm_obs, wand)
    root, parent = spanning_tree(pairs, rig.names)
    R = {root: np.eye(3)}
    t = {root: np.zeros(3)}
    pending = [c for c in range(len(rig)) if c != root]
    while pending:
        for c in list(pending):
            p = int(parent[c])
            if p not in R:
                continue
            if (p, c) in pairs:
                Rpc, tpc = pairs[(p, c)].R, pairs[(p, c)].t
            else:
                Rcp, tcp = pairs[(c, p)].R, pairs[(c, p)].t
                Rpc, tpc = Rcp.T, -Rcp.T @ tcp
            R[c] = Rpc @ R[p]
            t[c] = Rpc @ t[p] + tpc
            pending.remove(c)
    cams = [cam.with_pose(cv2.Rodrigues(R[c])[0].ravel(), t[c]) for c, cam in enumerate(rig)]
    return Rig(cams, dict(rig.metadata), dict(rig.extra_tables)), pairs, root


def order_two_marker_wand(norm_obs: np.ndarray, threshold: float = 2e-3) -> tuple[np.ndarray, np.ndarray]:
    """Number the two markers of a 2-marker wand alike in every camera (each image's order is arbitrary).

    Camera by camera, in order of how many frames it shares with the cameras already settled
    (the first one settles itself), each frame's order is chosen to agree with the settled cameras:
    the essential matrix is estimated robustly from both orders of every common frame (the wrong
    order is an outlier), then each frame keeps the order with the smaller epipolar error.

    Args:
        norm_obs: (F, C, 2, 2) normalised coordinates.
        threshold: inlier threshold, normalised units.

    Returns:
        ``(swap, unsettled)``, both (F, C) bool: swap the two markers of that observation; drop
        that observation (no settled camera saw the frame, so its order is unknown).
    """
    obs = norm_obs.copy()
    seen = np.isfinite(obs).all(axis=(2, 3))
    C = obs.shape[1]
    swap = np.zeros(seen.shape, dtype=bool)
    unsettled = np.zeros(seen.shape, dtype=bool)
    settled = [int(np.argmax(seen.sum(axis=0)))]
    while len(settled) < C:
        rest = [c for c in range(C) if c not in settled]
        shared = [(seen[:, c][:, None] & seen[:, settled]).sum() for c in rest]
        c = rest[int(np.argmax(shared))]
        votes = np.zeros(len(obs))
        for s in settled:
            both = seen[:, s] & seen[:, c]
            if both.sum() < MIN_PAIR_FRAMES:
                continue
            a = obs[both, s]  # (N, 2, 2)
            b = obs[both, c]
            p1 = np.concatenate([a.reshape(-1, 2), a.reshape(-1, 2)])
            p2 = np.concatenate([b.reshape(-1, 2), b[:, ::-1].reshape(-1, 2)])
            E, _ = cv2.findEssentialMat(p1, p2, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.999, threshold=threshold)
            if E is None or E.shape != (3, 3):
                continue
            h1 = np.concatenate([a, np.ones(a.shape[:2] + (1,))], axis=2)
            h2 = np.concatenate([b, np.ones(b.shape[:2] + (1,))], axis=2)
            keep = np.abs(np.einsum("nki,ij,nkj->nk", h2, E, h1)).sum(axis=1)
            swapped = np.abs(np.einsum("nki,ij,nkj->nk", h2[:, ::-1], E, h1)).sum(axis=1)
            votes[both] += np.sign(keep - swapped)  # > 0: swapping fits better
        swap[:, c] = votes > 0
        obs[swap[:, c], c] = obs[swap[:, c], c, ::-1]
        unsettled[:, c] = seen[:, c] & (votes == 0)
        obs[unsettled[:, c], c] = np.nan
        settled.append(c)
    return swap, unsettled
