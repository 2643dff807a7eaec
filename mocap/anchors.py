"""Fragments of a marker's track rejoined by their distances to rigid neighbours (offline).

A marker hidden in turn with its neighbours (a forearm's cluster in a sprint, pushing the wheels) comes back
again and again where its prediction is long gone: every return may start a new identity, and the tracker's
hops between the cluster's markers leave fragments of one marker under several identities. The markers it
moves with rigidly tell them apart where shape alone cannot: the forearm's triangle M1-M2-M4 is isosceles
(M1 and M4 both 48 mm from M2), so a plate of it has two labellings, but a fragment 76 mm from M1's identity
and 47 mm from M2's is M4's, whatever it was called.

On finished trajectories (after :mod:`mocap.plates`: rigid plates are labelled by their shape first; run before
it, the joins changed the plates it learned), :func:`rejoin_by_anchors`:

1. measures every pair of identities over the frames both are seen in (:func:`mocap.rigid.pair_statistics`):
   an identity's anchors are the identities within ``reach_m`` whose distance to it spread (1.4826 MAD) less
   than ``spread_m`` over ``min_frames`` frames seen together at least; an identity with fewer than
   ``min_anchors`` such anchors takes them within ``far_reach_m`` (a marker of a large rigid object: a
   wheelchair frame's markers stand 0.45-0.8 m apart, with no other marker rigid to them within 0.3 m), where
   the distance also holds over the frames in which the marker moves faster than ``moving_mps`` (an athlete who
   sits still for ten seconds makes the steering wheel look rigid to the frame in the median and its MAD);
2. takes the identities shortest first, and offers each (the fragment) to every longer identity (the target):
   the fragment's median distance to each of the target's anchors it was seen with (``piece_frames`` frames
   at least) must equal the target's within ``tolerance_m`` and spread less than ``spread_m``, for
   ``min_anchors`` anchors or more and more anchors than disagree (an anchor across a joint may have moved).
   The fragment's own anchors count as the target's too where the target's distance to them spreads less
   than ``joint_spread_m``: an elbow marker keeps its distances to the forearm's markers over a fragment of
   a few seconds, not over the take;
3. joins the fragment to the longest target it fits, unless it fits two targets seen together (two markers:
   ambiguous), or their samples share more than ``overlap_fraction`` of the fragment's frames. Where they
   share frames (the target's identity held a neighbour for a while), the fragment's sample replaces the
   target's where its distances to the anchors in that frame fit the target's (mean within ``tolerance_m``) and
   the target's own do not (a frame where no anchor is seen goes with the nearest shared frame where one is); the
   sample left over moves to a new identity, and with it the target's samples in the frames between that the
   fragment misses, within ``follow_frames`` of a replaced one, that continue the replaced samples (nearer the
   replaced sample than ``follow_ratio`` times the fragment's: the whole sprint's forearm at seed 1, where Marker3's
   identity held Marker4 in every frame Marker3 was hidden, 17 switches in 50 frames).
4. repeats 1-3 with anchors spreading less than ``loose_spread_m`` for the fragments left over (skin markers keep
   their distances to 3-5 mm; looser anchors in the first pass disagree where strict ones would have agreed).

:func:`move_refuted_samples` then moves the tracker's hops: pieces of an identity (its samples cut at gaps, jumps,
hops there and back, and where the fit to the anchors changes and the path breaks) whose samples fit another
identity's anchors go to that identity where it is free. Samples vote: one its identity's anchors refute (none of
those seen in its frame agrees, one or more disagree), or any sample of an identity with no anchors (the tracker's
mix of two markers has none: its distances spread), votes for the one identity absent from its frame whose anchors
it fits; a piece moves where half its samples vote for one identity and none for another. The repair alternates
the two (:func:`mocap.relabel.repair_identities`).

Only whole samples move between identity columns; positions are never changed, and no sample is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.gap_exchange import WindowProfile
from mocap.rigid import pair_statistics, placement_jumps, split_tracklets
from mocap.trajectories import MISSING, Trajectories

__all__ = ["AnchorConfig", "move_refuted_samples", "rejoin_by_anchors"]


@dataclass(frozen=True)
class AnchorConfig:
    """Settings of the rejoining by anchors.

    Attributes:
        tolerance_m: a fragment's median distance to an anchor must be within this of the target's, m (skin
            markers: a few millimetres; the cluster's other markers differ by centimetres).
        spread_m: an anchor's distance to the target (and to the fragment) spreads less than this, m ...
        loose_spread_m: ... or, for a fragment that fits no identity so, less than this, m (a second pass: an elbow's
            or a toe's skin marker to its neighbours spreads 3-5 mm; in one pass the looser anchors that disagree
            kept the sprint start's forearm marker from joining its identity).
        joint_spread_m: ... or less than this for the fragment's own anchors (a marker by a joint), m.
        reach_m: anchors are within this of the target (median), m ...
        far_reach_m: ... or within this for an identity with fewer than ``min_anchors`` anchors within ``reach_m``, m,
            whose distance also holds over the frames in which the identity moves faster than ``moving_mps``, m/s.
        min_frames: frames an anchor and the target must be seen together.
        piece_frames: frames an anchor and the fragment must be seen together.
        min_anchors: fewest anchors that must agree.
        overlap_fraction: largest share of the fragment's frames in which the target has a sample too.
        hop_m: pieces moved by :func:`move_refuted_samples` are also cut where the acceleration exceeds this on two
            consecutive samples in opposite directions (a hop onto a neighbour and back), m/frame^2.
        vote_fraction: fewest samples of a piece, as a fraction, that must fit the identity it moves to.
        follow_frames: a target's sample in a frame the joined fragment misses, this many frames at most from one
            where the fragment's sample replaced the target's ...
        follow_ratio: ... moves out with the replaced samples where it lies nearer the replaced sample than this
            times the fragment's (it continues the neighbour the target held, not the fragment's marker).
    """

    tolerance_m: float = 0.006
    spread_m: float = 0.003
    loose_spread_m: float = 0.005
    joint_spread_m: float = 0.006
    reach_m: float = 0.3
    far_reach_m: float = 1.0
    moving_mps: float = 0.12
    min_frames: int = 30
    piece_frames: int = 3
    min_anchors: int = 2
    overlap_fraction: float = 0.5
    hop_m: float = 0.015
    vote_fraction: float = 0.5
    follow_frames: int = 2
    follow_ratio: float = 0.5


def _statistics(P: np.ndarray, cfg: AnchorConfig, spread_m: float, fps: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`mocap.rigid.pair_statistics` of ``P`` (F, M, 3) (median m, spread m, count) and the (M, M) bool anchors,
    row m identity m's: those spreading less than ``spread_m`` within ``reach_m``, and for an identity with fewer
    than ``min_anchors`` of them, :func:`_far_anchors` (step 1 of the module docstring; ``fps``: frames per second)."""
    median, spread, count = pair_statistics(P, cfg.piece_frames)
    strong = _steady(median, spread, count, cfg, spread_m)
    for a in np.flatnonzero(strong.sum(axis=1) < cfg.min_anchors):
        strong[a, _far_anchors(P, a, median, spread, count, cfg, spread_m, fps)] = True
    return median, spread, count, strong


def _far_anchors(P: np.ndarray, a: int, median: np.ndarray, spread: np.ndarray, count: np.ndarray,
                 cfg: AnchorConfig, spread_m: float, fps: float) -> np.ndarray:
    """(k,) identities between ``reach_m`` and ``far_reach_m`` from identity ``a`` whose distance to it spreads less
    than ``spread_m`` over the take and over ``min_frames`` or more frames in which ``a`` moves faster than
    ``moving_mps`` (its central difference), both seen."""
    step = np.full(len(P), np.nan)
    step[1:-1] = np.linalg.norm(P[2:, a] - P[:-2, a], axis=1) * (0.5 * fps)
    with np.errstate(invalid="ignore"):
        rows = np.flatnonzero(step > cfg.moving_mps)
        candidates = np.flatnonzero((median[a] <= cfg.far_reach_m) & (median[a] > cfg.reach_m)
                                    & (count[a] >= cfg.min_frames) & (spread[a] < spread_m))
    if rows.size < cfg.min_frames or candidates.size == 0:
        return candidates[:0]
    moving = WindowProfile.of(np.linalg.norm(P[rows[:, None], candidates[None, :]] - P[rows, a][:, None], axis=2))
    with np.errstate(invalid="ignore"):
        return candidates[(moving.count >= cfg.min_frames) & (moving.spread < spread_m)]


def _steady(median: np.ndarray, spread: np.ndarray, count: np.ndarray, cfg: AnchorConfig, spread_m: float
            ) -> np.ndarray:
    """(M, M) bool: pairs within ``reach_m``, seen together ``min_frames`` frames or more, whose distance spreads
    less than ``spread_m``."""
    with np.errstate(invalid="ignore"):
        return (spread < spread_m) & (median <= cfg.reach_m) & (count >= cfg.min_frames)


def _target(p: int, median: np.ndarray, spread: np.ndarray, count: np.ndarray, strong: np.ndarray,
            frames: np.ndarray, cfg: AnchorConfig, spread_m: float) -> int:
    """The identity fragment ``p`` joins (step 2-3 of the module docstring; anchors ``strong``, the fragment's
    distances spreading less than ``spread_m``), or -1."""
    joint = strong[p][None, :] & _steady(median, spread, count, cfg, cfg.joint_spread_m)
    anchors = (strong | joint) & (count[p] >= cfg.piece_frames)[None, :]  # (target, anchor)
    anchors[:, p] = False
    with np.errstate(invalid="ignore"):
        ok = anchors & (np.abs(median[p][None, :] - median) <= cfg.tolerance_m) & (spread[p] < spread_m)[None, :]
    n_ok = ok.sum(axis=1)
    fits = (n_ok >= cfg.min_anchors) & (n_ok > (anchors & ~ok).sum(axis=1)) & (frames > frames[p])
    fits[p] = False
    fits &= count[p] <= cfg.overlap_fraction * frames[p]
    q = np.flatnonzero(fits)
    if q.size == 0:
        return -1
    together = count[np.ix_(q, q)] > cfg.overlap_fraction * np.minimum.outer(frames[q], frames[q])
    np.fill_diagonal(together, False)
    if together.any():  # fits two markers seen together
        return -1
    return int(q[np.argmax(frames[q])])


def _deviation(P: np.ndarray, rows: np.ndarray, X: np.ndarray, anchors: np.ndarray, expected: np.ndarray
               ) -> np.ndarray:
    """(n, A) |distance - expected| of points ``X`` (n, 3) m in frames ``rows`` (n,) of ``P`` (F, M, 3) to the
    identities ``anchors`` (A,), against ``expected`` (A,) m; NaN where the anchor is unseen in that frame."""
    d = np.linalg.norm(P[rows[:, None], anchors[None, :]] - X[:, None], axis=2)
    with np.errstate(invalid="ignore"):
        return np.abs(d - expected)


def _misfit(P: np.ndarray, rows: np.ndarray, column: int, target: int, anchors: np.ndarray,
            median: np.ndarray) -> np.ndarray:
    """(len(rows),) mean |distance - the target's median| to its ``anchors`` of identity ``column``'s samples in
    frames ``rows`` (inf where no anchor is seen)."""
    dev = _deviation(P, rows, P[rows, column], anchors, median[target, anchors])
    seen = np.isfinite(dev)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen.any(axis=1), np.where(seen, dev, 0.0).sum(axis=1) / seen.sum(axis=1), np.inf)


