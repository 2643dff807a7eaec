"""Exchanges between a skin-mounted cluster's identities undone by the neighbours' distances (offline).

A forearm's markers stuck on skin, seen in turn while the hand pushes a wheel (the sprint's ForearmL Marker3 and
Marker4, 46 mm apart), are re-acquired after each short absence by whichever identity's gate they fall in: two
identities then hold each other's markers for tens of frames. The other repair passes leave such an exchange: the
plates need a shape that holds within 2.5 mm and names every member (the forearm wobbles by 2-6 mm and is near
isosceles), the anchor moves need neighbours within 3 mm and an identity free to move to, and the bridge links
pieces across gaps by where the neighbours carry them, not across an exchange inside a run of short pieces.

The neighbours both identities keep within skin tolerance tell the two markers apart where their distances to them
differ by centimetres: Marker4 is 76 mm from Marker1 and 48 mm from Marker2, Marker3 63 and 65 mm. Markers of two
segments (the forearm's Marker3 and the wheelchair's Marker3 under the hand on the rim) are told apart by each
one's own. On finished trajectories, :func:`undo_skin_exchanges`, for every pair of identities A, B:

1. takes the references: where A and B share two or more (identities within ``reach_m`` of both whose distances
   to both spread (1.4826 MAD) less than ``spread_m`` over ``min_frames`` frames seen together), those whose
   median distances to A and to B differ by ``separation_m`` and by ``separation_spreads`` times the two spreads
   or more, for both; where they share none and come within ``meet_m`` of each other in some frame, each one's
   own (identities within ``own_reach_m`` whose distance to it spreads less than ``spread_m``), two at least;
2. scores every sample of A and of B that sees ``min_references`` references of each side or more: the
   log-likelihood ratio of its distances to B's references under B against those to A's under A (normal, with
   each pair's spread, at least ``floor_m``; each squared error clipped at ``clip``, so a point of neither marker,
   or a reference off for a while, scores near 0; as many distances on each side as the side with fewer seen);
3. finds the most likely labelling of the frames as kept or exchanged (Viterbi, two states), where a change of
   state costs ``switch_cost`` nats and is possible only where both identities break off: a gap, a jump (the
   repair's jump rule), or a sample whose score votes (beyond ``vote_nats``) against the previous one's;
4. exchanges A's and B's samples over every run of exchanged frames of which ``scored_fraction`` of the moved
   samples or more were scored and fit their new identity (their median squared error over its references, in
   spreads, at most ``fit_chi2`` on average).

Rounds repeat (``rounds`` at most) with the distances measured again while exchanges are found. Only whole
samples move between identity columns; positions are never changed, and no sample is dropped.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mocap.rigid import close_pairs, jump_starts, pair_statistics
from mocap.trajectories import Trajectories

__all__ = ["SkinConfig", "undo_skin_exchanges"]


@dataclass(frozen=True)
class SkinConfig:
    """Settings of the skin-cluster exchange repair.

    Attributes:
        reach_m: shared references are within this of both identities (median), m.
        spread_m: a reference's distance to its identity spreads less than this, m (skin: a few mm).
        meet_m: identities without shared references are a pair where they come this near in some frame, m ...
        own_reach_m: ... and each is scored by its own references within this, m (a wheelchair's markers are
            0.3-0.6 m apart).
        min_frames: frames a reference and an identity must be seen together.
        separation_m: a reference's median distances to the two identities differ by this at least, m ...
        separation_spreads: ... and by this many times the sum of the two spreads.
        floor_m: smallest spread a distance is scored with, m (a clean pair's MAD is below the points' noise).
        clip: largest squared error, in spreads, one distance adds to a score.
        min_references: fewest references (of each side) a sample must see to be scored.
        switch_cost: log-likelihood a change between kept and exchanged costs, nats.
        scored_fraction: fewest moved samples, as a fraction, that must be scored.
        vote_nats: a sample scoring beyond this votes for one identity; consecutive opposite votes break a run.
        fit_chi2: largest mean over the moved samples of their median squared error, in spreads, against their new
            identity's references.
        rounds: passes over all pairs at most.
    """

    reach_m: float = 0.15
    spread_m: float = 0.005
    meet_m: float = 0.1
    own_reach_m: float = 0.6
    min_frames: int = 100
    separation_m: float = 0.008
    separation_spreads: float = 1.5
    floor_m: float = 0.0015
    clip: float = 16.0
    min_references: int = 2
    switch_cost: float = 6.0
    scored_fraction: float = 0.5
    vote_nats: float = 4.0
    fit_chi2: float = 9.0
    rounds: int = 3


def _distances(P: np.ndarray, rows: np.ndarray, col: int, refs: np.ndarray) -> np.ndarray:
    """(n, R) distances, m, of identity ``col``'s samples in frames ``rows`` of ``P`` (F, M, 3) to the identities
    ``refs`` (R,); NaN where a reference is unseen."""
    return np.linalg.norm(P[rows[:, None], refs[None, :]] - P[rows, col][:, None], axis=2)


def _misfit(d: np.ndarray, stats: tuple[np.ndarray, np.ndarray], clip: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(n,) mean clipped and (n,) median squared error, in spreads, of the distances ``d`` (n, R) m against an
    identity's (median, spread) (R,) m to the same references; (n,) references seen (NaN errors where none)."""
    seen = np.isfinite(d)
    n = seen.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (a sample that sees no reference: NaN)
        err = ((d - stats[0]) / stats[1]) ** 2
        return np.where(seen, np.minimum(err, clip), 0.0).sum(axis=1) / n, np.nanmedian(err, axis=1), n


