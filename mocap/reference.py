"""The plain baseline tracker the engine is measured against (same API as :class:`mocap.tracker.Tracker`).

Per frame: all-pairs epipolar matching of every camera's detections with a fixed tolerance, DLT
triangulation of every match, points closer than ``merge_m`` averaged into one and kept when at
least ``min_matches`` pair matches agree on them (a marker seen by three cameras gives three); then greedy
frame-to-frame nearest-neighbour linking with a fixed distance threshold (shortest links first); an
unlinked point starts a new identity. No motion model, no multi-view consistency test, no
re-identification: what a straightforward implementation does.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.errors import MocapError
from mocap.geometry import fundamental_from_cameras, triangulate_dlt
from mocap.stereo import epipolar_distance
from mocap.tracker import FrameResult
from mocap.trajectories import Trajectories

__all__ = ["ReferenceConfig", "ReferenceTracker"]


@dataclass
class ReferenceConfig:
    """Fixed thresholds of the baseline.

    Attributes:
        epipolar_px: largest symmetric epipolar distance of a match, pixels.
        merge_m: points closer than this are one marker, m.
        link_m: largest frame-to-frame displacement of a marker, m.
        min_matches: pair matches a point needs (1 keeps every two-view point, ghosts included).
    """

    epipolar_px: float = 2.0
    merge_m: float = 0.01
    link_m: float = 0.03
    min_matches: int = 2


class ReferenceTracker:
    """All-pairs epipolar matching + DLT + greedy nearest-neighbour linking (see the module docstring)."""

    def __init__(self, rig: Rig, fps: float, config: ReferenceConfig | None = None) -> None:
        if not (np.isfinite(fps) and fps > 0):
            raise MocapError(f"frame rate must be a positive number of frames per second, got {fps}")
        self._rig, self._fps = rig, float(fps)
        self._cfg = config or ReferenceConfig()
        C = len(rig)
        self._pairs = np.array([(i, j) for i in range(C) for j in range(i + 1, C)], dtype=np.intp).reshape(-1, 2)
        self._F = np.stack([fundamental_from_cameras(rig[i], rig[j]) for i, j in self._pairs]) if C > 1 else None
        self._P = rig.projection_matrices()
        self._prev = np.zeros((0, 3))
        self._prev_id = np.zeros(0, dtype=np.intp)
        self._n_ident = 0
        self._rows: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (frame, ids, points) per frame
        self._first: int | None = None
        self._last = -1

    def step(self, frame_index: int, detections: list[Detections]) -> FrameResult:
        """Track one frame (one :class:`Detections` per camera, rig order)."""
        C = len(self._rig)
        if len(detections) != C:
            raise MocapError(f"frame {frame_index}: {len(detections)} detection sets for {C} cameras")
        if self._first is None:
            self._first = frame_index
        self._last = max(self._last, frame_index)
        points = self._points(detections)
        ids = self._link(points)
        self._rows.append((np.full(len(ids), frame_index), ids, points))
        return FrameResult(frame_index, ids, points, np.zeros(len(ids)), np.zeros(len(ids), dtype=np.uint32),
                           [np.full(len(d), -1, dtype=np.intp) for d in detections])

    def predicted_rois(self) -> list[np.ndarray]:
        """Per camera (K, 4) windows ``link_m`` around the previous frame's points."""
        out = []
        for cam in self._rig.cameras:
            uv = cam.project(self._prev)
            depth = cam.world_to_camera(self._prev)[:, 2]
            r = self._cfg.link_m * cam.matrix[0, 0] / np.maximum(depth, 1e-6)
            box = np.concatenate([uv - r[:, None], uv + r[:, None]], axis=1)
            w, h = cam.size
            ok = np.isfinite(box).all(axis=1)
            out.append(np.clip(np.round(box[ok]), 0, [w - 1, h - 1, w - 1, h - 1]).astype(np.int64))
        return out

    def finish(self) -> Trajectories:
        """All frames so far as :class:`Trajectories` (one column per identity)."""
        first = self._first if self._first is not None else 0
        F = max(self._last - first + 1, 0)
        pos = np.full((F, self._n_ident, 3), np.nan)
        for frames, ids, points in self._rows:
            pos[frames - first, ids] = points
        labels = [f"M{i + 1:03d}" for i in range(self._n_ident)]
        return Trajectories(labels, self._fps, pos, camera_names=self._rig.names, first_frame=first)

    def _points(self, detections: list[Detections]) -> np.ndarray:
        """(N, 3) merged DLT points of all epipolar matches."""
        ideal = [cam.undistort(d.xy) for cam, d in zip(self._rig.cameras, detections, strict=True)]
        C = len(ideal)
        found = []
        for p, (i, j) in enumerate(self._pairs):
            if len(ideal[i]) == 0 or len(ideal[j]) == 0:
                continue
            e = epipolar_distance(self._F[p], ideal[i][:, None, :], ideal[j][None, :, :])
            a, b = np.nonzero(e < self._cfg.epipolar_px)
            if a.size:
                uv = np.full((C, a.size, 2), np.nan)
                uv[i], uv[j] = ideal[i][a], ideal[j][b]
                found.append(triangulate_dlt(self._P, uv))
        if not found:
            return np.zeros((0, 3))
        pts = np.concatenate(found)
        pts = pts[np.isfinite(pts).all(axis=1)]
        merged: list[np.ndarray] = []
        counts: list[int] = []
        for x in pts:  # greedy merge into running means
            if merged:
                d = np.linalg.norm(np.array(merged) - x, axis=1)
                k = int(np.argmin(d))
                if d[k] < self._cfg.merge_m:
                    counts[k] += 1
                    merged[k] = merged[k] + (x - merged[k]) / counts[k]
                    continue
            merged.append(x)
            counts.append(1)
        return np.array(merged).reshape(-1, 3)[np.array(counts) >= self._cfg.min_matches]

    def _link(self, points: np.ndarray) -> np.ndarray:
        """(N,) identity of each point: greedy nearest previous point within ``link_m``, else new."""
        ids = np.full(len(points), -1, dtype=np.intp)
        if len(points) and len(self._prev):
            d = np.linalg.norm(points[:, None] - self._prev[None], axis=2)
            order = np.argsort(d, axis=None)
            used_prev = np.zeros(len(self._prev), dtype=bool)
            for flat in order:
                a, b = divmod(int(flat), len(self._prev))
                if d[a, b] > self._cfg.link_m:
                    break
                if ids[a] < 0 and not used_prev[b]:
                    ids[a] = self._prev_id[b]
                    used_prev[b] = True
        new = ids < 0
        ids[new] = np.arange(self._n_ident, self._n_ident + new.sum())
        self._n_ident += int(new.sum())
        self._prev, self._prev_id = points, ids
        return ids