def rejoin_by_anchors(traj: Trajectories, config: AnchorConfig | None = None) -> int:
    """Join fragments of identities to the identity whose rigid anchors they repeat (see the module docstring), in
    place. Samples displaced where the two overlapped go to new identity columns appended at the end.

    Anchors spread less than ``spread_m``; a second pass gives the fragments left over anchors spreading less than
    ``loose_spread_m``.

    Returns the number of fragments joined (their columns are left empty: the caller drops them).
    """
    cfg = config or AnchorConfig()
    return sum(_rejoin(traj, cfg, spread_m) for spread_m in (cfg.spread_m, cfg.loose_spread_m))


def _rejoin(traj: Trajectories, cfg: AnchorConfig, spread_m: float) -> int:
    """One pass of :func:`rejoin_by_anchors` with anchors spreading less than ``spread_m``, m."""
    P = traj.positions
    if traj.n_markers < cfg.min_anchors + 2 or not np.isfinite(P[..., 0]).any():
        return 0
    median, spread, count, strong = _statistics(P, cfg, spread_m, traj.fps)
    frames = np.isfinite(P[..., 0]).sum(axis=0)
    root = np.arange(traj.n_markers)
    arrays = [traj.positions, traj.residuals, traj.camera_masks]
    spilled: list[list[np.ndarray]] = []
    joined = 0
    for p in np.argsort(frames, kind="stable"):
        if frames[p] == 0:
            continue
        q = _target(int(p), median, spread, count, strong, frames, cfg, spread_m)
        if q < 0:
            continue
        r = int(root[q])
        while root[r] != r:
            r = int(root[r])
        here = np.flatnonzero(np.isfinite(P[:, p, 0]))
        both = here[np.isfinite(P[here, r, 0])]
        if both.size > cfg.overlap_fraction * here.size:
            continue
        if both.size:  # the target keeps its sample unless only the fragment's fits; the other moves out
            anchors = np.flatnonzero(strong[q])
            theirs = _misfit(P, both, r, q, anchors, median)
            mine = _told_or_nearest((_misfit(P, both, int(p), q, anchors, median) <= cfg.tolerance_m)
                                    & (theirs > cfg.tolerance_m), np.isfinite(theirs), both)
            leave = np.where(mine, r, p)  # the column whose sample moves out, per shared frame
            out = [np.full((len(P),) + a.shape[2:], MISSING[a.dtype.kind], dtype=a.dtype) for a in arrays]
            for a, o in zip(arrays, out, strict=True):
                o[both] = a[both, leave]
                a[both[mine], r] = a[both[mine], p]
            follow = _continuing(P, r, p, both[mine], out[0], cfg)
            for a, o in zip(arrays, out, strict=True):
                o[follow] = a[follow, r]
                a[follow, r] = MISSING[a.dtype.kind]
            spilled.append(out)
        moved = here[~np.isin(here, both)]
        for a in arrays:
            a[moved, r] = a[moved, p]
            a[here, p] = MISSING[a.dtype.kind]
        root[p] = r
        joined += 1
    if spilled:
        columns = traj.add_empty(len(spilled), [f"fragment{k + 1}" for k in range(len(spilled))])
        for col, out in zip(columns, spilled, strict=True):
            traj.positions[:, col], traj.residuals[:, col], traj.camera_masks[:, col] = out
    return joined