def _scores(P: np.ndarray, rows: np.ndarray, col: int, own: tuple, other: tuple, cfg: SkinConfig
            ) -> tuple[np.ndarray, np.ndarray]:
    """(n,) log-likelihood ratio (the other identity against its own) of identity ``col``'s samples in frames
    ``rows``, by their distances to each side's references: ``own`` and ``other`` are (references (R,), median
    (R,) m, spread (R,) m); 0 where either side sees fewer than ``min_references``; and (n,) their median squared
    error under the other (NaN there: a reference off for a while does not refute a fit to three or more). Where
    both sides have the same references (a pair that shares them), the distances are measured once."""
    d_own = _distances(P, rows, col, own[0])
    d_other = d_own if own[0] is other[0] else _distances(P, rows, col, other[0])
    err_own, _, n_own = _misfit(d_own, own[1:], cfg.clip)
    err_other, fit, n_other = _misfit(d_other, other[1:], cfg.clip)
    n = np.minimum(n_own, n_other)
    scored = n >= cfg.min_references
    return np.where(scored, 0.5 * n * (err_own - err_other), 0.0), np.where(scored, fit, np.nan)


def _exchanged(score: np.ndarray, breaks: np.ndarray, cost: float) -> np.ndarray:
    """(F,) bool: the most likely kept (False) / exchanged (True) labelling of the frames, given each frame's log-
    likelihood ratio ``score`` (F,) of exchanged against kept; the state changes only before frames ``breaks`` (F,)
    bool, at ``cost`` nats each (Viterbi). Runs between breaks whose sums have one sign are taken together first (a
    change between two of them is never better than one before the first: same cost, less of the wrong sign), so
    the loop runs over the sign changes only. Runs summing to 0 (no sample seeing two references) go with those above
    0: of equally likely labellings, the one exchanging them next to an exchanged run is found (the tracker's
    exchange holds in its identities until evidence says otherwise)."""
    starts = np.flatnonzero(breaks)
    block = np.add.reduceat(score, starts)  # (K,) sum of each run between breaks
    sign = block >= 0  # (runs summing to 0 go with those above 0)
    group = np.concatenate([[0], np.cumsum(sign[1:] != sign[:-1])])  # (K,)
    total = np.bincount(group, weights=block)
    kept, swapped = 0.0, -np.inf
    came = np.zeros((total.size, 2), dtype=bool)  # came[g, s]: the state before group g, when in s, was the other
    for g, s in enumerate(total):
        stay_kept, from_swapped = kept, swapped - cost
        stay_swapped, from_kept = swapped, kept - cost
        came[g] = from_swapped > stay_kept, from_kept > stay_swapped
        kept, swapped = max(stay_kept, from_swapped), max(stay_swapped, from_kept) + s
    state = np.zeros(total.size, dtype=bool)
    s = swapped > kept
    for g in range(total.size - 1, -1, -1):
        state[g] = s
        s = s != came[g, int(s)]
    return np.repeat(state[group], np.diff(np.append(starts, score.size)))


