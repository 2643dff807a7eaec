"""Marker motion to render: loaded from a C3D, TRC or Motive CSV file (any units, any up axis), windowed,
resampled.

World frame of every :class:`Motion`: z up, metres, the motion centred over the floor origin.
"""

from __future__ import annotations

import logging
import os
import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from mocap.errors import MocapError
from mocap.export.formats import read_trajectories
from mocap.synth.occlusion import Capsules, capsules_from_markers
from mocap.trajectories import Trajectories

__all__ = ["Motion", "as_motion", "load_motion", "motion_from_file", "detect_up_axis", "to_z_up", "UP_AXES"]

log = logging.getLogger(__name__)

# Right-handed rotations taking each possible "up" direction of a file to +z.
UP_AXES: dict[str, np.ndarray] = {
    "z": np.eye(3),
    "-z": np.diag([1.0, -1.0, -1.0]),
    "y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "-y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "x": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]),
    "-x": np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
}
UNSURE_EXTENT_RATIO = 1.25  # up is a guess when no axis spans this many times the next one
FLOOR_SNAP_M = 0.15  # a detected floor further than this from z = 0 is moved to z = 0
COPY_M = 0.001  # a point this near another in every frame is a copy of it (a marker named twice)
AXES_LENGTH_TOLERANCE = 1e-3  # segment axes: the three axis points' distances from the origin agree to this part
AXES_MAX_COSINE = 0.01  # ... and their directions from it are this near perpendicular (0.6 degrees)
MIDPOINT_M = 0.0002  # a point this near the midpoint of two others in every frame is a joint centre a model wrote
DUPLICATE_M = 0.010  # two samples this near in a frame are one marker reconstructed twice (no two markers' centres
# are: their spheres would overlap)


@dataclass(eq=False)
class Motion:
    """Marker positions to render.

    Attributes:
        labels: (M,) marker names.
        fps: frame rate, Hz.
        positions: (F, M, 3) positions, m, z up; NaN in gaps.
        capsules: the body for occlusion over the same frames, or None to approximate it from the
            markers (:func:`mocap.synth.occlusion.capsules_from_markers`).
        info: facts about where the motion came from and what was done to it (goes into the settings).
    """

    labels: list[str]
    fps: float
    positions: np.ndarray
    capsules: Capsules | None = None
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    def window(self, start: int = 0, frames: int | None = None) -> Motion:
        """Frames ``start : start + frames`` (all remaining when ``frames`` is None)."""
        if start < 0 or start >= self.n_frames:
            raise MocapError(f"--start {start}: the motion has frames 0..{self.n_frames - 1}")
        if frames is not None and frames < 1:
            raise MocapError(f"--frames {frames}: render at least one frame")
        stop = self.n_frames if frames is None else min(self.n_frames, start + frames)
        caps = self.capsules.window(start, stop) if self.capsules is not None else None
        info = dict(self.info, first_source_frame=start + int(self.info.get("first_source_frame", 0)))
        return replace(self, positions=self.positions[start:stop], capsules=caps, info=info)

    def resampled(self, fps: float) -> Motion:
        """The motion at another frame rate, by linear interpolation (a gap stays a gap)."""
        if fps <= 0:
            raise MocapError(f"--fps {fps}: the frame rate must be positive")
        if np.isclose(fps, self.fps):
            return self
        t_in = np.arange(self.n_frames) / self.fps
        t_out = np.arange(int(np.floor(t_in[-1] * fps + 1e-9)) + 1) / fps
        pos = _interp_with_gaps(t_in, self.positions, t_out)
        caps = None
        if self.capsules is not None:
            caps = Capsules(_interp_with_gaps(t_in, self.capsules.a, t_out),
                            _interp_with_gaps(t_in, self.capsules.b, t_out), self.capsules.radius, self.capsules.names)
        return replace(self, fps=float(fps), positions=pos, capsules=caps,
                       info=dict(self.info, resampled_from_fps=self.fps))

    def centred(self) -> Motion:
        """The motion shifted horizontally so the mid-range of its samples is over the origin.

        The floor (z) is left alone; ``info["shift_m"]`` accumulates every shift applied.
        """
        pts = self.positions.reshape(-1, 3)
        pts = pts[np.isfinite(pts).all(axis=1)]
        if len(pts) == 0:
            return self
        lo, hi = np.percentile(pts[:, :2], [0.5, 99.5], axis=0)
        shift = np.zeros(3)
        shift[:2] = -(lo + hi) / 2
        caps = None
        if self.capsules is not None:
            caps = Capsules(self.capsules.a + shift, self.capsules.b + shift, self.capsules.radius,
                            self.capsules.names)
        total = np.asarray(self.info.get("shift_m", np.zeros(3))) + shift
        return replace(self, positions=self.positions + shift, capsules=caps,
                       info=dict(self.info, shift_m=total.tolist()))

    def body(self) -> Capsules:
        """The occlusion capsules: the motion's own, else the marker-based approximation."""
        if self.capsules is not None:
            return self.capsules
        return capsules_from_markers(self.labels, self.positions)


