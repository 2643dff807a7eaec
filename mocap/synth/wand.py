"""Synthetic calibration takes with known truth: a wand waved through the volume, and an L-frame.

The wand (default: 3 markers at 0, 0.15 and 0.5 m along a rod) is carried along a smooth path
that sweeps the capture volume while it turns about every axis; the L-frame (default: 4 markers,
corner at the origin, long arm along +x, short arm along +y, marker centres on z = 0) lies still
on the floor. Both go through the synth's camera model (:func:`mocap.synth.simulate.plan_take`:
projection, dropouts, ghost reflections, Cramér-Rao centroid noise of each blob), so the
calibration sees what the detector would deliver.

Centroid level (:func:`centroid_frames`): each visible marker's blob centroid is its true
position plus Gaussian noise of its Cramér-Rao std ``truth.sigma_px``; two markers whose discs
touch in an image come out as one blob at their mean, flagged ``merged`` (as the detector reports
blobs it cannot split; each group of touching discs is one blob); the ghosts that are on in a frame
are extra blobs.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import tomli_w
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from mocap.atomic import atomic_write_bytes
from mocap.camera import Rig, load_rig, save_rig
from mocap.detections import Detections
from mocap.synth.motion import Motion
from mocap.synth.rig import ring_rig
from mocap.synth.settings import SynthSettings
from mocap.synth.simulate import TakePlan, plan_take
from mocap.synth.writer import default_truth_path, render_take, staged_directory
from mocap.truth import Truth

__all__ = [
    "DEFAULT_WAND_M",
    "DEFAULT_LFRAME_M",
    "WandTake",
    "wand_motion",
    "lframe_motion",
    "centroid_frames",
    "simulate_wand_take",
    "render_wand_take",
]

DEFAULT_WAND_M = (0.0, 0.15, 0.5)
DEFAULT_LFRAME_M = ((0.0, 0.0, 0.0), (0.2, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.35, 0.0))


def wand_motion(n_frames: int = 1200, fps: float = 120.0, offsets: tuple[float, ...] = DEFAULT_WAND_M,
                seed: int = 0, centre: tuple[float, float, float] = (0.0, 0.0, 1.0),
                reach: tuple[float, float, float] = (1.8, 1.8, 0.85)) -> Motion:
    """A wand wave: the wand's middle follows a smooth seeded path through a box, turning all the while.

    Args:
        n_frames, fps: length and rate of the take.
        offsets: (K,) marker positions along the wand, m.
        seed: seed of the path.
        centre: centre of the swept box, m.
        reach: half sizes of the swept box, m.

    Returns:
        A :class:`Motion` with markers ``wand0..``; no body (nothing occludes the wand).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / fps
    duration = max(n_frames / fps, 1.0)
    # Slow sweeps (a few passes over the take) for the position, faster turns for the direction.
    freq_pos = rng.uniform(1.5, 4.0, (3, 2)) / duration
    phase = rng.uniform(0, 2 * np.pi, (3, 2))
    path = np.sin(2 * np.pi * freq_pos[..., None] * t + phase[..., None]).mean(axis=1)  # (3, F) in [-1, 1]
    middle = np.asarray(centre) + np.asarray(reach) * np.clip(1.3 * path.T, -1.0, 1.0)  # (F, 3)
    freq_dir = rng.uniform(0.15, 0.45, 3)
    phase_dir = rng.uniform(0, 2 * np.pi, 3)
    direction = np.sin(2 * np.pi * freq_dir[:, None] * t + phase_dir[:, None]).T + np.array([0.0, 0.0, 0.3])
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    o = np.asarray(offsets, dtype=np.float64)
    positions = middle[:, None, :] + (o - o[-1] / 2)[None, :, None] * direction[:, None, :]
    info = {"kind": "wand", "wand_offsets_m": o.tolist(), "seed": int(seed), "centre_m": list(centre),
            "reach_m": list(reach)}
    return Motion([f"wand{k}" for k in range(len(o))], float(fps), positions, None, info)


