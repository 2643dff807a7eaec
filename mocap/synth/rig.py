"""Realistic camera rigs: a ring around a compact capture volume (fitted to a motion), or two staggered
rows of cameras along a long walkway."""

from __future__ import annotations

import logging

import cv2
import numpy as np

from mocap.camera import Camera, Rig
from mocap.errors import MocapError

__all__ = ["ring_rig", "fit_ring_radius", "fit_walkway_cameras", "look_at", "rig_for_motion", "walkway_rig"]

log = logging.getLogger(__name__)

MAX_RADIUS_M = 40.0
DEFAULT_CAMERAS = 6
DEFAULT_RADIUS_M = 4.0
WALKWAY_MIN_LENGTH_M = 2 * DEFAULT_RADIUS_M  # a motion this long and 3x longer than wide gets a walkway rig
FIT_SAMPLES = 4000  # motion samples used to fit a rig


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


def _jittered_camera(name: str, center: np.ndarray, aim: np.ndarray, size: tuple[int, int], focal_px: float,
                     distortion: float, rng: np.random.Generator) -> Camera:
    """A camera at ``center`` (3,) m looking at ``aim`` (3,) m with the lens jitter described in :func:`ring_rig`."""
    w, h = size
    R = look_at(center, aim, np.deg2rad(rng.normal(0.0, 1.0)))
    fx = focal_px * rng.uniform(0.97, 1.03)
    K = np.array([[fx, 0.0, (w - 1) / 2 + rng.normal(0, 6)],
                  [0.0, fx * rng.uniform(0.998, 1.002), (h - 1) / 2 + rng.normal(0, 6)],
                  [0.0, 0.0, 1.0]])
    dist = np.array([rng.uniform(-distortion, distortion), rng.uniform(-distortion, distortion) / 5,
                     rng.normal(0, 5e-4), rng.normal(0, 5e-4), 0.0])
    if distortion == 0:
        dist[:] = 0.0
    return Camera(name, (w, h), K, dist, cv2.Rodrigues(R)[0].ravel(), -R @ center)


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
    target = np.asarray(target, dtype=np.float64)
    cameras = []
    for i in range(n_cameras):
        azimuth = 2 * np.pi * i / n_cameras + np.deg2rad(rng.uniform(-8, 8))
        ring = radius * rng.uniform(0.92, 1.08)
        center = target + np.array([ring * np.cos(azimuth), ring * np.sin(azimuth), 0.0])
        center[2] = height + rng.uniform(-0.3, 0.3)
        aim = target + rng.normal(0.0, 0.1, 3)
        cameras.append(_jittered_camera(f"cam{i + 1}", center, aim, size, focal_px, distortion, rng))
    metadata = {"made_by": "mocap synth", "layout": "ring", "ring_radius_m": float(radius),
                "ring_height_m": float(height), "focal_px": float(focal_px), "seed": int(seed),
                "target_m": target.tolist()}
    return Rig(cameras, metadata)


