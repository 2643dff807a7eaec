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
   than ``spread_m`` over ``min_frames`` frames seen together at least;
2. takes the identities shortest first, and offers each (the fragment) to every longer identity (the target):
   the fragment's median distance to each of the target's anchors it was seen with (``piece_frames`` frames
   at least) must equal the target's within ``tolerance_m`` and spread less than ``spread_m``, for
   ``min_anchors`` anchors or more and more anchors than disagree (an anchor across a joint may have moved);
3. joins the fragment to the longest target it fits, unless it fits two targets seen together (two markers:
   ambiguous), or their samples share more than ``overlap_fraction`` of the fragment's frames. Where they
   share frames (the target's identity held a neighbour for a while), the fragment's sample replaces the
   target's where its distances to the anchors in that frame fit the target's (mean within ``tolerance_m``) and
   the target's own do not; the sample left over moves to a new identity.

Only whole samples move between identity columns; positions are never changed, and no sample is dropped.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.rigid import pair_statistics
from mocap.trajectories import Trajectories

__all__ = ["AnchorConfig", "rejoin_by_anchors"]

_EMPTY = {"f": np.nan, "u": 0}  # a missing sample: positions and residuals NaN, camera mask 0


@dataclass(frozen=True)
class AnchorConfig:
    """Settings of the rejoining by anchors.

    Attributes:
        tolerance_m: a fragment's median distance to an anchor must be within this of the target's, m (skin
            markers: a few millimetres; the cluster's other markers differ by centimetres).
        spread_m: an anchor's distance to the target (and to the fragment) spreads less than this, m.
        reach_m: anchors are within this of the target (median), m.
        min_frames: frames an anchor and the target must be seen together.
        piece_frames: frames an anchor and the fragment must be seen together.
        min_anchors: fewest anchors that must agree.
        overlap_fraction: largest share of the fragment's frames in which the target has a sample too.
    """

    tolerance_m: float = 0.006
    spread_m: float = 0.003
    reach_m: float = 0.3
    min_frames: int = 30
    piece_frames: int = 3
    min_anchors: int = 2
    overlap_fraction: float = 0.5


def _target(p: int, median: np.ndarray, spread: np.ndarray, count: np.ndarray, strong: np.ndarray,
            frames: np.ndarray, cfg: AnchorConfig) -> int:
    """The identity fragment ``p`` joins (step 2-3 of the module docstring), or -1."""
    anchors = strong & (count[p] >= cfg.piece_frames)[None, :]  # (target, anchor)
    anchors[:, p] = False
    with np.errstate(invalid="ignore"):
        ok = anchors & (np.abs(median[p][None, :] - median) <= cfg.tolerance_m) & (spread[p] < cfg.spread_m)[None, :]
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


def _misfit(P: np.ndarray, rows: np.ndarray, column: int, target: int, anchors: np.ndarray,
            median: np.ndarray) -> np.ndarray:
    """(len(rows),) mean |distance - the target's median| to its ``anchors`` of identity ``column``'s samples in
    frames ``rows`` (inf where no anchor is seen)."""
    d = np.linalg.norm(P[np.ix_(rows, anchors)] - P[rows, column][:, None, :], axis=2)
    dev = np.abs(d - median[target, anchors])
    seen = np.isfinite(dev)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(seen.any(axis=1), np.where(seen, dev, 0.0).sum(axis=1) / seen.sum(axis=1), np.inf)


def rejoin_by_anchors(traj: Trajectories, config: AnchorConfig | None = None) -> int:
    """Join fragments of identities to the identity whose rigid anchors they repeat (see the module docstring), in
    place. Samples displaced where the two overlapped go to new identity columns appended at the end.

    Returns the number of fragments joined (their columns are left empty: the caller drops them).
    """
    cfg = config or AnchorConfig()
    P = traj.positions
    if traj.n_markers < cfg.min_anchors + 2 or not np.isfinite(P[..., 0]).any():
        return 0
    median, spread, count = pair_statistics(P, cfg.piece_frames)
    with np.errstate(invalid="ignore"):
        strong = (spread < cfg.spread_m) & (median <= cfg.reach_m) & (count >= cfg.min_frames)
    frames = np.isfinite(P[..., 0]).sum(axis=0)
    root = np.arange(traj.n_markers)
    arrays = [traj.positions, traj.residuals, traj.camera_masks]
    spilled: list[list[np.ndarray]] = []
    joined = 0
    for p in np.argsort(frames, kind="stable"):
        if frames[p] == 0:
            continue
        q = _target(int(p), median, spread, count, strong, frames, cfg)
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
            mine = ((_misfit(P, both, int(p), q, anchors, median) <= cfg.tolerance_m)
                    & (_misfit(P, both, r, q, anchors, median) > cfg.tolerance_m))
            leave = np.where(mine, r, p)  # the column whose sample moves out, per shared frame
            out = [np.full((len(P),) + a.shape[2:], _EMPTY[a.dtype.kind], dtype=a.dtype) for a in arrays]
            for a, o in zip(arrays, out, strict=True):
                o[both] = a[both, leave]
                a[both[mine], r] = a[both[mine], p]
            spilled.append(out)
        moved = here[~np.isin(here, both)]
        for a in arrays:
            a[moved, r] = a[moved, p]
            a[here, p] = _EMPTY[a.dtype.kind]
        root[p] = r
        joined += 1
    if spilled:
        traj.positions, traj.residuals, traj.camera_masks = (
            np.concatenate([a] + [s[i][:, None] for s in spilled], axis=1) for i, a in enumerate(arrays))
        traj.labels = list(traj.labels) + [f"fragment{k + 1}" for k in range(len(spilled))]
    return joined
