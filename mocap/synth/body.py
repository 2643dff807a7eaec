"""A procedural person marching in place: a capsule skeleton with markers on its skin.

Forward kinematics of 15 rigid segments (torso, pelvis, head; per side thigh, shin, foot, upper
arm, forearm, hand), z up, metres. Marching: each thigh rises in turn (hip flexion up to ~60 deg,
knee ~80 deg, toes pointing down), the arms swing against the legs, the trunk sways and nods a
little. Body size, cadence, amplitudes, facing direction and phase are drawn from ``seed``.

Each segment is a capsule (its axis and radius are the occlusion model); each marker sits on the
skin of one segment: its centre ``radius + marker radius`` from the axis, so a marker is hidden by
its own segment exactly when it faces away from the camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.errors import MocapError
from mocap.synth.motion import Motion
from mocap.synth.occlusion import Capsules

__all__ = ["marching_body", "marching_motion", "MARKERS"]

# (name, segment, t along the axis (0 = first joint, 1 = second), outward direction in the neutral pose:
# x forward, y left, z up; only its part perpendicular to the segment axis counts). The first 40 form
# the default set; the rest are optional extras.
MARKERS: tuple[tuple[str, str, float, tuple[float, float, float]], ...] = (
    ("LFHD", "head", 0.5, (1, 0.6, 0)), ("RFHD", "head", 0.5, (1, -0.6, 0)),
    ("LBHD", "head", 0.5, (-1, 0.6, 0)), ("RBHD", "head", 0.5, (-1, -0.6, 0)),
    ("C7", "torso", 1.0, (-1, 0, 0)), ("T10", "torso", 0.45, (-1, 0, 0)),
    ("CLAV", "torso", 0.95, (1, 0, 0)), ("STRN", "torso", 0.6, (1, 0, 0)),
    ("LASI", "pelvis", 0.05, (1, 0, 0.3)), ("RASI", "pelvis", 0.95, (1, 0, 0.3)),
    ("LPSI", "pelvis", 0.3, (-1, 0, 0.3)), ("RPSI", "pelvis", 0.7, (-1, 0, 0.3)),
    ("LSHO", "l_uarm", 0.0, (0, 1, 0)), ("LUPA", "l_uarm", 0.5, (-0.5, 1, 0)),
    ("LELB", "l_uarm", 1.0, (-0.3, 1, 0)), ("LFRM", "l_farm", 0.5, (0, 1, 0)),
    ("LWRA", "l_farm", 1.0, (1, 0, 0)), ("LWRB", "l_farm", 1.0, (-1, 0, 0)), ("LFIN", "l_hand", 1.0, (0, 1, 0)),
    ("RSHO", "r_uarm", 0.0, (0, -1, 0)), ("RUPA", "r_uarm", 0.5, (-0.5, -1, 0)),
    ("RELB", "r_uarm", 1.0, (-0.3, -1, 0)), ("RFRM", "r_farm", 0.5, (0, -1, 0)),
    ("RWRA", "r_farm", 1.0, (1, 0, 0)), ("RWRB", "r_farm", 1.0, (-1, 0, 0)), ("RFIN", "r_hand", 1.0, (0, -1, 0)),
    ("LTHI", "l_thigh", 0.55, (0, 1, 0)), ("LKNE", "l_thigh", 1.0, (0, 1, 0)), ("LTIB", "l_shin", 0.5, (0, 1, 0)),
    ("LANK", "l_shin", 1.0, (0, 1, 0)), ("LHEE", "l_foot", -0.25, (-1, 0, -1)), ("LTOE", "l_foot", 1.0, (0, 0, 1)),
    ("LMT5", "l_foot", 0.7, (0, 1, 0.3)),
    ("RTHI", "r_thigh", 0.55, (0, -1, 0)), ("RKNE", "r_thigh", 1.0, (0, -1, 0)), ("RTIB", "r_shin", 0.5, (0, -1, 0)),
    ("RANK", "r_shin", 1.0, (0, -1, 0)), ("RHEE", "r_foot", -0.25, (-1, 0, -1)), ("RTOE", "r_foot", 1.0, (0, 0, 1)),
    ("RMT5", "r_foot", 0.7, (0, -1, 0.3)),
    ("RBAK", "torso", 0.7, (-1, -0.5, 0)),
    ("LKNM", "l_thigh", 1.0, (0, -1, 0)), ("RKNM", "r_thigh", 1.0, (0, 1, 0)),
    ("LELM", "l_uarm", 1.0, (0, -1, 0)), ("RELM", "r_uarm", 1.0, (0, 1, 0)),
    ("LSHN", "l_shin", 0.3, (1, 0, 0)), ("RSHN", "r_shin", 0.3, (1, 0, 0)),
    ("LTHB", "l_thigh", 0.4, (-1, 0, 0)), ("RTHB", "r_thigh", 0.4, (-1, 0, 0)),
)
DEFAULT_MARKERS = 40


@dataclass(frozen=True)
class _Segment:
    """One rigid segment: ``start`` (F, 3) m, ``rotation`` (F, 3, 3) neutral -> world, neutral
    ``axis`` (3,) unit, ``length`` m, capsule ``radius`` m."""

    start: np.ndarray
    rotation: np.ndarray
    axis: np.ndarray
    length: float
    radius: float

    @property
    def end(self) -> np.ndarray:
        return self.start + self.rotation @ (self.axis * self.length)


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """(F,) angles, radians -> (F, 3, 3) rotations about world axis 0/1/2 (x/y/z)."""
    angle = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(angle), np.sin(angle)
    R = np.zeros(angle.shape + (3, 3))
    i, j = [k for k in range(3) if k != axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s if axis != 1 else s
    R[..., j, i] = s if axis != 1 else -s
    return R


def _skeleton(n_frames: int, fps: float, rng: np.random.Generator) -> dict[str, _Segment]:
    """The 15 segments over ``n_frames`` frames, with seeded body size and gait."""
    scale = rng.uniform(0.94, 1.06)
    thigh, shin, ankle_h = 0.43 * scale, 0.43 * scale, 0.08
    trunk, uarm, farm = 0.52 * scale, 0.30 * scale, 0.27 * scale
    step_hz = rng.uniform(0.8, 1.0)
    hip_amp = np.deg2rad(rng.uniform(50, 65))
    knee_amp = hip_amp * rng.uniform(1.2, 1.4)
    arm_amp = np.deg2rad(rng.uniform(20, 35))
    yaw0 = rng.uniform(-np.pi, np.pi)
    phase = 2 * np.pi * step_hz * np.arange(n_frames) / fps + rng.uniform(0, 2 * np.pi)

    def lift(ph: np.ndarray) -> np.ndarray:
        return np.maximum(0.0, np.sin(ph)) ** 2

    up = np.array([0.0, 0.0, 1.0])
    down = -up
    pelvis_pos = np.zeros((n_frames, 3))
    pelvis_pos[:, 2] = thigh + shin + ankle_h - 0.005 * (1 - np.cos(2 * phase))
    R_pelvis = _rot(2, yaw0 + np.deg2rad(3) * np.sin(phase)) @ _rot(0, np.deg2rad(2) * np.sin(phase))
    R_trunk = R_pelvis @ _rot(1, np.deg2rad(4 + 2 * np.sin(2 * phase)))
    R_head = R_trunk @ _rot(1, np.deg2rad(-4 + 3 * np.sin(2 * phase + 1)))
    seg: dict[str, _Segment] = {}
    seg["torso"] = _Segment(pelvis_pos + R_trunk @ (up * 0.10), R_trunk, up, trunk - 0.20, 0.13)
    neck = pelvis_pos + R_trunk @ (up * trunk)
    seg["head"] = _Segment(neck + R_head @ (up * 0.09), R_head, up, 0.06, 0.095)
    seg["pelvis"] = _Segment(pelvis_pos + R_pelvis @ np.array([0.0, 0.09, 0.0]) * scale, R_pelvis,
                             np.array([0.0, -1.0, 0.0]), 0.18 * scale, 0.10)
    foot_axis = np.array([0.15, 0.0, -0.05]) / np.hypot(0.15, 0.05)
    for side, sign, ph in (("l", 1.0, phase), ("r", -1.0, phase + np.pi)):
        hip = pelvis_pos + R_pelvis @ np.array([0.0, 0.09 * sign * scale, 0.0])
        R_thigh = R_pelvis @ _rot(1, -hip_amp * lift(ph))
        seg[f"{side}_thigh"] = _Segment(hip, R_thigh, down, thigh, 0.07)
        R_shin = R_thigh @ _rot(1, knee_amp * lift(ph))
        seg[f"{side}_shin"] = _Segment(seg[f"{side}_thigh"].end, R_shin, down, shin, 0.05)
        R_foot = R_shin @ _rot(1, np.deg2rad(20) * lift(ph))
        seg[f"{side}_foot"] = _Segment(seg[f"{side}_shin"].end, R_foot, foot_axis, 0.16 * scale, 0.04)
        shoulder = pelvis_pos + R_trunk @ np.array([0.0, 0.18 * sign * scale, trunk - 0.04])
        swing = arm_amp * np.sin(ph + np.pi)
        R_uarm = R_trunk @ _rot(0, np.full(n_frames, np.deg2rad(8) * sign)) @ _rot(1, -swing)
        seg[f"{side}_uarm"] = _Segment(shoulder, R_uarm, down, uarm, 0.045)
        R_farm = R_uarm @ _rot(1, -np.deg2rad(25) - 1.2 * arm_amp * lift(ph + np.pi))
        seg[f"{side}_farm"] = _Segment(seg[f"{side}_uarm"].end, R_farm, down, farm, 0.035)
        seg[f"{side}_hand"] = _Segment(seg[f"{side}_farm"].end, R_farm, down, 0.08 * scale, 0.03)
    return seg


def marching_motion(n_frames: int, fps: float = 120.0, n_markers: int = DEFAULT_MARKERS, seed: int = 0,
                    marker_mm: float = 14.0) -> Motion:
    """The marching person as a :class:`Motion` with its capsule skeleton (for occlusion).

    Args:
        n_frames: frames to generate.
        fps: frame rate, Hz.
        n_markers: how many of :data:`MARKERS` to place (the first ``n_markers``; 1..49).
        seed: seed of the body's size and gait.
        marker_mm: marker diameter, mm (markers sit on the skin: their centres are a radius out).
    """
    if n_frames < 1:
        raise MocapError(f"--frames {n_frames}: render at least one frame")
    if not 1 <= n_markers <= len(MARKERS):
        raise MocapError(f"--markers {n_markers}: the built-in body carries 1 to {len(MARKERS)} markers")
    if fps <= 0:
        raise MocapError(f"--fps {fps}: the frame rate must be positive")
    seg = _skeleton(n_frames, fps, np.random.default_rng(seed))
    chosen = MARKERS[:n_markers]
    positions = np.empty((n_frames, n_markers, 3))
    for m, (_, name, t, direction) in enumerate(chosen):
        s = seg[name]
        d = np.asarray(direction, dtype=np.float64)
        d = d - (d @ s.axis) * s.axis
        d /= np.linalg.norm(d)
        offset = s.axis * (t * s.length) + d * (s.radius + marker_mm / 2000.0)
        positions[:, m] = s.start + s.rotation @ offset
    names = list(seg)
    capsules = Capsules(np.stack([seg[n].start for n in names], axis=1), np.stack([seg[n].end for n in names], axis=1),
                        np.array([seg[n].radius for n in names]), names)
    info = {"source": "built-in marching body", "body_seed": int(seed), "n_markers": int(n_markers)}
    return Motion([m[0] for m in chosen], float(fps), positions, capsules, info)


def marching_body(n_frames: int, fps: float = 120.0, n_markers: int = DEFAULT_MARKERS, seed: int = 0
                  ) -> tuple[list[str], float, np.ndarray]:
    """A person marching in place: labels (M,), fps, positions (F, M, 3) m, z up (no file needed).

    The capsule skeleton behind it is :func:`marching_motion` ``(...).capsules``.
    """
    motion = marching_motion(n_frames, fps, n_markers, seed)
    return motion.labels, motion.fps, motion.positions
