"""The engine's output: labelled 3D marker trajectories, as numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["MISSING", "RewrittenPoints", "Trajectories", "UnconfirmedPoints", "WithheldPoints"]

MISSING = {"f": np.nan, "u": 0}  # a missing sample by array kind: positions and residuals NaN, camera mask 0


@dataclass(eq=False)
class Trajectories:
    """Labelled 3D trajectories of one take.

    Attributes:
        labels: (M,) marker names, one per identity.
        fps: frame rate, Hz.
        positions: (F, M, 3) world positions, metres (z up); NaN where missing.
        residuals: (F, M) triangulation residuals, mm (RMS reprojection error back-projected
            to the marker's depth); NaN where missing.
        camera_masks: (F, M) uint32 bit field, bit c set when camera c saw the marker.
        camera_names: names of the cameras behind the mask bits, in bit order.
        first_frame: index of the first frame in the source recording.
        metadata: free-form facts about the take (written where a format allows).
    """

    labels: list[str]
    fps: float
    positions: np.ndarray
    residuals: np.ndarray | None = None
    camera_masks: np.ndarray | None = None
    camera_names: list[str] = field(default_factory=list)
    first_frame: int = 0
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.positions = np.asarray(self.positions, dtype=np.float64)
        if self.positions.ndim != 3 or self.positions.shape[2] != 3:
            raise ValueError(f"positions must have shape (frames, markers, 3), got {self.positions.shape}")
        F, M = self.positions.shape[:2]
        if len(self.labels) != M:
            raise ValueError(f"{len(self.labels)} labels for {M} markers")
        self.labels = [str(label) for label in self.labels]
        if self.residuals is None:
            self.residuals = np.where(np.isfinite(self.positions).all(axis=2), 0.0, np.nan)
        self.residuals = np.asarray(self.residuals, dtype=np.float64).reshape(F, M)
        if self.camera_masks is None:
            self.camera_masks = np.zeros((F, M), dtype=np.uint32)
        self.camera_masks = np.asarray(self.camera_masks, dtype=np.uint32).reshape(F, M)
        if not np.isfinite(self.fps) or self.fps <= 0:
            raise ValueError(f"fps must be a positive number, got {self.fps}")

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def n_markers(self) -> int:
        return self.positions.shape[1]

    @property
    def valid(self) -> np.ndarray:
        """(F, M) bool: the sample exists."""
        return np.isfinite(self.positions).all(axis=2)

    @property
    def times(self) -> np.ndarray:
        """(F,) capture time of each frame, seconds from the take's first frame."""
        return (np.arange(self.n_frames) + self.first_frame) / self.fps

    def drop_empty(self) -> int:
        """Drop, in place, the columns without a sample (identities whose samples all moved elsewhere) and name the
        rest ``M001``, ``M002`` ... in column order; returns how many were dropped (none: nothing changes)."""
        keep = np.isfinite(self.positions[..., 0]).any(axis=0)
        dropped = int(keep.size - np.count_nonzero(keep))
        if dropped:
            self.positions, self.residuals, self.camera_masks = (self.positions[:, keep], self.residuals[:, keep],
                                                                 self.camera_masks[:, keep])
            self.labels = [f"M{k + 1:03d}" for k in range(self.n_markers)]
        return dropped

    def add_empty(self, n: int, names: list[str] | None = None) -> range:
        """Append, in place, ``n`` identity columns without samples, named ``names`` (default: after the last,
        ``M...``); returns their column indices."""
        first = self.n_markers
        self.positions = np.concatenate([self.positions, np.full((self.n_frames, n, 3), np.nan)], axis=1)
        self.residuals = np.concatenate([self.residuals, np.full((self.n_frames, n), np.nan)], axis=1)
        self.camera_masks = np.concatenate([self.camera_masks, np.zeros((self.n_frames, n), np.uint32)], axis=1)
        self.labels = list(self.labels) + (list(names) if names is not None
                                           else [f"M{k + 1:03d}" for k in range(first, first + n)])
        return range(first, first + n)

    def move_samples(self, rows: np.ndarray | int, source: int, target: int) -> None:
        """Column ``source``'s samples in frames ``rows`` (index, bool mask or one frame) go to column ``target``
        (positions, residuals and camera masks together) and leave ``source`` missing there, in place."""
        for array in (self.positions, self.residuals, self.camera_masks):
            array[rows, target] = array[rows, source]
            array[rows, source] = MISSING[array.dtype.kind]

    def permute_tails(self, start: int, order: np.ndarray | list[int], columns: np.ndarray | list[int],
                      stop: int | None = None) -> None:
        """From frame ``start`` on (up to ``stop``, exclusive; default: the end), column ``columns[k]`` receives what
        column ``order[k]`` held (positions, residuals and camera masks together), in place."""
        for array in (self.positions, self.residuals, self.camera_masks):
            array[start:stop, columns] = array[start:stop, order]


@dataclass
class WithheldPoints:
    """Tracked samples the written trajectories leave out, applied after the identity repair (which works on the
    tracked samples).

    Attributes:
        rows: (n,) frame index into the trajectories.
        positions: (n, 3) the tracked positions, m (how the samples are found again, wherever the repair moved them).
    """

    rows: np.ndarray
    positions: np.ndarray

    def apply(self, traj: Trajectories) -> int:
        """Leave out, in place, each sample of ``traj`` in frame ``rows[i]`` at exactly ``positions[i]``; returns how
        many were (a position no sample holds any more, one the repair dropped or moved off its frame, is skipped)."""
        _, rows, col = _located(traj, self.rows, self.positions)
        traj.positions[rows, col] = np.nan
        traj.residuals[rows, col] = np.nan
        traj.camera_masks[rows, col] = 0
        return len(rows)


@dataclass
class RewrittenPoints:
    """Tracked samples the written trajectories give another position, applied after the identity repair as
    :class:`WithheldPoints` are: points triangulated again without a view of their marker that held too little of
    its light (:meth:`mocap.tracker.Tracker.rewritten`).

    Attributes:
        rows: (n,) frame index into the trajectories.
        positions: (n, 3) the tracked positions, m (how the samples are found again).
        written: (n, 3) the positions written instead, m.
        residuals: (n,) their residuals, mm.
        camera_masks: (n,) uint32 their cameras.
    """

    rows: np.ndarray
    positions: np.ndarray
    written: np.ndarray
    residuals: np.ndarray
    camera_masks: np.ndarray

    @classmethod
    def none(cls) -> RewrittenPoints:
        return cls(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.uint32))

    def apply(self, traj: Trajectories) -> int:
        """Give, in place, each sample of ``traj`` in frame ``rows[i]`` at exactly ``positions[i]`` the position,
        residual and cameras ``written[i]``; returns how many were (as :meth:`WithheldPoints.apply` finds them)."""
        which, rows, col = _located(traj, self.rows, self.positions)
        traj.positions[rows, col] = self.written[which]
        traj.residuals[rows, col] = self.residuals[which]
        traj.camera_masks[rows, col] = self.camera_masks[which]
        return len(rows)