def as_motion(motion: Motion | tuple[list[str], float, np.ndarray]) -> Motion:
    """A :class:`Motion` from itself or from a ``(labels, fps, positions)`` tuple (body approximated from markers)."""
    if isinstance(motion, Motion):
        return motion
    try:
        labels, fps, positions = motion
    except (TypeError, ValueError):
        raise TypeError("motion must be a Motion or a (labels, fps, positions) tuple") from None
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 3 or positions.shape[2] != 3 or positions.shape[1] != len(labels):
        raise MocapError(f"motion positions must have shape (frames, {len(labels)} markers, 3), got {positions.shape}")
    return Motion(list(labels), float(fps), positions, None, {"source": "positions given in Python"})


def _interp_with_gaps(t_in: np.ndarray, values: np.ndarray, t_out: np.ndarray) -> np.ndarray:
    """Linear interpolation of (F, ..., 3) ``values`` along axis 0; NaN between a sample and a gap."""
    idx = np.clip(np.searchsorted(t_in, t_out, side="right") - 1, 0, len(t_in) - 1)
    nxt = np.minimum(idx + 1, len(t_in) - 1)
    span = np.where(nxt > idx, t_in[nxt] - t_in[idx], 1.0)
    w = ((t_out - t_in[idx]) / span).reshape((-1,) + (1,) * (values.ndim - 1))
    blend = (1 - w) * values[idx] + w * values[nxt]
    return np.where(w < 1e-9, values[idx], np.where(w > 1 - 1e-9, values[nxt], blend))


def detect_up_axis(positions: np.ndarray, labels: list[str] | None = None) -> str:
    """Guess which file axis points up: one of :data:`UP_AXES`.

    Axis: people are taller than they are wide, and a take's samples hug the floor. Per subject
    (``Subject:`` label prefixes, so two people far apart do not count as one wide body) and frame,
    the extent of the markers along each axis is measured; the up axis has the largest median
    extent. Sign: where the labels name head or shoulder markers and foot markers (LFHD, C7,
    AcromionL; LHEE, RTOE, LMT5: :data:`UPPER_LABEL`, :data:`FOOT_LABEL`), the head is up if the
    two groups' mean heights differ by a quarter of the body's extent. Else the floor is where
    things rest. The marker lowest along the up axis in each
    frame (a foot in stance, a wheelchair frame) moves much less than the highest one (head,
    hands): the median speeds of the two ends decide if they differ by 30 % (not on a treadmill,
    whose belt moves the foot in stance: hence the labels first). Else the floor is
    a hard edge: the lowest 5 % of the samples span a shorter distance than the highest 5 % (by
    50 % or more). Else the side of the origin where the samples lie decides (labs put the origin
    on the floor).

    Args:
        positions: (F, M, 3) positions in file axes (any units), NaN in gaps.
        labels: (M,) labels, to split subjects.

    Raises:
        MocapError: too few samples to tell.
    """
    positions = np.asarray(positions, dtype=np.float64)
    labels = labels or [f"M{i}" for i in range(positions.shape[1])]
    groups: dict[str, list[int]] = {}
    for i, label in enumerate(labels):
        groups.setdefault(label.split(":", 1)[0] if ":" in label else "", []).append(i)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        extents = []
        for idx in groups.values():
            p = positions[:, idx]
            extents.append(np.nanmedian(np.nanmax(p, axis=1) - np.nanmin(p, axis=1), axis=0))
        extent = np.nanmedian(np.array(extents), axis=0)
        if not np.isfinite(extent).all():
            raise MocapError("too few marker samples to tell which axis is up; pass --up")
        axis = int(np.argmax(extent))
        sign = _label_side(positions, labels, axis, extent[axis]) or _floor_side(positions, axis)
    up = ("" if sign > 0 else "-") + "xyz"[axis]
    second = np.sort(extent)[-2]
    if extent[axis] < UNSURE_EXTENT_RATIO * second:  # an upper-body marker set reaching forward: as wide as tall
        log.warning("the up axis is a guess: the markers span %s m along x, y, z (the tallest axis is taken as up, "
                    "%s); pass --up if the rendered subject lies on its side", np.round(extent, 2).tolist(), up)
    return up


