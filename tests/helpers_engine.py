"""Centroid-level simulation for the tracking engine's tests and benchmark.

3D motion (scripted, or a real C3D recording) is projected through a calibrated rig with
``Camera.project``; the 2D centroids get Gaussian noise, temporally correlated dropouts, occlusion
by a vertical body cylinder per subject, fixed (partly blinking) ghost reflections, and merging of
blobs closer than a few pixels. The result is what a detector would hand the tracker
(``list[Detections]`` per frame, camera order) plus the ground truth (:class:`mocap.truth.Truth`)
for :func:`mocap.evaluate.evaluate`. The 3D motion of the C3D files is real; the 2D data are
simulated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.camera import Rig, rig_to_toml
from mocap.detections import Detections
from mocap.export.c3d import read_c3d
from mocap.truth import Truth

C3D_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
# Files recorded y-up (converted to the project's z-up by a +90 degree turn about x).
Y_UP = {"kinematics_tennis_serve", "kinematics_tennis_serve_2players", "walkingOptiTrack"}


@dataclass
class Motion:
    """3D marker motion: ``positions`` (F, M, 3) m, z up, NaN where missing; ``subjects`` (M,) int."""

    name: str
    fps: float
    labels: list[str]
    positions: np.ndarray
    subjects: np.ndarray


def load_motion(name: str, frames: int | None = None) -> Motion:
    """A real C3D motion from ``../shared/data/c3d``, z up, centred horizontally on the origin.

    Subjects are the label prefixes before ``:`` (the two tennis players).
    """
    traj = read_c3d(C3D_DIR / f"{name}.c3d")
    pos = traj.positions[:frames].copy()
    if name in Y_UP:
        pos = np.stack([pos[..., 0], -pos[..., 2], pos[..., 1]], axis=-1)
    pos[..., :2] -= np.nanmean(pos[..., :2].reshape(-1, 2), axis=0)
    prefixes = [lab.split(":")[0] if ":" in lab else "" for lab in traj.labels]
    names = sorted(set(prefixes))
    subjects = np.array([names.index(p) for p in prefixes])
    if "basket" in name:  # one person in a wheelchair: clusters carry per-segment prefixes
        subjects = np.zeros(len(prefixes), dtype=int)
    return Motion(name, traj.fps, traj.labels, pos, subjects)


def extent_radius(motion: Motion) -> float:
    """Largest horizontal distance of any marker from the origin, m."""
    return float(np.nanmax(np.linalg.norm(motion.positions[..., :2], axis=-1)))


def crossing_markers(frames: int = 300, fps: float = 100.0, crossings: int = 4) -> Motion:
    """Two markers swinging through each other repeatedly (they pass within 5 mm at each crossing)."""
    t = np.arange(frames) / fps
    omega = 2 * np.pi * crossings / (2 * t[-1] + 1 / fps)
    a = 0.25 * np.sin(omega * t)
    pos = np.zeros((frames, 2, 3))
    pos[:, 0] = np.stack([a, 0.005 * np.ones_like(t), 1.0 + 0.02 * np.cos(omega * t)], axis=1)
    pos[:, 1] = np.stack([-a, -0.005 * np.ones_like(t), 1.0 - 0.02 * np.cos(omega * t)], axis=1)
    return Motion("crossing", fps, ["A", "B"], pos, np.zeros(2, dtype=int))


@dataclass
class Simulated:
    """A simulated take: per frame one :class:`Detections` per camera, and its truth."""

    frames: list[list[Detections]]
    truth: Truth
    rig: Rig


def simulate(rig: Rig, motion: Motion, noise_px: float = 0.08, dropout_rate: float = 0.01,
             dropout_frames: float = 6.0, ghosts: int = 3, ghost_blink: float = 0.5, merge_px: float = 3.0,
             occlusion_radius: float = 0.1, hidden: np.ndarray | None = None, seed: int = 0) -> Simulated:
    """Project ``motion`` through ``rig`` and degrade it like a real detector's output.

    Args:
        rig: the cameras.
        motion: the 3D motion.
        noise_px: centroid noise std per axis, pixels (also the Detections' covariance).
        dropout_rate: long-run fraction of (camera, marker, frame) samples dropped.
        dropout_frames: mean dropout length, frames.
        ghosts: fixed false blobs per camera (not in the truth).
        ghost_blink: fraction of ghosts that flicker (each frame on with probability 1/2, in runs).
        merge_px: projections closer than this merge into one blob at their mean (flagged merged).
        occlusion_radius: radius of each subject's vertical occluding cylinder, m (0: none).
        hidden: optional (F, C, M) bool mask of extra scripted occlusions.
        seed: seed of every random choice.
    """
    rng = np.random.default_rng(seed)
    pos = motion.positions
    F, M = pos.shape[:2]
    C = len(rig)
    exists = np.isfinite(pos).all(axis=2)
    uv = np.stack([rig.project(np.nan_to_num(pos[k])) for k in range(F)])  # (F, C, M, 2)
    uv[~np.broadcast_to(exists[:, None, :], uv.shape[:3])] = np.nan
    visible = np.stack([[cam.in_image(uv[k, c]) for c, cam in enumerate(rig.cameras)] for k in range(F)])
    visible &= exists[:, None, :]
    if occlusion_radius > 0:
        visible &= ~_cylinder_occlusion(rig, pos, motion.subjects, occlusion_radius)
    if hidden is not None:
        visible &= ~hidden
    if dropout_rate > 0:
        visible &= ~_markov_dropouts(rng, (F, C, M), dropout_rate, dropout_frames)
    uv[~visible] = np.nan
    W, H = np.array([cam.size for cam in rig.cameras]).T
    ghost_xy = rng.random((C, ghosts, 2)) * np.stack([W, H], axis=1)[:, None, :]
    ghost_on = ~_markov_dropouts(rng, (F, C, ghosts), 0.5, 5.0)
    ghost_on |= (np.arange(ghosts) >= round(ghost_blink * ghosts))[None, None, :]
    frames: list[list[Detections]] = []
    for k in range(F):
        dets = []
        for c in range(C):
            pts = uv[k, c][visible[k, c]]
            pts, merged = _merge_close(pts, merge_px)
            pts = pts + rng.normal(scale=noise_px, size=pts.shape)
            pts = np.concatenate([pts, ghost_xy[c][ghost_on[k, c]]])
            merged = np.concatenate([merged, np.zeros(int(ghost_on[k, c].sum()), dtype=bool)])
            order = rng.permutation(len(pts))
            cov = np.broadcast_to(np.eye(2) * noise_px**2, (len(pts), 2, 2))
            dets.append(Detections(pts[order], cov=cov, merged=merged[order], area=np.full(len(pts), 20.0)))
        frames.append(dets)
    truth = Truth(
        labels=list(motion.labels), fps=motion.fps, positions=pos, camera_names=rig.names,
        uv=np.where(visible[..., None], uv, np.nan), visible=visible,
        sigma_px=np.where(visible, noise_px, np.nan),
        settings={"calibration_toml": rig_to_toml(rig), "simulator": "tests.helpers_engine", "seed": seed},
    )
    return Simulated(frames, truth, rig)


def _markov_dropouts(rng: np.random.Generator, shape: tuple[int, ...], rate: float, mean_len: float) -> np.ndarray:
    """(F, ...) bool two-state Markov chain: off runs of mean ``mean_len`` frames, long-run ``rate`` off."""
    p_end = 1.0 / mean_len
    p_start = rate * p_end / max(1.0 - rate, 1e-9)
    out = np.zeros(shape, dtype=bool)
    state = rng.random(shape[1:]) < rate
    for k in range(shape[0]):
        u = rng.random(shape[1:])
        state = np.where(state, u >= p_end, u < p_start)
        out[k] = state
    return out


def _cylinder_occlusion(rig: Rig, pos: np.ndarray, subjects: np.ndarray, radius: float) -> np.ndarray:
    """(F, C, M) bool: the marker is behind its subject's vertical cylinder as seen from the camera."""
    F, M = pos.shape[:2]
    hidden = np.zeros((F, len(rig), M), dtype=bool)
    cams = rig.centers()[:, :2]
    for s in np.unique(subjects):
        sel = subjects == s
        with np.errstate(invalid="ignore"):
            axis = np.nanmean(pos[:, sel, :2], axis=1)  # (F, 2)
        m = pos[:, sel, :2]  # (F, Ms, 2)
        for c, cam in enumerate(cams):
            d = m - cam  # camera -> marker
            a = (axis - cam)[:, None, :]
            with np.errstate(invalid="ignore", divide="ignore"):
                t = (a * d).sum(axis=2) / (d * d).sum(axis=2)
                closest = cam + t[..., None] * d
                gap = np.linalg.norm(closest - axis[:, None, :], axis=2)
                own = np.linalg.norm(m - axis[:, None, :], axis=2)
                hidden[:, c, sel] = (t > 0) & (t < 1) & (gap < radius) & (own > radius)
    return hidden


def _merge_close(pts: np.ndarray, merge_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Replace groups of points closer than ``merge_px`` by their mean; (N, 2) -> (N', 2), merged (N',)."""
    n = len(pts)
    if n < 2 or merge_px <= 0:
        return pts, np.zeros(n, dtype=bool)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    a, b = np.nonzero(np.triu(d < merge_px, 1))
    if a.size == 0:
        return pts, np.zeros(n, dtype=bool)
    group = np.arange(n)
    for i, j in zip(a, b, strict=True):  # few close pairs per frame: union them
        gi, gj = group[i], group[j]
        group[group == gj] = gi
    labels, inverse, counts = np.unique(group, return_inverse=True, return_counts=True)
    out = np.zeros((len(labels), 2))
    np.add.at(out, inverse, pts)
    return out / counts[:, None], counts > 1
