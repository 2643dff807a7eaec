"""Three or more identities that came out of a junction with each other's markers get them back (offline).

A 50 Hz serve's racket hand moves 100 mm a frame: for two or three frames its wrist and finger markers are
half-seen, one identity ends, another starts, a third jumps, and the tracker comes out of it with the three
markers' identities rotated (RWRA's under RWRB's, RWRB's under a new one, RFIN's under an identity last seen on
another marker). :mod:`mocap.gap_exchange` scores two identities by the neighbours their windows keep, but here
each marker's best neighbours are the other two, which moved with it: the windows only tell the markers apart
when every member's tail is mapped at once, the references among them included.

:func:`undo_junctions`, right after :mod:`mocap.gap_exchange`:

1. finds the junctions: ends (the first unseen frame after a sample), starts and jumps (the repair's jump rule)
   of ``min_members`` identities or more within ``span_s`` of the first one and linked to it through events
   within ``near_m`` of each other (where each is: the sample at it, or before it for an end); ``max_members``
   at most, the first reached;
2. takes each member's window before the junction (its samples in the ``window_s`` before the first event)
   and after it (in the ``window_s`` from the last event on);
3. scores every way of matching the windows before to the windows after (as many links as the fewer side
   has): each linked pair's fit both ways in time, as in :mod:`mocap.gap_exchange`, over the references of the
   scoring window, a member's reference read through the matching (the identity it continues, or that
   continues it); a link's direction counts its mean over references, and a matching is scored only where every
   direction has two references or more;
4. takes the best matching where it makes new links and wins by ``ratio`` (at most that times the rival's
   score) and ``margin`` (below it by that, in the fewest references' units), each new link fitting within
   ``worst_fit``: where it breaks a link the tracker made (an identity that continues itself), the rival is the
   best matching that keeps every such link; where it only joins identities that ended to identities that
   started (the serving hand's markers out of a swing under new identities), the best without those joins;
5. gives each matched after-window's identity, from the last event on, to the identity its window before
   belongs to, up to where all the moved identities are hidden for ``window_s`` (what comes after was linked by
   other evidence);
6. looks at a junction step 4 leaves undecided once more, widened: at a 50 Hz swing the arm's markers hide in turn
   over a few tenths of a second, and the identities that ended before the first event or start after the last are
   outside ``span_s`` (the two players' 5 %-hidden seed 42: RFIN's identity ended 0.4 s before its arm's rotation,
   RFRM's new one started 0.3 s after). It adds the identities unseen through the junction (and the frame before it)
   whose last sample before it is within ``widen_s`` (or, with none, whose first after it), within ``near_m`` of a
   member seen in that frame, and drops the members whose windows have fewer than two references each;
   ``max_widened`` members at most. The windows then span the swing's bending, so no link is held to ``worst_fit``;
   instead the best matching must also score at most ``ratio`` times every matching that makes other new links, and
   none of its new links may fit at the clip (no reference fits it one way: the serve's 5 %-hidden seed 62, where the
   forearm's identity, ended at the follow-through by the hip, took the hip's marker back from a 1 s gap). The
   repair widens only at rates where a body's own accelerations reach the jump threshold
   (:meth:`mocap.relabel.RelabelConfig.hops_clear`: 50 Hz, not 100): there a swing hides an arm's markers in turn.

Only whole samples move between identity columns; positions are never changed, and no sample is dropped.
"""

from __future__ import annotations

import copy
import itertools
import warnings
from dataclasses import dataclass

import numpy as np

from mocap.gap_exchange import GapExchangeConfig, WindowProfile
from mocap.rigid import jump_starts
from mocap.trajectories import Trajectories

__all__ = ["JunctionConfig", "undo_junctions"]


