"""Rigid clusters that come back after a long absence get their identities back (offline).

A plate of markers on one segment (a wheelchair frame, an arm's cluster) that leaves the volume, or is
hidden for seconds, comes back far from where it was lost: no gate around a prediction or a last position
finds it, and every marker of it starts a new identity. Its shape does find it: the distances between
markers of a rigid plate stay the same to a millimetre all take long, and differ from plate to plate.

On finished trajectories (after :mod:`mocap.relabel`), :func:`reunite_clusters`:

1. measures every pair of identities over the frames both are seen in: the median distance and its
   robust spread (1.4826 MAD); pairs closer than ``reach_m`` that spread less than ``spread_m`` are rigid;
2. maps identities that started later onto identities that ended before them (never seen together; at most
   ``max_absence_s`` before): a seed is a rigid triangle of later identities whose three distances equal
   (``tolerance_m``) those of a rigid triangle of earlier ones; it grows one identity at a time, each compared
   on two distances or more, the best-fitting first (the shorter time apart breaks near-ties, ``gap_cost_m``)
   unless another fits within ``margin_m``;
3. goes through the maps, largest first, then by how little their distances changed (``mean_tolerance_m``
   at most, on ``min_members`` distances at least), and takes each whose identities are still free, unless
   another map that sends one of its identities to another marker fits within ``margin_m`` (a symmetric
   plate, two plates alike). Such rivals are told apart by the markers around them (the context): the other
   identities within ``context_reach_m`` seen in the new identities' first ``context_s`` and in their images'
   last, each one's distances to the cluster's members centred on their mean (a joint's turn moves them all
   alike). The map whose context changed least (``context_max_m`` at most), by ``context_margin_m`` over every
   rival, is taken; otherwise all their candidates are left alone (a mirror image of a symmetric plate turns
   its neighbours' distances round: a forearm's markers near the elbow stand far from the wrist). Rival maps that
   differ only by earlier identities seen together in fewer than ``min_frames`` frames (pieces of one marker's
   track, which the tracker left in a cluster's glimpses) are one candidate, the first found standing for them;
4. joins each mapped pair into one identity, and repeats (``rounds``) so that a cluster away several
   times chains up.

:data:`SKIN_CLUSTERS` are the settings of a second, softer pass the repair makes after its anchors: clusters
whose distances hold within 5 mm (skin-mounted, a forearm's), seen together for 12 frames at least (a glimpse
after a gap), each map taken only where its context confirms it; a skin cluster's shape drifts, so there the
nearer in time wins among maps whose shapes differ by a millimetre or two (2 mm per second apart), which chains
a cluster seen in glimpses in time order. On the whole sprint (seed 1) the forearm's three markers back after
its 6 s gap get their identities back that way (47 -> 45 switches, IDF1 0.9803 -> 0.9903). It also maps glimpses
in a gap of their identities (``fill_holes``: new identities that started later, were seen less and were never
seen with their images, which go on after the glimpse).

Only whole samples move between identity columns; positions are never changed.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from mocap.rigid import PAIRS, PERMUTATIONS, pair_statistics, rigid_triangles
from mocap.trajectories import Trajectories

__all__ = ["SKIN_CLUSTERS", "ReuniteConfig", "centred_change", "reunite_clusters"]



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
        rounds: most passes; each joins identities once, so a cluster away n times needs log2(n + 1) passes.
        max_absence_s: identities that started more than this after others ended are not mapped onto them, s (a
            cluster away longer comes back under new identities: the maps to try grow with the square of the
            identities that come and go, and a long take's, cut by gaps into fragments, have thousands).
        context_s: the context is measured over the new identities' first and their images' last samples (before the
            new ones start), this many seconds' worth of frames (``context_s`` x fps samples), s.
        context_reach_m: other identities within this (median) distance of a member make the context, m.
        context_max_m: a map whose context changed more than this is not taken, m ...
        context_margin_m: ... nor one whose rival's context changed less than this more, m.
        require_context: every map, not only an ambiguous one, must be confirmed by its context.
        fill_holes: new identities may also be ones that started later, were seen less and were never seen with their
            images (glimpses of a cluster in its identities' gap, which go on after it), not only ones that started
            after their images ended.
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
    rounds: int = 8
    max_absence_s: float = 60.0
    context_s: float = 1.0
    context_reach_m: float = 0.4
    context_max_m: float = 0.03
    context_margin_m: float = 0.02
    require_context: bool = False
    fill_holes: bool = False


SKIN_CLUSTERS = ReuniteConfig(min_frames=12, spread_m=0.005, tolerance_m=0.004, mean_tolerance_m=0.003,
                              gap_cost_m=0.002, require_context=True, fill_holes=True)


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
        return bool(self._rivals_of(x, np.array([y]))[0])

    def seeds(self) -> list[dict[int, int]]:
        """Triangle-to-triangle maps (new -> old) whose three distances agree within ``tolerance_m``."""
        M = self.median
        new_t = rigid_triangles(self.rigid, np.flatnonzero(self.after.any(axis=1)))  # (Tb, 3)
        old_t = rigid_triangles(self.rigid, np.flatnonzero(self.after.any(axis=0)))  # (Ta, 3)
        if len(new_t) == 0 or len(old_t) == 0:
            return []
        db = M[new_t[:, PAIRS[:, 0]], new_t[:, PAIRS[:, 1]]]  # (Tb, 3)
        perm = old_t[:, PERMUTATIONS]  # (Ta, 6, 3): every order of each old triangle
        da = M[perm[..., PAIRS[:, 0]], perm[..., PAIRS[:, 1]]]  # (Ta, 6, 3)
        fit = np.abs(db[:, None, None, :] - da[None]).max(axis=3) < self.cfg.tolerance_m  # (Tb, Ta, 6)
        fit &= self.after[new_t[:, None, None, :], perm[None]].all(axis=3)
        t, u, q = np.nonzero(fit)
        return [dict(zip(b, a, strict=True)) for b, a in zip(new_t[t].tolist(), perm[u, q].tolist(), strict=True)]

    def grow(self, seed: dict[int, int]) -> tuple[dict[int, int], list[float]]:
        """Extend ``seed`` one identity at a time (the best-fitting pair, when no rival comes within
        ``margin_m``); returns the map and the changes of every distance it compares, m."""
        M, R, cfg = self.median, self.rigid, self.cfg
        mapping = dict(seed)
        keys, images = list(mapping), list(mapping.values())
        is_key, is_image = np.zeros(len(R), dtype=bool), np.zeros(len(R), dtype=bool)
        is_key[keys], is_image[images] = True, True
        rigid_k, rigid_i = R[:, keys], R[:, images]  # (M, k): every identity's rigidity and distance to the keys ...
        median_k, median_i = M[:, keys], M[:, images]  # ... and to their images, a column per mapped pair
        while True:
            news = np.flatnonzero((rigid_k.sum(axis=1) >= 2) & ~is_key)  # (rigid with two mapped ones at least)
            olds = np.flatnonzero((rigid_i.sum(axis=1) >= 2) & ~is_image)
            if news.size == 0 or olds.size == 0:
                break
            bi, ai = np.nonzero(self.after[news][:, olds])  # (p,) the pairs b after a
            b_of, a_of = news[bi], olds[ai]
            # (p, key): distance b-key against a-image(key), where both pairs are rigid
            both = rigid_k[b_of] & rigid_i[a_of]
            change = np.abs(median_k[b_of] - median_i[a_of])
            n = both.sum(axis=1)
            with np.errstate(invalid="ignore"):  # (no comparison: n = 0, not ok)
                ok = (n >= 2) & (np.where(both, change, -np.inf).max(axis=1) < cfg.tolerance_m)
            if not ok.any():
                break
            mean = np.where(both[ok], change[ok], 0.0).sum(axis=1) / n[ok]  # (k,)
            b_of, a_of = b_of[ok], a_of[ok]
            order = np.lexsort((a_of, b_of, mean, mean + self.gap_cost[b_of, a_of]))
            mean, b_of, a_of = mean[order], b_of[order], a_of[order]
            for k in range(mean.size):  # the best-fitting pair that no rival comes close to
                b, a = int(b_of[k]), int(a_of[k])
                rival = (((b_of == b) & self._rivals_of(a, a_of)) | ((a_of == a) & self._rivals_of(b, b_of)))
                rival[k] = False
                if not (mean[rival] < mean[k] + cfg.margin_m).any():
                    mapping[b] = a
                    is_key[b], is_image[a] = True, True
                    rigid_k, rigid_i = np.c_[rigid_k, R[:, b]], np.c_[rigid_i, R[:, a]]
                    median_k, median_i = np.c_[median_k, M[:, b]], np.c_[median_i, M[:, a]]
                    break
            else:
                break
        return mapping, self.changes(mapping)

    def _rivals_of(self, x: int, ys: np.ndarray) -> np.ndarray:
        """(n,) bool: :meth:`rivals` of ``x`` and each of ``ys`` (n,)."""
        return self.together[x, ys] & (self.size[ys] >= self.cfg.fragment_ratio * self.size[x])

    def changes(self, mapping: dict[int, int]) -> list[float]:
        """Changes, m, of every rigid distance among the mapped new identities whose images are rigid too."""
        M, R = self.median, self.rigid
        keys = list(mapping)
        return [abs(M[x, y] - M[mapping[x], mapping[y]]) for x, y in itertools.combinations(keys, 2)
                if R[x, y] and R[mapping[x], mapping[y]]]


def _context_change(P: np.ndarray, seen: np.ndarray, mapping: dict[int, int], window: int, reach: float,
                    min_seen: int = 3) -> float:
    """Mean change, m, of how the other identities near both sides stand towards the mapped ones (``P`` (F, M, 3),
    ``seen`` (F, M)): for each neighbour within ``reach`` m of a member on both sides, its median distances to the
    new identities (over their first ``window`` samples) and to their images (over the images' last ``window`` before
    the new ones start),
    each centred on their mean over the members; NaN where no neighbour is seen on both sides."""
    news, olds = list(mapping), list(mapping.values())
    members = set(news) | set(olds)
    others = np.array([n for n in range(P.shape[1]) if n not in members])
    if others.size == 0:
        return np.nan

    start = min(int(np.argmax(seen[:, x])) for x in news)

    def profile(ids: list[int], tail: bool) -> np.ndarray:
        out = np.full((len(ids), others.size), np.nan)
        for i, x in enumerate(ids):
            frames = np.flatnonzero(seen[:, x])
            frames = frames[frames < start][-window:] if tail else frames[:window]
            with_n = seen[frames][:, others]  # (T, n)
            d = np.linalg.norm(P[frames][:, others] - P[frames, x][:, None], axis=2)
            d[~with_n] = np.nan
            enough = with_n.sum(axis=0) >= min_seen
            if enough.any():
                out[i, enough] = np.nanmedian(d[:, enough], axis=0)
        return out

    new_p, old_p = profile(news, False), profile(olds, True)
    ok = np.isfinite(new_p).all(axis=0) & np.isfinite(old_p).all(axis=0)
    ok &= (np.fmin.reduce(new_p, axis=0) < reach) & (np.fmin.reduce(old_p, axis=0) < reach)  # (NaN compares False)
    if not ok.any():
        return np.nan
    return centred_change(old_p[:, ok], new_p[:, ok])


def centred_change(before: np.ndarray, after: np.ndarray) -> float:
    """Mean change, m, of neighbours' distances to a cluster's members, ``before`` and ``after`` (members,
    neighbours), each neighbour's centred on its mean over the members: a joint's turn moves them alike and changes
    little, a mirror image of the cluster turns them round."""
    return float(np.abs((before - before.mean(axis=0)) - (after - after.mean(axis=0))).mean())


def _join(traj: Trajectories, pairs: list[tuple[int, int]]) -> None:
    """Move every sample of identity ``b`` into identity ``a`` for each ``(b, a)`` (following chains: ``c`` joined
    to ``b`` joined to ``a`` all end in ``a``); the joined columns are left empty."""
    parent = dict(pairs)

    def root(x: int) -> int:
        while x in parent:
            x = parent[x]
        return x

    arrays = (traj.positions, traj.residuals, traj.camera_masks)
    moves = [(b, root(b), np.isfinite(traj.positions[:, b, 0])) for b in parent]
    taken = [(b, got, tuple(array[got, b].copy() for array in arrays)) for b, _, got in moves]
    for b, got, _ in taken:
        traj.positions[got, b] = np.nan
        traj.residuals[got, b] = np.nan
        traj.camera_masks[got, b] = 0
    for (_, a, _), (_, got, values) in zip(moves, taken, strict=True):
        for array, value in zip(arrays, values, strict=True):
            array[got, a] = value


def _matches(P: np.ndarray, fps: float, cfg: ReuniteConfig) -> list[tuple[int, int]]:
    """(later, earlier) pairs of identities of ``P`` (F, M, 3) that the shapes join (steps 1-3 above)."""
    seen = np.isfinite(P[..., 0])
    F = len(P)
    first = np.where(seen.any(axis=0), np.argmax(seen, axis=0), F)
    last = np.where(seen.any(axis=0), F - 1 - np.argmax(seen[::-1], axis=0), -1)
    median, spread, count = pair_statistics(P, cfg.min_frames)
    rigid = (spread < cfg.spread_m) & (median < cfg.reach_m)  # (NaN compares False)
    after = first[:, None] > last[None, :]  # (M, M): identity b started after identity a ended ...
    if cfg.fill_holes:  # ... or b, started later and seen less, was never seen with a (it lies in a's gaps)
        size = seen.sum(axis=0)
        after |= (count == 0) & (size[:, None] < size[None, :]) & (first[:, None] > first[None, :])
    after &= first[:, None] - last[None, :] <= cfg.max_absence_s * fps  # ... and not too long after
    gap_cost = cfg.gap_cost_m * np.maximum(first[:, None] - last[None, :], 0) / fps
    window = max(1, int(round(cfg.context_s * fps)))
    matcher = _Matcher(median, rigid, after, seen.sum(axis=0), count > 0, gap_cost, cfg)
    later_free = np.ones(P.shape[1], dtype=bool)  # identities not yet joined after another ...
    earlier_free = later_free.copy()  # ... and not yet followed by another
    found: list[tuple[dict[int, int], list[float]]] = []
    holding: dict[tuple[int, int], set[int]] = {}  # (new, old) -> the maps found so far that hold it
    for seed in matcher.seeds():  # (a seed inside a map already grown grows into that map)
        if not set.intersection(*(holding.get(item, set()) for item in seed.items())):
            for item in (grown := matcher.grow(seed))[0].items():
                holding.setdefault(item, set()).add(len(found))
            found.append(grown)
    found = [(m, c) for m, c in found if len(c) >= cfg.min_members and np.mean(c) < cfg.mean_tolerance_m]
    found.sort(key=lambda mc: (-len(mc[1]), float(np.mean(mc[1])) + np.mean([gap_cost[b, a] for b, a in
                                                                            mc[0].items()])))
    joined: list[tuple[int, int]] = []
    for k, (mapping, changes) in enumerate(found):
        if not (later_free[list(mapping)].all() and earlier_free[list(mapping.values())].all()):
            continue
        inverse = {a: b for b, a in mapping.items()}
        rivals = [m for m, c in found[k + 1:] if len(c) == len(changes)
                  and float(np.mean(c)) < float(np.mean(changes)) + cfg.margin_m and any(
                      (b in mapping and mapping[b] != a and matcher.rivals(mapping[b], a))
                      or (a in inverse and inverse[a] != b and matcher.rivals(inverse[a], b)) for b, a in m.items())]
        distinct: list[dict[int, int]] = []  # one map of each set that differs only by one marker's pieces
        for m in [mapping, *rivals]:
            if not any(_fragments_apart(kept, m, count, cfg.min_frames) for kept in distinct):
                distinct.append(m)
        choice = mapping if not (rivals or cfg.require_context) else _by_context(P, seen, distinct, window, cfg)
        if choice is not None and not (later_free[list(choice)].all() and earlier_free[list(choice.values())].all()):
            choice = None  # (a rival whose identities an earlier map took)
        for m in [mapping, *rivals]:  # an ambiguous shape (symmetric, or two alike): no other map takes its candidates
            later_free[list(m)] = False
            earlier_free[list(m.values())] = False
        if choice is not None:
            joined += list(choice.items())
    return joined


def _fragments_apart(mapping: dict[int, int], rival: dict[int, int], count: np.ndarray, min_frames: int) -> bool:
    """True where ``rival`` maps the same new identities as ``mapping`` and differs only by old identities seen
    together (``count`` (M, M): frames seen together) in fewer than ``min_frames`` frames with ``mapping``'s (too few
    to measure them as two markers): pieces of one marker's track (the tracker's glimpses in a cluster), not another
    labelling of a symmetric shape, whose markers are seen together. The map found first (the better shape, the
    nearer in time) stands for them."""
    return mapping.keys() == rival.keys() and all(
        mapping[b] == a or count[mapping[b], a] < min_frames for b, a in rival.items())


def _by_context(P: np.ndarray, seen: np.ndarray, maps: list[dict[int, int]], window: int,
                cfg: ReuniteConfig) -> dict[int, int] | None:
    """The map among ``maps`` (which the shape cannot tell apart) whose neighbours stand towards it as they stood
    towards its images (:func:`_context_change` within ``context_max_m``), by ``context_margin_m`` over every other;
    None if none does."""
    change = np.array([_context_change(P, seen, m, window, cfg.context_reach_m) for m in maps])
    if not np.isfinite(change).all():
        return None
    order = np.argsort(change)
    best = change[order[0]]
    if best > cfg.context_max_m or (len(maps) > 1 and change[order[1]] < best + cfg.context_margin_m):
        return None
    return maps[int(order[0])]


def reunite_clusters(traj: Trajectories, config: ReuniteConfig | None = None) -> int:
    """Join identities of rigid clusters seen apart in time (see the module docstring), in place; repeated
    (``rounds``) so that a cluster away several times chains up.

    Returns the number of identities joined into others (their columns are left empty: the caller drops them).
    """
    cfg = config or ReuniteConfig()
    if traj.n_markers < 2 * cfg.min_members or not np.isfinite(traj.positions[..., 0]).any():
        return 0
    joined = 0
    for _ in range(cfg.rounds):
        pairs = _matches(traj.positions, traj.fps, cfg)
        if not pairs:
            break
        _join(traj, pairs)
        joined += len(pairs)
    return joined
