"""How good is a recovered calibration? Against the true rig, and by what it does to a reconstruction.

* :func:`compare_rigs`: per camera, position (mm), orientation (degrees) and focal-length (%)
  differences, as the files stand (same world frame) and after the best rigid alignment of the
  camera centres (what remains when the world frame itself is set aside).
* :func:`reconstruction_scores`: reconstruct one synthetic take with each calibration (the take's
  recordings with another ``calibration.toml`` beside them) and score every result against the
  truth with :func:`mocap.evaluate.evaluate`. A recovered calibration is good when its RMSE is
  close to the RMSE with the true one.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calibration.align import similarity_transform, transform_rig
from mocap.camera import Rig, save_rig
from mocap.errors import MocapError

__all__ = ["compare_rigs", "reconstruction_scores"]


def _pose_errors(est: Rig, ref: Rig) -> tuple[np.ndarray, np.ndarray]:
    pos = 1000 * np.linalg.norm(est.centers() - ref.centers(), axis=1)
    ang = np.array([np.degrees(np.linalg.norm(cv2.Rodrigues(a.R @ b.R.T)[0])) for a, b in zip(est, ref, strict=True)])
    return pos, ang


def compare_rigs(estimated: Rig, reference: Rig) -> dict[str, Any]:
    """Differences between two calibrations of the same cameras (matched by name).

    Returns:
        ``{"cameras": [{name, position_mm, angle_deg, aligned_position_mm, aligned_angle_deg,
        focal_pct}], "max_position_mm", "max_angle_deg", "max_aligned_position_mm",
        "max_aligned_angle_deg", "max_focal_pct"}``.

    Raises:
        MocapError: the calibrations do not hold the same camera names.
    """
    if sorted(estimated.names) != sorted(reference.names):
        raise MocapError(f"the calibrations hold different cameras: {estimated.names} vs {reference.names}")
    est = Rig([estimated[estimated.index(n)] for n in reference.names])
    pos, ang = _pose_errors(est, reference)
    aligned = transform_rig(est, similarity_transform(est.centers(), reference.centers(), with_scale=False))
    apos, aang = _pose_errors(aligned, reference)
    focal = np.array([100 * (a.matrix[0, 0] / b.matrix[0, 0] - 1) for a, b in zip(est, reference, strict=True)])
    cams = [{"name": n, "position_mm": float(p), "angle_deg": float(a), "aligned_position_mm": float(ap),
             "aligned_angle_deg": float(aa), "focal_pct": float(f)}
            for n, p, a, ap, aa, f in zip(reference.names, pos, ang, apos, aang, focal, strict=True)]
    return {"cameras": cams, "max_position_mm": float(pos.max()), "max_angle_deg": float(ang.max()),
            "max_aligned_position_mm": float(apos.max()), "max_aligned_angle_deg": float(aang.max()),
            "max_focal_pct": float(np.abs(focal).max())}


def _take_with(take: Path, rig: Rig, folder: Path) -> Path:
    """A take folder in ``folder`` with ``take``'s recordings (linked) and ``rig`` as its calibration."""
    out = folder / take.name
    out.mkdir()
    for item in take.iterdir():
        if item.name != "calibration.toml":
            os.symlink(item.resolve(), out / item.name)
    save_rig(rig, out / "calibration.toml")
    return out


def reconstruction_scores(take: str | os.PathLike, truth_path: str | os.PathLike, calibrations: dict[str, Rig],
                          progress: bool = False) -> dict[str, Any]:
    """Reconstruct ``take`` with each calibration and score it against the truth.

    Args:
        take: a synthetic take folder.
        truth_path: its truth (``mocap synth`` writes ``<take>.truth.npz``).
        calibrations: label -> rig (e.g. ``{"true": ..., "recovered": ...}``).
        progress: show progress bars.

    Returns:
        label -> :meth:`mocap.evaluate.EvalReport.to_dict`; the Cramér-Rao reference always uses the
        truth's own calibration, so the figures are comparable.
    """
    from mocap.evaluate import evaluate
    from mocap.pipeline import ReconstructOptions, reconstruct
    from mocap.truth import load_truth

    take = Path(take)
    truth = load_truth(truth_path)
    scores: dict[str, Any] = {}
    with tempfile.TemporaryDirectory(prefix="mocap-calib-score-") as tmp:
        for label, rig in calibrations.items():
            folder = Path(tmp) / label
            folder.mkdir()
            traj = reconstruct(_take_with(take, rig, folder), ReconstructOptions(progress=progress))
            scores[label] = evaluate(traj, truth).to_dict()
    return scores