@dataclass(frozen=True)
class JunctionConfig:
    """Settings of the junction repair; ``fit`` scores windows as the gap exchanges do.

    Attributes:
        span_s: a junction's events lie within this of its first, s.
        near_m: a member's event is within this of the first event's identity, m.
        min_members: fewest identities a junction has.
        max_members: most identities a junction has (the nearest to the first event's).
        worst_fit: each direction of a link the decision makes fits within this (mean over references of the
            clipped squared error, in spreads): 3 spreads, on average.
        widen_s: an undecided junction is widened by the identities ended this long before it or starting this
            long after it, s (step 6 of the module docstring).
        max_widened: most identities a widened junction has, those with too few references left out (its
            matchings grow as the factorial).
        fit: windows, references and the decision's ratio and margin.
    """

    span_s: float = 0.1
    near_m: float = 0.3
    min_members: int = 3
    max_members: int = 6
    worst_fit: float = 9.0
    widen_s: float = 0.4
    max_widened: int = 7
    fit: GapExchangeConfig = GapExchangeConfig()


def _events(P: np.ndarray, seen: np.ndarray, jump: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(E, 2) int (frame, column) of every end (first unseen frame after a sample), start and jump of ``P`` (F, M,
    3), sorted by frame, and (E, 3) where each one is, m: the sample at it, or the one before it for an end."""
    marks = np.zeros(seen.shape, dtype=bool)
    marks[1:] |= seen[:-1] & ~seen[1:]  # ends
    marks[1:] |= ~seen[:-1] & seen[1:]  # starts
    if np.isfinite(jump).any():
        marks |= jump_starts(P, *jump)
    frames, cols = np.nonzero(marks)
    at = np.where(seen[frames, cols], frames, frames - 1)
    return np.stack([frames, cols], axis=1), P[at, cols]


def _junctions(events: np.ndarray, where: np.ndarray, cfg: JunctionConfig, fps: float
               ) -> list[tuple[int, int, tuple[int, ...]]]:
    """(first event frame, last, members) of every junction (step 1 of the module docstring) among ``events``
    (E, 2) at ``where`` (E, 3) m, in time order."""
    span = max(1, int(round(cfg.span_s * fps)))
    upto = np.searchsorted(events[:, 0], events[:, 0] + span, side="right")
    out = []
    for i in np.flatnonzero(upto - np.arange(len(events)) >= cfg.min_members):
        inside, at = events[i:upto[i]], where[i:upto[i]]
        if np.unique(inside[:, 1]).size < cfg.min_members:
            continue
        with np.errstate(invalid="ignore"):
            near = np.linalg.norm(at[:, None] - at[None], axis=2) < cfg.near_m  # (e, e)
        members: list[int] = []
        reached = near[0].copy()
        while len(members) < cfg.max_members:  # events linked to the first one through near events, nearest first
            fresh = np.flatnonzero(reached & ~np.isin(inside[:, 1], members))
            if fresh.size == 0:
                break
            members.append(int(inside[fresh[0], 1]))
            reached |= near[np.isin(inside[:, 1], members)].any(axis=0)
        if len(members) < cfg.min_members:
            continue
        members.sort()
        out.append((int(events[i, 0]), int(inside[np.isin(inside[:, 1], members), 0].max()), tuple(members)))
    return out


class _Profiles:
    """Windows before and after a junction (frames ``t0``, ``t1``) of its members in ``P`` (F, M, 3): each one's
    profile of distances (n, M) to every identity (its own NaN) and its references (M,) bool."""

    def __init__(self, P: np.ndarray, seen: np.ndarray, members: tuple[int, ...], t0: int, t1: int, n: int,
                 cfg: GapExchangeConfig):
        self.profile: dict[tuple[int, bool], WindowProfile] = {}
        self.refs: dict[tuple[int, bool], np.ndarray] = {}
        for c in members:
            frames = np.flatnonzero(seen[:, c])
            for before, rows in ((True, frames[(frames < t0) & (frames >= t0 - n)]),
                                 (False, frames[(frames >= t1) & (frames < t1 + n)])):
                if rows.size < cfg.min_samples:
                    continue
                d = np.linalg.norm(P[rows] - P[rows, c][:, None], axis=2)  # (n, M) m
                d[:, c] = np.nan
                self.profile[c, before] = WindowProfile.of(d)
                self.refs[c, before] = self.profile[c, before].steady(cfg)
        self.before = [c for c in members if (c, True) in self.profile]
        self.after = [c for c in members if (c, False) in self.profile]
        self.members = np.array(members)
        self.tables: dict[tuple[tuple[int, bool], tuple[int, bool]], tuple] = {}  # by (key, other) window

    def restricted(self, members: tuple[int, ...]) -> _Profiles:
        """These windows for ``members`` (a subset of the members) only; the tables, which read references through
        the members, afresh."""
        out = copy.copy(self)
        out.profile = {key: p for key, p in self.profile.items() if key[0] in members}
        out.refs = {key: r for key, r in self.refs.items() if key[0] in members}
        out.before = [c for c in self.before if c in members]
        out.after = [c for c in self.after if c in members]
        out.members = np.array(members)
        out.tables = {}
        return out

    def directions(self, key: tuple[int, bool], other: tuple[int, bool], to_other: np.ndarray,
                   cfg: GapExchangeConfig) -> tuple[np.ndarray, np.ndarray]:
        """(K,) means over references and (K,) references of window ``other``'s fit to window ``key``'s references
        under K matchings: a reference r of ``key`` that is a member is read as identity ``to_other[k, i]`` of
        ``other`` (i: r's place among the members; -1: not read); one outside the junction always as itself."""
        if (key, other) not in self.tables:
            self.tables[key, other] = self._table(key, other, cfg)
        fixed_sum, fixed_count, member_refs, table = self.tables[key, other]
        read = to_other[:, np.searchsorted(self.members, member_refs)]  # (K, R) identity read, -1: none
        slot = np.minimum(np.searchsorted(self.members, read), self.members.size - 1)
        value = table[np.arange(member_refs.size), slot]  # (K, R)
        used = (read >= 0) & np.isfinite(value)
        count = fixed_count + used.sum(axis=1)
        total = fixed_sum + np.where(used, value, 0.0).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(count > 0, total / count, 0.0), count

    def _table(self, key: tuple[int, bool], other: tuple[int, bool], cfg: GapExchangeConfig
               ) -> tuple[float, int, np.ndarray, np.ndarray]:
        """(summed fit of the references outside the junction, their number, (R,) the references that are members,
        (R, members) the fit of each read as each member, NaN where that member is not seen enough): the fit of one
        reference is the mean over ``other``'s samples of the clipped squared error in ``key``'s spreads."""
        refs = np.flatnonzero(self.refs[key])
        inside = np.isin(refs, self.members)
        fixed = refs[~inside]
        seen_enough = self.profile[other].count >= cfg.min_samples  # (M,)
        fixed = fixed[seen_enough[fixed]]
        member_refs = refs[inside]

        def fit(rows: np.ndarray, columns: np.ndarray) -> np.ndarray:
            """(R, C) mean clipped squared error of ``other``'s distances to ``columns`` (R, C) under the profile
            of ``key``'s references ``rows`` (R,)."""
            err = self.profile[key].misfit(rows, self.profile[other].d[:, columns], cfg)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # (a member never seen with the window: NaN)
                return np.nanmean(err, axis=0)

        table = fit(member_refs, np.broadcast_to(self.members, (member_refs.size, self.members.size)))
        table[:, ~seen_enough[self.members]] = np.nan
        return float(fit(fixed, fixed[:, None]).sum()), int(fixed.size), member_refs, table


def _scores(prof: _Profiles, matchings: list[list[tuple[int, int]]], cfg: GapExchangeConfig
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K,) sum of the links' direction means, (K,) fewest references of a direction and (K,) worst direction mean
    of a link between two identities, of K ``matchings`` (lists of (before identity, after identity) links, as many
    in each): a matching with a direction of fewer than two references is not scored (fewest under 2)."""
    links = np.array(matchings, dtype=np.intp)  # (K, L, 2)
    K, L = links.shape[:2]
    rows = np.repeat(np.arange(K), L)
    before_to_after = np.full((K, prof.members.size), -1)  # by member: the identity it continues as, -1: none
    before_to_after[rows, np.searchsorted(prof.members, links[..., 0]).ravel()] = links[..., 1].ravel()
    after_to_before = np.full((K, prof.members.size), -1)
    after_to_before[rows, np.searchsorted(prof.members, links[..., 1]).ravel()] = links[..., 0].ravel()
    total, fewest, worst = np.zeros(K), np.full(K, np.iinfo(np.intp).max), np.zeros(K)
    for place in range(L):
        pairs, which = np.unique(links[:, place], axis=0, return_inverse=True)
        which = which.ravel()
        for p, (b, a) in enumerate(pairs):
            sel = np.flatnonzero(which == p)
            for key, other, to_other in (((b, True), (a, False), before_to_after),
                                         ((a, False), (b, True), after_to_before)):
                mean, refs = prof.directions(key, other, to_other[sel], cfg)
                total[sel] += mean
                fewest[sel] = np.minimum(fewest[sel], refs)
                if a != b:
                    worst[sel] = np.maximum(worst[sel], mean)
    return total, fewest, worst


def _matchings(before: list[int], after: list[int]):
    """Every matching of as many links as the fewer side has: lists of (before, after) pairs."""
    if len(before) >= len(after):
        for chosen in itertools.permutations(before, len(after)):
            yield list(zip(chosen, after, strict=True))
    else:
        for chosen in itertools.permutations(after, len(before)):
            yield list(zip(before, chosen, strict=True))


def _decide(prof: _Profiles, cfg: JunctionConfig, widened: bool = False) -> list[tuple[int, int]] | None:
    """The links to make (step 4 of the module docstring; ``widened``: step 6), or None."""
    tracked = set(prof.before) & set(prof.after)  # identities the tracker continued through the junction
    if len(prof.before) < 2 or len(prof.after) < 2:
        return None
    matchings = list(_matchings(prof.before, prof.after))
    total, fewest, worst = _scores(prof, matchings, cfg.fit)
    scored = []  # (score, fewest references, worst new link, links, keeps the tracker's links)
    for k in np.flatnonzero(fewest >= 2):
        links = matchings[k]
        keeps = all((c, c) in links for c in tracked if any(c in link for link in links))
        scored.append((float(total[k]), int(fewest[k]), float(worst[k]), links, keeps))
    if not scored:
        return None
    best = min(scored, key=lambda s: s[0])
    new = {link for link in best[3] if link[0] != link[1]}
    if not new:
        return None
    # Breaking a tracker's link is weighed against the best matching that keeps them all; joining identities that
    # ended to ones that started, against the best matching without those joins.
    rivals = [s for s in scored if (s[4] if not best[4] else not new & set(s[3]))]
    if not rivals:
        return None
    rival = min(rivals, key=lambda s: s[0])
    if best[0] > cfg.fit.ratio * rival[0] or (rival[0] - best[0]) * min(best[1], rival[1]) < cfg.fit.margin:
        return None
    if widened:
        others = [s[0] for s in scored if {link for link in s[3] if link[0] != link[1]} != new]
        if (others and best[0] > cfg.fit.ratio * min(others)) or best[2] >= cfg.fit.clip:
            return None
    elif best[2] > cfg.worst_fit:
        return None
    return best[3]


def _widened(P: np.ndarray, seen: np.ndarray, members: tuple[int, ...], t0: int, t1: int, cfg: JunctionConfig,
             fps: float) -> tuple[int, ...]:
    """``members`` of the junction with events ``t0``-``t1`` and the identities of ``P`` (F, M, 3) unseen from
    ``t0 - 1`` to ``t1`` (one that ended at the first event is an event step 1 left out) whose last sample before
    is within ``widen_s`` of ``t0`` (or, with none, whose first after ``t1``), within ``near_m`` of a member seen in
    that frame (step 6 of the module docstring)."""
    reach = int(round(cfg.widen_s * fps))
    lo, hi = max(0, t0 - reach), min(len(P), t1 + reach + 1)
    quiet = ~seen[max(0, t0 - 1):t1 + 1].any(axis=0) & seen[lo:hi].any(axis=0)  # (not ended at the first event)
    quiet[list(members)] = False
    added = []
    for c in np.flatnonzero(quiet):
        rows = np.flatnonzero(seen[lo:hi, c]) + lo
        f = rows[rows < t0][-1] if rows[0] < t0 else rows[0]
        with np.errstate(invalid="ignore"):
            if (np.linalg.norm(P[f, list(members)] - P[f, c], axis=1) < cfg.near_m).any():
                added.append(int(c))
    return tuple(sorted(set(members) | set(added)))


def _decide_widened(P: np.ndarray, seen: np.ndarray, wider: tuple[int, ...], t0: int, t1: int, n: int,
                    cfg: JunctionConfig) -> list[tuple[int, int]] | None:
    """The links to make at a junction step 4 left undecided, with its members ``wider`` from :func:`_widened`
    (step 6 of the module docstring), or None; ``n``: frames of a window."""
    prof = _Profiles(P, seen, wider, t0, t1, n, cfg.fit)
    referenced = tuple(c for c in wider if any(prof.refs[key].sum() >= 2 for key in ((c, True), (c, False))
                                               if key in prof.refs))
    if len(referenced) > cfg.max_widened:
        return None
    return _decide(prof.restricted(referenced), cfg, widened=True)


def _stop(seen: np.ndarray, cols: list[int], t: int, n: int) -> int:
    """First frame after ``t`` from which none of ``cols`` is seen for ``n`` frames (the junction's markers all
    hidden: what comes after was linked by other evidence); the take's length where there is none."""
    hidden = ~seen[t:, cols].any(axis=1)
    run = np.convolve(hidden, np.ones(n, dtype=int), mode="valid") if hidden.size >= n else np.zeros(0)
    starts = np.flatnonzero(run == n)
    return t + int(starts[0]) if starts.size else seen.shape[0]


def undo_junctions(traj: Trajectories, config: JunctionConfig | None = None, jump_acc: float = np.inf,
                   reversal_acc: float = np.inf, widen: bool = True) -> int:
    """Give back, in place, the markers three or more identities exchanged at a junction (see the module
    docstring). ``jump_acc`` and ``reversal_acc``: the repair's jump rule (:func:`mocap.rigid.jump_starts`),
    m/frame^2; ``widen``: look at undecided junctions once more widened (step 6). Returns the number of junctions
    undone."""
    cfg = config or JunctionConfig()
    fit = cfg.fit
    P = traj.positions
    n = max(fit.min_samples, int(round(fit.window_s * traj.fps)))
    undone = 0
    done_upto = (-1, ())
    while True:
        seen = np.isfinite(P[..., 0])
        changed = False
        for t0, t1, members in _junctions(*_events(P, seen, (jump_acc, reversal_acc)), cfg, traj.fps):
            if (t0, members) <= done_upto:
                continue
            done_upto = (t0, members)
            links = _decide(_Profiles(P, seen, members, t0, t1, n, fit), cfg)
            if links is None and widen:
                wider = _widened(P, seen, members, t0, t1, cfg, traj.fps)
                if wider != members:
                    links = _decide_widened(P, seen, wider, t0, t1, n, cfg)
            if links is None:
                continue
            moved = [(b, a) for b, a in links if b != a]
            sources = [a for _, a in moved]
            targets = [b for b, _ in moved]
            rest = sorted(set(targets) - set(sources))  # identities whose tails make room
            free = sorted(set(sources) - set(targets))
            traj.permute_tails(t1, sources + rest, targets + free, _stop(seen, sources, t1, n))
            undone += 1
            changed = True
            break
        if not changed:
            return undone
