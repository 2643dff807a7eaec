"""Stereo camera pairs formed from the calibration (paper 004's "neighbouring cameras as pairs").

A pair is used when its two cameras see a common part of the capture volume from usefully different
directions: the angle between the two cameras' rays at the middle of their common view lies in
``[min_angle_deg, max_angle_deg]`` (too small: poor depth; near 180 degrees: the cameras face each
other, their epipoles sit in the images and triangulation degenerates along the baseline), and enough
of what either camera sees of the volume is seen by the other. The volume is where each camera's
view, at its working distance (where its optical axis passes other cameras' axes), is seen by at
least one other camera: the middle of a ring, or a long walkway along which each camera sees only a
stretch. Nothing is tied to six cameras or to one central volume.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from mocap.camera import Rig
from mocap.geometry import fundamental_from_cameras

__all__ = ["CameraPairs", "camera_pairs", "volume_of_interest"]

DEPTH_RANGE = (0.3, 1.7)  # the volume sampled in each camera's view, x its working distance


@dataclass(frozen=True)
class CameraPairs:
    """The stereo pairs of a rig.

    Attributes:
        index: (P, 2) camera indices ``(i, j)``, i < j.
        F: (P, 3, 3) fundamental matrices, ideal pixels, image i -> image j (``x_j^T F x_i = 0``).
        angle_deg: (P,) angle between the two cameras' rays at the middle of their common view, degrees.
        overlap: (P,) fraction of the smaller of the two cameras' views of the volume that both see.
        neighbour: (P,) bool, the cameras are adjacent by azimuth around the volume.
    """

    index: np.ndarray
    F: np.ndarray
    angle_deg: np.ndarray
    overlap: np.ndarray
    neighbour: np.ndarray

    def __len__(self) -> int:
        return len(self.index)

    @functools.cached_property
    def F_t(self) -> np.ndarray:
        """(P, 3, 3) the transposed fundamental matrices (image j -> image i), contiguous."""
        return np.ascontiguousarray(np.swapaxes(self.F, 1, 2))

    def incidence(self, cameras: int) -> np.ndarray:
        """(P, cameras) bool: row p is True at pair p's two cameras (built once per camera count)."""
        cache = self.__dict__.setdefault("_incidence", {})
        if cameras not in cache:
            out = np.zeros((len(self.index), cameras), dtype=bool)
            out[np.arange(len(self.index))[:, None], self.index] = True
            cache[cameras] = out
        return cache[cameras]


def volume_of_interest(rig: Rig) -> tuple[np.ndarray, float]:
    """Centre (3,) m and radius (m) of the capture volume, from where the cameras look.

    The centre is the least-squares point closest to all optical axes; the radius is half the mean
    camera distance to it (a volume the cameras can frame).
    """
    centers = rig.centers()
    axes = np.stack([cam.R[2] for cam in rig.cameras])  # optical axes, world frame
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c, a in zip(centers, axes, strict=True):
        proj = np.eye(3) - np.outer(a, a)
        A += proj
        b += proj @ c
    if np.linalg.cond(A) > 1e8:  # parallel axes: look one mean distance ahead of the cameras
        centre = centers.mean(axis=0) + axes.mean(axis=0) * 3.0
    else:
        centre = np.linalg.solve(A, b)
    radius = 0.5 * float(np.linalg.norm(centers - centre, axis=1).mean())
    return centre, radius


