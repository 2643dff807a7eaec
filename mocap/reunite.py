"""Rigid clusters that come back after a long absence get their identities back (offline).

A plate of markers on one segment (a wheelchair frame, an arm's cluster) that leaves the volume, or is
hidden for seconds, comes back far from where it was lost: no gate around a prediction or a last position
finds it, and every marker of it starts a new identity. Its shape does find it: the distances between
markers of a rigid plate stay the same to a millimetre all take long, and differ from plate to plate.

On finished trajectories (after :mod:`mocap.relabel`), :func:`reunite_clusters`:

1. measures every pair of identities over the frames both are seen in: the median distance and its
   robust spread (1.4826 MAD); pairs closer than ``reach_m`` that spread less than ``spread_m`` are rigid;
2. maps identities that started later onto identities that ended before them (never seen together): a
   seed is a rigid triangle of later identities whose three distances equal (``tolerance_m``) those of a
   rigid triangle of earlier ones; it grows one identity at a time, each compared on two distances or
   more, the best-fitting first unless another fits within ``margin_m``;
3. takes the largest map, then the one whose distances changed least (``mean_tolerance_m`` at most, on
   ``min_members`` distances at least), unless another map that sends one of its identities to another
   marker fits within ``margin_m`` (a symmetric plate, two plates alike): all its candidates are then left
   alone; and repeats on the identities left;
4. joins each mapped pair into one identity.

Only whole samples move between identity columns; positions are never changed.
"""

from __future__ import annotations

import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from mocap.trajectories import Trajectories

__all__ = ["ReuniteConfig", "reunite_clusters"]

STATISTICS_FRAMES = 4096  # frames per chunk of the co-seen counts, and most frames the distances are taken over


@dataclass(frozen=True)
class ReuniteConfig:
    """Settings of the cluster reunion.

    Attributes:
        reach_m: identities farther apart than this (median distance) are never rigid partners, m.
        spread_m: a pair whose distance's robust spread is below this is rigid, m.
        min_frames: frames two identities must be seen together for their pair to be judged.
        min_members: fewest distances a map must compare.
        tolerance_m: largest change of any compared distance in an accepted map, m ...
        mean_tolerance_m: ... and largest mean change, m (a soft cluster, skin markers, fits no better than that).
        margin_m: the best map's mean change must beat every other's by this much, m ...
        fragment_ratio: ... unless the other map's identity was never seen with the best's (pieces of one marker's
            track) or lived less than this fraction of its life (a fragment that held that marker for a while).
        gap_cost_m: among maps that fit alike, the one across the shorter time wins: each second between two
            identities counts as this much change, m.
    """

    reach_m: float = 1.0
    spread_m: float = 0.003
    min_frames: int = 30
    min_members: int = 3
    tolerance_m: float = 0.0025
    mean_tolerance_m: float = 0.00125
    margin_m: float = 0.0005
    fragment_ratio: float = 0.25
    gap_cost_m: float = 0.0001


