"""A realistic ring of cameras around the capture volume, and fitting its size to a motion."""

from __future__ import annotations

import cv2
import numpy as np

from mocap.camera import Camera, Rig
from mocap.errors import MocapError

__all__ = ["ring_rig", "fit_ring_radius", "look_at"]

MAX_RADIUS_M = 40.0


def look_at(center: np.ndarray, target: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """(3, 3) world -> camera rotation for a camera at ``center`` looking at ``target`` (z up).

    Camera axes: z forward, x right, y down in the image; ``roll`` (radians) turns the image
    about the viewing direction.
    """
    z = np.asarray(target, dtype=np.float64) - np.asarray(center, dtype=np.float64)
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        raise MocapError("a synthetic camera looks straight up or down; move it or its target")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    return np.stack([c * x + s * y, -s * x + c * y, z])


def ring_rig(n_cameras: int = 6, radius: float = 4.0, height: float = 2.4,
             size: tuple[int, int] = (1024, 768), focal_px: float = 1000.0, distortion: float = 0.05,
             seed: int = 0, target: tuple[float, float, float] = (0.0, 0.0, 0.95)) -> Rig:
    """``n_cameras`` cameras on a ring around ``target``, slightly irregular (seeded).

    Each camera gets, independently: ring radius ``radius`` * U(0.92, 1.08), height ``height``
    + U(-0.3, 0.3) m, azimuth jitter U(-8, 8) deg, aim point jitter N(0, 0.1 m), roll N(0, 1 deg),
    focal ``focal_px`` * U(0.97, 1.03) (fy = fx * U(0.998, 1.002)), principal point N(0, 6 px) from the
    image centre, k1 ~ U(-distortion, distortion), k2 ~ U(-distortion, distortion) / 5,
    p1, p2 ~ N(0, 5e-4), k3 = 0.

    Args:
        n_cameras: number of cameras (>= 2).
        radius: nominal horizontal distance from ``target``, m (default: 4 m; cameras 3.5-4.5 m away).
        height: nominal camera height above the floor, m.
        size: (width, height) of the images, px.
        focal_px: nominal focal length, px.
        distortion: bound of the radial coefficient k1 (0 gives distortion-free lenses).
        seed: seed of the jitter.
        target: the point every camera roughly looks at, m.

    Returns:
        The rig; cameras named ``cam1`` ... and ``metadata`` describing how it was made.
    """
    if n_cameras < 2:
        raise MocapError(f"--cameras {n_cameras}: a rig needs at least 2 cameras")
    if radius <= 0 or focal_px <= 0 or size[0] <= 0 or size[1] <= 0:
        raise MocapError("ring rig: radius, focal length and image size must be positive")
    rng = np.random.default_rng(seed)
    w, h = size
    target = np.asarray(target, dtype=np.float64)
    cameras = []
    for i in range(n_cameras):
        azimuth = 2 * np.pi * i / n_cameras + np.deg2rad(rng.uniform(-8, 8))
        ring = radius * rng.uniform(0.92, 1.08)
        center = target + np.array([ring * np.cos(azimuth), ring * np.sin(azimuth), 0.0])
        center[2] = height + rng.uniform(-0.3, 0.3)
        aim = target + rng.normal(0.0, 0.1, 3)
        R = look_at(center, aim, np.deg2rad(rng.normal(0.0, 1.0)))
        fx = focal_px * rng.uniform(0.97, 1.03)
        K = np.array([[fx, 0.0, (w - 1) / 2 + rng.normal(0, 6)],
                      [0.0, fx * rng.uniform(0.998, 1.002), (h - 1) / 2 + rng.normal(0, 6)],
                      [0.0, 0.0, 1.0]])
        dist = np.array([rng.uniform(-distortion, distortion), rng.uniform(-distortion, distortion) / 5,
                         rng.normal(0, 5e-4), rng.normal(0, 5e-4), 0.0])
        if distortion == 0:
            dist[:] = 0.0
        cameras.append(Camera(f"cam{i + 1}", (w, h), K, dist, cv2.Rodrigues(R)[0].ravel(), -R @ center))
    metadata = {"made_by": "mocap synth", "ring_radius_m": float(radius), "ring_height_m": float(height),
                "focal_px": float(focal_px), "seed": int(seed), "target_m": target.tolist()}
    return Rig(cameras, metadata)


def _coverage(rig: Rig, points: np.ndarray, margin_px: float) -> float:
    """Smallest fraction, over cameras, of ``points`` (N, 3) that project inside the image."""
    worst = 1.0
    for cam in rig:
        worst = min(worst, float(cam.in_image(cam.project(points), margin_px).mean()))
    return worst


def fit_ring_radius(points: np.ndarray, min_radius: float = 4.0, coverage: float = 0.995,
                    margin_px: float = 10.0, **ring_kwargs: object) -> float:
    """Smallest ring radius >= ``min_radius`` at which every camera sees ``coverage`` of the points.

    Grows the radius by 5 % steps (the rig's jitter stays the same for a given seed).

    Args:
        points: (N, 3) motion samples, m (NaN rows ignored); subsample long takes first.
        min_radius: the radius to start from, m.
        coverage: fraction of the points each camera must see.
        margin_px: distance from the image border that counts as inside.
        ring_kwargs: the other :func:`ring_rig` arguments.

    Raises:
        MocapError: even a ring of 40 m does not cover the motion.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    radius = float(min_radius)
    while radius <= MAX_RADIUS_M:
        if len(points) == 0 or _coverage(ring_rig(radius=radius, **ring_kwargs), points, margin_px) >= coverage:
            return radius
        radius *= 1.05
    raise MocapError(f"the motion spans too much of the floor for a camera ring of up to {MAX_RADIUS_M:.0f} m; "
                     "render a part of it with --start/--frames")
