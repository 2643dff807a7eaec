"""Offline identity repair on finished trajectories: swap repair and fragment stitching.

The online tracker decides each frame's identities from the past alone. Once the take is done,
the frames on both sides of a decision are known, and two kinds of identity error are easy to
see and undo:

* **Swaps.** Two identities exchange markers between frame ``f`` and ``f + 1`` (fast motion next to
  a close neighbour). Relabelling the tails after ``f`` with a permutation ``pi`` changes the
  second differences (accelerations, m/frame^2) at ``f`` and ``f + 1`` of the tracks involved.
  For every frame, :func:`repair_swaps` finds the permutation of the tracks alive on
  ``f - 1 .. f + 2`` that minimises the summed squared accelerations (Hungarian,
  ``scipy.optimize.linear_sum_assignment``) and applies it only when it is far smoother than
  keeping the labels (ratio and absolute margin), so real hard accelerations are left alone.
* **Fragments and swaps through gaps.** An identity is lost and the marker comes back as a new one,
  or two identities exchange markers across a missing frame. :func:`relink_tracklets` cuts every
  identity into tracklets (at gaps and at acceleration spikes) and re-links them in time order:
  tracklets starting together are assigned (Hungarian) to identities that ended before. Where
  both ends have markers rigidly attached to them (the same segment: distances steady over a few
  frames) that are seen at both ends, and those distances agree (``shape_gate_m``), the cost is how
  much they changed, over any gap up to ``shape_max_s``: distances within a segment do not depend on
  how it moved meanwhile, and they tell apart markers a few centimetres apart that come back in turn.
  Otherwise the cost is how well the constant-velocity extrapolations of both ends agree across a
  short gap. The tracker's own link is preferred and kept across any gap unless the distances clearly
  disagree (``shape_refuse_m``: a new marker next to a hidden one took its identity); it is the
  fallback when nothing else fits.

Both passes only move whole samples between identity columns (positions, residuals and camera
masks together); they never change a position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap.trajectories import Trajectories

__all__ = ["RelabelConfig", "RelabelStats", "relink_tracklets", "repair_identities", "repair_swaps"]


@dataclass(frozen=True)
class RelabelConfig:
    """Settings of the offline identity repair.

    Attributes:
        swap_ratio: a tail permutation is applied when its acceleration cost is below this fraction
            of the cost of keeping the labels.
        swap_margin_m: ... and below it by at least this acceleration, m/frame^2 (squared internally),
            so that noise-level differences never relabel anything.
        max_gap: longest gap, frames, a fragment may be stitched across.
        stitch_gate_m: extrapolation disagreement allowed for a one-frame gap, metres.
        stitch_acc_m: extra disagreement allowed per squared frame of gap (unmodelled acceleration),
            m/frame^2; half the speed times the gap is allowed too.
        own_link_weight: the tracker's own link (same identity before and after) costs this fraction
            of its disagreement, and is kept across any gap (the tracker re-identified it).
        split_acc_m: a track is cut where its acceleration exceeds this on two consecutive samples,
            m/frame^2 (a jump to another marker), and the pieces are re-linked.
        shape_window: samples at each tracklet end over which the distances to its neighbours are taken.
        shape_radius_m: neighbours within this distance ...
        shape_steady_m: ... whose distance varies less than this over the window count as attached.
        shape_min: attached neighbours seen at both ends needed to compare distances.
        shape_gate_m: a link is made on distances when their weighted mean change is below this, m ...
        shape_refuse_m: ... and refused, the tracker's own link included, above this (between the two, the
            extrapolation rules decide).
        shape_max_s: longest gap, seconds, a link by distances may span.
    """

    swap_ratio: float = 0.25
    swap_margin_m: float = 0.01
    max_gap: int = 12
    stitch_gate_m: float = 0.02
    stitch_acc_m: float = 0.01
    own_link_weight: float = 0.5
    split_acc_m: float = 0.06
    shape_window: int = 6
    shape_radius_m: float = 0.25
    shape_steady_m: float = 0.004
    shape_min: int = 2
    shape_gate_m: float = 0.008
    shape_refuse_m: float = 0.024
    shape_max_s: float = 10.0


@dataclass
class RelabelStats:
    """What the repair changed: tail permutations applied and fragments joined."""

    swaps: int = 0
    stitches: int = 0


def _permute_tails(traj: Trajectories, start: int, order: np.ndarray, columns: np.ndarray) -> None:
    """From frame ``start`` on, column ``columns[k]`` receives what column ``order[k]`` held."""
    for array in (traj.positions, traj.residuals, traj.camera_masks):
        array[start:, columns] = array[start:, order]


def repair_swaps(traj: Trajectories, config: RelabelConfig | None = None) -> int:
    """Undo identity swaps in place (see the module docstring); returns how many frames were relabelled."""
    cfg = config or RelabelConfig()
    P = traj.positions
    F = traj.n_frames
    swaps = 0
    margin = cfg.swap_margin_m**2
    for f in range(1, F - 2):
        alive = np.flatnonzero(np.isfinite(P[f - 1 : f + 3, :, 0]).all(axis=0))
        if alive.size < 2:
            continue
        a, b, c, d = (P[f + k, alive] for k in (-1, 0, 1, 2))  # (K, 3) each
        # cost[i, k]: track i keeps its head (f-1, f) and takes track k's tail (f+1, f+2).
        acc_f = c[None, :, :] - 2 * b[:, None, :] + a[:, None, :]
        acc_f1 = d[None, :, :] - 2 * c[None, :, :] + b[:, None, :]
        cost = (acc_f**2).sum(axis=2) + (acc_f1**2).sum(axis=2)
        keep = np.diag(cost)
        # Only pairs that could plausibly swap matter: cheap pre-check before the assignment.
        if not np.any(cost < cfg.swap_ratio * keep[:, None] - margin):
            continue
        rows, cols = linear_sum_assignment(cost)
        moved = rows != cols
        if not moved.any():
            continue
        new, old = cost[rows[moved], cols[moved]].sum(), keep[rows[moved]].sum()
        if new < cfg.swap_ratio * old and old - new > margin:
            _permute_tails(traj, f + 1, alive[cols[moved]], alive[rows[moved]])
            swaps += 1
    return swaps


def _tracklets(P: np.ndarray, split_acc: float) -> list[np.ndarray]:
    """Cut every identity column into runs of consecutive samples, also where the acceleration
    (second difference, m/frame^2) exceeds ``split_acc``; returns (frames, column) index pairs per run."""
    valid = np.isfinite(P[:, :, 0])
    acc = np.full(valid.shape, np.inf)
    acc[1:-1] = np.linalg.norm(P[2:] - 2 * P[1:-1] + P[:-2], axis=2)
    runs = []
    for col in range(P.shape[1]):
        frames = np.flatnonzero(valid[:, col])
        if frames.size == 0:
            continue
        # A break before sample k: a gap, or a jump at k-1 -> k (acceleration spike at k-1 or k).
        jump = np.zeros(frames.size, dtype=bool)
        jump[1:] = (np.diff(frames) > 1) | (
            (acc[frames[:-1], col] > split_acc) & np.isfinite(acc[frames[:-1], col])
            & (acc[frames[1:], col] > split_acc) & np.isfinite(acc[frames[1:], col]))
        for piece in np.split(frames, np.flatnonzero(jump)):
            runs.append(np.stack([piece, np.full(piece.size, col)], axis=1))
    return runs


def _end_state(P: np.ndarray, run: np.ndarray, at_start: bool) -> tuple[int, np.ndarray, np.ndarray]:
    """Frame, position and velocity (m/frame, pointing forward in time) at one end of a tracklet."""
    frame, col = run[0] if at_start else run[-1]
    pos = P[frame, col]
    if run.shape[0] < 2:
        return int(frame), pos, np.zeros(3)
    if at_start:
        return int(frame), pos, P[run[1][0], run[1][1]] - pos
    return int(frame), pos, pos - P[run[-2][0], run[-2][1]]


def _attached(P: np.ndarray, samples: np.ndarray, cfg: RelabelConfig) -> tuple[np.ndarray, np.ndarray]:
    """Columns of the markers rigidly attached to a marker over ``samples`` (n, 2) (frame, column), and their
    median distances, m: columns seen in every sample, within ``shape_radius_m``, whose distance varies less
    than ``shape_steady_m`` (none with fewer than three samples)."""
    if len(samples) < 3:
        return np.zeros(0, dtype=np.intp), np.zeros(0)
    frames, cols = samples[:, 0], samples[:, 1]
    d = np.linalg.norm(P[frames] - P[frames, cols][:, None, :], axis=2)  # (n, M)
    d[:, np.unique(cols)] = np.nan
    seen = np.isfinite(d).all(axis=0)
    d = d[:, seen]
    keep = (np.median(d, axis=0) < cfg.shape_radius_m) & (d.max(axis=0) - d.min(axis=0) < cfg.shape_steady_m)
    return np.flatnonzero(seen)[keep], np.median(d[:, keep], axis=0)


def _distance_change(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], exclude: tuple[int, int],
                     minimum: int) -> float:
    """How much the distances (m) to the attached markers two tracklet ends share changed: their mean change
    weighted by 1 / distance^2 (the nearest are the most likely on the same segment); NaN with too few."""
    common, ia, ib = np.intersect1d(a[0], b[0], return_indices=True)
    use = ~np.isin(common, exclude)
    if use.sum() < minimum:
        return np.nan
    da, db = a[1][ia[use]], b[1][ib[use]]
    w = 1.0 / (0.5 * (da + db)) ** 2
    return float((w * np.abs(da - db)).sum() / w.sum())


def relink_tracklets(traj: Trajectories, config: RelabelConfig | None = None) -> int:
    """Re-link identities globally, in place; returns the number of identities saved.

    Tracklets (see :func:`_tracklets`) are taken in order of their first frame; those starting at
    the same frame are assigned together (Hungarian) to identities that ended within ``max_gap``
    frames before, by the mean disagreement of the two constant-velocity extrapolations across
    the gap (the identity's forwards, the tracklet's backwards); a tracklet with no identity within
    the gate starts a new one. Output columns are the resulting identities.
    """
    cfg = config or RelabelConfig()
    P = traj.positions
    runs = _tracklets(P, cfg.split_acc_m)
    if not runs:
        return 0
    runs.sort(key=lambda r: int(r[0, 0]))
    shape_max = max(int(round(cfg.shape_max_s * traj.fps)), cfg.max_gap)
    chains: list[list[np.ndarray]] = []
    ends: list[tuple[int, np.ndarray, np.ndarray]] = []  # per chain: last frame, position, velocity
    attached: list[tuple[np.ndarray, np.ndarray]] = []  # per chain: markers attached to its end, distances
    i = 0
    while i < len(runs):
        start = int(runs[i][0, 0])
        group = []
        while i < len(runs) and int(runs[i][0, 0]) == start:
            group.append(runs[i])
            i += 1
        columns = {int(run[0, 1]) for run in group}
        open_chains = [c for c, (e, _, _) in enumerate(ends)
                       if 0 < start - e and (start - e <= cfg.max_gap or int(chains[c][-1][0, 1]) in columns
                                             or (start - e <= shape_max and len(attached[c][0]) >= cfg.shape_min))]
        assigned: dict[int, int] = {}
        refused: set[tuple[int, int]] = set()  # (group index, chain): the distances disagree
        if open_chains:
            cost = np.full((len(group), len(open_chains)), np.inf)
            for g, run in enumerate(group):
                _, p0, v0 = _end_state(P, run, at_start=True)
                here = _attached(P, run[: cfg.shape_window], cfg)
                for j, c in enumerate(open_chains):
                    e, pe, ve = ends[c]
                    gap = start - e
                    own_col = int(chains[c][-1][0, 1])
                    same = own_col == int(run[0, 1])  # the tracker's own link
                    change = _distance_change(attached[c], here, (own_col, int(run[0, 1])), cfg.shape_min)
                    if np.isfinite(change):
                        if change < cfg.shape_gate_m and gap <= shape_max:
                            cost[g, j] = (cfg.own_link_weight if same else 1.0) * change
                            continue
                        if change > cfg.shape_refuse_m:
                            refused.add((g, c))
                            continue
                    miss = 0.5 * (np.linalg.norm(pe + ve * gap - p0) + np.linalg.norm(p0 - v0 * gap - pe))
                    speed = 0.5 * (np.linalg.norm(ve) + np.linalg.norm(v0))
                    gate = cfg.stitch_gate_m + speed * 0.5 * gap + cfg.stitch_acc_m * gap * gap
                    if same:
                        cost[g, j] = cfg.own_link_weight * miss if gap > cfg.max_gap or miss < gate else np.inf
                    elif gap <= cfg.max_gap and miss < gate:
                        cost[g, j] = miss
            finite = np.isfinite(cost)
            if finite.any():
                rows, cols = linear_sum_assignment(np.where(finite, cost, 1e9))
                for g, j in zip(rows, cols, strict=True):
                    if finite[g, j]:
                        assigned[g] = open_chains[j]
        taken = set(assigned.values())
        for g, run in enumerate(group):
            c = assigned.get(g)
            if c is None:  # nothing fits: keep the tracker's own link if that identity is free and not refused
                own = [c for c in open_chains if int(chains[c][-1][0, 1]) == int(run[0, 1]) and c not in taken
                       and (g, c) not in refused]
                c = own[0] if own else None
                if c is not None:
                    taken.add(c)
            if c is None:
                c = len(chains)
                chains.append([])
                ends.append(None)
                attached.append(None)
            chains[c].append(run)
            ends[c] = _end_state(P, run, at_start=False)
            attached[c] = _attached(P, np.concatenate(chains[c][-cfg.shape_window :])[-cfg.shape_window :], cfg)
    before = traj.n_markers
    F = traj.n_frames
    positions = np.full((F, len(chains), 3), np.nan)
    residuals = np.full((F, len(chains)), np.nan)
    masks = np.zeros((F, len(chains)), dtype=np.uint32)
    for c, pieces in enumerate(chains):
        idx = np.concatenate(pieces)
        positions[idx[:, 0], c] = P[idx[:, 0], idx[:, 1]]
        residuals[idx[:, 0], c] = traj.residuals[idx[:, 0], idx[:, 1]]
        masks[idx[:, 0], c] = traj.camera_masks[idx[:, 0], idx[:, 1]]
    traj.positions, traj.residuals, traj.camera_masks = positions, residuals, masks
    traj.labels = [f"M{k + 1:03d}" for k in range(len(chains))]
    return before - len(chains)


def repair_identities(traj: Trajectories, config: RelabelConfig | None = None) -> RelabelStats:
    """Swap repair, then fragment stitching, in place; empty identity columns are dropped.

    Labels of the remaining identities are renumbered ``M001``, ``M002`` ... in column order.
    """
    stats = RelabelStats()
    if traj.n_markers == 0 or traj.n_frames < 4:
        return stats
    stats.swaps = repair_swaps(traj, config)
    stats.stitches = relink_tracklets(traj, config)
    return stats
