"""Placing the calibrated rig in the world: rigid and similarity transforms, L-frame and floor.

After bundle adjustment the world frame is the reference camera's and the scale is the wand's.
The user's world (z up, metres, origin on the floor) comes from:

* an L-frame: 3-4 markers at stated coordinates (default: corner at the origin, long arm +x,
  short arm +y, marker centres on z = 0). Its markers are triangulated, matched to the stated
  points by their pairwise distances (the distances of an L-frame are all different), and the
  rig is moved by the rigid transform that best maps the measured points onto the stated ones
  (Kabsch / Umeyama, least squares). The best *similarity* transform's scale is reported too:
  far from 1 it means the wand's stated length is wrong;
* or floor markers: >= 3 markers lying on the floor; their plane becomes z = 0 (normal pointing
  to the cameras), the origin their centroid, the horizontal axes turned as little as possible.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import permutations

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.errors import MocapError
from mocap.geometry import epipolar_distance_matrix, fundamental_from_cameras, triangulate_weighted

__all__ = [
    "DEFAULT_LFRAME",
    "Similarity",
    "similarity_transform",
    "transform_rig",
    "parse_points",
    "static_markers",
    "match_lframe",
    "align_to_lframe",
    "align_to_floor",
]

DEFAULT_LFRAME = np.array([[0.0, 0.0, 0.0], [0.2, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 0.35, 0.0]])


@dataclass
class Similarity:
    """``x' = scale * R @ x + t`` (metres)."""

    scale: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, 3)."""
        return self.scale * np.asarray(points) @ self.R.T + self.t


def similarity_transform(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity (or rigid, ``with_scale=False``) transform mapping ``src`` onto ``dst``.

    Umeyama, *Least-squares estimation of transformation parameters between two point patterns*,
    IEEE PAMI 13(4), 1991 (proper rotations only: the reflection case is excluded).

    Args:
        src, dst: (N, 3) corresponding points, N >= 3 not collinear.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    U, S, Vt = np.linalg.svd(b.T @ a / len(src))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    R = U @ D @ Vt
    scale = float(np.trace(np.diag(S) @ D) / ((a**2).sum() / len(src))) if with_scale else 1.0
    return Similarity(scale, R, mu_d - scale * R @ mu_s)


def transform_rig(rig: Rig, T: Similarity) -> Rig:
    """The same rig in a new world frame ``x' = s R x + t``: positions scale, cameras turn.

    A camera ``X_c = R_c X + t_c`` (metres) becomes ``X_c' = R_c R^T X' + (s t_c - R_c R^T t)``
    in the new units (its camera-frame coordinates scale by ``s`` too).
    """
    cams = []
    for cam in rig:
        Rc = cam.R @ T.R.T
        tc = T.scale * cam.translation - Rc @ T.t
        cams.append(cam.with_pose(cv2.Rodrigues(Rc)[0].ravel(), tc))
    return Rig(cams, dict(rig.metadata), dict(rig.extra_tables))


def parse_points(text: str, what: str = "--lframe") -> np.ndarray:
    """``"x,y,z; x,y,z; ..."`` (metres) -> (P, 3)."""
    try:
        pts = np.array([[float(v) for v in p.split(",")] for p in text.split(";") if p.strip()])
    except ValueError:
        pts = np.zeros((0, 0))
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise MocapError(f"{what} {text!r}: give at least 3 marker positions in metres as 'x,y,z; x,y,z; x,y,z'")
    return pts


def _average_blobs(frames: Sequence[Sequence[Detections]], camera: int, radius_px: float) -> np.ndarray:
    """(B, 2) blobs of one camera that stay put in at least half the frames, averaged over the frames."""
    xy = np.concatenate([frame[camera].xy for frame in frames]) if frames else np.zeros((0, 2))
    if len(xy) == 0:
        return np.zeros((0, 2))
    n, label = connected_components(_near_pairs(xy, radius_px), directed=False)
    count = np.bincount(label, minlength=n)
    keep = np.flatnonzero(count >= 0.5 * len(frames))
    sums = np.stack([np.bincount(label, weights=xy[:, a], minlength=n) for a in range(2)], axis=1)
    return sums[keep] / count[keep, None]


def static_markers(rig: Rig, frames: Sequence[Sequence[Detections]], tol_px: float = 2.0,
                   radius_px: float = 1.0) -> np.ndarray:
    """3D positions of still markers (L-frame, floor markers) seen in a short static take.

    Each camera's blobs are averaged over the frames; candidate points come from every camera pair's
    epipolar matches and are kept when a third camera sees a blob where they project (two-camera
    rigs: the pair suffices); duplicates are merged and every point is re-triangulated from all
    cameras that see it.

    Args:
        rig: the calibrated cameras.
        frames: per frame, one :class:`Detections` per camera (rig order).
        tol_px: epipolar / reprojection tolerance, pixels.
        radius_px: how far a still blob may wander between frames, pixels.

    Returns:
        (N, 3) marker positions, metres.
    """
    C = len(rig)
    ideal = [rig[c].undistort(_average_blobs(frames, c, radius_px)) for c in range(C)]
    P = rig.projection_matrices()
    found: list[np.ndarray] = []
    for i in range(C):
        for j in range(i + 1, C):
            if not len(ideal[i]) or not len(ideal[j]):
                continue
            a, b = np.nonzero(epipolar_distance_matrix(fundamental_from_cameras(rig[i], rig[j]), ideal[i],
                                                       ideal[j]) < tol_px)
            for n in range(len(a)):
                uv = np.full((C, 1, 2), np.nan)
                uv[i, 0], uv[j, 0] = ideal[i][a[n]], ideal[j][b[n]]
                X = triangulate_weighted(P[[i, j]], uv[[i, j]])[0]
                support = 0
                for k in range(C):
                    if k in (i, j) or not len(ideal[k]):
                        continue
                    proj = rig[k].undistort(rig[k].project(X))[0]
                    gap = np.linalg.norm(ideal[k] - proj, axis=1)
                    if gap.min() < tol_px:
                        uv[k, 0] = ideal[k][int(np.argmin(gap))]
                        support += 1
                if support or C == 2:
                    found.append(triangulate_weighted(P, uv)[0][0])
    if not found:
        return np.zeros((0, 3))
    pts = np.array(found)
    n, label = connected_components(_near_pairs(pts, 0.01), directed=False)
    return np.stack([pts[label == k].mean(axis=0) for k in range(n)])


def _near_pairs(points: np.ndarray, radius: float) -> coo_matrix:
    """Graph joining points closer than ``radius`` (for merging by connected components)."""
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    return coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))


def match_lframe(measured: np.ndarray, lframe: np.ndarray, tol_m: float = 0.02) -> np.ndarray:
    """Which measured point is which L-frame marker, by pairwise distances.

    Args:
        measured: (N, 3) triangulated still markers, metres (N >= P; extra points are ignored).
        lframe: (P, 3) stated L-frame marker positions, metres.
        tol_m: largest tolerated distance mismatch, metres.

    Returns:
        (P,) index into ``measured`` of each L-frame marker.

    Raises:
        MocapError: too few markers, or none of the assignments fits.
    """
    N, P = len(measured), len(lframe)
    if N < P:
        raise MocapError(f"L-frame: only {N} still marker(s) were found in at least two cameras, {P} are needed; "
                         "check that every L-frame marker is visible to two or more cameras")
    target = np.linalg.norm(lframe[:, None] - lframe[None], axis=2)
    dist = np.linalg.norm(measured[:, None] - measured[None], axis=2)
    perms = np.array(list(permutations(range(N), P)))
    mismatch = np.abs(dist[perms[:, :, None], perms[:, None, :]] - target).max(axis=(1, 2))
    best = int(np.argmin(mismatch))
    if mismatch[best] > tol_m:
        raise MocapError(
            f"L-frame: no {P} of the {N} still markers have the stated distances (best mismatch "
            f"{1000 * mismatch[best]:.0f} mm); check --lframe (marker coordinates in metres) and the wand length"
        )
    return perms[best]


def align_to_lframe(rig: Rig, measured: np.ndarray, lframe: np.ndarray) -> tuple[Rig, dict[str, float]]:
    """Move the rig so that the measured L-frame markers land on their stated positions.

    Args:
        rig: the calibrated cameras.
        measured: (P, 3) measured L-frame markers in the rig's frame, metres (matched order).
        lframe: (P, 3) stated positions, metres.

    Returns:
        The aligned rig and facts: ``rms_mm`` (fit residual of the rigid transform) and ``scale``
        (of the best similarity transform: 1.0 when the wand length is right).
    """
    rigid = similarity_transform(measured, lframe, with_scale=False)
    scale = similarity_transform(measured, lframe).scale
    rms = float(np.sqrt(((rigid.apply(measured) - lframe) ** 2).sum(axis=1).mean()))
    return transform_rig(rig, rigid), {"rms_mm": 1000 * rms, "scale": scale}


def align_to_floor(rig: Rig, floor: np.ndarray) -> Rig:
    """Make the plane through ``floor`` (N >= 3 markers, metres) z = 0, normal towards the cameras.

    The origin goes to the markers' centroid; the rotation is the smallest one taking the
    plane's normal to +z.
    """
    floor = np.asarray(floor, dtype=np.float64)
    if len(floor) < 3:
        raise MocapError(f"floor: only {len(floor)} floor marker(s) were found; at least 3 are needed")
    centroid = floor.mean(axis=0)
    normal = np.linalg.svd(floor - centroid)[2][2]
    if np.dot(rig.centers().mean(axis=0) - centroid, normal) < 0:
        normal = -normal
    axis = np.cross(normal, [0.0, 0.0, 1.0])
    angle = np.arctan2(np.linalg.norm(axis), normal[2])
    rvec = axis / max(np.linalg.norm(axis), 1e-15) * angle
    R = cv2.Rodrigues(rvec)[0]
    return transform_rig(rig, Similarity(1.0, R, -R @ centroid))
