"""Gaps in every view bridged by where the neighbours carry the hidden marker (offline, the last repair pass).

A marker hidden from every camera for a few tenths of a second (behind the body in a serve) comes back far from
its prediction: the tracker gives it a new identity, or a lost identity of another marker that happens to be
near, and the repair's distance rules need rigid neighbours a skin-marker body swung at 50 Hz does not have. Its
neighbours do carry it, though, rigid or not: over the frames before the gap the marker is (to millimetres) a
fixed combination of its nearest neighbours' offsets from their mean, and the same combination of where those
neighbours are after the gap says where the marker is. The prediction turns and moves with the neighbours (the
combination is of offsets: a rigid motion of the neighbours moves it the same way) and follows a segment's slow
bending. On the seven tennis takes with such gaps the right piece after a gap was the best-predicted one 347
times in 361 (median miss 27 mm against 0.75 m for the others).

:func:`bridge_gaps` cuts every identity into pieces at gaps of more than ``min_gap`` frames and where it jumped (the
repair's jump rule: an identity that took another marker without a gap), and, for every piece that ends and every
piece that starts within ``max_gap_s`` after it (from the next frame on, in any identity), predicts the ending
piece's marker from its ``neighbours`` nearest identities (within ``reach_m``, seen through the last ``fit_frames``
frames of the ending piece and the first ``check_frames`` of the starting one; ridge ``ridge_m2``) and measures the
miss. Then one optimal assignment of ends to starts per group of competing pieces:

* a link the identities already make across a gap of a few frames (``coast_s``) that the marker's own path
  crosses (its constant-velocity extrapolation lands within ``coast_m`` per frame of the gap) stands, and neither of
  its pieces is linked otherwise: a wheelchair marker's nearest neighbours are the pushing arm's, which do not
  carry it;
* another link the identities already make costs its miss / ``favour`` (a miss over ``keep_m``: as much as no link), or
  nothing where no miss can be measured (an ending piece too short to fit, too few neighbours): the repair's links
  stand unless the neighbours refute them. A starting piece of one sample is measured on that sample: a lost
  identity that took one glimpse of another marker in its gap kept that link for free, and the marker's own return
  under a new identity was left unlinked (the serve's seed 42: a thigh marker's identity, with a finger's glimpse).
  A link over a gap longer than ``max_gap_s`` (the repair's distance rules join pieces seconds apart; the bridge
  measures such a link but does not search for one) weighs less: refuted, it costs as much as leaving both its
  pieces unlinked, and unmeasured ``miss_m / 2``;
* another link costs its miss where it is below ``miss_m`` and its ending piece is ``fit_frames`` long or more
  (``short_frames`` or more where the miss is clearly the piece's best, ``short_ratio``);
* leaving a piece unlinked costs ``miss_m``.

The identities are then rebuilt from the chains of linked pieces (each keeps the column of its longest piece where
that is free). Only whole samples move between identity columns; positions are never changed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from mocap.rigid import column_runs, jump_starts
from mocap.trajectories import MISSING, Trajectories

__all__ = ["BridgeConfig", "bridge_gaps", "carried_miss"]


@dataclass(frozen=True)
class BridgeConfig:
    """Settings of the bridging (frames are the take's).

    Attributes:
        min_gap: identities are cut into pieces at gaps longer than this, frames.
        max_gap_s: longest gap bridged, s.
        fit_frames: frames of the ending piece the combination is fitted over (at most; 3 at least).
        check_frames: frames of the starting piece it is checked over (at most; its one sample at least).
        neighbours: nearest identities the combination is of (3 at least are needed).
        reach_m: neighbours farther than this from the marker at the end are not used, m.
        ridge_m2: ridge of the combination's least squares, m^2 (a steady pose fits many combinations).
        fit_m: the combination must give the ending piece's own samples over the fitted frames within this, m RMS;
            else the miss is not measured (neighbours that do not carry the marker: a forearm marker's arm
            neighbours all hidden, the wheelchair's and the hand's left, 0.1-0.2 m off it already; a serving arm's
            skin markers fit their right links to a few centimetres).
        miss_m: a new link must miss by less than this, m; leaving a piece unlinked costs as much.
        keep_m: an existing link missing by more than this costs as much as no link, m.
        favour: an existing link's miss counts divided by this.
        short_frames: a piece shorter than ``fit_frames`` but this long at least makes a new link only where its
            miss is under ``short_ratio`` times every other candidate's, its own link's too (a fit over a few
            frames tells a marker from its near neighbours less surely: a forearm cluster's flicker).
        short_ratio: see ``short_frames``.
        coast_s: a link the identities make across a gap this short at most, s, ...
        coast_m: ... whose marker coasts into its next piece (constant velocity from its last two samples) within
            this per frame of the gap, m, stands, and neither piece is linked otherwise: over a few frames the
            marker's own path tells more than neighbours that may not carry it (a wheelchair's marker, whose nearest
            neighbours are the pushing arm's).
    """

    min_gap: int = 2
    max_gap_s: float = 3.0
    fit_frames: int = 15
    check_frames: int = 3
    neighbours: int = 8
    reach_m: float = 0.6
    ridge_m2: float = 1e-3
    fit_m: float = 0.08
    miss_m: float = 0.16
    keep_m: float = 0.15
    favour: float = 2.0
    short_frames: int = 5
    short_ratio: float = 0.5
    coast_s: float = 0.05
    coast_m: float = 0.005


def _pieces(seen: np.ndarray, min_gap: int, jumped: np.ndarray) -> np.ndarray:
    """(n, 3) column, first and last frame of every run of samples of ``seen`` (F, M) bool, cut where two samples
    are more than ``min_gap`` frames apart and before every sample of ``jumped`` (F, M) bool, column by column in
    time order (:func:`mocap.rigid.column_runs`)."""
    out = [(col, run[0], run[-1]) for col, run in column_runs(seen, jumped, min_gap)]
    return np.array(out, dtype=np.intp).reshape(-1, 3)


def _own_links(pieces: np.ndarray) -> dict[int, int]:
    """Piece -> the next piece of its column (the links the identities make), for ``pieces`` from :func:`_pieces`."""
    same = np.flatnonzero(pieces[1:, 0] == pieces[:-1, 0])
    return dict(zip(same.tolist(), (same + 1).tolist(), strict=True))


def carried_miss(P: np.ndarray, end: np.ndarray, start: np.ndarray, cfg: BridgeConfig,
                 seen: np.ndarray | None = None) -> float:
    """Distance, m, between the start of piece ``start`` and where the neighbours carry the marker of piece ``end``
    (both (column, first, last) in ``P`` (F, M, 3)); NaN where too few frames or neighbours to tell.

    The marker's offsets from its neighbours' mean over the end's last ``fit_frames`` samples are fitted as one
    combination of the neighbours' offsets (ridge least squares), which is then applied to the neighbours at the
    start's first ``check_frames`` samples: the mean distance to the start's samples there; NaN too where the
    combination misses the end's own samples by more than ``fit_m`` RMS. ``seen``: (F, M) bool, the samples of ``P``
    (computed if not given)."""
    (ma, fa, la), (mb, fb, lb) = end, start
    if seen is None:
        seen = np.isfinite(P[..., 0])
    before = np.arange(max(fa, la - cfg.fit_frames + 1), la + 1)
    after = np.arange(fb, min(lb, fb + cfg.check_frames - 1) + 1)
    before, after = before[seen[before, ma]], after[seen[after, mb]]
    if before.size < 3 or not after.size:
        return np.nan
    both = seen[before].all(axis=0) & seen[after].all(axis=0)
    both[[ma, mb]] = False
    candidates = np.flatnonzero(both)
    d = np.linalg.norm(P[la, candidates] - P[la, ma], axis=1)
    nearest = np.argsort(d)[:cfg.neighbours]
    near = candidates[nearest[d[nearest] < cfg.reach_m]]
    if near.size < 3:
        return np.nan
    N = P[before][:, near]  # (T, n, 3)
    centre = N.mean(axis=1, keepdims=True)
    A = (N - centre).transpose(0, 2, 1).reshape(-1, near.size)  # (3T, n)
    y = (P[before, ma] - centre[:, 0]).reshape(-1)
    w = np.linalg.solve(A.T @ A + cfg.ridge_m2 * np.eye(near.size), A.T @ y)
    if np.mean((A @ w - y) ** 2) * 3 > cfg.fit_m**2:  # (the mean over coordinates: x 3 for points)
        return np.nan
    Nb = P[after][:, near]
    centre_b = Nb.mean(axis=1)
    carried = centre_b + np.einsum("tni,n->ti", Nb - centre_b[:, None], w)
    return float(np.linalg.norm(carried - P[after, mb], axis=1).mean())


def _coasts(P: np.ndarray, end: np.ndarray, start: np.ndarray, max_gap: int, cfg: BridgeConfig) -> bool:
    """Whether the marker of piece ``end`` coasts into piece ``start`` (both (column, first, last) in ``P`` (F, M, 3))
    across a gap of ``max_gap`` frames at most: its constant-velocity extrapolation from its last two samples misses
    the start's first sample by less than ``coast_m`` per frame of the gap."""
    (ma, fa, la), (mb, fb, _) = end, start
    gap = fb - la
    if gap > max_gap or la - 1 < fa:
        return False
    coasted = P[la, ma] + (P[la, ma] - P[la - 1, ma]) * gap
    return bool(np.linalg.norm(coasted - P[fb, mb]) < cfg.coast_m * gap)


def _own_cost(miss: float, long_gap: bool, cfg: BridgeConfig) -> float:
    """Cost of keeping a link the identities make, whose ``miss`` (m; NaN: not measurable) is over a gap of at most
    ``max_gap_s`` or, ``long_gap``, longer (a link the repair's distance rules made, which the bridge does not search
    for: without evidence it gives way to a link the neighbours carry within ``miss_m / 2``, and refuted it costs as
    much as leaving both its pieces unlinked)."""
    if not np.isfinite(miss):
        return cfg.miss_m / 2 if long_gap else 0.0
    if miss <= cfg.keep_m:
        return miss / cfg.favour
    return 2 * cfg.miss_m if long_gap else cfg.miss_m


def _clear(miss: float, misses: dict[int, float], b: int, ratio: float) -> bool:
    """Whether ``miss`` (m), candidate ``b``'s, is under ``ratio`` times every other measured one of ``misses``."""
    return all(not np.isfinite(other) or miss < ratio * other for c, other in misses.items() if c != b)


def _links(P: np.ndarray, pieces: np.ndarray, fps: float, cfg: BridgeConfig) -> dict[int, int]:
    """Piece -> next piece of its marker, by the assignment of the module docstring."""
    F = len(P)
    seen = np.isfinite(P[..., 0])
    max_gap = int(round(cfg.max_gap_s * fps))
    coast_gap = max(2, int(round(cfg.coast_s * fps)))
    following = _own_links(pieces)
    ends = np.flatnonzero(pieces[:, 2] < F - 1)
    starts = np.flatnonzero(pieces[:, 1] > 0)
    starts = starts[np.argsort(pieces[starts, 1], kind="stable")]
    first = pieces[starts, 1]
    column = {int(b): k for k, b in enumerate(starts)}  # a start piece's column in the assignment
    length = pieces[:, 2] - pieces[:, 1] + 1
    coasting = {a: b for a, b in following.items() if _coasts(P, pieces[a], pieces[b], coast_gap, cfg)}
    coasted = set(coasting.values())
    rows, cols, costs = [], [], []
    for i, a in enumerate(ends):
        if a in coasting:  # (the link stands: no other is weighed against it)
            rows.append(i)
            cols.append(column[coasting[a]])
            costs.append(0.0)
            continue
        la = pieces[a, 2]
        candidates = set()
        if length[a] >= cfg.short_frames:  # new links: from a piece long enough to fit, to one as long as the check
            lo = np.searchsorted(first, la + 1, side="left")
            hi = np.searchsorted(first, la + max_gap, side="right")
            window = starts[lo:hi]
            candidates = set(window[length[window] >= cfg.check_frames].tolist()) - coasted
        if a in following:
            candidates.add(following[a])
        misses = {b: carried_miss(P, pieces[a], pieces[b], cfg, seen) for b in candidates}
        for b, miss in misses.items():
            if following.get(a) == b:
                cost = _own_cost(miss, pieces[b, 1] - la > max_gap, cfg)
            elif np.isfinite(miss) and miss < cfg.miss_m and (length[a] >= cfg.fit_frames
                                                              or _clear(miss, misses, b, cfg.short_ratio)):
                cost = miss
            else:
                continue
            rows.append(i)
            cols.append(column[b])
            costs.append(cost)
    links: dict[int, int] = {}
    if not rows:
        return links
    rows, cols, costs = np.array(rows), np.array(cols), np.array(costs)
    nE = len(ends)
    graph = coo_matrix((np.ones(rows.size), (rows, nE + cols)), shape=(nE + len(starts),) * 2)
    _, group = connected_components(graph, directed=False)
    for g in np.unique(group[rows]):  # one assignment per group of competing pieces
        sel = group[rows] == g
        r_ids, r = np.unique(rows[sel], return_inverse=True)
        c_ids, c = np.unique(cols[sel], return_inverse=True)
        nr, nc = r_ids.size, c_ids.size
        big = 1e6
        full = np.full((nr + nc, nc + nr), big)
        full[r, c] = costs[sel]
        full[:nr, nc:] = np.where(np.eye(nr, dtype=bool), cfg.miss_m, big)  # an end left unlinked
        full[nr:, :nc] = np.where(np.eye(nc, dtype=bool), cfg.miss_m, big)  # a start left unlinked
        full[nr:, nc:] = 0.0
        ri, ci = linear_sum_assignment(full)
        for x, y in zip(ri, ci, strict=True):
            if x < nr and y < nc and full[x, y] < big:
                links[int(ends[r_ids[x]])] = int(starts[c_ids[y]])
    return links


def bridge_gaps(traj: Trajectories, config: BridgeConfig | None = None, jump_acc: float = np.inf,
                reversal_acc: float = np.inf) -> int:
    """Re-link the pieces of the identities across gaps by where their neighbours carry them (see the module
    docstring), in place. Identities are also cut where they jumped (:func:`mocap.rigid.jump_starts` with
    ``jump_acc`` and ``reversal_acc``, m/frame^2). Identity columns no chain keeps are left empty (the caller drops
    them); new ones are appended.

    Returns the number of links made that the identities did not make before.
    """
    cfg = config or BridgeConfig()
    P = traj.positions
    if traj.n_markers < 4 or traj.n_frames < 4:
        return 0
    pieces = _pieces(np.isfinite(P[..., 0]), cfg.min_gap, jump_starts(P, jump_acc, reversal_acc))
    links = _links(P, pieces, traj.fps, cfg)
    following = _own_links(pieces)
    made = sum(following.get(a) != b for a, b in links.items())
    if made == 0 and all(links.get(a) == b for a, b in following.items()):
        return 0
    linked = set(links.values())
    chains = []
    for p in range(len(pieces)):
        if p not in linked:
            chain = [p]
            while chain[-1] in links:
                chain.append(links[chain[-1]])
            chains.append(chain)
    length = pieces[:, 2] - pieces[:, 1] + 1
    chains.sort(key=lambda chain: -int(length[chain].sum()))
    homes, taken, extra = [], set(), 0  # each chain's column: its longest piece's, unless a longer chain has it
    for chain in chains:
        home = int(pieces[chain[int(np.argmax(length[chain]))], 0])
        if home in taken:
            home, extra = traj.n_markers + extra, extra + 1
        else:
            taken.add(home)
        homes.append(home)
    arrays = [traj.positions, traj.residuals, traj.camera_masks]
    out = [np.full((a.shape[0], traj.n_markers + extra) + a.shape[2:], MISSING[a.dtype.kind], dtype=a.dtype)
           for a in arrays]
    for chain, home in zip(chains, homes, strict=True):
        for m, f, last in pieces[chain]:
            for o, a in zip(out, arrays, strict=True):
                o[f:last + 1, home] = a[f:last + 1, m]
    traj.positions, traj.residuals, traj.camera_masks = out
    traj.labels = list(traj.labels) + [f"bridged{k + 1}" for k in range(extra)]
    return made
