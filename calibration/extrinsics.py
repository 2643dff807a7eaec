"""The wand calibration end to end: wand observations in, a calibrated rig and its report out.

1. Find the wand in every camera-frame (:func:`calibration.wand.wand_observations`); gates: every
   camera saw it often enough, coverage (:mod:`calibration.quality`).
2. Split the frames seen by >= 2 cameras: every ``holdout_every``-th is held out (never used in
   the fit; it measures the wand length afterwards), the rest are thinned evenly to ``max_frames``.
3. First rig from pairwise essential matrices along the view graph (:mod:`calibration.initial`).
4. Bundle adjustment (:mod:`calibration.bundle`); observations further than ``outlier_sigma``
   robust standard deviations are dropped and the adjustment repeated.
5. Held-out frames are triangulated with the result; their wand lengths against the stated one.
6. World frame from an L-frame or floor markers (:mod:`calibration.align`), if given.
7. Fundamental matrices of every pair, with their epipolar errors on the wand observations.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration import quality
from calibration.align import align_to_floor, align_to_lframe, match_lframe, static_markers
from calibration.bundle import BundleOptions, bundle_adjust
from calibration.fundamental import TABLE, fundamental_table
from calibration.initial import initial_rig, normalised_observations, order_two_marker_wand
from calibration.wand import Wand, wand_observations
from mocap.camera import Rig
from mocap.detections import Detections
from mocap.geometry import triangulate_dlt, triangulate_weighted

__all__ = ["WandOptions", "WandCalibration", "calibrate_wand", "observation_sigma"]

log = logging.getLogger(__name__)


@dataclass
class WandOptions:
    """Settings of :func:`calibrate_wand`.

    Attributes:
        max_frames: most frames used in the bundle adjustment (evenly thinned).
        holdout_every: every n-th usable frame is held out for the wand-length check.
        outlier_sigma: observations further than this many robust standard deviations are dropped.
        bundle: bundle-adjustment settings (refine focal / k1, loss).
        min_camera_frames: fewest frames with the whole wand each camera needs.
    """

    max_frames: int = 600
    holdout_every: int = 5
    outlier_sigma: float = 5.0
    bundle: BundleOptions = field(default_factory=BundleOptions)
    min_camera_frames: int = quality.MIN_CAMERA_FRAMES


@dataclass
class WandCalibration:
    """The result of :func:`calibrate_wand`.

    Attributes:
        rig: the calibrated cameras, with the ``[fundamental]`` table and calibration facts in metadata.
        obs: (F, C, K, 2) wand observations found, distorted pixels (after outlier rejection).
        residuals: (F, C, K, 2) final reprojection errors of the fitted observations, pixels (NaN elsewhere).
        holdout_errors_mm: (H, P) held-out wand distance errors (measured - stated) for the P marker pairs, mm.
        report: every figure, JSON-ready (see :mod:`calibration.report`).
    """

    rig: Rig
    obs: np.ndarray
    residuals: np.ndarray
    holdout_errors_mm: np.ndarray
    report: dict[str, Any]


def observation_sigma(frames: Sequence[Sequence[Detections]], obs: np.ndarray) -> np.ndarray:
    """(F, C, K) centroid std of each wand observation, px, from the matching blob's covariance."""
    sigma = np.full(obs.shape[:3], np.nan)
    for f, row in enumerate(frames):
        for c, det in enumerate(row):
            if not np.isfinite(obs[f, c, 0, 0]) or not len(det):
                continue
            gap = np.linalg.norm(det.xy[None, :, :] - obs[f, c][:, None, :], axis=2)
            match = gap.argmin(axis=1)
            sigma[f, c] = np.sqrt(0.5 * (det.cov[match, 0, 0] + det.cov[match, 1, 1]))
    return sigma


