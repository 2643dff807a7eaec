"""Quality gates of the wand calibration, in plain language.

Hard failures raise :class:`mocap.errors.MocapError` (the calibration would be wrong); soft ones
return warning sentences that go to the log and into the report.
"""

from __future__ import annotations

import logging

import numpy as np

from mocap.camera import Rig
from mocap.errors import MocapError

__all__ = [
    "MIN_CAMERA_FRAMES",
    "COVERAGE_GRID",
    "coverage",
    "check_wand_seen",
    "coverage_warnings",
    "check_converged",
    "check_wand_length",
]

log = logging.getLogger(__name__)

MIN_CAMERA_FRAMES = 30
COVERAGE_GRID = (8, 6)
POOR_COVERAGE = 0.4
MAX_RMS_PX = 2.0
WAND_SCALE_WARN = 0.002
WAND_SCALE_FAIL = 0.01


def coverage(rig: Rig, obs: np.ndarray) -> np.ndarray:
    """(C,) fraction of each camera's 8 x 6 image cells that hold at least one wand marker.

    Args:
        rig: the cameras (image sizes).
        obs: (F, C, K, 2) wand markers, pixels; NaN where unseen.
    """
    gx, gy = COVERAGE_GRID
    out = np.zeros(len(rig))
    for c, cam in enumerate(rig):
        xy = obs[:, c].reshape(-1, 2)
        xy = xy[np.isfinite(xy).all(axis=1)]
        cx = np.clip((xy[:, 0] / cam.size[0] * gx).astype(int), 0, gx - 1)
        cy = np.clip((xy[:, 1] / cam.size[1] * gy).astype(int), 0, gy - 1)
        out[c] = np.unique(cy * gx + cx).size / (gx * gy)
    return out


def check_wand_seen(rig: Rig, obs: np.ndarray, where: str, min_frames: int = MIN_CAMERA_FRAMES) -> None:
    """Every camera must have seen the whole wand in ``min_frames`` frames.

    Raises:
        MocapError: naming the cameras that never (or too rarely) saw it.
    """
    frames = np.isfinite(obs).all(axis=(2, 3)).sum(axis=0)
    never = [n for n, k in zip(rig.names, frames, strict=True) if k == 0]
    if never:
        raise MocapError(
            f"{where}: camera(s) {', '.join(never)} never saw the whole wand; check that they are connected and "
            "pointed at the volume, that the wand description (--wand) matches the real wand, and wave it "
            "in their view"
        )
    few = [f"{n} ({k})" for n, k in zip(rig.names, frames, strict=True) if k < min_frames]
    if few:
        raise MocapError(
            f"{where}: too few frames with the whole wand in camera(s) {', '.join(few)}; at least {min_frames} "
            "are needed: record a longer wave that passes through every camera's view"
        )


def coverage_warnings(rig: Rig, obs: np.ndarray) -> list[str]:
    """Warnings for cameras whose images the wand covered poorly."""
    cov = coverage(rig, obs)
    return [
        f"camera {name}: the wand covered only {100 * c:.0f} % of the image; its lens distortion and pose are "
        "less certain: wave the wand near the image edges too"
        for name, c in zip(rig.names, cov, strict=True)
        if c < POOR_COVERAGE
    ]


def check_converged(rms_px: float, success: bool, where: str) -> None:
    """The bundle adjustment must have converged to a small reprojection error.

    Raises:
        MocapError: the solution diverged (NaN) or the RMS error is above 2 px.
    """
    if not np.isfinite(rms_px) or rms_px > MAX_RMS_PX:
        raise MocapError(
            f"{where}: the calibration did not converge (reprojection RMS {rms_px:.3g} px, solver "
            f"{'converged' if success else 'stopped early'}); check the intrinsics (--intrinsics), the wand "
            "description (--wand) and that every camera's recording belongs to this session"
        )


def check_wand_length(scale: float, wand_length_m: float) -> list[str]:
    """Compare the wand with an independent length (the L-frame): the best similarity scale must be ~1.

    Args:
        scale: scale of the best similarity transform from the measured to the stated L-frame.
        wand_length_m: the stated wand length.

    Returns:
        Warnings (empty when fine).

    Raises:
        MocapError: the wand is more than 1 % off its stated length.
    """
    measured_mm = 1000 * wand_length_m * scale
    text = (f"against the L-frame the wand measures {measured_mm:.1f} mm end to end, but --wand states "
            f"{1000 * wand_length_m:.1f} mm")
    if abs(scale - 1) > WAND_SCALE_FAIL:
        raise MocapError(f"{text}; measure the wand (marker centre to marker centre) and the L-frame, and fix "
                         "--wand or --lframe")
    if abs(scale - 1) > WAND_SCALE_WARN:
        return [f"{text} ({100 * (scale - 1):+.2f} %); check both"]
    return []
