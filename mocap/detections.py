"""2D blobs found in one camera image: arrays, never one object per blob."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Detections", "MIN_CENTROID_STD_PX", "floored_covariance"]

MIN_CENTROID_STD_PX = 0.002  # no centroid is trusted to better than this, px (model and quantisation limits)


@dataclass(eq=False)
class Detections:
    """The N blobs one camera saw in one frame.

    Attributes:
        xy: (N, 2) sub-pixel centroids, distorted pixels (x right, y down; pixel centres at
            integer coordinates, OpenCV's convention).
        area: (N,) blob area, pixels.
        roundness: (N,) in (0, 1]: minor/major axis ratio of the blob's second moments.
        cov: (N, 2, 2) centroid covariance, pixels^2 (from image noise and blob shape).
        merged: (N,) bool, True where the blob is probably two or more markers merged.
        flux: (N,) the blob's light, grey levels above the background summed over its pixels (the parts of a
            split blob share it equally); NaN: not measured (older logs, centroid files without it).
        cut: (N,) bool, True where the blob was measured as a marker partly hidden by an edge (its centre and
            covariance from the cut disc's fit, :mod:`mocap.cutdisc`; its area, roundness and light as seen, of the
            part in view).
    """

    xy: np.ndarray
    area: np.ndarray | None = None
    roundness: np.ndarray | None = None
    cov: np.ndarray | None = None
    merged: np.ndarray | None = None
    flux: np.ndarray | None = None
    cut: np.ndarray | None = None

    DEFAULT_SIGMA_PX = 0.1

    def __post_init__(self) -> None:
        self.xy = np.asarray(self.xy, dtype=np.float64).reshape(-1, 2)
        n = len(self.xy)
        if self.area is None:
            self.area = np.zeros(n)
        if self.roundness is None:
            self.roundness = np.ones(n)
        if self.cov is None:
            self.cov = np.broadcast_to(np.eye(2) * self.DEFAULT_SIGMA_PX**2, (n, 2, 2)).copy()
        if self.merged is None:
            self.merged = np.zeros(n, dtype=bool)
        if self.flux is None:
            self.flux = np.full(n, np.nan)
        if self.cut is None:
            self.cut = np.zeros(n, dtype=bool)
        self.area = np.asarray(self.area, dtype=np.float64).reshape(n)
        self.roundness = np.asarray(self.roundness, dtype=np.float64).reshape(n)
        self.cov = np.asarray(self.cov, dtype=np.float64).reshape(n, 2, 2)
        self.merged = np.asarray(self.merged, dtype=bool).reshape(n)
        self.flux = np.asarray(self.flux, dtype=np.float64).reshape(n)
        self.cut = np.asarray(self.cut, dtype=bool).reshape(n)

    def __len__(self) -> int:
        return len(self.xy)

    @classmethod
    def empty(cls) -> Detections:
        return cls(np.zeros((0, 2)))

    def subset(self, index: np.ndarray) -> Detections:
        """The blobs selected by a boolean mask or an index array."""
        return Detections(self.xy[index], self.area[index], self.roundness[index], self.cov[index],
                          self.merged[index], self.flux[index], self.cut[index])


def floored_covariance(cov: np.ndarray, std_px: float = MIN_CENTROID_STD_PX) -> np.ndarray:
    """(N, 2, 2) centroid covariances, px^2, with the smallest eigenvalue raised to at least ``std_px`` squared;
    non-finite ones become the default (:attr:`Detections.DEFAULT_SIGMA_PX`).

    A fit can claim any precision (a saturated or merged blob, a centroid file with zeros); the weights
    (inverse covariances) built from it must stay finite and well conditioned.
    """
    cov = np.asarray(cov, dtype=np.float64)
    a, d = cov[:, 0, 0], cov[:, 1, 1]
    b = 0.5 * (cov[:, 0, 1] + cov[:, 1, 0])
    with np.errstate(invalid="ignore"):  # (non-finite entries: replaced below)
        smallest = 0.5 * (a + d) - np.sqrt((0.5 * (a - d)) ** 2 + b * b)
    lift = np.maximum(std_px * std_px - smallest, 0.0)
    out = cov.copy()
    out[:, 0, 0] += lift
    out[:, 1, 1] += lift
    if not np.isfinite(smallest).all():  # (any non-finite entry makes ``smallest`` non-finite)
        out[~np.isfinite(out).all(axis=(1, 2))] = np.eye(2) * Detections.DEFAULT_SIGMA_PX**2
    return out