def _split(seen: np.ndarray, holdout_every: int, max_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Frame indices to fit and to hold out, from (F, C) seen flags."""
    usable = np.flatnonzero(seen.sum(axis=1) >= 2)
    hold = usable[holdout_every - 1 :: holdout_every] if holdout_every > 0 else usable[:0]
    fit = np.setdiff1d(usable, hold)
    if len(fit) > max_frames:
        fit = fit[np.unique(np.linspace(0, len(fit) - 1, max_frames).round().astype(int))]
    return fit, hold


def _ideal(rig: Rig, obs: np.ndarray) -> np.ndarray:
    """(F, C, K, 2) distorted -> (C, F*K, 2) ideal pixels."""
    F, C, K = obs.shape[:3]
    return np.stack([rig[c].undistort(obs[:, c].reshape(-1, 2)) for c in range(C)])


def _holdout_errors(rig: Rig, obs: np.ndarray, sigma: np.ndarray, wand: Wand) -> np.ndarray:
    """(H, P) measured - stated distances (mm) of marker pairs (0, 1), (0, 2) ... (``np.triu_indices`` order)."""
    H, C, K = obs.shape[:3]
    if H == 0:
        return np.zeros((0, K * (K - 1) // 2))
    cov = (np.nan_to_num(sigma, nan=1.0) ** 2).transpose(1, 0, 2).reshape(C, -1)[..., None, None] * np.eye(2)
    X = triangulate_weighted(rig.projection_matrices(), _ideal(rig, obs), cov)[0].reshape(H, K, 3)
    a, b = np.triu_indices(K, 1)
    stated = wand.array[b] - wand.array[a]
    return 1000 * (np.linalg.norm(X[:, b] - X[:, a], axis=2) - stated)


def _stats_mm(err: np.ndarray) -> dict[str, float]:
    err = err[np.isfinite(err)]
    if not err.size:
        return {"n": 0, "rms_mm": float("nan"), "mean_mm": float("nan"), "p95_abs_mm": float("nan")}
    return {"n": int(err.size), "rms_mm": float(np.sqrt((err**2).mean())), "mean_mm": float(err.mean()),
            "p95_abs_mm": float(np.percentile(np.abs(err), 95))}


def calibrate_wand(
    rig: Rig,
    frames: Sequence[Sequence[Detections]],
    wand: Wand,
    options: WandOptions | None = None,
    lframe_frames: Sequence[Sequence[Detections]] | None = None,
    lframe: np.ndarray | None = None,
    floor_frames: Sequence[Sequence[Detections]] | None = None,
    where: str = "wand take",
) -> WandCalibration:
    """Calibrate the rig's extrinsics from a wand wave.

    Args:
        rig: the cameras with their intrinsics (poses are ignored).
        frames: the wave: per frame, one :class:`Detections` per camera (rig order).
        wand: the wand.
        options: settings.
        lframe_frames, lframe: a still take of the L-frame and its (P, 3) marker coordinates, m.
        floor_frames: a still take of >= 3 markers lying on the floor (used when no L-frame is given).
        where: the take's name for messages.

    Raises:
        MocapError: a camera that never (or rarely) saw the wand, cameras not linked to the others,
            divergence, an L-frame not found or a wand of the wrong length.
    """
    options = options or WandOptions()
    obs = wand_observations(frames, wand)
    sigma = observation_sigma(frames, obs)
    quality.check_wand_seen(rig, obs, where, options.min_camera_frames)
    warnings = quality.coverage_warnings(rig, obs)
    if wand.n_markers == 2:
        swap, unsettled = order_two_marker_wand(normalised_observations(rig, obs))
        obs[swap] = obs[swap][:, ::-1]
        obs[unsettled] = np.nan
    seen = np.isfinite(obs).all(axis=(2, 3))
    fit, hold = _split(seen, options.holdout_every, options.max_frames)

    start, pairs, root = initial_rig(rig, normalised_observations(rig, obs[fit]), wand)
    F, C, K = obs[fit].shape[:3]
    X0 = triangulate_dlt(start.projection_matrices(), _ideal(start, obs[fit])).reshape(F, K, 3)
    fit_obs = obs[fit].copy()
    result = bundle_adjust(start, fit_obs, X0, wand.array, root, sigma[fit], options.bundle)
    norm_res = np.linalg.norm(result.residuals, axis=3) / np.nan_to_num(sigma[fit], nan=1.0)
    robust = 1.4826 * float(np.nanmedian(norm_res)) / 1.1774  # median of a 2D Rayleigh is 1.1774 sigma
    outliers = norm_res > options.outlier_sigma * max(robust, 1e-12)
    if outliers.any():
        fit_obs[outliers] = np.nan
        result = bundle_adjust(result.rig, fit_obs, result.points, wand.array, root, sigma[fit], options.bundle)
    res = result.residuals
    used = np.isfinite(res).all(axis=3)
    rms_px = float(np.sqrt(np.nanmean(res**2))) if used.any() else float("nan")
    quality.check_converged(rms_px, result.success, where)

    calibrated = result.rig
    holdout = _holdout_errors(calibrated, obs[hold], sigma[hold], wand)
    alignment: dict[str, Any] = {"method": "none", "reference_camera": rig.names[root]}
    if lframe_frames is not None and lframe is not None:
        measured = static_markers(calibrated, lframe_frames)
        idx = match_lframe(measured, lframe)
        calibrated, facts = align_to_lframe(calibrated, measured[idx], lframe)
        alignment = {"method": "lframe", **facts}
        warnings += quality.check_wand_length(facts["scale"], wand.length)
    elif floor_frames is not None:
        calibrated = align_to_floor(calibrated, static_markers(calibrated, floor_frames))
        alignment = {"method": "floor"}
    else:
        warnings.append(f"no L-frame or floor markers: the world frame is camera {rig.names[root]}'s "
                        "(z along its optical axis, not up); record an L-frame take to set the floor and origin")

    ideal = _ideal(calibrated, fit_obs)
    correspondences = {(i, j): (ideal[i][ok], ideal[j][ok]) for i in range(C) for j in range(i + 1, C)
                       if (ok := np.isfinite(ideal[i]).all(axis=1) & np.isfinite(ideal[j]).all(axis=1)).any()}
    calibrated.extra_tables[TABLE] = fundamental_table(calibrated, correspondences=correspondences)

    sig_used = sigma[fit][used]
    per_camera = []
    for c, name in enumerate(rig.names):
        r = res[:, c][used[:, c]]
        per_camera.append({
            "name": name,
            "observations": int(used[:, c].sum()),
            "frames_seen": int(seen[:, c].sum()),
            "rms_px": float(np.sqrt((r**2).mean())) if r.size else float("nan"),
            "max_px": float(np.linalg.norm(r, axis=1).max()) if r.size else float("nan"),
            "coverage": float(quality.coverage(rig, obs)[c]),
        })
    for w in warnings:
        log.warning("%s", w)
    report = {
        "wand_m": list(wand.offsets),
        "frames": {"total": len(frames), "fitted": int(len(fit)), "held_out": int(len(hold)),
                   "outliers_dropped": int(outliers.sum())},
        "reprojection": {"rms_px": rms_px, "centroid_sigma_rms_px": float(np.sqrt(np.mean(sig_used**2)))
                         if np.isfinite(sig_used).all() and sig_used.size else float("nan")},
        "per_camera": per_camera,
        "holdout_wand": {"end_to_end": _stats_mm(holdout[:, K - 2]), "all_pairs": _stats_mm(holdout)},
        "pairs_initialised": len(pairs),
        "bundle": {"success": result.success, "message": result.message, "nfev": result.nfev},
        "alignment": alignment,
        "warnings": warnings,
    }
    calibrated.metadata.update({"made_by": "mocap calibrate wand", "wand_m": list(wand.offsets),
                                "reprojection_rms_px": rms_px, "alignment": alignment["method"]})
    residuals = np.full(obs.shape, np.nan)
    residuals[fit] = res
    return WandCalibration(calibrated, obs, residuals, holdout, report)
