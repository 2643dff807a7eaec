"""Fundamental matrices for every camera pair, and their epipolar error statistics.

Two sources:

* a calibrated rig: ``F = K2^-T [t]x R K1^-1`` (:func:`mocap.geometry.fundamental_from_cameras`);
* point correspondences (board corners seen by both cameras, or wand markers): the normalised
  8-point algorithm inside a robust estimator (``cv2.findFundamentalMat`` with ``USAC_MAGSAC``),
  then Levenberg-Marquardt on the Sampson distance (the first-order approximation of the
  gold-standard geometric error, H&Z sec. 11.4.3, p. 287) over a rank-2 parametrisation
  ``F = U diag(1, s, 0) V^T`` (7 degrees of freedom, so rank 2 holds at every step; H&Z sec. 11.4.2).

Convention (as in :mod:`mocap.geometry`): pixels are *ideal* (undistorted) unless said otherwise,
and ``x_to^T F x_from = 0``, so ``F @ x_from`` is the epipolar line in the ``to`` image.

The matrices are stored in ``calibration.toml`` as one extra table, which readers that do not
know it ignore (:attr:`mocap.camera.Rig.extra_tables` keeps it)::

    [fundamental.cam1-cam2]
    from = "cam1"
    to = "cam2"
    F = [[...], [...], [...]]
    source = "rig"            # or "correspondences"
    pixels = "ideal"
    n_points = 1234           # points the statistics were measured on (0: none)
    mean_px = 0.08            # mean symmetric point-to-epipolar-line distance
    rms_px = 0.10
    median_px = 0.07
    max_px = 0.41
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from mocap.camera import Rig
from mocap.errors import MocapError
from mocap.geometry import epipolar_lines, fundamental_from_cameras

__all__ = [
    "EpipolarStats",
    "FundamentalFit",
    "epipolar_errors",
    "epipolar_stats",
    "estimate_fundamental",
    "refine_fundamental",
    "rig_fundamentals",
    "fundamental_table",
    "TABLE",
]

TABLE = "fundamental"
MIN_POINTS = 8


@dataclass
class EpipolarStats:
    """Symmetric point-to-epipolar-line distances of a set of correspondences, pixels."""

    n_points: int
    mean_px: float
    rms_px: float
    median_px: float
    max_px: float

    def as_dict(self) -> dict[str, float | int]:
        return {"n_points": self.n_points, "mean_px": self.mean_px, "rms_px": self.rms_px,
                "median_px": self.median_px, "max_px": self.max_px}


@dataclass
class FundamentalFit:
    """A fundamental matrix estimated from correspondences.

    Attributes:
        F: (3, 3) rank-2, unit Frobenius norm, ``x2^T F x1 = 0``.
        inliers: (N,) bool, the correspondences the robust estimator kept.
        stats: epipolar distances over the inliers.
    """

    F: np.ndarray
    inliers: np.ndarray
    stats: EpipolarStats


def _points(x: np.ndarray, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 2:
        raise ValueError(f"{name} must have shape (N, 2), got {x.shape}")
    return x


def epipolar_errors(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Point-to-epipolar-line distances of N correspondences in both images.

    Args:
        F: (3, 3) with ``x2^T F x1 = 0``.
        x1, x2: (N, 2) corresponding points, pixels.

    Returns:
        (N, 2) distances, pixels: of ``x2`` to ``F x1`` and of ``x1`` to ``F^T x2``.
    """
    x1, x2 = _points(x1, "x1"), _points(x2, "x2")
    l2 = epipolar_lines(F, x1)
    l1 = epipolar_lines(F.T, x2)
    d2 = np.abs((l2[:, :2] * x2).sum(axis=1) + l2[:, 2]) / np.hypot(l2[:, 0], l2[:, 1])
    d1 = np.abs((l1[:, :2] * x1).sum(axis=1) + l1[:, 2]) / np.hypot(l1[:, 0], l1[:, 1])
    return np.column_stack([d2, d1])


def epipolar_stats(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> EpipolarStats:
    """Mean / RMS / median / max of :func:`epipolar_errors` over both images."""
    d = epipolar_errors(F, x1, x2).ravel()
    if d.size == 0:
        return EpipolarStats(0, float("nan"), float("nan"), float("nan"), float("nan"))
    return EpipolarStats(len(d) // 2, float(d.mean()), float(np.sqrt((d**2).mean())), float(np.median(d)),
                         float(d.max()))


def _hartley(x: np.ndarray) -> np.ndarray:
    """(3, 3) similarity moving (N, 2) points to zero mean and RMS distance sqrt(2) (H&Z sec. 4.4.4)."""
    c = x.mean(axis=0)
    s = np.sqrt(2) / max(np.sqrt(((x - c) ** 2).sum(axis=1).mean()), 1e-12)
    return np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1]])


def _sampson(F: np.ndarray, h1: np.ndarray, h2: np.ndarray) -> np.ndarray:
    """(N,) signed Sampson distances of homogeneous (N, 3) correspondences, pixels."""
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = (h2 * Fx1).sum(axis=1)
    return num / np.sqrt(Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2)


