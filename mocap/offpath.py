"""Samples off their identity's own path are withheld (offline).

Inside a tight cluster (a hand on a wheel's rim, a forearm's markers 47 mm apart seen in glimpses) an identity
whose marker is hidden for a frame or two can hold a neighbour's point meanwhile and come back to its own: one to
three samples on another marker between two stretches of its own. Each such hop costs two identity switches, and
a user reads a 40-120 mm excursion that no body makes. No pass before this one can give the samples to the right
identity when that identity has no samples around them (the neighbour's track was lost).

:func:`withhold_off_path` fits a cubic in time to an identity's samples within ``reach_s`` on both sides of a short
stretch (at least ``min_side`` samples on each side) and empties the stretch where every one of its samples misses
that path by more than ``far_m`` and ``ratio`` times the fit's own worst residual: a stretch the identity's path
passes through, or a path too irregular to say, is kept. The samples are removed (positions, residuals and camera
masks), never moved: the output has a short gap where it had a wrong identity.

:func:`give_hops_back` then gives back the hops that can be told whose they are: a single sample that hops out from
both its identity's neighbours and back (more than ``far_m`` each way) and lies within ``near_m`` of where another
identity, missing that frame only, passes (a cubic through its samples on both sides) goes to that identity (the whole
sprint: a wheel marker's identity, glimpsed for three frames, held the hand passing by in the middle one while the
hand's own identity missed it).

:func:`give_end_hops_back` does the same for a stretch (``end_most`` samples at most) at an end of an identity's run,
next to a gap of more than ``reach_s``: where :func:`withhold_off_path` has no samples on the gap's side, a quadratic
through the ``min_side`` or more samples on the run's side, extrapolated over the stretch, must miss it by more than
``far_m`` (and ``ratio`` times its worst residual), and the stretch goes to the one identity, unseen there, whose path
(a quadratic through its samples just before, or else just after) passes within ``end_near_m`` of every sample of it.
A stretch no other path takes (a recording's glitch, the marker's own sudden turn) is left alone. (The whole sprint,
frames 2135 and 2144: the forearm's markers seen in glimpses, one identity's run ending with a neighbour's point a
frame after that neighbour's identity was lost, another starting with one a frame before it is back: three fewer
switches on seed 0, two on seed 2.)
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from mocap.trajectories import Trajectories

__all__ = ["OffPathConfig", "give_end_hops_back", "give_hops_back", "withhold_off_path"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OffPathConfig:
    """Settings of :func:`withhold_off_path`, :func:`give_hops_back` and :func:`give_end_hops_back`.

    Attributes:
        reach_s: the path is fitted to the identity's samples at most this long before and after a stretch, s.
        min_side: samples needed on each side of a stretch.
        most: most samples in a stretch.
        span_s: longest time from a stretch's first sample to its last, s.
        far_m: every sample of a stretch misses the path by more than this, m ...
        ratio: ... and by more than this many times the fit's worst residual on the samples it was fitted to.
        near_m: a hop lies this close to the path of the identity it is given to, m (:func:`give_hops_back`).
        end_near_m: a stretch at the end of a run lies this close to the path (extrapolated over up to ``reach_s``)
            of the identity it is given to, m (:func:`give_end_hops_back`) ...
        end_most: ... and has this many samples at most: the path it continues says whose it is, where a stretch
            inside a run, withheld, is only off its own.
    """

    reach_s: float = 0.07
    min_side: int = 4
    most: int = 3
    span_s: float = 0.05
    far_m: float = 0.030
    ratio: float = 2.5
    near_m: float = 0.005
    end_near_m: float = 0.015
    end_most: int = 5


def withhold_off_path(traj: Trajectories, config: OffPathConfig | None = None) -> int:
    """Empty, in place, the short stretches of identities that miss their own path (module docstring).

    Returns the number of samples withheld.
    """
    cfg = config or OffPathConfig()
    reach = max(1, int(round(cfg.reach_s * traj.fps)))
    span = int(round(cfg.span_s * traj.fps))
    withheld = 0
    for col in range(traj.n_markers):
        frames = np.flatnonzero(np.isfinite(traj.positions[:, col, 0]))
        for stretch in _off_path(frames, traj.positions[frames, col], reach, span, cfg):
            traj.positions[stretch, col] = np.nan
            traj.residuals[stretch, col] = np.nan
            traj.camera_masks[stretch, col] = 0
            withheld += len(stretch)
    if withheld:
        log.info("withheld %d samples off their identity's path (hops onto a neighbour)", withheld)
    return withheld


def give_hops_back(traj: Trajectories, config: OffPathConfig | None = None) -> int:
    """Move, in place, single samples that hop out from their identity's path and back onto the path of an identity
    that misses only their frame (module docstring). Returns the number of samples moved."""
    cfg = config or OffPathConfig()
    P = traj.positions  # (F, M, 3) m
    if P.shape[0] < 3:
        return 0
    seen = np.isfinite(P[..., 0])
    step = np.linalg.norm(np.diff(P, axis=0), axis=2)  # (F - 1, M) NaN where either side is missing
    with np.errstate(invalid="ignore"):
        hop = (step[:-1] > cfg.far_m) & (step[1:] > cfg.far_m)  # (F - 2, M): frame f + 1 hops out and back
        gap = seen[:-2] & ~seen[1:-1] & seen[2:]  # (F - 2, M): frame f + 1 missing alone
    moved = 0
    for f, b in zip(*np.nonzero(hop & gap.any(axis=1)[:, None]), strict=True):
        f += 1
        candidates = np.flatnonzero(gap[f - 1])
        if candidates.size == 0:  # (given a hop of this frame already)
            continue
        path = np.array([_across_gap(P[:, a], f) for a in candidates])  # (n, 3) m, NaN: too few samples
        miss = np.linalg.norm(path - P[f, b], axis=1)
        near = np.flatnonzero(miss < cfg.near_m)
        if near.size != 1:
            continue
        a = candidates[near[0]]
        traj.move_samples(f, b, a)
        gap[f - 1, a] = False
        moved += 1
    if moved:
        log.info("gave %d samples that hopped off their identity's path to the identity whose path they lie on", moved)
    return moved


def _across_gap(x: np.ndarray, f: int, side: int = 2) -> np.ndarray:
    """(3,) m: where an identity seen at ``x`` (F, 3) m (NaN: unseen) passes at frame ``f``, which it misses: a cubic
    (a line with fewer samples) through its ``side`` frames on each side, all seen; NaN where they are not."""
    frames = np.r_[f - side:f, f + 1:f + side + 1]
    if frames[0] < 0 or frames[-1] >= len(x) or not np.isfinite(x[frames, 0]).all():
        return np.full(3, np.nan)
    return _path_fit(frames.astype(float), x[frames], np.array([float(f)]), min(4, len(frames)))[0][0]


def _off_path(frames: np.ndarray, x: np.ndarray, reach: int, span: int, cfg: OffPathConfig) -> list[np.ndarray]:
    """The stretches (frame arrays) of one identity, seen at ``frames`` (n,) at ``x`` (n, 3) m, that miss its path.

    A stretch starts at a sample whose step from the sample before misses that sample's extrapolation (constant
    velocity from the two before it) by more than ``far_m``: a sample on the path cannot be off it at its entry.
    """
    n = len(frames)
    if n < 2 * cfg.min_side + 1:
        return []
    dt = np.diff(frames).astype(float)  # (n - 1,)
    velocity = np.diff(x, axis=0) / dt[:, None]  # (n - 1, 3) m/frame, between samples i and i + 1
    entry = np.zeros(n, dtype=bool)
    entry[2:] = np.linalg.norm(x[2:] - x[1:-1] - velocity[:-1] * dt[1:, None], axis=1) > cfg.far_m
    found: list[np.ndarray] = []
    free_from = 0  # samples before this index belong to a stretch found already
    for i in np.flatnonzero(entry):
        if i < max(cfg.min_side, free_from):
            continue
        for k in range(1, cfg.most + 1):
            last = i + k - 1
            if last + cfg.min_side >= n or frames[last] - frames[i] > span:
                break
            first = np.searchsorted(frames, frames[i] - reach)  # the samples within reach on both sides
            stop = np.searchsorted(frames, frames[last] + reach, side="right")
            if i - first < cfg.min_side or stop - last - 1 < cfg.min_side:
                continue
            side = np.r_[first:i, last + 1:stop]
            t = (frames[side] - frames[i]).astype(float)
            basis = np.vander(t, 4)  # (m, 4): cubic in frames from the stretch's first
            coef, *_ = np.linalg.lstsq(basis, x[side], rcond=None)
            worst_fit = float(np.linalg.norm(basis @ coef - x[side], axis=1).max())
            miss = np.linalg.norm(np.vander((frames[i:last + 1] - frames[i]).astype(float), 4) @ coef
                                  - x[i:last + 1], axis=1)
            if miss.min() > max(cfg.far_m, cfg.ratio * worst_fit):
                found.append(frames[i:last + 1])
                free_from = last + 1
                break
    return found



def give_end_hops_back(traj: Trajectories, config: OffPathConfig | None = None) -> int:
    """Move, in place, the stretches at the ends of identities' runs that miss their run's path onto the one identity
    whose path they continue (module docstring). Returns the number of samples moved."""
    cfg = config or OffPathConfig()
    P = traj.positions  # (F, M, 3) m
    reach = max(1, int(round(cfg.reach_s * traj.fps)))
    span = int(round(cfg.span_s * traj.fps))
    moved = 0
    for col in range(traj.n_markers):
        frames = np.flatnonzero(np.isfinite(P[:, col, 0]))
        for stretch in _off_path_at_ends(frames, P[frames, col], reach, span, cfg):
            owner = _continued_by(P, stretch, col, reach, cfg)
            if owner >= 0:
                traj.move_samples(stretch, col, owner)
                moved += len(stretch)
    if moved:
        log.info("gave %d samples at the ends of their identity's runs, off its path, to the identity whose path they "
                 "continue", moved)
    return moved


def _path_fit(frames: np.ndarray, x: np.ndarray, at: np.ndarray, terms: int = 3) -> tuple[np.ndarray, float]:
    """A polynomial in time of ``terms`` coefficients (a quadratic by default) through samples ``x`` (m, 3) m at
    ``frames`` (m,), evaluated at frames ``at`` (k,): (k, 3) m, and its worst residual on the samples, m."""
    t0 = float(at[0])
    basis = np.vander(frames - t0, terms)
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    worst = float(np.linalg.norm(basis @ coef - x, axis=1).max())
    return np.vander(at - t0, terms) @ coef, worst


def _off_path_at_ends(frames: np.ndarray, x: np.ndarray, reach: int, span: int, cfg: OffPathConfig
                      ) -> list[np.ndarray]:
    """The stretches (frame arrays) at the ends of one identity's runs (``frames`` (n,) seen at ``x`` (n, 3) m; runs
    cut where no sample is within ``reach`` frames) that miss the path the run's other samples make: a quadratic
    through the ``min_side`` or more samples within ``reach`` frames of the stretch, on its one side, extrapolated
    over it, misses each of its samples by more than ``far_m`` and ``ratio`` times the fit's worst residual
    (``end_most`` samples at most, within ``span`` frames)."""
    found: list[np.ndarray] = []
    cuts = np.flatnonzero(np.diff(frames) > reach) + 1
    for run in np.split(np.arange(len(frames)), cuts):
        if len(run) <= cfg.min_side:
            continue
        for order in (run, run[::-1]):  # the run's first samples, then its last ones: stretch first, then its side
            for k in range(1, cfg.end_most + 1):
                stretch, rest = order[:k], order[k:]
                if len(rest) < cfg.min_side or abs(int(frames[stretch[-1]] - frames[stretch[0]])) > span:
                    break
                side = rest[np.abs(frames[rest] - frames[stretch[-1]]) <= reach]
                if len(side) < cfg.min_side:
                    break
                ahead, worst = _path_fit(frames[side].astype(float), x[side], frames[stretch].astype(float))
                if np.linalg.norm(ahead - x[stretch], axis=1).min() > max(cfg.far_m, cfg.ratio * worst):
                    found.append(np.sort(frames[stretch]))
                    break
    return found


def _continued_by(P: np.ndarray, stretch: np.ndarray, col: int, reach: int, cfg: OffPathConfig) -> int:
    """The one identity other than ``col``, unseen in the frames ``stretch`` (k,) of ``P`` (F, M, 3) m, whose path (a
    quadratic through its ``min_side`` or more samples within ``reach`` frames before the stretch, or else after it)
    passes within ``end_near_m`` of every sample of column ``col`` there; -1 where none or several do."""
    F = len(P)
    lo, hi = int(stretch[0]), int(stretch[-1])
    before = np.arange(max(0, lo - reach), lo)
    after = np.arange(hi + 1, min(F, hi + 1 + reach))
    seen = np.isfinite(P[..., 0])
    free = ~seen[stretch].any(axis=0)
    free[col] = False
    found = -1
    for a in np.flatnonzero(free & ((seen[before].sum(axis=0) >= cfg.min_side)
                                     | (seen[after].sum(axis=0) >= cfg.min_side))):
        near = before[seen[before, a]]
        if len(near) < cfg.min_side:
            near = after[seen[after, a]]
        path, _ = _path_fit(near.astype(float), P[near, a], stretch.astype(float))
        if (np.linalg.norm(path - P[stretch, col], axis=1) < cfg.end_near_m).all():
            if found >= 0:
                return -1
            found = int(a)
    return found