def _pair_statistics(P: np.ndarray, min_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, M) median distance m, robust spread m (NaN where seen together in fewer than ``min_frames``
    frames) and co-seen frame count of every pair of identities in ``P`` (F, M, 3).

    The counts are exact; the medians of long takes are taken over every k-th frame (at most
    ``STATISTICS_FRAMES``), which bounds time and memory.
    """
    F, M = P.shape[:2]
    count = np.zeros((M, M), dtype=np.int64)
    for start in range(0, F, STATISTICS_FRAMES):  # (frame chunks: the (F, M) product stays small)
        seen = np.isfinite(P[start:start + STATISTICS_FRAMES, :, 0]).astype(np.float32)
        count += np.rint(seen.T @ seen).astype(np.int64)
    sample = P[:: max(1, -(-F // STATISTICS_FRAMES))]
    median = np.full((M, M), np.nan)
    spread = np.full((M, M), np.nan)
    for a in range(M):
        others = np.flatnonzero(count[a] >= min_frames)
        others = others[others > a]
        if others.size == 0:
            continue
        with np.errstate(invalid="ignore"), warnings.catch_warnings():  # (a pair never seen in the sample: NaN)
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.linalg.norm(sample[:, others] - sample[:, a, None], axis=2)  # (F', n), NaN where either is unseen
            med = np.nanmedian(d, axis=0)
            mad = 1.4826 * np.nanmedian(np.abs(d - med), axis=0)
        median[a, others] = median[others, a] = med
        spread[a, others] = spread[others, a] = mad
    return median, spread, count


def _rigid_triangles(rigid: np.ndarray, among: np.ndarray) -> list[tuple[int, int, int]]:
    """Triples of identities in ``among`` whose three pairs are all rigid."""
    out = []
    for x in among:
        ys = among[(among > x) & rigid[x, among]]
        for i, y in enumerate(ys):
            out += [(x, y, z) for z in ys[i + 1:] if rigid[y, z]]
    return out


class _Matcher:
    """Maps identities that started later ("new") onto identities that ended before them ("old") so that
    the rigid distances among the new ones equal those among their images."""

    def __init__(self, median: np.ndarray, rigid: np.ndarray, after: np.ndarray, size: np.ndarray,
                 together: np.ndarray, gap_cost: np.ndarray, cfg: ReuniteConfig) -> None:
        self.median, self.rigid, self.after, self.size, self.cfg = median, rigid, after, size, cfg
        self.together = together  # (M, M) bool: seen in one frame at least once
        self.gap_cost = gap_cost  # (M, M) m: what joining b after a costs for the time between them

    def rivals(self, x: int, y: int) -> bool:
        """Identity ``y`` is a real alternative to ``x``: another marker (the two were seen together), and not a
        short fragment (``fragment_ratio``) of ``x``'s life (one that held that marker for a while). Two identities
        never seen together may be pieces of one marker's track: either is right."""
        return bool(self.together[x, y] and self.size[y] >= self.cfg.fragment_ratio * self.size[x])

    def seeds(self, free: np.ndarray) -> list[dict[int, int]]:
        """Triangle-to-triangle maps (new -> old) whose three distances agree within ``tolerance_m``."""
        M, tol = self.median, self.cfg.tolerance_m
        news = np.flatnonzero(free & self.after.any(axis=1))
        olds = np.flatnonzero(free & self.after.any(axis=0))
        old_triangles = _rigid_triangles(self.rigid, olds)
        out = []
        for tb in _rigid_triangles(self.rigid, news):
            db = np.array([M[tb[0], tb[1]], M[tb[0], tb[2]], M[tb[1], tb[2]]])
            for ta in old_triangles:
                for pa in itertools.permutations(ta):
                    if not all(self.after[b, a] for b, a in zip(tb, pa, strict=True)):
                        continue
                    da = np.array([M[pa[0], pa[1]], M[pa[0], pa[2]], M[pa[1], pa[2]]])
                    if np.abs(db - da).max() < tol:
                        out.append(dict(zip(tb, pa, strict=True)))
        return out

    def grow(self, seed: dict[int, int], free: np.ndarray) -> tuple[dict[int, int], list[float]]:
        """Extend ``seed`` one identity at a time (the best-fitting pair, when no rival comes within
        ``margin_m``); returns the map and the changes of every distance it compares, m."""
        M, R, cfg = self.median, self.rigid, self.cfg
        mapping = dict(seed)
        while True:
            news = [b for b in np.flatnonzero(free & self.after.any(axis=1)) if b not in mapping]
            taken = set(mapping.values())
            options = []  # (mean change, b, a)
            for b in news:
                ref = [x for x in mapping if R[b, x]]
                if len(ref) < 2:
                    continue
                for a in np.flatnonzero(free & self.after[b]):
                    if a in taken:
                        continue
                    pairs = [(M[b, x], M[a, mapping[x]]) for x in ref if R[a, mapping[x]]]
                    if len(pairs) < 2:
                        continue
                    change = np.abs(np.subtract(*np.array(pairs).T))
                    if change.max() < cfg.tolerance_m:
                        options.append((float(change.mean()) + self.gap_cost[b, a], float(change.mean()), b, a))
            options.sort()
            for k, (_, best, b, a) in enumerate(options):  # the best-fitting pair that no rival comes close to
                if not any(c < best + cfg.margin_m for _, c, ob, oa in options[:k] + options[k + 1:]
                           if (ob == b and self.rivals(a, oa)) or (oa == a and self.rivals(b, ob))):
                    mapping[b] = a
                    break
            else:
                break
        return mapping, self.changes(mapping)

    def changes(self, mapping: dict[int, int]) -> list[float]:
        """Changes, m, of every rigid distance among the mapped new identities whose images are rigid too."""
        M, R = self.median, self.rigid
        keys = list(mapping)
        return [abs(M[x, y] - M[mapping[x], mapping[y]]) for x, y in itertools.combinations(keys, 2)
                if R[x, y] and R[mapping[x], mapping[y]]]