def refine_fundamental(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Levenberg-Marquardt on the Sampson distance over rank-2 matrices; returns the refined (3, 3) F.

    The parameters are small rotations of ``U`` and ``V`` and the singular value ratio ``s``
    of the Hartley-normalised matrix, so the solution stays rank 2 at every step.
    """
    x1, x2 = _points(x1, "x1"), _points(x2, "x2")
    T1, T2 = _hartley(x1), _hartley(x2)
    Fn = np.linalg.inv(T2).T @ F @ np.linalg.inv(T1)
    U, S, Vt = np.linalg.svd(Fn)
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])

    def compose(p: np.ndarray) -> np.ndarray:
        Uk = U @ Rotation.from_rotvec(p[:3]).as_matrix()
        Vk = Vt.T @ Rotation.from_rotvec(p[3:6]).as_matrix()
        return T2.T @ (Uk @ np.diag([1.0, p[6], 0.0]) @ Vk.T) @ T1

    p0 = np.zeros(7)
    p0[6] = S[1] / S[0]
    sol = least_squares(lambda p: _sampson(compose(p), h1, h2), p0, method="lm", x_scale="jac")
    Fr = compose(sol.x)
    return Fr / np.linalg.norm(Fr)


def estimate_fundamental(x1: np.ndarray, x2: np.ndarray, threshold_px: float = 1.0, where: str = "pair"
                         ) -> FundamentalFit:
    """Robust F from correspondences: MAGSAC++ (8-point inside), then Sampson refinement on the inliers.

    Args:
        x1, x2: (N, 2) corresponding points in images 1 and 2, pixels (ideal pixels when the
            cameras have lens distortion; F cannot model distortion).
        threshold_px: inlier threshold of the robust estimator, pixels.
        where: the pair's name, for error messages.

    Raises:
        MocapError: fewer than 8 correspondences, or no model found.
    """
    x1, x2 = _points(x1, "x1"), _points(x2, "x2")
    ok = np.isfinite(x1).all(axis=1) & np.isfinite(x2).all(axis=1)
    x1, x2 = x1[ok], x2[ok]
    if len(x1) < MIN_POINTS:
        raise MocapError(f"{where}: only {len(x1)} points seen by both cameras; at least {MIN_POINTS} are needed "
                         "for a fundamental matrix (more views of the board or a longer wand wave)")
    F, mask = cv2.findFundamentalMat(x1, x2, cv2.USAC_MAGSAC, threshold_px, 0.9999, 20000)
    if F is None or F.shape != (3, 3):
        raise MocapError(f"{where}: no fundamental matrix fits these correspondences; are the points matched "
                         "(same board corner / wand marker in both images)?")
    inliers = np.zeros(len(ok), dtype=bool)
    inliers[np.flatnonzero(ok)] = mask.ravel().astype(bool)
    sel = mask.ravel().astype(bool)
    if sel.sum() < MIN_POINTS:
        raise MocapError(f"{where}: only {int(sel.sum())} correspondences agree on one epipolar geometry")
    F = refine_fundamental(F, x1[sel], x2[sel])
    return FundamentalFit(F, inliers, epipolar_stats(F, x1[sel], x2[sel]))


def rig_fundamentals(rig: Rig) -> dict[tuple[int, int], np.ndarray]:
    """(i, j) -> F from camera i to camera j (ideal pixels) for every pair ``i < j`` of the rig."""
    C = len(rig)
    return {(i, j): fundamental_from_cameras(rig[i], rig[j]) for i in range(C) for j in range(i + 1, C)}


def fundamental_table(
    rig: Rig,
    fundamentals: dict[tuple[int, int], np.ndarray] | None = None,
    correspondences: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] | None = None,
    source: str = "rig",
) -> dict[str, Any]:
    """The ``[fundamental]`` table for ``calibration.toml``.

    Args:
        rig: the cameras (names and, when ``fundamentals`` is None, the poses).
        fundamentals: (i, j) -> F; default :func:`rig_fundamentals`.
        correspondences: (i, j) -> ((N, 2), (N, 2)) ideal pixels to measure the statistics on.
        source: ``"rig"`` or ``"correspondences"``, recorded in each entry.
    """
    fundamentals = rig_fundamentals(rig) if fundamentals is None else fundamentals
    table: dict[str, Any] = {}
    for (i, j), F in sorted(fundamentals.items()):
        entry: dict[str, Any] = {"from": rig[i].name, "to": rig[j].name, "F": np.asarray(F).tolist(),
                                 "source": source, "pixels": "ideal"}
        pts = (correspondences or {}).get((i, j))
        stats = epipolar_stats(F, *pts) if pts is not None else EpipolarStats(0, 0.0, 0.0, 0.0, 0.0)
        entry.update(stats.as_dict())
        table[f"{rig[i].name}-{rig[j].name}"] = entry
    return table