def _continuing(P: np.ndarray, target: int, fragment: int, entered: np.ndarray, moved: np.ndarray,
                cfg: AnchorConfig) -> np.ndarray:
    """Frames in which the ``target`` identity's sample continues the samples it gave up where the ``fragment``'s
    replaced them (frames ``entered``, in order; ``moved`` (F, 3) m: where those went): those between the first and
    the last of ``entered`` in which the fragment has no sample, within ``follow_frames`` of the nearest of
    ``entered``, whose sample lies nearer that frame's moved sample than ``follow_ratio`` times the fragment's
    sample there (``P`` (F, M, 3) m, the target already holding the fragment's samples)."""
    if entered.size == 0:
        return entered
    span = np.arange(entered[0], entered[-1] + 1)
    alone = span[np.isfinite(P[span, target, 0]) & np.isnan(P[span, fragment, 0])]
    nearest = entered[np.abs(alone[:, None] - entered[None, :]).argmin(axis=1)]  # (n,) the nearest replaced frame
    to_moved = np.linalg.norm(P[alone, target] - moved[nearest], axis=1)
    to_fragment = np.linalg.norm(P[alone, target] - P[nearest, target], axis=1)
    return alone[(np.abs(alone - nearest) <= cfg.follow_frames) & (to_moved < cfg.follow_ratio * to_fragment)]


