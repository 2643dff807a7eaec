"""Markers of rigid plates are labelled by the plate's shape (offline, a pass of the identity repair).

A plate of three or more markers (an arm cluster, a steering wheel) that is hidden and comes back in pieces
is where frame-to-frame tracking mixes identities up: every returning marker is near every lost one, and
re-identification by the nearest prediction rotates them. The plate's shape does not, when its distances
differ: a triangle of sides 47, 53 and 72 mm has one labelling only.

On finished trajectories (after :mod:`mocap.relabel` and :mod:`mocap.reunite`), :func:`label_plates`:

1. learns the plates: the largest cliques (three or more identities) of rigid pairs, whose distance's robust
   spread (1.4826 MAD) is below ``spread_m`` over ``min_frames`` frames seen together at least, of at most
   ``MAX_MEMBERS``; a plate with two members at the same distances from the others (within ``2 x
   tolerance_m``: a square, an isosceles triangle, which the shape cannot label) is not used, and of
   plates of one shape (the same plate under other identities after a long absence) the one seen longest
   is; another rigid structure seen with it whose triangle has the shape of one of its triangles (a twin
   plate) is remembered with that triangle. Plates are learned from the whole take, then from stretches of
   it: a plate whose identities the tracker mixed up after every absence is rigid under one labelling only
   within a stretch (such a plate must keep its shape, in some order of its members, over the take);
2. finds, in every frame, the points whose distances match a plate triangle's (``tolerance_m``) and not
   those of its twins (points that fit both cannot be told apart), and the other members whose distances to
   those three fit: votes, sample -> plate member; a sample voted for two members, or a member voted to two
   samples in one frame, has none;
3. cuts every identity into tracklets (runs of consecutive samples, also cut where the votes change) and
   gives a tracklet whose votes all name one member (``min_votes``, and ``vote_fraction`` of its samples) to
   that member; a tracklet without enough votes goes with the nearest voted tracklet of its identity (the
   tracker followed one marker through it), unless the nearest before and after disagree and neither its own
   votes nor a short gap (``near_frames``, the other side farther) side with one;
4. moves each tracklet given to a member into that member's identity where it is free over those frames,
   longest first; a tracklet that would end in a member's identity without votes of its own for it, while that
   member's marker is voted elsewhere in its frames (another segment's marker the tracker put on the identity while
   the plate was hidden), leaves for an identity of its own (one per identity it leaves);
5. gives the tracker's unconfirmed points (:meth:`mocap.tracker.Tracker.unconfirmed`: a marker the recording
   has only every other frame never makes the tracker's confirmation), voted alongside in step 2, to the
   member they were voted for, where its identity has no sample and the point would not make it jump (an
   acceleration above ``jump_acc`` with its samples next to it: a mirror image of a plate in a shiny floor has the
   plate's shape).

Only whole samples move between identity columns; positions are never changed.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from mocap.rigid import PAIRS, PERMUTATIONS, pair_statistics, placement_jumps, rigid_triangles, seen_blocks
from mocap.trajectories import Trajectories, UnconfirmedPoints

__all__ = ["PlateConfig", "label_plates"]

CHUNK_ENTRIES = 1 << 22  # frames x identities^2 searched at a time (the distance arrays stay near 32 MB)
MAX_MEMBERS = 8  # larger cliques of rigid pairs are not taken for plates
TWIN_FRAMES = 10  # frames two structures of one shape must be seen together to be two structures
WINDOW_SPAN = 3  # plates are also learned from stretches of this many times min_frames frames ...
WINDOW_FIT = 0.75  # ... when their members keep the shape, in some order, in this fraction of the take's frames
EVICT_COVER = 0.5  # a tracklet leaves a member's identity where the member is voted elsewhere in this much of it


@dataclass(frozen=True)
class PlateConfig:
    """Settings of the plate labelling.

    Attributes:
        spread_m: pairs of identities whose distance's robust spread is below this are rigid, m.
        reach_m: pairs farther apart than this (median) are never on one plate, m.
        min_frames: frames two identities must be seen together for their pair to be judged.
        tolerance_m: points match a plate when each of their distances is within this of the plate's, m.
        min_votes: fewest votes a tracklet needs to be given to a member ...
        vote_fraction: ... and fewest, as a fraction of its samples.
        backing_fraction: a tracklet given a member, whose votes all name it, ``min_votes`` and this fraction of
            its samples at least (fewer than it needs to be given the member by its votes alone: a plate whose
            shape changed a little over the take matches only some of its triangles), makes another segment's
            marker on that member's identity in its frames leave (step 4).
        near_frames: a tracklet with too few votes, between voted tracklets of its identity that name different
            members, follows the one at most this many frames away when the other is farther (a marker back after
            a short gap, then the identity carried on to another marker after a long one).
    """

    spread_m: float = 0.0025
    reach_m: float = 0.3
    min_frames: int = 100
    tolerance_m: float = 0.003
    min_votes: int = 3
    vote_fraction: float = 0.5
    near_frames: int = 12
    backing_fraction: float = 0.2


def _cliques(adjacent: np.ndarray) -> list[list[int]]:
    """Maximal cliques of the graph ``adjacent`` (n, n) bool (Bron-Kerbosch with pivoting)."""
    near = [set(np.flatnonzero(row).tolist()) for row in adjacent]
    found: list[list[int]] = []

    def grow(r: list[int], p: set[int], x: set[int]) -> None:
        if not p and not x:
            found.append(r)
            return
        pivot = max(p | x, key=lambda u: len(p & near[u]))
        for v in list(p - near[pivot]):
            grow(r + [v], p & near[v], x & near[v])
            p.remove(v)
            x.add(v)

    grow([], {v for v, n in enumerate(near) if n}, set())
    return found


def _sides(D: np.ndarray, tri: tuple[int, ...]) -> np.ndarray:
    """(3,) distances a-b, a-c, b-c of the triangle ``tri`` = (a, b, c) in the distance matrix ``D``."""
    a, b, c = tri
    return np.array([D[a, b], D[a, c], D[b, c]])


def _symmetric(D: np.ndarray, tol: float) -> bool:
    """Two members of the shape ``D`` (n, n) have the same distances to the others (sorted, within ``2 tol``), as
    any labelling of it other than its own that keeps the distances would need (a square, an isosceles triangle)."""
    profile = np.sort(np.where(np.eye(len(D), dtype=bool), np.inf, D), axis=1)[:, :-1]  # (n, n - 1)
    alike = np.abs(profile[:, None] - profile[None]).max(axis=2) < 2 * tol
    return bool(alike[np.triu_indices(len(D), 1)].any())


def _fits_into(D: np.ndarray, E: np.ndarray, tol: float) -> bool:
    """The shape ``D`` (n, n) is that of ``n`` members of the shape ``E`` (m, m), in some order (within ``2 tol``)."""
    n = len(D)
    off = ~np.eye(n, dtype=bool)
    return n <= len(E) and any(np.abs(E[np.ix_(q, q)] - D)[off].max() < 2 * tol
                               for q in itertools.permutations(range(len(E)), n))


def _twins(tri: np.ndarray, median: np.ndarray, others: np.ndarray, seen: np.ndarray, tol: float) -> np.ndarray:
    """(T, 3) distances, in every vertex order, of the rigid triangles of other identities, ``others`` (n, 3),
    that have the shape of ``tri`` (3,) within ``2 tol`` and are seen in the same frames as it (``TWIN_FRAMES``):
    other structures alike, whose points could match it. (Never seen with it, one may be the same markers under
    other identities.)"""
    if len(others) == 0:
        return np.zeros((0, 3))
    orders = others[:, PERMUTATIONS]  # (n, 6, 3)
    sides = median[orders[..., PAIRS[:, 0]], orders[..., PAIRS[:, 1]]]  # (n, 6, 3)
    alike = (np.abs(sides - _sides(median, tuple(tri))) < 2 * tol).all(axis=2).any(axis=1)
    both = seen[:, tri].all(axis=1)
    together = np.array([(both & seen[:, t].all(axis=1)).sum() >= TWIN_FRAMES for t in others[alike]], dtype=bool)
    return sides[np.flatnonzero(alike)[together]].reshape(-1, 3)


@dataclass(frozen=True)
class _Plate:
    """A learned plate: member identities (n,), their distances (n, n) m, their triangles (indices into the
    members), per triangle the distances of its twins (:func:`_twins`), and their samples counted."""

    members: np.ndarray
    shape: np.ndarray
    triangles: list[tuple[int, int, int]]
    twins: list[np.ndarray]
    samples: int


def _plates(median: np.ndarray, rigid: np.ndarray, seen: np.ndarray, tol: float) -> list[_Plate]:
    """The plates of one stretch of the take (step 1 of the module docstring), seen longest first, from its pair
    statistics ``median`` and ``rigid`` (M, M) and its samples ``seen`` (F, M) bool. Of overlapping
    cliques, the larger is taken first, and of two as large the one of the earlier identities (member by member,
    by first frame seen): the identity that has been on a marker from its start, not one that joined it later;
    the order of the identities' columns does not matter."""

    first = np.where(seen.any(axis=0), seen.argmax(axis=0), len(seen))  # (M,) each identity's first frame

    def rank(clique: list[int]) -> tuple[int, list[int]]:
        return -len(clique), sorted(first[clique].tolist())

    candidates, used = [], set()
    for clique in sorted(_cliques(rigid), key=rank):
        members = np.array(sorted(set(clique) - used))
        if members.size < 3 or members.size < len(clique):
            continue
        if members.size > MAX_MEMBERS or _symmetric(median[np.ix_(members, members)], tol):
            continue  # too many to be one plate (a subject standing still), or a labelling the shape cannot tell
        candidates.append(members)
        used.update(members.tolist())
    rigid_ids = np.flatnonzero(rigid.any(axis=1))
    structures = rigid_triangles(rigid, rigid_ids)  # (T, 3)
    plates: list[_Plate] = []
    for i in np.argsort([-seen[:, m].sum() for m in candidates], kind="stable"):
        members = candidates[i]
        shape = median[np.ix_(members, members)]
        if any(_fits_into(shape, p.shape, tol) for p in plates):
            continue  # the shape of a plate seen longer
        others = structures[~np.isin(structures, members).any(axis=1)]
        triangles = list(itertools.combinations(range(members.size), 3))
        plates.append(_Plate(members, shape, triangles, [_twins(members[list(t)], median, others, seen, tol)
                                                         for t in triangles], int(seen[:, members].sum())))
    return plates