def lframe_motion(n_frames: int = 30, fps: float = 120.0,
                  points: tuple[tuple[float, float, float], ...] = DEFAULT_LFRAME_M) -> Motion:
    """An L-frame lying still at the origin for ``n_frames`` frames (markers ``lframe0..``)."""
    p = np.asarray(points, dtype=np.float64)
    positions = np.broadcast_to(p, (n_frames,) + p.shape).copy()
    info = {"kind": "lframe", "lframe_m": p.tolist()}
    return Motion([f"lframe{k}" for k in range(len(p))], float(fps), positions, None, info)


def centroid_frames(plan: TakePlan, seed: int = 0, extra_noise_px: float = 0.0) -> list[list[Detections]]:
    """Per frame, per camera: the blobs a detector would report (noisy centroids, merges, ghosts).

    Args:
        plan: the simulated take.
        seed: seed of the centroid noise.
        extra_noise_px: std of further centroid noise per axis, px, added in quadrature to the
            Cramér-Rao std (a detector's own imperfections).

    Returns:
        ``frames[f][c]`` :class:`Detections` with ``cov = sigma^2 I`` (the noise variance actually used).
    """
    truth = plan.truth
    rng = np.random.default_rng(seed)
    F, C, M = truth.visible.shape
    std = np.sqrt(truth.sigma_px**2 + extra_noise_px**2)
    noise = rng.standard_normal((F, C, M, 2)) * std[..., None]
    frames: list[list[Detections]] = []
    for f in range(F):
        row = []
        for c in range(C):
            vis = np.flatnonzero(truth.visible[f, c])
            xy = truth.uv[f, c, vis] + noise[f, c, vis]
            sigma = std[f, c, vis]
            r = plan.radius_px[f, c, vis]
            # Discs that touch merge: each group of touching discs is one blob at their mean, flagged merged.
            gap = np.linalg.norm(xy[:, None] - xy[None], axis=2) - (r[:, None] + r[None] + 1.0)
            np.fill_diagonal(gap, np.inf)
            touch = gap < 0
            merged = touch.any(axis=1)
            blobs, sig, flag = [xy[~merged]], [sigma[~merged]], [np.zeros(int((~merged).sum()), dtype=bool)]
            if merged.any():
                n_groups, group = connected_components(csr_matrix(touch), directed=False)
                group = group[merged]
                count = np.bincount(group, minlength=n_groups)
                used = np.flatnonzero(count)
                mean = np.stack([np.bincount(group, xy[merged, k], n_groups) for k in (0, 1)], axis=1) / np.maximum(
                    count, 1)[:, None]
                blobs.append(mean[used])
                sig.append(np.maximum.reduceat(sigma[merged][np.argsort(group, kind="stable")],
                                               np.concatenate([[0], np.cumsum(count[used])[:-1]])))
                flag.append(np.ones(used.size, dtype=bool))
            on = plan.ghost_on[f, c]
            blobs.append(plan.ghost_uv[c, on])
            sig.append(np.full(int(on.sum()), 0.1))
            flag.append(np.zeros(int(on.sum()), dtype=bool))
            s = np.concatenate(sig)
            row.append(Detections(np.concatenate(blobs), cov=s[:, None, None] ** 2 * np.eye(2),
                                  merged=np.concatenate(flag)))
        frames.append(row)
    return frames


@dataclass(eq=False)
class WandTake:
    """A simulated calibration session: the wand wave and the L-frame, their truths and blobs.

    Attributes:
        rig: the true calibration.
        wand: truth of the wand wave (markers ``wand0..``).
        wand_frames: blobs per frame per camera of the wave.
        lframe: truth of the L-frame take.
        lframe_frames: blobs per frame per camera of the L-frame take.
        wand_offsets: (K,) the wand, m.
        lframe_points: (P, 3) the L-frame, m.
    """

    rig: Rig
    wand: Truth
    wand_frames: list[list[Detections]]
    lframe: Truth
    lframe_frames: list[list[Detections]]
    wand_offsets: tuple[float, ...]
    lframe_points: tuple[tuple[float, float, float], ...]