def _told_or_nearest(verdicts: np.ndarray, told: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """(n,) bool: ``verdicts`` in the ``frames`` (n,) sorted where ``told`` (an anchor was seen), elsewhere the
    verdict of the nearest told frame (a frame without evidence goes with those around it)."""
    if told.all() or not told.any():
        return verdicts
    at, said = frames[told], verdicts[told]
    i = np.searchsorted(at, frames)
    before, after = np.clip(i - 1, 0, at.size - 1), np.clip(i, 0, at.size - 1)
    nearest = np.where(np.abs(frames - at[before]) <= np.abs(at[after] - frames), before, after)
    return np.where(told, verdicts, said[nearest])


def _anchor_votes(P: np.ndarray, rows: np.ndarray, X: np.ndarray, median: np.ndarray, strong: np.ndarray,
                  tolerance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(n, M) anchors that agree and (n, M) that disagree, per identity, with points ``X`` (n, 3) m in frames
    ``rows`` (n,) of ``P`` (F, M, 3) being that identity: the point's distance to each anchor seen in its frame
    against the identity's median distance to it, within ``tolerance_m`` or not."""
    ident, anchor = np.nonzero(strong)  # (pairs,) sorted by identity
    dev = _deviation(P, rows, X, anchor, median[ident, anchor])  # (n, pairs)
    owners, start = np.unique(ident, return_index=True)
    ok = np.zeros((len(rows), strong.shape[0]), dtype=np.intp)
    off = np.zeros_like(ok)
    ok[:, owners] = np.add.reduceat(dev <= tolerance_m, start, axis=1)
    off[:, owners] = np.add.reduceat(dev > tolerance_m, start, axis=1)
    return ok, off


def _candidates(P: np.ndarray, seen: np.ndarray, median: np.ndarray, strong: np.ndarray, tolerance_m: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(frames, columns) of the samples of ``P`` (F, M, 3) that may belong to another identity: those that no anchor
    of their identity seen in their frame agrees with (within ``tolerance_m`` of the median distance) and one or more
    disagree with, those whose identity's anchors are all unseen in their frame, and every sample of an identity
    without anchors; (n,) bool: the candidate has no anchor of its own to refute it (the last two kinds: it votes
    only where no anchor disagrees); and the (F, M) bool samples that an anchor of their identity agrees with."""
    frames, columns, unrefuted = [], [], []
    agreed = np.zeros(seen.shape, dtype=bool)
    for m in np.flatnonzero(strong.any(axis=1)):
        anchors = np.flatnonzero(strong[m])
        rows = np.flatnonzero(seen[:, m])
        dev = _deviation(P, rows, P[rows, m], anchors, median[m, anchors])
        agreed[rows, m] = (dev <= tolerance_m).any(axis=1)
        bad = ~agreed[rows, m] & (dev > tolerance_m).any(axis=1)
        blind = ~np.isfinite(dev).any(axis=1)  # none of its anchors seen in its frame
        pick = bad | blind
        frames.append(rows[pick])
        columns.append(np.full(int(pick.sum()), m))
        unrefuted.append(blind[pick])
    loose = ~strong.any(axis=1)
    free_f, free_c = np.nonzero(seen[:, loose])
    frames.append(free_f)
    columns.append(np.flatnonzero(loose)[free_c])
    unrefuted.append(np.ones(free_f.size, dtype=bool))
    return np.concatenate(frames), np.concatenate(columns), np.concatenate(unrefuted), agreed


def _continued(P: np.ndarray, frame: np.ndarray, col: np.ndarray, step: int, hop_m: float) -> np.ndarray:
    """(n,) bool: identity ``col``'s samples at ``frame - step`` and ``frame - 2 step`` exist and predict its sample
    at ``frame`` within ``hop_m`` (its path goes on through it)."""
    F = len(P)
    a, b = frame - step, frame - 2 * step
    inside = (a >= 0) & (a < F) & (b >= 0) & (b < F)
    out = np.zeros(frame.size, dtype=bool)
    f, c = frame[inside], col[inside]
    miss = P[f, c] - (2.0 * P[a[inside], c] - P[b[inside], c])
    with np.errstate(invalid="ignore"):
        out[inside] = np.sqrt((miss * miss).sum(axis=1)) < hop_m
    return out


def _pieces(P: np.ndarray, state: np.ndarray, jump_acc: float, hop_m: float) -> list[np.ndarray]:
    """(n, 2) (frame, column) runs of the identities of ``P`` (F, M, 3) cut at gaps, jumps (``jump_acc``) and hops
    there and back (:func:`mocap.rigid.split_tracklets`), and where the (F, M) ``state`` of the samples changes
    (-2: its identity's anchors agree, k >= 0: it votes for identity k; -1, neither, goes with the samples before
    it) and the path does not go on through the change (a hop right after a gap: no acceleration to see)."""
    out = []
    for run in split_tracklets(P, jump_acc, hop_m):
        s = state[run[:, 0], run[:, 1]]
        decided = np.flatnonzero(s != -1)
        cuts = decided[1:][s[decided[1:]] != s[decided[:-1]]]
        if cuts.size:
            col = run[cuts, 1]
            cuts = cuts[~(_continued(P, run[cuts, 0], col, 1, hop_m) | _continued(P, run[cuts - 1, 0], col, -1, hop_m))]
        out.extend(np.split(run, cuts))
    return out


def move_refuted_samples(traj: Trajectories, config: AnchorConfig | None = None, jump_acc: float = np.inf) -> int:
    """Move pieces of identities whose samples another identity's anchors fit to that identity, in place: the
    tracker's hops between markers of a cluster (a forearm's Marker3 and Marker4, mostly seen in turn, under one
    identity for a while).

    A sample votes when its identity's anchors refute it (none seen in its frame agrees within ``tolerance_m``,
    one or more disagree), when none of them is seen in its frame, or when its identity has no anchors; it votes
    for the one identity without a sample in its frame that it fits (``min_anchors`` anchors or more agree, more
    agree than disagree, none disagree for a sample that no anchor of its own refutes), unless another sample of
    its frame votes for that identity too. Each
    identity is cut into pieces at gaps, at jumps (an acceleration over ``jump_acc``, m/frame^2, on both samples
    of a step), at hops there and back (over ``hop_m`` in opposite directions), and where the votes change (to or
    from a sample its own anchors agree with, or between two identities) and its path does not go on through the
    change (``hop_m``: a hop on the first sample after a gap shows no acceleration); a piece moves when
    ``vote_fraction`` of its samples or more vote for one identity and none for another, that identity has no sample
    over its frames, and it makes no acceleration above ``jump_acc`` with that identity's samples next to its ends.
    A marker that merely strays from an anchor for a frame or two (skin, a merged blob) is a small share of its
    piece and stays. Pieces with more votes move first.

    Returns the number of samples moved.
    """
    cfg = config or AnchorConfig()
    P = traj.positions
    F, M = P.shape[:2]
    if M < cfg.min_anchors + 2:
        return 0
    median, _, _, strong = _statistics(P, cfg, cfg.spread_m, traj.fps)
    if not strong.any():
        return 0
    seen = np.isfinite(P[..., 0])
    f, c, unrefuted, agreed = _candidates(P, seen, median, strong, cfg.tolerance_m)
    votes = [np.zeros((0, 3), dtype=np.intp)]  # (frame, column, identity) of the samples that fit one identity
    step = max(1, 2_000_000 // int(strong.sum() + M))
    for s in range(0, f.size, step):
        ff, cc = f[s:s + step], c[s:s + step]
        ok, off = _anchor_votes(P, ff, P[ff, cc], median, strong, cfg.tolerance_m)
        fits = (ok >= cfg.min_anchors) & (ok > off) & ~seen[ff] & (~unrefuted[s:s + step, None] | (off == 0))
        one = fits.sum(axis=1) == 1
        votes.append(np.stack([ff[one], cc[one], fits[one].argmax(axis=1)], axis=1))
    f, c, t = np.concatenate(votes).T
    _, at, n = np.unique(f * M + t, return_inverse=True, return_counts=True)
    f, c, t = f[n[at] == 1], c[n[at] == 1], t[n[at] == 1]
    state = np.where(agreed, -2, -1)
    state[f, c] = t
    pieces = _pieces(P, state, jump_acc, cfg.hop_m)
    piece = np.full((F, M), -1)
    for k, run in enumerate(pieces):
        piece[run[:, 0], run[:, 1]] = k
    length = np.array([len(run) for run in pieces])
    key, count = np.unique(piece[f, c] * M + t, return_counts=True)
    k, target = key // M, key % M
    alone = np.bincount(k, minlength=len(pieces))[k] == 1  # the piece votes for one identity only
    chosen = np.flatnonzero(alone & (count >= cfg.vote_fraction * length[k]))
    moved = 0
    for j in chosen[np.argsort(-count[chosen], kind="stable")]:
        rows, col, tgt = pieces[k[j]][:, 0], int(pieces[k[j]][0, 1]), int(target[j])
        ends = rows[[0, -1]]
        if seen[rows, tgt].any() or placement_jumps(P, ends, np.full(2, tgt), P[ends, col], jump_acc).any():
            continue
        for a in (traj.positions, traj.residuals, traj.camera_masks):
            a[rows, tgt] = a[rows, col]
            a[rows, col] = MISSING[a.dtype.kind]
        seen[rows, tgt], seen[rows, col] = True, False
        moved += rows.size
    return moved