def _axis_crossings(rig: Rig, centre: np.ndarray, min_angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the cameras' optical axes pass each other.

    Returns:
        distance: (C, C) distance along camera i's axis to its closest approach with camera j's axis, m
            (NaN where the axes cross at less than ``min_angle_deg`` or not in front of both cameras).
        working: (C,) each camera's working distance: the median of its row of ``distance``, or its
            distance to the volume ``centre`` (3,) m when the row is all NaN.
    """
    centers = rig.centers()
    axes = np.stack([cam.R[2] for cam in rig.cameras])
    C = len(centers)
    cosine = np.clip(axes @ axes.T, -1.0, 1.0)
    gap = centers[None, :, :] - centers[:, None, :]  # (C, C, 3): camera i -> camera j
    # closest approach of c_i + t a_i and c_j + u a_j: solve [1, -cos; cos, -1] [t, u] = [a_i.g, a_j.g]
    ai_g = np.einsum("id,ijd->ij", axes, gap)
    aj_g = np.einsum("jd,ijd->ij", axes, gap)
    with np.errstate(divide="ignore", invalid="ignore"):
        det = cosine**2 - 1.0
        t = (cosine * aj_g - ai_g) / det
        u = (aj_g - cosine * ai_g) / det
    crossing = (np.degrees(np.arccos(cosine)) >= min_angle_deg) & (t > 0) & (u > 0) & ~np.eye(C, dtype=bool)
    distance = np.where(crossing, t, np.nan)
    fallback = np.linalg.norm(centers - centre, axis=1)
    working = np.array([np.median(distance[i, crossing[i]]) if crossing[i].any() else fallback[i] for i in range(C)])
    return distance, working


def _view_samples(rig: Rig, working: np.ndarray, samples: int, seed: int) -> np.ndarray:
    """(C * samples, 3) seeded points in each camera's view, from 0.3 to 1.7 x its ``working`` distance (C,), m."""
    rng = np.random.default_rng(seed)
    out = []
    for cam, distance in zip(rig.cameras, working, strict=True):
        w, h = cam.size
        pixels = np.column_stack([rng.uniform(0, w, samples), rng.uniform(0, h, samples), np.ones(samples)])
        rays = pixels @ np.linalg.inv(cam.matrix).T  # camera frame, z = 1
        depth = distance * rng.uniform(DEPTH_RANGE[0], DEPTH_RANGE[1], samples)
        out.append(cam.camera_to_world(rays * depth[:, None]))
    return np.concatenate(out)


def _middle(rig: Rig, i: int, j: int, crossing: np.ndarray, working: np.ndarray, common: np.ndarray) -> np.ndarray:
    """(3,) the middle of cameras i and j's common view: where their axes cross when that is within both
    cameras' sampled depths, else the mean of the ``common`` (K, 3) sample points."""
    lo, hi = DEPTH_RANGE
    t, u = crossing[i, j], crossing[j, i]
    if lo * working[i] <= t <= hi * working[i] and lo * working[j] <= u <= hi * working[j]:
        return 0.5 * (rig[i].center + t * rig[i].R[2] + rig[j].center + u * rig[j].R[2])
    return common.mean(axis=0)


def camera_pairs(rig: Rig, min_angle_deg: float = 15.0, max_angle_deg: float = 150.0,
                 min_overlap: float = 0.2, samples: int = 1000, seed: int = 0) -> CameraPairs:
    """Pairs of cameras with a useful common view (see the module docstring).

    Args:
        rig: the calibrated cameras.
        min_angle_deg, max_angle_deg: accepted angle between the cameras' rays at the middle of their common view.
        min_overlap: least fraction of either camera's view of the volume that the other camera sees.
        samples: sample points per camera (seeded, in its view).
        seed: seed of the sample points.

    Returns:
        :class:`CameraPairs` (possibly empty for a one-camera rig).
    """
    C = len(rig)
    if C < 2:
        return CameraPairs(np.zeros((0, 2), int), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0), np.zeros(0, bool))
    centre, _ = volume_of_interest(rig)
    crossing, working = _axis_crossings(rig, centre, min_angle_deg)
    pts = _view_samples(rig, working, samples, seed)
    homogeneous = np.einsum("cij,nj->cni", rig.projection_matrices(), np.column_stack([pts, np.ones(len(pts))]))
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = homogeneous[..., :2] / homogeneous[..., 2:]
    inside = np.stack([(homogeneous[c, :, 2] > 0) & cam.in_image(uv[c]) for c, cam in enumerate(rig.cameras)])
    inside &= inside.sum(axis=0) >= 2  # (C, S): the volume is what two cameras see
    seen = inside.sum(axis=1)
    centers = rig.centers()
    rays = centers - centre
    azimuth = np.arctan2(rays[:, 1], rays[:, 0])
    order = np.argsort(azimuth)
    adjacent = {tuple(sorted((int(order[k]), int(order[(k + 1) % C])))) for k in range(C)} if C > 2 else set()
    rows = []
    for i in range(C):
        for j in range(i + 1, C):
            common = inside[i] & inside[j]
            if not common.any():
                continue
            middle = _middle(rig, i, j, crossing, working, pts[common])
            to_i = (centers[i] - middle) / np.linalg.norm(centers[i] - middle)
            to_j = (centers[j] - middle) / np.linalg.norm(centers[j] - middle)
            angle = float(np.degrees(np.arccos(np.clip(to_i @ to_j, -1.0, 1.0))))
            overlap = float(common.sum() / min(seen[i], seen[j]))
            if min_angle_deg <= angle <= max_angle_deg and overlap >= min_overlap:
                rows.append((i, j, angle, overlap, (i, j) in adjacent or C == 2))
    if not rows:
        return CameraPairs(np.zeros((0, 2), int), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0), np.zeros(0, bool))
    index = np.array([(r[0], r[1]) for r in rows], dtype=np.intp)
    F = np.stack([fundamental_from_cameras(rig[i], rig[j]) for i, j in index])
    return CameraPairs(index, F, np.array([r[2] for r in rows]), np.array([r[3] for r in rows]),
                       np.array([r[4] for r in rows], dtype=bool))
