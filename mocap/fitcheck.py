"""Does the calibration fit the images? An epipolar-support check on the first frames.

With a correct calibration almost every real marker blob in one camera has a partner on
its epipolar line in some other camera. With a wrong calibration (another session's file,
swapped camera names, a camera that was bumped) that support collapses for the cameras at
fault. The check is cheap and runs once, on the first frames that hold detections.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.geometry import epipolar_distance_matrix, fundamental_from_cameras

__all__ = ["FitReport", "check_calibration_fit"]


@dataclass
class FitReport:
    """Epipolar support per camera.

    Attributes:
        support: (C,) fraction of the camera's blobs that have a partner within the tolerance
            on the epipolar line in at least one other camera; NaN for a camera with no blobs.
        blobs: (C,) number of blobs examined per camera.
        tolerance_px: the epipolar distance tolerance used, pixels.
    """

    support: np.ndarray
    blobs: np.ndarray
    tolerance_px: float

    def poor_cameras(self, rig: Rig, minimum: float = 0.5) -> list[str]:
        """Names of cameras whose blobs mostly have no epipolar partner."""
        return [name for name, s in zip(rig.names, self.support, strict=True) if np.isfinite(s) and s < minimum]


def check_calibration_fit(rig: Rig, frames: list[list[Detections]], tolerance_px: float = 3.0) -> FitReport:
    """Measure epipolar support of the blobs in ``frames`` under ``rig``.

    Args:
        rig: the calibration to check.
        frames: a few frames, each a list of one :class:`Detections` per camera (rig order).
        tolerance_px: symmetric epipolar distance under which two blobs count as partners.

    Returns:
        A :class:`FitReport`.
    """
    C = len(rig)
    fundamentals = {(i, j): fundamental_from_cameras(rig[i], rig[j]) for i in range(C) for j in range(C) if i < j}
    supported = np.zeros(C)
    total = np.zeros(C)
    for dets in frames:
        ideal = [rig[c].undistort(d.xy) for c, d in enumerate(dets)]
        has_partner = [np.zeros(len(p), dtype=bool) for p in ideal]
        for (i, j), F in fundamentals.items():
            if len(ideal[i]) == 0 or len(ideal[j]) == 0:
                continue
            close = epipolar_distance_matrix(F, ideal[i], ideal[j]) < tolerance_px
            has_partner[i] |= close.any(axis=1)
            has_partner[j] |= close.any(axis=0)
        for c in range(C):
            supported[c] += has_partner[c].sum()
            total[c] += len(has_partner[c])
    with np.errstate(invalid="ignore", divide="ignore"):
        support = np.where(total > 0, supported / total, np.nan)
    return FitReport(support, total.astype(int), tolerance_px)
