"""Does the calibration fit the images? An epipolar-support check on the first frames.

With a correct calibration almost every real marker blob is explained by a 3D point seen by
three cameras: it has a partner on its epipolar line in a second camera, and the pair's
triangulated point lands on a blob in a third. With a wrong calibration (another session's
file, swapped camera names, a camera that was bumped) that support collapses for the cameras
at fault. Two-view support alone is not enough: with dozens of markers, a random blob finds
some partner within a few pixels of a 1000-pixel epipolar line by chance. The check is cheap
and runs once, on the first frames that hold detections.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.geometry import (
    epipolar_distance_matrix,
    fundamental_from_cameras,
    reprojection_jacobians,
    triangulate_dlt,
)

__all__ = ["FitMonitor", "FitReport", "check_calibration_fit"]

MIN_POINTS_IN_VIEW = 10  # supported points of the other cameras needed to say whether a camera's view holds them


@dataclass
class FitReport:
    """Epipolar support per camera.

    Attributes:
        support: (C,) fraction of the camera's blobs that belong to a three-camera-consistent
            point (epipolar partner in a second camera, reprojection onto a blob in a third, both
            within the tolerance); NaN for a camera with no blobs.
        chance: (C,) the same fraction with every image's blobs mirrored through its centre: what
            chance alone explains under this calibration.
        blobs: (C,) number of blobs examined per camera.
        tolerance_px: the epipolar distance tolerance used, pixels.
        in_view: (C,) fraction of the three-camera-consistent points of the other cameras that the camera's
            calibration puts in its image (NaN when there are too few such points to say).
    """

    support: np.ndarray
    chance: np.ndarray
    blobs: np.ndarray
    tolerance_px: float
    in_view: np.ndarray | None = None

    def poor_cameras(self, rig: Rig, relative: float = 0.5, over_chance: float = 3.0, margin: float = 0.02,
                     few: float = 0.25) -> list[str]:
        """Names of cameras whose support is below ``relative`` x the median camera's, or not clearly above
        chance (``over_chance`` x chance + ``margin``). Cameras with fewer blobs than ``few`` x the busiest
        camera's are not judged: along a walkway, a camera far from the subject sees only its reflections.

        A correct calibration's support is the share of blobs seen by three cameras or more: ~0.9 with six
        cameras, ~0.4 with four, ~0.05 with three (measured; chance 0-0.09); a camera at fault falls far
        below the others (a swapped pair: 0.01-0.3 where the rest keep 0.7-0.9), and a wrong file takes
        every camera to chance.
        """
        s = np.where(self._judged(few), self.support, np.nan)
        if not np.isfinite(s).any():
            return []
        limit = np.maximum(relative * float(np.nanmedian(s)), over_chance * np.nan_to_num(self.chance) + margin)
        return [name for name, v, lim in zip(rig.names, s, limit, strict=True) if np.isfinite(v) and v < lim]

    def judged_cameras(self, rig: Rig, few: float = 0.25) -> list[str]:
        """Names of the cameras :meth:`poor_cameras` judges (enough blobs)."""
        return [name for name, ok in zip(rig.names, self._judged(few), strict=True) if ok]

    def _judged(self, few: float, seen: float = 0.25) -> np.ndarray:
        """(C,) bool: cameras with blobs, at least ``few`` x the busiest camera's, in whose view the calibration
        puts ``seen`` of the markers the other cameras agree on (or there are too few of those to say): along a
        walkway the subject can be out of a camera's view for seconds while it sees reflections."""
        judged = (self.blobs >= few * self.blobs.max(initial=0)) & np.isfinite(self.support)
        if self.in_view is not None:
            judged &= ~(self.in_view < seen)  # (NaN: too few points to say)
        return judged


class FitMonitor:
    """The calibration-fit check over a few windows of frames spread over the start of a take.

    One window can lack the power to judge a camera: along a walkway, a camera far from the subject may see
    markers that no second camera sees in those frames (no three-view support, and chance none either), and
    it looked like a camera at fault. A camera is named only if it is poor in every window in which it was
    judged: ``windows`` windows of ``frames`` frames holding detections, each starting ``spacing`` frames
    after the previous one started (fewer when the take is shorter). A camera at fault stays poor in all.

    Feed every frame's detections to :meth:`offer`; it returns the report and the names once decided (then
    None forever); :meth:`finish` decides with what was seen if the take ended first.
    """

    def __init__(self, rig: Rig, frames: int, spacing: int, windows: int = 4) -> None:
        self.rig, self.frames, self.spacing, self.windows = rig, frames, max(spacing, frames), windows
        self._window: list[list[Detections]] = []
        self._start: int | None = None  # frame index the current window started at
        self._suspects: set[str] | None = None  # named so far in every window that judged them
        self._first: FitReport | None = None
        self._done = 0
        self._decided = False

    def offer(self, frame_index: int, detections: list[Detections]) -> tuple[FitReport, list[str]] | None:
        if self._decided:
            return None
        if self._start is not None and len(self._window) == 0 and frame_index < self._start:
            return None  # waiting for the next window
        if sum(len(d) > 0 for d in detections) < 2:
            return None
        if not self._window:
            self._start = frame_index
        self._window.append(detections)
        if len(self._window) < self.frames:
            return None
        self._close_window()
        if not self._suspects or self._done >= self.windows:
            return self._decide()
        self._start = self._start + self.spacing  # (the next window starts no earlier than this)
        return None

    def finish(self) -> tuple[FitReport, list[str]] | None:
        """The decision from the windows seen, if :meth:`offer` has not given it."""
        if self._decided:
            return None
        if self._window:
            self._close_window()
        return self._decide() if self._first is not None else None

    def _close_window(self) -> None:
        report = check_calibration_fit(self.rig, self._window)
        poor, judged = set(report.poor_cameras(self.rig)), set(report.judged_cameras(self.rig))
        if self._first is None:
            self._first, self._suspects = report, poor
        else:
            self._suspects -= judged - poor  # judged fine once: not at fault
        self._window = []
        self._done += 1

    def _decide(self) -> tuple[FitReport, list[str]]:
        self._decided = True
        return self._first, [name for name in self.rig.names if name in self._suspects]