# Marker names (after any "Subject:" prefix, any case) of the head and shoulders, and of the feet, in the usual
# marker sets (Plug-in Gait, ISB, OptiTrack's skeletons): LFHD, C7, CLAV, AcromionL, EarL; LHEE, RTOE, LMT5, LLM.
UPPER_LABEL = re.compile(r"^([LR]?(FHD|BHD|HEAD|EAR|TEMPLE|ACR[A-Z]*|SHO)|C7|CLAV|STRN|JN|FOREHEAD)[LR]?$")
FOOT_LABEL = re.compile(r"^([LR]?(HEE[A-Z]*|TOE|ANK[A-Z]*|MT[1-5]|MTP[1-5]?|LM|MM|CAL[A-Z]*)|FOOT[A-Z_0-9]*)[LR]?$")


def _label_side(positions: np.ndarray, labels: list[str], axis: int, extent: float) -> float | None:
    """+1 if the markers ``labels`` (M,) names as head or shoulders lie above those it names as feet along
    ``axis`` of (F, M, 3) ``positions`` by a quarter of ``extent`` (median over frames), -1 if below; None where
    the labels name no two such groups or their heights do not tell."""
    names = [label.rsplit(":", 1)[-1].strip().upper() for label in labels]
    upper = [i for i, name in enumerate(names) if UPPER_LABEL.match(name)]
    feet = [i for i, name in enumerate(names) if FOOT_LABEL.match(name)]
    if not upper or not feet:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (frames with either group hidden: NaN)
        heights = positions[..., axis]
        above = np.nanmedian(np.nanmean(heights[:, upper], axis=1) - np.nanmean(heights[:, feet], axis=1))
    if not np.isfinite(above) or abs(above) < 0.25 * extent:
        return None
    return 1.0 if above > 0 else -1.0


def _floor_side(positions: np.ndarray, axis: int) -> float:
    """+1 if the floor is at the low end of ``axis`` of (F, M, 3) positions, -1 if at the high end."""
    values = positions[..., axis]
    speed = np.linalg.norm(np.diff(positions, axis=0), axis=2)  # (F-1, M), NaN across gaps
    level = np.where(np.isfinite(speed), values[:-1], np.nan)
    usable = np.isfinite(level).any(axis=1)
    if usable.any():
        rows = np.arange(int(usable.sum()))
        lowest = np.argmin(np.where(np.isfinite(level[usable]), level[usable], np.inf), axis=1)
        highest = np.argmax(np.where(np.isfinite(level[usable]), level[usable], -np.inf), axis=1)
        at_rest = np.log(np.median(speed[usable][rows, highest]) + 1e-9) - np.log(
            np.median(speed[usable][rows, lowest]) + 1e-9)
        if abs(at_rest) > np.log(1.3):
            return 1.0 if at_rest > 0 else -1.0
    q = np.percentile(values[np.isfinite(values)], [0.5, 5, 95, 99.5])
    edge = np.log((q[3] - q[2] + 1e-9) / (q[1] - q[0] + 1e-9))
    if abs(edge) > np.log(1.5):
        return 1.0 if edge > 0 else -1.0
    return 1.0 if abs(q[3]) >= abs(q[0]) else -1.0


def to_z_up(positions: np.ndarray, up: str) -> np.ndarray:
    """(F, M, 3) positions with ``up`` (a key of :data:`UP_AXES`) turned to +z (a proper rotation)."""
    if up not in UP_AXES:
        raise MocapError(f"--up {up!r}: expected one of {sorted(UP_AXES)}")
    return np.asarray(positions, dtype=np.float64) @ UP_AXES[up].T


