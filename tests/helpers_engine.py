"""Centroid-level takes for the tracking engine's tests and benchmark (no images rendered).

The renderer's own planning (:func:`mocap.synth.plan_take`: projection through the rig, capsule
occlusion, temporally correlated dropouts, fixed and flickering ghosts, Cramér–Rao centroid noise)
and its centroid-level detector stand-in (:func:`mocap.synth.wand.centroid_frames`: noisy centroids,
touching discs merged, ghosts) give exactly what ``mocap synth`` + the detector would hand the
tracker, at a fraction of the cost. The 3D motion of the C3D takes is real (OptiTrack recordings in
``../shared/data/c3d``); the 2D data are simulated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.synth import SynthSettings, marching_motion, motion_from_file, plan_take, rig_for_motion, ring_rig
from mocap.synth.motion import Motion
from mocap.synth.occlusion import Capsules
from mocap.synth.wand import centroid_frames
from mocap.truth import Truth

C3D_DIR = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d"
C3D_TAKES = ("kinematics_tennis_serve", "kinematics_tennis_serve_2players", "walkingOptiTrack",
             "kinematics_basket_sprint")


@dataclass
class Take:
    """A simulated take: per frame one :class:`Detections` per camera, its truth and rig."""

    name: str
    frames: list[list[Detections]]
    truth: Truth
    rig: Rig


def fitted_rig(motion: Motion, seed: int = 1) -> Rig:
    """The rig ``mocap synth`` puts around a motion (a widened ring, or a walkway for a long straight path)."""
    return rig_for_motion(motion.positions, seed=seed)


def simulate(name: str, rig: Rig, motion: Motion, settings: SynthSettings | None = None,
             hidden: np.ndarray | None = None, seed: int = 1) -> Take:
    """Centroids of ``motion`` seen by ``rig``; ``hidden`` (F, C, M) bool adds scripted occlusions."""
    plan = plan_take(rig, motion, settings or SynthSettings(seed=seed))
    if hidden is not None:
        plan.truth.visible &= ~hidden
        plan.drawn &= ~hidden
        plan.truth.sigma_px[hidden] = np.nan
    return Take(name, centroid_frames(plan, seed=seed), plan.truth, rig)


def c3d_take(name: str, frames: int | None = None, start: int = 0, seed: int = 1,
             settings: SynthSettings | None = None) -> Take:
    """A real C3D motion (``C3D_TAKES``), windowed and centred, through its fitted rig."""
    motion = motion_from_file(C3D_DIR / f"{name}.c3d").window(start, frames).centred()
    return simulate(name, fitted_rig(motion, seed), motion, settings, seed=seed)


def body_take(frames: int = 600, fps: float = 120.0, markers: int = 40, seed: int = 1,
              settings: SynthSettings | None = None) -> Take:
    """The built-in marching person (the paper's test motion) through the default ring."""
    motion = marching_motion(frames, fps, markers, seed)
    return simulate("body", ring_rig(seed=seed), motion, settings, seed=seed)


def scripted_motion(positions: np.ndarray, fps: float, labels: list[str] | None = None) -> Motion:
    """A bare marker motion (no body, so no occlusion except what a test scripts)."""
    F, M = positions.shape[:2]
    empty = np.zeros((F, 0, 3))
    return Motion(labels or [f"T{m + 1}" for m in range(M)], fps, positions, Capsules(empty, empty, np.zeros(0), []))


def crossing_positions(frames: int = 300, fps: float = 100.0, crossings: int = 6, gap_m: float = 0.004
                       ) -> np.ndarray:
    """(F, 2, 3) two markers swinging through each other ``crossings`` times, ``gap_m`` apart when they pass.

    They move along x in opposite directions (0.5 m swing) at slightly different heights, so at each
    crossing their blobs touch and merge in every camera.
    """
    t = np.arange(frames) / fps
    phase = np.pi * crossings * t / t[-1]
    a = 0.25 * np.sin(phase)
    pos = np.zeros((frames, 2, 3))
    pos[:, 0] = np.stack([a, np.zeros_like(t), 1.0 + gap_m / 2 + 0.02 * np.cos(phase)], axis=1)
    pos[:, 1] = np.stack([-a, np.zeros_like(t), 1.0 - gap_m / 2 - 0.02 * np.cos(phase)], axis=1)
    return pos


def swing_positions(frames: int = 200, fps: float = 50.0, amplitude: float = 1.5, hz: float = 2.0) -> np.ndarray:
    """(F, 8, 3) a rigid bar swinging like an arm: two rows of 4 markers, 0.1 m apart along the bar and
    across it, 0.2-0.5 m from a pivot 1.2 m up; angle ``amplitude sin(2 pi hz t)`` (rad) in the x-z plane.

    The defaults move the outer markers up to 187 mm per frame at 50 Hz, accelerating up to 120 m/s^2:
    a tennis serve's arm with its neighbours only 0.1 m apart.
    """
    t = np.arange(frames) / fps
    angle = amplitude * np.sin(2 * np.pi * hz * t)
    r = np.tile([0.2, 0.3, 0.4, 0.5], 2)
    pos = np.zeros((frames, 8, 3))
    pos[:, :, 0] = r * np.sin(angle)[:, None]
    pos[:, 4:, 1] = 0.1
    pos[:, :, 2] = 1.2 - r * np.cos(angle)[:, None]
    return pos


def walk_positions(frames: int = 360, fps: float = 60.0, speed: float = 2.0, markers: int = 10,
                   seed: int = 5) -> np.ndarray:
    """(F, markers, 3) a rigid cluster walked along x at ``speed`` m/s (12 m at the defaults), centred on
    the origin, swaying 0.1 m sideways and bobbing 0.03 m; markers 0.3-1.5 m up within 0.15 m of the axis."""
    t = np.arange(frames) / fps
    offsets = np.random.default_rng(seed).uniform([-0.15, -0.15, 0.3], [0.15, 0.15, 1.5], (markers, 3))
    path = np.stack([speed * (t - t[-1] / 2), 0.1 * np.sin(2 * np.pi * t), 0.03 * np.sin(4 * np.pi * t)], axis=1)
    return offsets[None] + path[:, None]