def check_calibration_fit(rig: Rig, frames: list[list[Detections]], tolerance_px: float = 3.0) -> FitReport:
    """Measure three-view support of the blobs in ``frames`` under ``rig``.

    Args:
        rig: the calibration to check (three cameras or more; with two, support is two-view).
        frames: a few frames, each a list of one :class:`Detections` per camera (rig order).
        tolerance_px: epipolar and reprojection distance under which blobs count as partners.

    Returns:
        A :class:`FitReport`.
    """
    support, total, in_view = _support(rig, [[d.xy for d in dets] for dets in frames], tolerance_px)
    sizes = np.array([cam.size for cam in rig], dtype=float) - 1.0
    mirrored = [[sizes[c] - d.xy for c, d in enumerate(dets)] for dets in frames]
    chance, _, _ = _support(rig, mirrored, tolerance_px, views=False)
    return FitReport(support, chance, total.astype(int), tolerance_px, in_view)


def _support(rig: Rig, frames: list[list[np.ndarray]], tolerance_px: float, views: bool = True
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(C,) fraction of each camera's blobs (``frames[f][c]`` (N, 2) distorted px) with three-view support
    (NaN without blobs), (C,) the number of blobs, and (C,) the fraction of the points that other cameras' blobs
    support (three views, each found once per pair) that project in front of the camera, inside its image (NaN below
    ``MIN_POINTS_IN_VIEW``, or without ``views``)."""
    C = len(rig)
    P = rig.projection_matrices()
    fundamentals = {(i, j): fundamental_from_cameras(rig[i], rig[j]) for i in range(C) for j in range(i + 1, C)}
    supported = np.zeros(C)
    total = np.zeros(C)
    others = np.zeros(C)  # supported points found without the camera
    inside = np.zeros(C)  # ... of those, in its view
    for dets in frames:
        ideal = [rig[c].undistort(xy) for c, xy in enumerate(dets)]
        explained = [np.zeros(len(p), dtype=bool) for p in ideal]
        points, owners = [], []  # the frame's supported points (n, 3) and (C, n) whose they are
        for (i, j), F in fundamentals.items():
            if len(ideal[i]) == 0 or len(ideal[j]) == 0:
                continue
            a, b = np.nonzero(epipolar_distance_matrix(F, ideal[i], ideal[j]) < tolerance_px)
            if a.size == 0:
                continue
            confirmed = np.full(a.size, C == 2)
            X = triangulate_dlt(P[[i, j]], np.stack([ideal[i][a], ideal[j][b]]))
            by = np.zeros((C, a.size), dtype=bool)  # confirmed by camera k
            for k in range(C):
                if k in (i, j) or len(ideal[k]) == 0:
                    continue
                uv, _ = reprojection_jacobians(P[k : k + 1], np.nan_to_num(X))
                gap = np.linalg.norm(uv[0][:, None, :] - ideal[k][None, :, :], axis=2).min(axis=1)
                by[k] = gap < tolerance_px
                confirmed |= by[k]
            explained[i][a[confirmed]] = True
            explained[j][b[confirmed]] = True
            if views:  # (a point is the camera's own if the camera is in its pair or confirmed it alone)
                own = by[:, confirmed] & (by[:, confirmed].sum(axis=0) == 1)
                own[[i, j]] = True
                points.append(X[confirmed])
                owners.append(own)
        if views and points:
            X, own = np.concatenate(points), np.concatenate(owners, axis=1)
            for k in range(C):
                X_k = X[~own[k]]
                others[k] += len(X_k)
                inside[k] += np.count_nonzero(rig[k].in_image(rig[k].project(X_k)))  # (behind it: NaN, outside)
        for c in range(C):
            supported[c] += explained[c].sum()
            total[c] += len(explained[c])
    with np.errstate(invalid="ignore", divide="ignore"):
        return (np.where(total > 0, supported / total, np.nan), total,
                np.where(others >= MIN_POINTS_IN_VIEW, inside / others, np.nan))