def _located(traj: Trajectories, rows: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, ...]:
    """(which (k,), frame (k,), column (k,)) of the samples of ``traj`` in frame ``rows[which]`` at exactly
    ``positions[which]`` ((n,) and (n, 3) m; rows outside the take are skipped)."""
    inside = np.flatnonzero((rows >= 0) & (rows < traj.n_frames))
    if inside.size == 0:
        empty = np.zeros(0, dtype=np.intp)
        return empty, empty, empty
    i, col = np.nonzero((traj.positions[rows[inside]] == positions[inside][:, None, :]).all(axis=2))
    return inside[i], rows[inside[i]], col


@dataclass
class UnconfirmedPoints:
    """Points the tracker measured but never gave an identity (tentative tracks shorter than its confirmation:
    a marker the recording has only every other frame, say), for the offline identity repair.

    Attributes:
        rows: (n,) frame index into the trajectories.
        positions: (n, 3) m.
        residuals: (n,) mm.
        camera_masks: (n,) uint32.
    """

    rows: np.ndarray
    positions: np.ndarray
    residuals: np.ndarray
    camera_masks: np.ndarray

    def as_columns(self, P: np.ndarray, apart_m: float) -> tuple[np.ndarray, np.ndarray]:
        """The points laid out as extra columns (F, K, 3) beside the samples ``P`` (F, M, 3), m, leaving out any
        within ``apart_m`` of a sample of their frame (a second measurement of a marker already there); and each
        point's (row, column) slot, (n, 2), -1 where left out."""
        F = len(P)
        rows = self.rows
        inside = (rows >= 0) & (rows < F)
        near = np.ones(len(rows), dtype=bool)
        with np.errstate(invalid="ignore"):
            near[inside] = (np.linalg.norm(P[rows[inside]] - self.positions[inside, None], axis=2)
                            < apart_m).any(axis=1)
        keep = np.flatnonzero(~near)
        order = keep[np.argsort(rows[keep], kind="stable")]
        r = rows[order]
        rank = np.arange(r.size) - np.searchsorted(r, r)  # 0, 1, ... among the kept points of one frame
        E = np.full((F, int(rank.max()) + 1 if r.size else 0, 3), np.nan)
        E[r, rank] = self.positions[order]
        slot = np.full((len(rows), 2), -1, dtype=np.intp)
        slot[order] = np.stack([r, rank], axis=1)
        return E, slot