def _join(traj: Trajectories, pairs: list[tuple[int, int]]) -> None:
    """Move every sample of identity ``b`` into identity ``a`` for each ``(b, a)``; ``b`` is left empty."""
    for b, a in pairs:
        got = np.isfinite(traj.positions[:, b, 0])
        for array in (traj.positions, traj.residuals, traj.camera_masks):
            array[got, a] = array[got, b]
        traj.positions[got, b] = np.nan
        traj.residuals[got, b] = np.nan
        traj.camera_masks[got, b] = 0


def reunite_clusters(traj: Trajectories, config: ReuniteConfig | None = None) -> int:
    """Join identities of rigid clusters seen apart in time (see the module docstring), in place.

    Returns the number of identities joined into others (their columns are left empty: the caller drops them).
    """
    cfg = config or ReuniteConfig()
    seen = np.isfinite(traj.positions[..., 0])
    if traj.n_markers < 2 * cfg.min_members or not seen.any():
        return 0
    F = traj.n_frames
    first = np.where(seen.any(axis=0), np.argmax(seen, axis=0), F)
    last = np.where(seen.any(axis=0), F - 1 - np.argmax(seen[::-1], axis=0), -1)
    median, spread, count = _pair_statistics(traj.positions, cfg.min_frames)
    rigid = (spread < cfg.spread_m) & (median < cfg.reach_m)  # (NaN compares False)
    after = first[:, None] > last[None, :]  # (M, M): identity b started after identity a ended
    gap_cost = cfg.gap_cost_m * np.maximum(first[:, None] - last[None, :], 0) / traj.fps
    matcher = _Matcher(median, rigid, after, seen.sum(axis=0), count > 0, gap_cost, cfg)
    free = np.ones(traj.n_markers, dtype=bool)
    joined: list[tuple[int, int]] = []
    while True:
        found = [matcher.grow(seed, free) for seed in matcher.seeds(free)]
        found = [(m, c) for m, c in found if len(c) >= cfg.min_members and np.mean(c) < cfg.mean_tolerance_m]
        if not found:
            break
        found.sort(key=lambda mc: (-len(mc[1]), float(np.mean(mc[1])) + np.mean([gap_cost[b, a] for b, a in
                                                                                mc[0].items()])))
        mapping, changes = found[0]
        inverse = {a: b for b, a in mapping.items()}
        rivals = [m for m, c in found[1:] if len(c) == len(changes)
                  and float(np.mean(c)) < float(np.mean(changes)) + cfg.margin_m and any(
                      (b in mapping and mapping[b] != a and matcher.rivals(mapping[b], a))
                      or (a in inverse and inverse[a] != b and matcher.rivals(inverse[a], b)) for b, a in m.items())]
        for m in [mapping, *rivals]:  # an ambiguous shape (symmetric, or two alike): all its candidates are left alone
            free[list(m) + list(m.values())] = False
        if not rivals:
            joined += list(mapping.items())
    _join(traj, joined)
    return len(joined)
