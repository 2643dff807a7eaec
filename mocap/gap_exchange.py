"""Two identities that came back from a gap with each other's markers are given them back (offline).

Two markers a few centimetres apart, both hidden from every camera for a while (a shank's Leg_Marker1 and
Leg_Marker3, 36 mm apart, behind the other leg for 60 frames), may come back each under the other's identity: the
tracker's gate, the re-linking and the bridge all link a return by where the marker is expected, and over a long
gap two close markers are expected within millimetres of each other's place. The exchange then holds for the rest
of the take, so no pass that compares whole identities sees it: each identity's distances to its neighbours are
one marker's before and the other's after (Knee_Marker2 185 mm from one, 170 mm from the other), and whole-take
statistics only blur.

Around the gap the two windows tell it: over a second before and a second after, a marker's distances to the
neighbours on its own segment hold within millimetres, so the identity whose distances after the gap are those
the other one had before holds the other's marker. :func:`undo_gap_exchanges` runs right after the bridge, and,
for every pair of identities whose gaps overlap (unseen runs inside their spans, ``max_gap_s`` at most; for one of
the two also the ``max_gap_s`` after its last sample or before its first) and which come within ``near_m`` of each
other around it, and for every jump of an identity (the repair's jump rule) onto a sample nearer another
identity's sample the frame before than its own (a 50 Hz serve's wrist and finger markers, 43-98 mm apart, taking
each other's identities between two frames), and for every jump of an identity in a frame where another one is in
such a gap, near or not (a clavicle marker back from 0.9 s hidden, taken by the identity of the finger marker that
swung past it and was lost), and for every gap of two frames at most beside an identity that accelerated over 0.8
of the jump threshold in it within 0.3 m of the hidden marker (a 50 Hz swing hides a hop onto it in the arm's own
acceleration: the serve's RFRM identity stepped onto RELB while RELB's missed a frame, then took RFRM), in time
order (shared gaps, jumps onto another's path, jumps into a gap, short gaps beside a jolt, in a frame):

1. takes the windows: each identity's last ``window_s`` of samples before the shared gap (or the jump) and first
   after it (none after for an identity that ended, none before for one that started);
2. takes each window's references: identities (not the pair) seen with it ``min_samples`` times or more, within
   ``reach_m`` (median) and steady (1.4826 MAD under ``spread_m``), and seen ``min_samples`` times in every
   window on the gap's other side; where that leaves the pair unscored (step 3), steady under ``loose_spread_m``
   instead (a 50 Hz serving arm: over a second, nothing within 0.3 m of the elbow holds its distance to 5 mm);
3. scores how well each window on the other side fits them: the mean over its samples of the squared difference
   to the reference window's median distance, in its spread (at least ``floor_m``), clipped at ``clip``, summed
   over the references; ``kept`` sums the fits of each identity to itself, ``exchanged`` of each to the other,
   both ways in time. Where one identity ended (or started), the two hypotheses link different windows (the marker
   back after the gap continues one identity or the other): each direction counts its mean over references times
   the fewest references any direction has (two at least), so a window with more references weighs no more;
4. exchanges the two identities from the gap on (to the end of the take) where ``exchanged`` is at most
   ``ratio`` times ``kept`` and below it by ``margin`` or more; where the pair has more shared gaps within the
   window after it (a short piece of one marker between them; for an exchange found at a jump into a gap, or at a
   short gap beside a jolt, also its later ones of that kind) the exchange starts at the one that best sorts the
   pieces between them, by their fit to the windows before over the steady references (a piece fits no window of
   an identity that started at the gap: it stays; loose references decide whether to exchange, not where: on the
   walking take's 2400-frame window they moved its start wrongly, IDF1 0.9097 -> 0.8827).

On the 61 captured takes of the repair's replays (the tennis takes with 5 % of samples hidden, the walking and
sprint takes), where the pass runs, the exchanges the truth calls right score 0.12-0.86 times ``kept`` (those over
``ratio`` are left), and where two markers' identities were right the closest is 0.94 (the two players' 5 %-hidden
seed 12: a shoulder and a back marker at a swing), 0.88 where both identities held one marker (the whole sprint).
On the repair benchmark's 4-minute marching stream (120 Hz) no right pair scores under 1. Only whole samples
move between identity columns; positions are never changed, and no sample is dropped.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from mocap.quickstats import nanmedian_columns
from mocap.rigid import jump_starts
from mocap.trajectories import Trajectories

__all__ = ["GapExchangeConfig", "WindowProfile", "undo_gap_exchanges"]


@dataclass(frozen=True)
class GapExchangeConfig:
    """Settings of the repair of exchanges across a shared gap.

    Attributes:
        max_gap_s: gaps longer than this are not looked at, s.
        near_m: the pair must come this near each other within a window of the shared gap (or jump onto
            another's path), m: a 50 Hz serving arm's markers are 0.54 m from those whose identities they take
            across a gap (no limit at all gives the same figures on 79 captures).
        window_s: samples each window takes (at most), s of the take's frames.
        min_samples: fewest samples a window, and a reference seen with it, must have.
        reach_m: a reference is within this of its window's identity (median), m.
        spread_m: a reference's distance to its window's identity spreads (1.4826 MAD) less than this, m ...
        loose_spread_m: ... or less than this where that leaves a pair unscored (no window has a reference), m:
            a reference that spreads 15 mm still tells markers 10 cm apart (the serve's 5 %-hidden seed 18: RELB
            and RUPA each back under the other's identity, 0.9796 -> 0.9875).
        floor_m: smallest spread a distance is scored with, m.
        clip: largest squared error, in spreads, one reference adds to a fit.
        ratio: the exchanged fit must be at most this times the kept one ...
        margin: ... and below it by this at least (one reference's full clip).
        beside_frames: a gap this long at most inside an identity's span pairs it with ...
        beside_m: ... every identity seen in the gap's first frame within this of the gap's last sample before, m ...
        beside_jolt: ... that accelerated over this fraction of the jump threshold there (in the gap's first frame or
            the one before): it may have taken the hidden identity's marker in a swing that hides the hop.
    """

    max_gap_s: float = 3.0
    near_m: float = 0.8
    window_s: float = 1.0
    min_samples: int = 5
    reach_m: float = 0.3
    spread_m: float = 0.005
    loose_spread_m: float = 0.015
    floor_m: float = 0.0015
    clip: float = 16.0
    ratio: float = 0.8
    margin: float = 16.0
    beside_frames: int = 2
    beside_m: float = 0.3
    beside_jolt: float = 0.8


def _gaps(seen: np.ndarray, max_len: int) -> np.ndarray:
    """(K, 4) int: (column, first, last frame, open) of every run of unseen frames inside a column's span of
    ``seen`` (F, M) bool, ``max_len`` frames long at most (open 0), and of the ``max_len`` frames after its last
    sample and before its first (open 1: the identity ended, or started); sorted by first frame."""
    F = seen.shape[0]
    out = [np.zeros((0, 4), dtype=np.intp)]
    for col in range(seen.shape[1]):
        frames = np.flatnonzero(seen[:, col])
        if frames.size == 0:
            continue
        step = np.diff(frames)
        k = np.flatnonzero((step > 1) & (step - 1 <= max_len))
        out.append(np.stack([np.full(k.size, col), frames[k] + 1, frames[k + 1] - 1, np.zeros(k.size, int)], axis=1))
        if frames[-1] < F - 1:
            out.append(np.array([[col, frames[-1] + 1, min(F - 1, frames[-1] + max_len), 1]]))
        if frames[0] > 0:
            out.append(np.array([[col, max(0, frames[0] - max_len), frames[0] - 1, 1]]))
    gaps = np.concatenate(out)
    return gaps[np.argsort(gaps[:, 1], kind="stable")]


def _shared_gaps(gaps: np.ndarray) -> np.ndarray:
    """(L, 4) int: (first frame both are unseen, last, column a, column b) of every two overlapping ``gaps`` (K, 4)
    (sorted by first frame) of two columns, one of them inside its column's span, a < b; sorted by first frame."""
    first, last = gaps[:, 1], gaps[:, 2]
    upto = np.searchsorted(first, last, side="right")  # gaps j > i with first[j] <= last[i] overlap gap i
    count = upto - np.arange(len(gaps)) - 1
    i = np.repeat(np.arange(len(gaps)), count)
    j = i + 1 + np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    keep = (gaps[i, 0] != gaps[j, 0]) & ~(gaps[i, 3].astype(bool) & gaps[j, 3].astype(bool))
    i, j = i[keep], j[keep]
    a, b = np.minimum(gaps[i, 0], gaps[j, 0]), np.maximum(gaps[i, 0], gaps[j, 0])
    shared = np.stack([first[j], np.minimum(last[i], last[j]), a, b], axis=1)
    return shared[np.lexsort((shared[:, 3], shared[:, 2], shared[:, 0]))]


def _window(seen_col: np.ndarray, t: int, n: int, before: bool) -> np.ndarray:
    """Frames of the last ``n`` samples of a column (``seen_col`` (F,) bool) before frame ``t``, or the first ``n``
    from ``t`` on."""
    frames = np.flatnonzero(seen_col)
    return frames[frames < t][-n:] if before else frames[frames >= t][:n]


@dataclass(frozen=True)
class WindowProfile:
    """One identity's distances over a window to R others, m: ``d`` (n, R), NaN where unseen, and per other
    identity the median, the robust spread (1.4826 MAD) and the samples seen (R,)."""

    d: np.ndarray
    median: np.ndarray
    spread: np.ndarray
    count: np.ndarray

    @classmethod
    def of(cls, d: np.ndarray) -> WindowProfile:
        """The profile of distances ``d`` (n, R) m."""
        median = nanmedian_columns(d)  # NaN: never seen
        return cls(d, median, 1.4826 * nanmedian_columns(np.abs(d - median)), np.isfinite(d).sum(axis=0))

    def steady(self, cfg: GapExchangeConfig) -> np.ndarray:
        """(R,) bool: the references a window keeps (step 2 of the module docstring, before the other side)."""
        with np.errstate(invalid="ignore"):
            return (self.count >= cfg.min_samples) & (self.median <= cfg.reach_m) & (self.spread < cfg.spread_m)

    def misfit(self, refs: np.ndarray, d: np.ndarray, cfg: GapExchangeConfig) -> np.ndarray:
        """Clipped squared errors, in spreads (``floor_m`` at least), of distances ``d`` (n, R', ...) to the
        references ``refs`` (R',) (an index or a mask of R) under this profile; NaN where unseen."""
        shape = (-1,) + (1,) * (d.ndim - 2)
        spread = np.maximum(self.spread[refs], cfg.floor_m).reshape(shape)
        return np.minimum(((d - self.median[refs].reshape(shape)) / spread) ** 2, cfg.clip)


class _Windows:
    """The four windows of a pair ``a``, ``b`` of ``P`` (F, M, 3) around frame ``t``: distances to every other
    identity, and each window's profile (median, spread, samples per reference)."""

    def __init__(self, P: np.ndarray, seen: np.ndarray, a: int, b: int, t: int, n: int):
        self.pair = (a, b)
        self.refs = np.setdiff1d(np.arange(P.shape[1]), [a, b])
        self.frames = {(c, before): _window(seen[:, c], t, n, before) for c in (a, b) for before in (True, False)}
        self.profile = {key: WindowProfile.of(np.linalg.norm(P[rows][:, self.refs] - P[rows, key[0]][:, None], axis=2))
                        for key, rows in self.frames.items()}  # distances (n, R) to the references

    def references(self, key: tuple[int, bool], others: list[tuple[int, bool]], cfg: GapExchangeConfig
                   ) -> np.ndarray:
        """(R,) bool: window ``key``'s references (step 2 of the module docstring), seen in both ``others``."""
        ok = self.profile[key].steady(cfg)
        for other in others:
            ok &= self.profile[other].count >= cfg.min_samples
        return ok

    def fits(self, cfg: GapExchangeConfig) -> tuple[float, float] | None:
        """(kept, exchanged) fits of the pair (step 3 of the module docstring); None where the two hypotheses do
        not link as many windows, a link is not scored both ways, or no window has a reference."""
        a, b = self.pair
        have = {key: rows.size >= cfg.min_samples for key, rows in self.frames.items()}
        links = {True: [(a, a), (b, b)], False: [(a, b), (b, a)]}  # (before, after) identities, kept / exchanged
        links = {kept: [link for link in pairs if have[link[0], True] and have[link[1], False]]
                 for kept, pairs in links.items()}
        if not links[True] or len(links[True]) != len(links[False]):
            return None
        scores = []  # (kept, sum, mean, references) of each scored direction of each link
        for before in (True, False):
            others = [(c, not before) for c in (a, b) if have[c, not before]]
            for key in [(c, before) for c in (a, b) if have[c, before]]:
                ok = self.references(key, others, cfg)
                if not ok.any():
                    continue
                for other in others:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)  # (a reference unseen throughout: NaN)
                        per_reference = np.nanmean(self.profile[key].misfit(ok, self.profile[other].d[:, ok], cfg),
                                                    axis=0)
                    scores.append((other[0] == key[0], np.nansum(per_reference), np.nanmean(per_reference), ok.sum()))
        if not scores:
            return None
        if len(links[True]) == 2:  # every window scores both hypotheses with the same references
            return (sum(total for kept, total, _, _ in scores if kept),
                    sum(total for kept, total, _, _ in scores if not kept))
        # One identity ended or started: the two hypotheses are scored by different windows, each direction by its
        # mean over references times the fewest any direction has.
        fewest = min((n for *_, n in scores), default=0)
        if len(scores) < 4 or fewest < 2:
            return None
        return (sum(mean for kept, _, mean, _ in scores if kept) * fewest,
                sum(mean for kept, _, mean, _ in scores if not kept) * fewest)


def _sample_fit(win: _Windows, key: tuple[int, bool], P: np.ndarray, rows: np.ndarray, col: int,
                cfg: GapExchangeConfig) -> np.ndarray:
    """(n,) mean clipped squared error, in spreads, of column ``col``'s samples in frames ``rows`` against window
    ``key``'s references (:meth:`WindowProfile.misfit`); 0 where none is seen."""
    d = np.linalg.norm(P[rows][:, win.refs] - P[rows, col][:, None], axis=2)  # (n, R) m
    ok = win.references(key, [], cfg)
    err = win.profile[key].misfit(ok, d[:, ok], cfg)
    seen = np.isfinite(err)
    return np.where(seen, err, 0.0).sum(axis=1) / np.maximum(seen.sum(axis=1), 1)


def _best_start(win: _Windows, P: np.ndarray, seen: np.ndarray, a: int, b: int, starts: np.ndarray,
                cfg: GapExchangeConfig) -> int:
    """Of the shared gaps' first frames ``starts`` (sorted, the decided one first), the one from which on the
    exchange best sorts the pieces of ``a`` and ``b`` between them: each sample fits the window before of the
    identity it ends in."""
    if starts.size == 1:
        return int(starts[0])
    gain = np.zeros(starts.size)  # gain[j]: cost of the exchange from starts[0] less from starts[j]
    for col, other in ((a, b), (b, a)):
        rows = np.flatnonzero(seen[starts[0]:starts[-1], col]) + starts[0]
        if rows.size == 0:
            continue
        # Kept before the exchange's start: fits its own window; exchanged: the other's (none where that identity
        # started at the gap: the worst fit).
        own = _sample_fit(win, (col, True), P, rows, col, cfg)
        swapped = (_sample_fit(win, (other, True), P, rows, col, cfg)
                   if win.frames[other, True].size >= cfg.min_samples else np.full(rows.size, cfg.clip))
        piece = np.searchsorted(starts, rows, side="right")  # samples before starts[j] for j >= piece
        gain += np.array([(swapped - own)[piece <= j].sum() for j in range(starts.size)])
    return int(starts[int(np.argmax(gain))])


def _jump_pairs(P: np.ndarray, frames: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """(L, 4) int: (frame, frame before, column a, column b), a < b, for every jump (``frames``, ``cols``: the
    samples :func:`mocap.rigid.jump_starts` marks) of an identity of ``P`` (F, M, 3) onto a sample nearer another
    identity's sample the frame before than its own: that one (the nearest)."""
    if frames.size == 0:
        return np.zeros((0, 4), dtype=np.intp)
    d = np.linalg.norm(P[frames - 1] - P[frames, cols][:, None], axis=2)  # (K, M) m
    d[np.arange(frames.size), cols] = np.inf
    d = np.where(np.isfinite(d), d, np.inf)
    other = d.argmin(axis=1)
    own = np.linalg.norm(P[frames, cols] - P[frames - 1, cols], axis=1)
    keep = d[np.arange(frames.size), other] < own
    frames, cols, other = frames[keep], cols[keep], other[keep]
    return np.stack([frames, frames - 1, np.minimum(cols, other), np.maximum(cols, other)], axis=1)


def _jumps_into_gaps(frames: np.ndarray, cols: np.ndarray, gaps: np.ndarray) -> np.ndarray:
    """(L, 4) int: (frame, frame, column a, column b), a < b, for every jump (``frames``, ``cols``) of an identity
    in a frame where another identity is in one of its ``gaps`` (K, 4) (a marker back from a gap, or out of a
    swing, taken by an identity that jumped to it, where its own had ended)."""
    if frames.size == 0 or gaps.size == 0:
        return np.zeros((0, 4), dtype=np.intp)
    inside = (gaps[None, :, 1] <= frames[:, None]) & (frames[:, None] <= gaps[None, :, 2])  # (J, K)
    j, k = np.nonzero(inside & (gaps[None, :, 0] != cols[:, None]))
    a, b = np.minimum(cols[j], gaps[k, 0]), np.maximum(cols[j], gaps[k, 0])
    return np.unique(np.stack([frames[j], frames[j], a, b], axis=1), axis=0)


def _beside_short_gaps(P: np.ndarray, gaps: np.ndarray, jump_acc: float, cfg: GapExchangeConfig) -> np.ndarray:
    """(L, 4) int: (first frame, last frame, column a, column b), a < b, for every gap of ``gaps`` (K, 4) inside its
    column's span and ``beside_frames`` long at most, with each identity of ``P`` (F, M, 3) seen in its first frame
    within ``beside_m`` of the column's last sample before it and accelerating there (that frame or the one before)
    over ``beside_jolt`` times ``jump_acc`` m/frame^2 (a 50 Hz swing's hop onto the hidden marker, masked by the
    arm's own acceleration)."""
    short = gaps[(gaps[:, 3] == 0) & (gaps[:, 2] - gaps[:, 1] < cfg.beside_frames) & (gaps[:, 1] >= 2)]
    if short.size == 0 or not np.isfinite(jump_acc):
        return np.zeros((0, 4), dtype=np.intp)
    col, t = short[:, 0], short[:, 1]
    near = np.linalg.norm(P[t] - P[t - 1, col][:, None], axis=2)  # (K, M) m, NaN where unseen
    jolt = np.fmax(np.linalg.norm(P[t + 1] - 2 * P[t] + P[t - 1], axis=2),
                   np.linalg.norm(P[t] - 2 * P[t - 1] + P[t - 2], axis=2))  # (K, M) m/frame^2
    with np.errstate(invalid="ignore"):
        k, other = np.nonzero((near < cfg.beside_m) & (jolt > cfg.beside_jolt * jump_acc))
    keep = other != col[k]
    k, other = k[keep], other[keep]
    return np.stack([t[k], short[k, 2], np.minimum(other, col[k]), np.maximum(other, col[k])], axis=1)


def _candidates(P: np.ndarray, max_len: int, jump: tuple[float, float], cfg: GapExchangeConfig
                ) -> list[tuple[int, int, int, int, int]]:
    """(first frame, kind, column a, column b, last frame) of every shared gap (kind 0), jump onto another's
    path (kind 1), jump while another is in a gap (kind 2) and short gap beside a jolt (kind 3,
    :func:`_beside_short_gaps`) of ``P`` (F, M, 3), in time order, by kind in a frame; ``jump``: the jump rule's
    accelerations (inf: gaps only)."""
    gaps = _gaps(np.isfinite(P[..., 0]), max_len)
    shared = _shared_gaps(gaps)
    frames, cols = np.nonzero(jump_starts(P, *jump)) if np.isfinite(jump).any() else (np.zeros(0, np.intp),) * 2
    jumps = _jump_pairs(P, frames, cols)
    into = _jumps_into_gaps(frames, cols, gaps)
    beside = _beside_short_gaps(P, gaps, jump[0], cfg)
    rows = np.concatenate([shared, jumps, into, beside]).astype(np.intp)
    kind = np.repeat(np.arange(4), [len(shared), len(jumps), len(into), len(beside)])
    order = np.lexsort((rows[:, 3], rows[:, 2], kind, rows[:, 0]))
    return [(int(r[0]), int(k), int(r[2]), int(r[3]), int(r[1])) for r, k in zip(rows[order], kind[order], strict=True)]


def undo_gap_exchanges(traj: Trajectories, config: GapExchangeConfig | None = None, jump_acc: float = np.inf,
                       reversal_acc: float = np.inf) -> int:
    """Exchange back, in place, the identities of two markers that came back from a shared gap each under the
    other's, or that one jumped onto the other's path (see the module docstring). ``jump_acc`` and
    ``reversal_acc``: the repair's jump rule (:func:`mocap.rigid.jump_starts`), m/frame^2 (inf: gaps only).
    Returns the number of exchanges undone."""
    cfg = config or GapExchangeConfig()
    P = traj.positions
    F = traj.n_frames
    n = max(cfg.min_samples, int(round(cfg.window_s * traj.fps)))
    loose = replace(cfg, spread_m=cfg.loose_spread_m) if cfg.loose_spread_m > cfg.spread_m else None
    undone = 0
    done_upto = (-1, -1, -1, -1)  # (frame, kind, a, b) of the last candidate looked at
    while True:
        seen = np.isfinite(P[..., 0])
        candidates = _candidates(P, int(round(cfg.max_gap_s * traj.fps)), (jump_acc, reversal_acc), cfg)
        exchanged = False
        for t, kind, a, b, last in candidates:
            if (t, kind, a, b) <= done_upto:
                continue
            done_upto = (t, kind, a, b)
            if kind != 2:  # (a jump into a gap pairs the two however far apart)
                lo, hi = max(0, t - n), min(F, max(t, last) + n + 1)
                with np.errstate(invalid="ignore"):
                    if not (np.linalg.norm(P[lo:hi, a] - P[lo:hi, b], axis=1) < cfg.near_m).any():
                        continue
            win = _Windows(P, seen, a, b, t, n)
            fits = win.fits(cfg)
            if fits is None and loose is not None:  # (loose references decide whether, not where: the start
                fits = win.fits(loose)  # below takes the steady ones)
            if fits is None or fits[1] > cfg.ratio * fits[0] or fits[0] - fits[1] < cfg.margin:
                continue
            after = max(rows[-1] for (_, before), rows in win.frames.items() if not before and rows.size)
            starts = np.unique([c[0] for c in candidates  # (jumps into a gap, short gaps: for their own kind only)
                                if c[2:4] == (a, b) and (c[1] < 2 or c[1] == kind) and t <= c[0] <= after])
            start = _best_start(win, P, seen, a, b, starts, cfg)
            traj.permute_tails(start, [b, a], [a, b])
            undone += 1
            exchanged = True
            break
        if not exchanged:
            return undone
