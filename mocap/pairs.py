"""Stereo camera pairs formed from the calibration (paper 004's "neighbouring cameras as pairs").

A pair is used when its two cameras see a common part of the capture volume from usefully different
directions: the angle between the two viewing rays at the volume centre lies in
``[min_angle_deg, max_angle_deg]`` (too small: poor depth; near 180 degrees: the cameras face each
other, their epipoles sit in the images and triangulation degenerates along the baseline), and enough
sample points of the volume project inside both images. Neighbours by azimuth around the volume are
always kept when they pass these tests, so every camera belongs to at least one pair where possible.
Nothing is tied to six cameras.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from mocap.camera import Rig
from mocap.geometry import fundamental_from_cameras

__all__ = ["CameraPairs", "camera_pairs", "volume_of_interest"]


@dataclass(frozen=True)
class CameraPairs:
    """The stereo pairs of a rig.

    Attributes:
        index: (P, 2) camera indices ``(i, j)``, i < j.
        F: (P, 3, 3) fundamental matrices, ideal pixels, image i -> image j (``x_j^T F x_i = 0``).
        angle_deg: (P,) angle between the two cameras' rays at the volume centre, degrees.
        overlap: (P,) fraction of the volume's sample points inside both images.
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


def camera_pairs(rig: Rig, min_angle_deg: float = 15.0, max_angle_deg: float = 150.0,
                 min_overlap: float = 0.2, samples: int = 2000, seed: int = 0) -> CameraPairs:
    """Pairs of cameras with a useful common view (see the module docstring).

    Args:
        rig: the calibrated cameras.
        min_angle_deg, max_angle_deg: accepted angle between the cameras' rays at the volume centre.
        min_overlap: least fraction of the volume's sample points both cameras must see.
        samples: number of sample points in the volume (a seeded uniform ball).
        seed: seed of the sample points.

    Returns:
        :class:`CameraPairs` (possibly empty for a one-camera rig).
    """
    C = len(rig)
    centre, radius = volume_of_interest(rig)
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(samples, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = centre + dirs * radius * rng.random(samples)[:, None] ** (1 / 3)
    inside = np.stack([cam.in_image(cam.project(pts)) for cam in rig.cameras])  # (C, S)
    rays = rig.centers() - centre
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    azimuth = np.arctan2(rays[:, 1], rays[:, 0])
    order = np.argsort(azimuth)
    adjacent = {tuple(sorted((int(order[k]), int(order[(k + 1) % C])))) for k in range(C)} if C > 2 else set()
    rows = []
    for i in range(C):
        for j in range(i + 1, C):
            angle = float(np.degrees(np.arccos(np.clip(rays[i] @ rays[j], -1.0, 1.0))))
            overlap = float((inside[i] & inside[j]).mean())
            if min_angle_deg <= angle <= max_angle_deg and overlap >= min_overlap:
                rows.append((i, j, angle, overlap, (i, j) in adjacent or C == 2))
    if not rows:
        return CameraPairs(np.zeros((0, 2), int), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0), np.zeros(0, bool))
    index = np.array([(r[0], r[1]) for r in rows], dtype=np.intp)
    F = np.stack([fundamental_from_cameras(rig[i], rig[j]) for i, j in index])
    return CameraPairs(index, F, np.array([r[2] for r in rows]), np.array([r[3] for r in rows]),
                       np.array([r[4] for r in rows], dtype=bool))