def _centre(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shift (F, M, 3) z-up positions: horizontal mid-range to the origin, floor to z = 0 if far off.

    Returns the shifted positions and the shift (3,), m.
    """
    flat = positions.reshape(-1, 3)
    flat = flat[np.isfinite(flat).all(axis=1)]
    lo, hi = np.percentile(flat, [0.5, 99.5], axis=0)
    shift = np.zeros(3)
    shift[:2] = -(lo[:2] + hi[:2]) / 2
    if abs(lo[2]) > FLOOR_SNAP_M:
        shift[2] = -lo[2]
    return positions + shift, shift


def _probe(positions: np.ndarray, cols: np.ndarray, frames: int) -> np.ndarray:
    """(R, K, 3) the points ``cols`` (K,) of ``positions`` (F, M, 3) in ``frames`` frames spread over the take (R of
    them, fewer in a shorter take): where a test over every frame's candidates is first made cheaply."""
    rows = np.unique(np.linspace(0, len(positions) - 1, min(len(positions), frames)).astype(int))
    return positions[rows][:, cols]


def _copies(positions: np.ndarray, keep: np.ndarray, within_m: float = COPY_M, probe_frames: int = 200
            ) -> np.ndarray:
    """(M,) bool: the points of ``positions`` (F, M, 3) m among ``keep`` (M,) that lie within ``within_m`` of an
    earlier kept point in every frame both are seen (one or more): copies, not markers. Candidates come from
    ``probe_frames`` frames spread over the take, each one is then checked on every frame."""
    cols = np.flatnonzero(keep)
    probe = _probe(positions, cols, probe_frames)
    with warnings.catch_warnings(), np.errstate(invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)  # (pairs never seen together: NaN)
        worst = np.nanmax(np.linalg.norm(probe[:, :, None] - probe[:, None], axis=3), axis=0)  # (K, K)
    copies = np.zeros(len(keep), dtype=bool)
    for a, b in zip(*np.nonzero(np.triu(worst < within_m, 1)), strict=True):
        if copies[cols[a]]:
            continue
        gap = np.linalg.norm(positions[:, cols[a]] - positions[:, cols[b]], axis=1)
        both = np.isfinite(gap)
        copies[cols[b]] |= bool(both.any() and gap[both].max() < within_m)
    return copies


def _segment_axes(positions: np.ndarray, labels: list[str], keep: np.ndarray) -> np.ndarray:
    """(M,) bool: the points among ``keep`` (M,) that a model wrote as a segment's axes, not markers: four labels
    that differ only in a last letter O, A, L, P (Plug-in Gait's PELO, PELA, PELL, PELP: the origin and a point
    along each of the anterior, lateral and proximal axes), the three axis points at one distance from the origin
    (``AXES_LENGTH_TOLERANCE``) along perpendicular directions (``AXES_MAX_COSINE``) in every frame all four are
    seen (``positions`` (F, M, 3) m; one such frame at least). No marker set stands so."""
    index = {label: i for i, label in enumerate(labels) if keep[i]}
    axes = np.zeros(len(labels), dtype=bool)
    for label, origin in index.items():
        if not label.endswith("O"):
            continue
        quad = [index.get(label[:-1] + letter) for letter in "ALP"]
        if None in quad:
            continue
        arms = positions[:, quad] - positions[:, [origin]]  # (F, 3, 3) m
        both = np.isfinite(arms).all(axis=(1, 2))
        if not both.any():
            continue
        arms = arms[both]
        length = np.linalg.norm(arms, axis=2)  # (n, 3)
        if (length.min(axis=1) <= 0).any():
            continue
        unit = arms / length[..., None]
        cosine = np.abs(np.einsum("nij,nkj->nik", unit, unit)[:, [0, 0, 1], [1, 2, 2]])  # (n, 3) pairs
        if ((length.max(axis=1) - length.min(axis=1)) <= AXES_LENGTH_TOLERANCE * length.max(axis=1)).all() and (
                cosine < AXES_MAX_COSINE).all():
            axes[[origin, *quad]] = True
    return axes


def _midpoints(positions: np.ndarray, keep: np.ndarray, within_m: float = MIDPOINT_M, probe_frames: int = 50,
               min_frames: int = 10) -> np.ndarray:
    """(M,) bool: the points of ``positions`` (F, M, 3) m among ``keep`` (M,) that lie within ``within_m`` of the
    midpoint of two other kept points in every frame the three are seen (``min_frames`` at least): joint centres a
    model wrote (OpenSim's and Plug-in Gait's KJC and AJC, halfway between the condyles or the malleoli), not
    markers; a skin marker wobbles by millimetres. Candidates come from ``probe_frames`` frames spread over the
    take, each then checked on every frame."""
    cols = np.flatnonzero(keep)
    out = np.zeros(len(keep), dtype=bool)
    if cols.size < 3:
        return out
    probe = _probe(positions, cols, probe_frames)  # (R, K, 3)
    a, b = np.triu_indices(cols.size, 1)
    middle = (probe[:, a] + probe[:, b]) / 2  # (R, P, 3)
    for k in range(cols.size):
        with warnings.catch_warnings(), np.errstate(invalid="ignore"):
            warnings.simplefilter("ignore", RuntimeWarning)  # (never seen together: NaN)
            worst = np.nanmax(np.linalg.norm(middle - probe[:, [k]], axis=2), axis=0)  # (P,)
        for pair in np.flatnonzero((worst < within_m) & (a != k) & (b != k)):
            i, j = cols[a[pair]], cols[b[pair]]
            off = np.linalg.norm(positions[:, cols[k]] - (positions[:, i] + positions[:, j]) / 2, axis=1)
            seen = np.isfinite(off)
            if seen.sum() >= min_frames and off[seen].max() < within_m:
                out[cols[k]] = True
                break
    return out


def _duplicate_samples(positions: np.ndarray, keep: np.ndarray, within_m: float = DUPLICATE_M,
                       chunk_entries: int = 1 << 22) -> np.ndarray:
    """(F, M) bool: samples of ``positions`` (F, M, 3) m among ``keep`` (M,) within ``within_m`` of another kept
    point's sample in their frame: of the two, the one off its own path (its step from the mean of its samples either
    side over ``within_m``, the other's under: a label on another marker for a frame, the tennis serve's LWRA on
    LWRB at frame 400), else the one whose point is seen in fewer frames (the later on a tie: a reconstruction's
    second copy of a marker, a Vicon file's unlabelled trajectory *20 beside RASI, 2-7 mm away for 800 frames).
    Frames are searched ``chunk_entries`` (frames x points^2) at a time."""
    cols = np.flatnonzero(keep)
    out = np.zeros(positions.shape[:2], dtype=bool)
    if cols.size < 2:
        return out
    P = positions[:, cols]
    count = np.isfinite(P[..., 0]).sum(axis=0)
    off_path = np.full(P.shape[:2], np.nan)  # (F, K) m: distance from the mean of the samples either side
    off_path[1:-1] = np.linalg.norm(P[1:-1] - (P[:-2] + P[2:]) / 2, axis=2)
    step = max(1, chunk_entries // cols.size**2)
    for lo in range(0, len(P), step):
        p = P[lo:lo + step]
        with np.errstate(invalid="ignore"):
            close = np.linalg.norm(p[:, :, None] - p[:, None], axis=3) < within_m  # (n, K, K) (NaN: False)
        f, i, j = np.nonzero(np.triu(close, 1))
        off_i, off_j = off_path[lo + f, i], off_path[lo + f, j]
        with np.errstate(invalid="ignore"):  # (NaN: at a gap's edge, compares False)
            loser = np.where(count[i] < count[j], i, j)
            loser = np.where((off_i > within_m) & (off_j < within_m), i, loser)
            loser = np.where((off_j > within_m) & (off_i < within_m), j, loser)
        out[lo + f, cols[loser]] = True
    return out


def _named(labels: list[str], mask: np.ndarray) -> str:
    """The ``labels`` (M,) where ``mask`` (M,) holds, for a log line."""
    return ", ".join(label for label, m in zip(labels, mask, strict=True) if m)


def _points_to_film(traj: Trajectories, path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Which points of a motion file are markers to film: (M,) bool, the (F, M) samples not to film (a marker
    reconstructed twice, a label on another marker), and the counts of what was left out (for the take's info),
    each logged: points never seen, model outputs the file names (:func:`mocap.export.c3d.read_c3d`), segment axes,
    joint centres, copies, second reconstructions, duplicate samples."""
    valid = traj.valid
    not_markers = np.isin(traj.labels, traj.metadata.get("not_markers", []))
    if not_markers.any():
        log.info("%s: %d of its %d points are model outputs (angles, forces, moments, powers, modelled markers), "
                 "not markers: not filmed", path, int(not_markers.sum()), traj.n_markers)
    seen_ever = valid.any(axis=0)
    keep = seen_ever & ~not_markers
    axes = _segment_axes(traj.positions, traj.labels, keep)
    if axes.any():
        log.info("%s: %d points are segments' axes a model wrote (origin and three axis points, e.g. Plug-in Gait's "
                 "bones), not markers: not filmed", path, int(axes.sum()))
        keep &= ~axes
    if not keep.any():
        raise MocapError(f"{path}: every point of the file seen is a model output (angles, forces, segment axes, "
                         "...), none a marker; give the file with the markers' trajectories")
    centres = _midpoints(traj.positions, keep)
    if centres.any():
        log.info("%s: %d point(s) stay halfway between two others in every frame (joint centres a model wrote), not "
                 "markers: not filmed: %s", path, int(centres.sum()), _named(traj.labels, centres))
        keep &= ~centres
    copies = _copies(traj.positions, keep)
    if copies.any():
        log.info("%s: %d point(s) coincide with another in every frame (a marker named twice), not filmed twice: %s",
                 path, int(copies.sum()), _named(traj.labels, copies))
        keep &= ~copies
    twice = _duplicate_samples(traj.positions, keep)
    shadows = keep & twice.any(axis=0) & (2 * twice.sum(axis=0) >= valid.sum(axis=0))
    if shadows.any():
        log.info("%s: %d point(s) lie on another marker in half their frames or more (a second reconstruction of it, "
                 "wandering off where they do not), not filmed: %s", path, int(shadows.sum()),
                 _named(traj.labels, shadows))
        keep &= ~shadows
        twice[:, shadows] = False
    if twice.any():
        worst = np.argsort(twice.sum(axis=0))[::-1][:3]
        log.info("%s: %d samples lie within %.0f mm of another marker's in their frame (one marker reconstructed "
                 "twice), not filmed; most from %s", path, int(twice.sum()), DUPLICATE_M * 1e3,
                 ", ".join(f"{traj.labels[k]} ({int(twice[:, k].sum())})" for k in worst if twice[:, k].any()))
    dropped = {"markers_dropped_never_seen": int((~seen_ever & ~not_markers).sum()),
               "points_dropped_not_markers": int(not_markers.sum()), "points_dropped_segment_axes": int(axes.sum()),
               "points_dropped_joint_centres": int(centres.sum()), "points_dropped_copies": int(copies.sum()),
               "points_dropped_duplicates": int(shadows.sum()), "samples_dropped_duplicates": int(twice.sum())}
    return keep, twice, dropped


def load_motion(path: str | os.PathLike, up: str | None = None) -> tuple[list[str], float, np.ndarray]:
    """Marker motion from a C3D, TRC or Motive CSV file, in the synthetic world frame.

    Units come from the file (C3D: POINT:UNITS); the up axis is detected (:func:`detect_up_axis`) unless ``up``
    is given; the motion is centred horizontally on the origin (mid-range of the samples) and, if
    its floor is more than 15 cm from z = 0, lifted or lowered onto it. Gaps stay NaN.

    Args:
        path: the C3D, TRC or CSV file (by its suffix).
        up: the file's up axis ("x", "y", "z", "-x", "-y", "-z"); None to detect it.

    Returns:
        labels (M,), fps, positions (F, M, 3) in metres, z up.
    """
    motion = motion_from_file(path, up)
    return motion.labels, motion.fps, motion.positions


def motion_from_file(path: str | os.PathLike, up: str | None = None) -> Motion:
    """Like :func:`load_motion`, as a :class:`Motion` whose ``info`` records the up axis and the shift."""
    path = Path(path)
    traj = read_trajectories(path)
    if traj.n_frames == 0 or traj.n_markers == 0:
        raise MocapError(f"{path}: the file holds no marker samples ({traj.n_frames} frames, "
                         f"{traj.n_markers} markers); give a file with 3D points")
    valid = traj.valid
    if not valid.any():
        raise MocapError(f"{path}: every marker sample is missing (all gaps); nothing to render")
    keep, twice, dropped = _points_to_film(traj, path)
    labels = [label for label, k in zip(traj.labels, keep, strict=True) if k]
    raw = np.where(twice[..., None], np.nan, traj.positions)[:, keep]
    source = "--up"
    if up is None:
        try:
            up = detect_up_axis(raw, labels)
        except MocapError as exc:
            raise MocapError(f"{path}: {exc}") from None
        source = "detected"
    positions, shift = _centre(to_z_up(raw, up))
    info = {"source": str(path), "source_fps": traj.fps, "up_axis": up, "up_axis_from": source,
            "shift_m": shift.tolist(), **dropped, "missing_fraction": float(1 - valid[:, keep].mean())}
    return Motion(labels, traj.fps, positions, None, info)