def _pair_exchanges(P: np.ndarray, a: int, b: int, refs: tuple[np.ndarray, np.ndarray], median: np.ndarray,
                    spread: np.ndarray, jump: tuple[float, float], cfg: SkinConfig) -> list[np.ndarray]:
    """Frames (runs, each (n,)) over which identities ``a`` and ``b`` of ``P`` (F, M, 3) hold each other's markers,
    by their references ``refs`` (a's, b's) (steps 2-4 of the module docstring); ``jump``: the repair's jump rule
    (:func:`mocap.rigid.jump_starts`)."""
    F = len(P)
    seen = np.isfinite(P[:, [a, b], 0])  # (F, 2)
    sides = [(r, median[c, r], np.maximum(spread[c, r], cfg.floor_m)) for c, r in zip((a, b), refs, strict=True)]
    score = np.zeros(F)
    fit = np.full((F, 2), np.nan)
    for k, col in enumerate((a, b)):
        rows = np.flatnonzero(seen[:, k])
        ratio, fit[rows, k] = _scores(P, rows, col, sides[k], sides[1 - k], cfg)
        score[rows] += ratio
    whole = seen[1:] & seen[:-1] & ~jump_starts(P[:, [a, b]], *jump)[1:]  # (F - 1, 2): the identity goes on
    vote = np.sign(score) * (np.abs(score) > cfg.vote_nats)
    breaks = np.ones(F, dtype=bool)
    breaks[1:] = ~whole.any(axis=1) | (vote[1:] * vote[:-1] < 0)
    state = _exchanged(score, breaks, cfg.switch_cost)
    on = np.flatnonzero(state)
    runs = np.split(on, np.flatnonzero(np.diff(on) > 1) + 1) if on.size else []
    out = []
    for run in runs:
        moved = fit[run][seen[run]]
        if np.isfinite(moved).sum() >= cfg.scored_fraction * moved.size and np.nanmean(moved) <= cfg.fit_chi2:
            out.append(run)
    return out


def _meeting(P: np.ndarray, among: np.ndarray, meet_m: float) -> np.ndarray:
    """(n, n) bool: identities ``among`` (n,) of ``P`` (F, M, 3) that come within ``meet_m`` of each other in some
    frame (:func:`mocap.rigid.close_pairs`)."""
    met = np.zeros((among.size, among.size), dtype=bool)
    for hits in close_pairs(P[:, among], meet_m):
        met[hits[:, 1], hits[:, 2]] = met[hits[:, 2], hits[:, 1]] = True
    return met


def _pairs(P: np.ndarray, median: np.ndarray, spread: np.ndarray, count: np.ndarray, cfg: SkinConfig
           ) -> list[tuple[int, int, tuple[np.ndarray, np.ndarray]]]:
    """(a, b, (a's references, b's)) of every pair of identities of ``P`` (F, M, 3) to score (step 1 of the module
    docstring), from their (M, M) median distances, spreads (m) and counts of frames seen together."""
    with np.errstate(invalid="ignore"):
        steady = (spread < cfg.spread_m) & (count >= cfg.min_frames)
        shared_ok = steady & (median <= cfg.reach_m)
        own_ok = steady & (median <= cfg.own_reach_m)
    shared = shared_ok.astype(np.int64) @ shared_ok.T.astype(np.int64)  # (M, M) references in common
    out = []
    for a, b in zip(*np.nonzero(np.triu(shared >= cfg.min_references, 1)), strict=True):
        refs = np.flatnonzero(shared_ok[a] & shared_ok[b])
        gap = np.abs(median[a, refs] - median[b, refs])
        refs = refs[(gap >= cfg.separation_m) & (gap >= cfg.separation_spreads * (spread[a, refs] + spread[b, refs]))]
        if refs.size >= cfg.min_references:
            out.append((int(a), int(b), (refs, refs)))
    among = np.flatnonzero(own_ok.sum(axis=1) >= cfg.min_references)
    met = _meeting(P, among, cfg.meet_m)
    for i, j in zip(*np.nonzero(np.triu(met, 1)), strict=True):
        a, b = int(among[i]), int(among[j])
        if shared[a, b] or own_ok[a, b]:  # (a pair sharing references, or one segment: scored above or not at all)
            continue
        refs = tuple(np.setdiff1d(np.flatnonzero(own_ok[c]), [a, b]) for c in (a, b))
        if min(r.size for r in refs) >= cfg.min_references and np.intersect1d(*refs).size == 0:
            out.append((a, b, refs))
    return out


def undo_skin_exchanges(traj: Trajectories, config: SkinConfig | None = None, jump_acc: float = np.inf,
                        reversal_acc: float = np.inf) -> int:
    """Give back the markers two identities hold of each other's where their references tell them apart (see the
    module docstring), in place. ``jump_acc`` and ``reversal_acc``: the repair's jump rule
    (:func:`mocap.rigid.jump_starts`), m/frame^2. Returns the number of exchanges undone."""
    cfg = config or SkinConfig()
    undone = 0
    for _ in range(cfg.rounds):
        P = traj.positions
        if P.shape[1] < 3:
            break
        median, spread, count = pair_statistics(P, cfg.min_frames)
        found = 0
        for a, b, refs in _pairs(P, median, spread, count, cfg):
            runs = _pair_exchanges(P, a, b, refs, median, spread, (jump_acc, reversal_acc), cfg)
            for rows in runs:
                for arr in (traj.positions, traj.residuals, traj.camera_masks):
                    arr[rows, a], arr[rows, b] = arr[rows, b].copy(), arr[rows, a].copy()
            found += len(runs)
        undone += found
        if found == 0:
            break
    return undone