def _plates_of(P: np.ndarray, cfg: PlateConfig) -> list[_Plate]:
    """:func:`_plates` of the frames ``P`` (F, M, 3), from their own pair statistics."""
    median, spread, _ = pair_statistics(P, cfg.min_frames)
    rigid = (spread < cfg.spread_m) & (median < cfg.reach_m)
    return _plates(median, rigid, np.isfinite(P[..., 0]), cfg.tolerance_m)


def _keeps_shape(P: np.ndarray, shape: np.ndarray, tol: float) -> bool:
    """Whether the markers ``P`` (F, n, 3) have the distances of ``shape`` (n, n), in some order (sorted distances
    within ``tol``), in ``WINDOW_FIT`` of the frames all are seen in: a plate whose identities were mixed up does."""
    i, j = np.triu_indices(shape.shape[0], 1)
    whole = P[np.isfinite(P[..., 0]).all(axis=1)]
    sides = np.sort(np.linalg.norm(whole[:, i] - whole[:, j], axis=2), axis=1)  # (frames, pairs)
    return bool(len(whole)) and (np.abs(sides - np.sort(shape[i, j])) < tol).all(axis=1).mean() >= WINDOW_FIT


def _learn(P: np.ndarray, cfg: PlateConfig) -> list[_Plate]:
    """The plates of the take ``P`` (F, M, 3).

    First from the whole take's pair statistics; then from stretches of ``WINDOW_SPAN x min_frames`` frames
    (overlapping by half): a plate whose identities the tracker mixed up after each absence is rigid under one
    labelling within a stretch, not over the take. A plate from a stretch is kept when its shape is new and
    none of its identities is a member of a plate kept already (stretches seen longest first), and its members
    keep its shape in some order (:func:`_keeps_shape`) over the take: skin markers steady for a while do not."""
    plates = _plates_of(P, cfg)
    span = WINDOW_SPAN * cfg.min_frames
    found = [plate for start in (range(0, len(P) - span + 1, span // 2) if len(P) > span else [])
             for plate in _plates_of(P[start:start + span], cfg)]
    for plate in sorted(found, key=lambda p: -p.samples):
        if any(np.isin(plate.members, p.members).any() or _fits_into(plate.shape, p.shape, cfg.tolerance_m)
               for p in plates) or not _keeps_shape(P[:, plate.members], plate.shape, cfg.tolerance_m):
            continue
        plates.append(plate)
    return plates


def _distances(P: np.ndarray) -> np.ndarray:
    """(F, M, M) distances between the points of every frame of ``P`` (F, M, 3), m; NaN where either is unseen.
    (From the Gram matrix of each frame's points about their mean: no (F, M, M, 3) array.)"""
    seen = np.isfinite(P[..., :1])  # (F, M, 1)
    mean = np.where(seen, P, 0.0).sum(axis=1, keepdims=True) / np.maximum(seen.sum(axis=1, keepdims=True), 1)
    Q = np.where(seen, P - mean, 0.0)
    sq = np.einsum("fmi,fmi->fm", Q, Q)
    D2 = sq[:, :, None] + sq[:, None, :] - 2.0 * np.matmul(Q, Q.transpose(0, 2, 1))
    D = np.sqrt(np.maximum(D2, 0.0))
    unseen = ~seen[..., 0]
    D[unseen[:, :, None] | unseen[:, None, :]] = np.nan
    return D


class _SortedPairs:
    """The entries of a distance array ``D`` (F, M, M) below ``reach`` m, sorted by distance: the pairs at a given
    distance are found by bisection instead of a scan of the whole array (one per plate triangle)."""

    def __init__(self, D: np.ndarray, reach: float) -> None:
        flat = D.reshape(-1)
        with np.errstate(invalid="ignore"):
            index = np.flatnonzero(flat < reach)
        order = np.argsort(flat[index], kind="stable")
        self.shape, self.index, self.values = D.shape, index[order], flat[index[order]]

    def near(self, distance: float, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(frame, i, j) of the entries within ``tol`` of ``distance`` (``|d - distance| < tol``), in the order of
        ``np.nonzero``."""
        lo, hi = np.searchsorted(self.values, [distance - 2 * tol, distance + 2 * tol])
        index = self.index[lo:hi]
        index = np.sort(index[np.abs(self.values[lo:hi] - distance) < tol])
        return np.unravel_index(index, self.shape)


def _votes(D: np.ndarray, pairs: _SortedPairs, shape: np.ndarray, triangles: list[tuple[int, int, int]],
           twins: list[np.ndarray], tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 2 for one plate over frames whose point distances are ``D`` (F, M, M) (:func:`_distances`; ``pairs``
    the same, sorted): (frame, column, member) of every vote, unresolved. ``twins``: per triangle, (T, 3)
    distances of other structures alike; points that match one of them too are not told apart from it and give no
    vote."""
    n = len(shape)
    out = []
    with np.errstate(invalid="ignore"):
        for (a, b, c), alike in zip(triangles, twins, strict=True):
            f, i, j = pairs.near(shape[a, b], tol)
            fit = (np.abs(D[f, i] - shape[a, c]) < tol) & (np.abs(D[f, j] - shape[b, c]) < tol)
            r, k = np.nonzero(fit)
            f, i, j = f[r], i[r], j[r]
            ok = (k != i) & (k != j)
            if len(alike):  # points that fit another structure of this shape as well: no telling which
                sides = np.stack([D[f, i, j], D[f, i, k], D[f, j, k]], axis=1)  # (m, 3)
                ok &= ~(np.abs(sides[:, None] - alike[None]) < tol).all(axis=2).any(axis=1)
            f, got = f[ok], np.stack([i[ok], j[ok], k[ok]], axis=1)  # (m,) frames, (m, 3) columns
            out += [(f, got[:, q], np.full(f.size, member)) for q, member in enumerate((a, b, c))]
            for member in set(range(n)) - {a, b, c}:
                near = np.ones((f.size, D.shape[1]), dtype=bool)
                for q, corner in enumerate((a, b, c)):
                    near &= np.abs(D[f, got[:, q]] - shape[corner, member]) < tol
                near[np.arange(f.size)[:, None], got] = False
                one = near.sum(axis=1) == 1
                out.append((f[one], np.argmax(near[one], axis=1), np.full(int(one.sum()), member)))
    return tuple(np.concatenate(x) for x in zip(*out, strict=True)) if out else (np.zeros(0, np.intp),) * 3


def _resolve(frame: np.ndarray, col: np.ndarray, member: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(F, M) the member each sample is voted for, -1 where none or more than one (also where a member is
    voted to two samples of one frame)."""
    keys = np.unique(np.stack([frame, col, member], axis=1), axis=0)  # distinct votes
    F, M = shape
    sample = keys[:, 0] * M + keys[:, 1]
    once = np.bincount(sample, minlength=F * M)[sample] == 1  # one member per sample
    slot = keys[:, 0] * (keys[:, 2].max() + 1 if keys.size else 1) + keys[:, 2]
    alone = np.bincount(slot[once], minlength=slot.max() + 1 if slot.size else 0)[slot] == 1  # one sample
    vote = np.full((F, M), -1, dtype=np.intp)
    good = once & alone
    vote[keys[good, 0], keys[good, 1]] = keys[good, 2]
    return vote


def _tracklets(seen: np.ndarray, vote: np.ndarray) -> list[tuple[int, np.ndarray]]:
    """(column, frames) runs of every identity, in time order: consecutive samples, cut again where the votes
    inside such a run change (at the first sample of the new vote)."""
    runs = []
    for col in range(seen.shape[1]):
        frames = np.flatnonzero(seen[:, col])
        for run in np.split(frames, np.flatnonzero(np.diff(frames) > 1) + 1) if frames.size else []:
            v = vote[run, col]
            voted = np.flatnonzero(v >= 0)
            change = voted[1:][v[voted[1:]] != v[voted[:-1]]]
            runs += [(col, piece) for piece in np.split(run, change)]
    return runs


def _destinations(runs: list[tuple[int, np.ndarray]], vote: np.ndarray,
                  cfg: PlateConfig) -> tuple[list[int], list[bool]]:
    """Step 3: the identity each tracklet is given (-1: none), and whether its own votes back it (all for it,
    ``min_votes`` and ``backing_fraction`` of its samples at least). A tracklet with too few votes of its own
    follows the nearest voted tracklets of its identity; where those before and after it disagree, it follows the
    one its own votes name, if any, else, without votes of its own, the one within ``near_frames`` of it when the
    other is farther."""
    dest, few, backing = [], [], []
    for col, run in runs:
        v = vote[run, col]
        named = np.unique(v[v >= 0])
        votes = int((v >= 0).sum())
        enough = votes >= max(cfg.min_votes, cfg.vote_fraction * run.size)
        dest.append(int(named[0]) if named.size == 1 and enough else -1)
        few.append(int(named[0]) if named.size == 1 else -1 if named.size == 0 else -2)  # (-2: votes disagree)
        backing.append(named.size == 1 and votes >= max(cfg.min_votes, cfg.backing_fraction * run.size))
    before, after = _nearest_voted(runs, dest, True), _nearest_voted(runs, dest, False)
    out = []
    for d, f, (b, b_gap), (a, a_gap) in zip(dest, few, before, after, strict=True):
        named = {x for x in (b, a) if x >= 0}  # the nearest voted before and after: none, one, or two alike
        if d < 0 and len(named) == 2:  # they disagree: its own few votes, else (none) a short gap, may side
            if f in named:
                named = {f}
            elif f == -1 and b_gap <= cfg.near_frames < a_gap:
                named = {b}  # (the identity's own continuity across a short gap, against a re-identification)
            elif f == -1 and a_gap <= cfg.near_frames < b_gap:
                named = {a}
        out.append(d if d >= 0 or len(named) != 1 else named.pop())
    return out, [backed and d == f for d, f, backed in zip(out, few, backing, strict=True)]


def _nearest_voted(runs: list[tuple[int, np.ndarray]], dest: list[int], forward: bool) -> list[tuple[int, int]]:
    """Per tracklet, the destination of the nearest tracklet of its identity given one, before it (``forward``)
    or after it, and the frames between the two; (-1, 0) for none. (``runs`` come identity by identity, in time
    order.)"""
    out = [(-1, 0)] * len(runs)
    order = range(len(runs)) if forward else range(len(runs) - 1, -1, -1)
    column, last, edge = None, -1, 0
    for i in order:
        col, run = runs[i]
        if col != column:
            column, last = col, -1
        out[i] = (last, int(run[0] - edge) if forward else int(edge - run[-1])) if last >= 0 else (-1, 0)
        if dest[i] >= 0:
            last, edge = dest[i], int(run[-1] if forward else run[0])
    return out


def _evicted(runs: list[tuple[int, np.ndarray]], dest: list[int], own: list[bool],
             shape: tuple[int, int]) -> list[bool]:
    """Tracklets that would end in a plate member's identity (given it by their neighbours, or staying in it)
    without votes of their own to back it, while a tracklet of another identity, given that member and backed by
    its own votes (``own``), is seen in ``EVICT_COVER`` of its frames at least: the member's marker is that one. (A
    marker of another segment that the tracker put on a plate member's identity while the plate was hidden; not the
    member's own long track, which a marker voted for it by chance overlaps for a few frames.)"""
    claimed = np.zeros(shape, dtype=bool)  # (F, M) frames in which each identity's member is voted elsewhere
    for (col, run), d, voted in zip(runs, dest, own, strict=True):
        if voted and d != col:
            claimed[run, d] = True
    return [not voted and claimed[run, d if d >= 0 else col].mean() >= EVICT_COVER
            for (col, run), d, voted in zip(runs, dest, own, strict=True)]


def _settle(runs: list[tuple[int, np.ndarray]], dest: list[int], evicted: list[bool],
            shape: tuple[int, int]) -> list[int]:
    """Step 4: the identity every tracklet ends in (-1: an identity of its own, for the ``evicted``). A tracklet
    moves to its destination unless that collides there with a tracklet that stays or with a longer one moving in
    (then it stays, which may make others collide with it in turn: passes repeated until nothing collides).
    Rotations of identities resolve together."""
    final = [-1 if out else d if d >= 0 else col for (col, _), d, out in zip(runs, dest, evicted, strict=True)]
    order = [i for i in sorted(range(len(runs)), key=lambda i: -runs[i][1].size) if not evicted[i]]
    while True:
        owner = np.full(shape, -1, dtype=np.intp)
        for i in order:  # stayers first, then movers longest first
            if final[i] == runs[i][0]:
                owner[runs[i][1], final[i]] = i
        collided = False
        for i in order:
            col, run = runs[i]
            if final[i] == col:
                continue
            if (owner[run, final[i]] >= 0).any():
                final[i] = col  # (its staying may block a mover already placed: the next pass sees to it)
                collided = True
            else:
                owner[run, final[i]] = i
        if not collided:
            return final


def label_plates(traj: Trajectories, config: PlateConfig | None = None, extra: UnconfirmedPoints | None = None,
                 jump_acc: float = math.inf) -> int:
    """Label the markers of rigid plates by their shape (see the module docstring), in place.

    ``extra``: the tracker's unconfirmed points; one voted for a plate member joins that member's identity
    where it has no sample (step 5), unless it makes an acceleration above ``jump_acc``, m/frame^2, with that identity's
    samples next to it.

    Returns the number of samples moved to another identity or added.
    """
    cfg = config or PlateConfig()
    P = traj.positions
    F, M = P.shape[:2]
    if M < 3 or not np.isfinite(P[..., 0]).any():
        return 0
    plates = _learn(P, cfg)
    seen = np.isfinite(P[..., 0])
    if not plates:
        return 0
    E, slot = extra.as_columns(P, cfg.tolerance_m) if extra is not None and len(extra.rows) else (
        np.zeros((F, 0, 3)), np.zeros((0, 2), dtype=np.intp))
    everything = np.concatenate([P, E], axis=1)
    found = []  # (frame, column, member identity) of every vote
    reach = max(float(np.nanmax(plate.shape)) for plate in plates) + 2 * cfg.tolerance_m  # no plate edge is longer
    for start, stop, alive in seen_blocks(np.isfinite(everything[..., 0]), CHUNK_ENTRIES):
        D = _distances(everything[start:stop, alive])
        pairs = _SortedPairs(D, reach)
        for plate in plates:
            f, col, m = _votes(D, pairs, plate.shape, plate.triangles, plate.twins, cfg.tolerance_m)
            found.append((f + start, alive[col], plate.members[m]))
    v_frame, v_col, v_member = (np.concatenate(x) for x in zip(*found, strict=True))
    mine = v_col < M  # the identities' own samples are resolved first: an unconfirmed point never takes their votes
    vote = _resolve(v_frame[mine], v_col[mine], v_member[mine], shape=(F, M))
    runs = _tracklets(seen, vote)
    dest, own = _destinations(runs, vote, cfg)
    final = _settle(runs, dest, _evicted(runs, dest, own, (F, M)), (F, M))
    leaving = sorted({col for (col, _), target in zip(runs, final, strict=True) if target < 0})
    if leaving:  # (one new identity for the tracklets that leave each identity)
        fresh = dict(zip(leaving, traj.add_empty(len(leaving)), strict=True))
        final = [fresh[col] if target < 0 else target for (col, _), target in zip(runs, final, strict=True)]
        vote = np.pad(vote, ((0, 0), (0, len(leaving))), constant_values=-1)
    movers = [(run, col, target) for (col, run), target in zip(runs, final, strict=True) if target != col]
    held = vote.copy()  # the member each sample is voted for, moved along with the samples
    for array, empty in ((traj.positions, np.nan), (traj.residuals, np.nan), (traj.camera_masks, 0), (held, -1)):
        values = [array[run, col] for run, col, _ in movers]  # (copies: fancy indexing)
        for run, col, _ in movers:
            array[run, col] = empty
        for (run, _, target), value in zip(movers, values, strict=True):
            array[run, target] = value
    added = 0
    if len(slot):  # step 5: unconfirmed points voted for a member, where its identity has no sample
        loose = _resolve(v_frame[~mine], v_col[~mine] - M, v_member[~mine], shape=(F, E.shape[1]))
        k = np.flatnonzero(slot[:, 0] >= 0)
        member = loose[slot[k, 0], slot[k, 1]]
        k, member = k[member >= 0], member[member >= 0]
        rows = extra.rows[k]
        free = ~np.isfinite(traj.positions[rows, member, 0])
        for step in (-1, 0, 1):  # another identity holds that member's marker next to it: it would interleave
            near = np.clip(rows + step, 0, F - 1)
            other = (held[near] == member[:, None]) & (np.arange(held.shape[1])[None, :] != member[:, None])
            free &= ~other.any(axis=1)
        k, member = k[free], member[free]
        calm = ~placement_jumps(traj.positions, extra.rows[k], member, extra.positions[k], jump_acc)
        k, member = k[calm], member[calm]
        traj.positions[extra.rows[k], member] = extra.positions[k]
        traj.residuals[extra.rows[k], member] = extra.residuals[k]
        traj.camera_masks[extra.rows[k], member] = extra.camera_masks[k]
        added = k.size
    return sum(run.size for run, _, _ in movers) + added
