"""Synthetic trajectories and 2D detections for the export tests and benchmark (seeded)."""

from __future__ import annotations

import numpy as np

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.trajectories import Trajectories


def synthetic_trajectories(n_frames: int = 240, n_markers: int = 12, fps: float = 120.0, gap_fraction: float = 0.1,
                           seed: int = 0, first_frame: int = 0, n_cameras: int = 6) -> Trajectories:
    """Markers circling at 0.5-1.5 m height (z up, metres) with random gaps, residuals and camera masks."""
    rng = np.random.default_rng(seed)
    t = (np.arange(n_frames) / fps)[:, None]
    phase = rng.uniform(0, 2 * np.pi, n_markers)
    radius = rng.uniform(0.1, 0.8, n_markers)
    positions = np.stack([radius * np.cos(2 * t + phase), radius * np.sin(2 * t + phase),
                          1.0 + 0.5 * np.sin(3 * t + phase) + rng.normal(0, 1e-4, (n_frames, n_markers))], axis=2)
    gaps = rng.random((n_frames, n_markers)) < gap_fraction
    positions[gaps] = np.nan
    residuals = np.where(gaps, np.nan, rng.gamma(2.0, 0.2, (n_frames, n_markers)))
    masks = rng.integers(1, 2**n_cameras, (n_frames, n_markers)).astype(np.uint32)
    masks[gaps] = 0
    labels = [f"Body:Marker{i + 1}" for i in range(n_markers)]
    return Trajectories(labels, fps, positions, residuals, masks, [f"cam{i + 1}" for i in range(n_cameras)],
                        first_frame, {"subject": "synthetic"})


def synthetic_detections(rig: Rig, points: np.ndarray, rng: np.random.Generator, clutter: int = 3) -> list[Detections]:
    """One :class:`Detections` per camera: the projections of ``points`` (N, 3) m that land in the image,
    plus ``clutter`` random blobs, with random (exactly representable-or-not) float64 fields and flags."""
    out = []
    for cam in rig:
        uv = cam.project(points)
        uv = np.vstack([uv[cam.in_image(uv)], rng.uniform((0, 0), cam.size, (clutter, 2))])
        n = len(uv)
        a = rng.uniform(0.01, 0.2, (n, 2, 2))
        out.append(Detections(uv + rng.normal(0, 0.05, uv.shape), rng.uniform(4, 60, n), rng.uniform(0.5, 1, n),
                              a @ a.transpose(0, 2, 1), rng.random(n) < 0.1, rng.uniform(50, 9000, n),
                              rng.random(n) < 0.1))
    return out