def simulate_wand_take(rig: Rig | None = None, n_frames: int = 1200, fps: float = 120.0,
                       wand: tuple[float, ...] = DEFAULT_WAND_M,
                       lframe: tuple[tuple[float, float, float], ...] = DEFAULT_LFRAME_M,
                       settings: SynthSettings | None = None, lframe_frames: int = 30,
                       extra_noise_px: float = 0.0) -> WandTake:
    """Simulate a wand wave and an L-frame take at centroid level (no images).

    Args:
        rig: the cameras (default: ``mocap.synth.rig.ring_rig(seed=settings.seed)``, six cameras).
        n_frames, fps: length and rate of the wave.
        wand: marker positions along the wand, m.
        lframe: L-frame marker positions, m.
        settings: sensor and artefact settings (occlusion is off: no body carries the wand).
        lframe_frames: frames of the L-frame take.
        extra_noise_px: centroid noise beyond the Cramér-Rao bound, px (see :func:`centroid_frames`).
    """
    settings = (settings or SynthSettings()).replace(occlusion=False)
    rig = rig if rig is not None else ring_rig(seed=settings.seed)
    wave = plan_take(rig, wand_motion(n_frames, fps, wand, settings.seed), settings)
    still = plan_take(rig, lframe_motion(lframe_frames, fps, lframe), settings.replace(seed=settings.seed + 1))
    return WandTake(rig, wave.truth, centroid_frames(wave, settings.seed, extra_noise_px), still.truth,
                    centroid_frames(still, settings.seed + 1, extra_noise_px), tuple(wand), tuple(lframe))


def _strip_poses(take: Path, facts: dict[str, object]) -> None:
    """Replace a rendered take's calibration by its intrinsics alone and add ``facts`` to its take.toml."""
    rig = load_rig(take / "calibration.toml")
    unposed = Rig([cam.with_pose(np.zeros(3), np.zeros(3)) for cam in rig],
                  {"made_by": "mocap synth", "extrinsics": "unknown: run mocap calibrate wand"})
    save_rig(unposed, take / "calibration.toml")
    record = tomllib.loads((take / "take.toml").read_text(encoding="utf-8"))
    record.update(facts)
    atomic_write_bytes(take / "take.toml", tomli_w.dumps(record).encode("utf-8"))


def render_wand_take(out_dir: str | os.PathLike, rig: Rig | None = None, settings: SynthSettings | None = None,
                     n_frames: int = 1200, fps: float = 120.0, truth_path: str | os.PathLike | None = None,
                     progress: bool = True, force: bool = False, lframe_frames: int = 30) -> Truth:
    """Render a calibration session: two takes, a wand wave and a still L-frame.

    Layout: ``out_dir/wand/`` and ``out_dir/lframe/`` are ordinary takes (DESIGN.md sec. 1) whose
    ``calibration.toml`` holds the cameras' intrinsics with zero poses (the extrinsics are what the
    calibration must find) and whose ``take.toml`` states the wand (``wand_m``, marker positions
    along it, m) and the L-frame (``lframe_m``, marker coordinates, m). The truths go beside
    ``out_dir``: ``truth_path`` (default ``<out_dir>.truth.npz``: the wave, whose settings hold the
    true ``calibration_toml``) and the same name with ``.lframe.truth.npz`` for the L-frame.

    Args:
        out_dir: folder to create.
        rig: the cameras (default: six-camera ``ring_rig``).
        settings: rendering settings (occlusion is turned off: no body carries the wand).
        n_frames, fps: length and rate of the wave.
        truth_path: where the wave's truth goes.
        progress: show progress bars.
        force: replace an existing non-empty ``out_dir``.
        lframe_frames: frames of the L-frame take.

    Returns:
        The wave's truth.
    """
    settings = (settings or SynthSettings()).replace(occlusion=False)
    rig = rig if rig is not None else ring_rig(seed=settings.seed)
    out_dir = Path(out_dir)
    truth_path = Path(truth_path) if truth_path is not None else default_truth_path(out_dir)
    lframe_truth = truth_path.with_name(truth_path.name.removesuffix(".truth.npz") + ".lframe.truth.npz")
    facts = {"wand_m": list(DEFAULT_WAND_M), "lframe_m": [list(p) for p in DEFAULT_LFRAME_M]}
    with staged_directory(out_dir, force) as folder:
        truth = render_take(folder / "wand", rig, wand_motion(n_frames, fps, DEFAULT_WAND_M, settings.seed),
                            settings, truth_path, progress)
        render_take(folder / "lframe", rig, lframe_motion(lframe_frames, fps), settings.replace(seed=settings.seed + 1),
                    lframe_truth, progress)
        for name in ("wand", "lframe"):
            _strip_poses(folder / name, facts)
    return truth