def walkway_rig(n_cameras: int, length: float, standoff: float, height: float = 2.4,
                size: tuple[int, int] = (1024, 768), focal_px: float = 1000.0, distortion: float = 0.05,
                seed: int = 0, target: tuple[float, float, float] = (0.0, 0.0, 0.95), heading: float = 0.0,
                yaw_deg: float = 25.0) -> Rig:
    """``n_cameras`` cameras in two staggered rows along a straight walkway (a gait lab's layout).

    The walkway runs through ``target`` along the floor direction ``heading``. Camera ``i`` aims at
    the walkway point ``(i + 0.5) * length / n_cameras - length / 2`` along it, from alternate sides,
    ``standoff`` * U(0.92, 1.08) from the centre line and turned ``yaw_deg`` forward or back
    (alternating along each row), so that same-row neighbours cross at ~2 yaw degrees and cameras of
    the two rows at 110-155 degrees. Height, aim and lens jitter as :func:`ring_rig`.

    Args:
        n_cameras: number of cameras (>= 2).
        length: walkway length the aim points span, m.
        standoff: horizontal distance from the cameras to the centre line, m.
        height: nominal camera height above the floor, m.
        size, focal_px, distortion, seed: as :func:`ring_rig`.
        target: centre of the walkway, m.
        heading: direction of the walkway on the floor, radians from +x.
        yaw_deg: turn of every camera from square-on, degrees.

    Returns:
        The rig; cameras named ``cam1`` ... and ``metadata`` describing how it was made.
    """
    if n_cameras < 2:
        raise MocapError(f"--cameras {n_cameras}: a rig needs at least 2 cameras")
    if length <= 0 or standoff <= 0 or focal_px <= 0 or size[0] <= 0 or size[1] <= 0:
        raise MocapError("walkway rig: length, standoff, focal length and image size must be positive")
    rng = np.random.default_rng(seed)
    target = np.asarray(target, dtype=np.float64)
    along = np.array([np.cos(heading), np.sin(heading), 0.0])
    across = np.array([-along[1], along[0], 0.0])
    forward = np.tan(np.deg2rad(yaw_deg))
    cameras = []
    for i in range(n_cameras):
        side = 1.0 if i % 2 == 0 else -1.0
        turn = 1.0 if (i // 2) % 2 == 0 else -1.0
        aim = target + along * ((i + 0.5) * length / n_cameras - length / 2) + rng.normal(0.0, 0.1, 3)
        distance = standoff * rng.uniform(0.92, 1.08)
        center = aim + side * distance * across - turn * forward * distance * along
        center[2] = height + rng.uniform(-0.3, 0.3)
        cameras.append(_jittered_camera(f"cam{i + 1}", center, aim, size, focal_px, distortion, rng))
    metadata = {"made_by": "mocap synth", "layout": "walkway", "walkway_length_m": float(length),
                "standoff_m": float(standoff), "heading_rad": float(heading), "yaw_deg": float(yaw_deg),
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


def _views(rig: Rig, points: np.ndarray, margin_px: float) -> np.ndarray:
    """(N,) number of cameras in whose image each of ``points`` (N, 3) falls."""
    return sum(cam.in_image(cam.project(points), margin_px).astype(int) for cam in rig)


def fit_walkway_cameras(points: np.ndarray, min_cameras: int = 6, views: int = 4, coverage: float = 0.99,
                        margin_px: float = 10.0, max_cameras: int = 32, **walkway_kwargs: object) -> int:
    """Fewest cameras (an even number >= ``min_cameras``) along a walkway giving ``coverage`` of the points
    at least ``views`` cameras each (body occlusion not counted).

    Args:
        points: (N, 3) motion samples, m (NaN rows ignored); subsample long takes first.
        min_cameras: the count to start from.
        views: cameras each point needs.
        coverage: fraction of the points that must have ``views`` cameras.
        margin_px: distance from the image border that counts as inside.
        max_cameras: give up beyond this count.
        walkway_kwargs: the other :func:`walkway_rig` arguments.

    Raises:
        MocapError: even ``max_cameras`` cameras do not cover the motion.
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(axis=1)]
    n = max(2, min_cameras + min_cameras % 2)
    if len(points) == 0:
        return n
    while n <= max_cameras:
        if np.mean(_views(walkway_rig(n, **walkway_kwargs), points, margin_px) >= views) >= coverage:
            return n
        n += 2
    raise MocapError(f"{max_cameras} cameras along the walkway do not give {coverage:.0%} of the motion "
                     f"{views} views; give --cameras and --radius, or render a part with --start/--frames")


def rig_for_motion(positions: np.ndarray, layout: str = "auto", n_cameras: int | None = None,
                   radius: float | None = None, **lens: object) -> Rig:
    """The rig ``mocap synth`` puts around a motion: a ring widened until every camera sees 99.5 % of it,
    or, for a long straight path (``layout`` "auto": over 8 m and 3x longer than wide), a walkway with as
    many cameras as give 99 % of it 4 views.

    Args:
        positions: (F, M, 3) the motion (centred on the floor, z up), m; NaN for gaps.
        layout: "auto", "ring" or "walkway".
        n_cameras: camera count (default: 6 on a ring, fitted along a walkway).
        radius: ring radius, or the walkway cameras' distance from its centre line, m (default: fitted).
        lens: ``size``, ``focal_px``, ``distortion`` and ``seed`` of :func:`ring_rig`.
    """
    pts = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) == 0:
        raise MocapError("the motion holds no marker samples to fit the cameras around")
    lo, hi = np.percentile(pts, [0.5, 99.5], axis=0)
    pts = pts[np.random.default_rng(0).choice(len(pts), min(len(pts), FIT_SAMPLES), replace=False)]
    target = (0.0, 0.0, float(np.clip((lo[2] + hi[2]) / 2, 0.2, 1.2)))
    heading, along, across = _floor_extent(pts)
    if layout == "auto":
        layout = "walkway" if along > WALKWAY_MIN_LENGTH_M and along >= 3 * across else "ring"
    if layout == "walkway":
        walkway = {"length": along + 2.0, "standoff": radius or across / 2 + DEFAULT_RADIUS_M, "target": target,
                   "heading": heading, **lens}
        n_cameras = n_cameras or fit_walkway_cameras(pts, DEFAULT_CAMERAS, **walkway)
        log.info("the motion runs %.1f m along a %.1f m wide path: %d cameras in two rows along it", along, across,
                 n_cameras)
        rig = walkway_rig(n_cameras, **walkway)
    elif layout == "ring":
        ring = {"n_cameras": n_cameras or DEFAULT_CAMERAS, "target": target, **lens}
        fitted = radius is None
        if fitted:
            radius = fit_ring_radius(pts, DEFAULT_RADIUS_M, **ring)
            if radius > DEFAULT_RADIUS_M:
                log.warning("the motion spans %.1f x %.1f m of floor: camera ring widened from %.1f to %.1f m so "
                            "every camera sees it (markers get smaller; use --start/--frames to film a part, or "
                            "--layout walkway)", hi[0] - lo[0], hi[1] - lo[1], DEFAULT_RADIUS_M, radius)
        rig = ring_rig(radius=radius, **ring)
        rig.metadata["ring_radius_fitted_to_motion"] = fitted
    else:
        raise MocapError(f"camera layout {layout!r}: choose auto, ring or walkway")
    rig.metadata["motion_volume_m"] = [lo.round(3).tolist(), hi.round(3).tolist()]
    return rig


def _floor_extent(points: np.ndarray) -> tuple[float, float, float]:
    """The motion's main direction on the floor (radians from +x) and its length and width along and
    across it, m (0.5-99.5 percentiles of the (N, 3) ``points``)."""
    xy = points[:, :2] - points[:, :2].mean(axis=0)
    _, vectors = np.linalg.eigh(np.cov(xy.T) if len(xy) > 1 else np.eye(2))
    main = vectors[:, 1]
    spans = [np.ptp(np.percentile(xy @ v, [0.5, 99.5])) for v in (main, vectors[:, 0])]
    return float(np.arctan2(main[1], main[0])), float(spans[0]), float(spans[1])
