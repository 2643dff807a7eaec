"""Two identities that exchanged markers where the markers passed close get them back (offline).

Where two markers pass within a few centimetres of each other in fast motion (a tennis player's wrist and finger,
at 200 mm/frame, with a garbled frame of the recording between them), the tracker can exchange their identities
with no acceleration spike for the swap and jump passes of :mod:`mocap.relabel` to see. The markers attached to
them tell: a marker's distances to the other markers of its segment hold through the passage, and after an
exchange they step by as much as the two markers' distances to them differ.

:func:`undo_exchanges`, on the identities :func:`mocap.relabel.relink_tracklets` made:

1. finds every passage: two identities closer than ``near_m``, once per run of such frames (at its closest frame);
2. takes each one's attached identities over the ``window`` frames that end ``gap`` frames before the passage (a
   distance below ``reach_m`` that held within ``steady_m``), and compares those distances with the ones over the
   ``window`` frames that start ``gap`` frames after it: from the same identity (kept) and from the other one
   (exchanged);
3. exchanges the two identities' tails where the exchanged distances fit (mean change below ``fit_m``) and the
   kept ones do not (mean change above ``step_m``), from the passage's frame, or the one before or after it,
   whichever gives the two tracks the smoother accelerations there. Both identities must hold a marker in both
   windows: one that starts (or ends) at the passage exchanged nothing (a hand turning away from the wrist as a
   forearm marker comes into view beside it, at the hand's old distance from the wrist).

Only whole samples move between identity columns; positions are never changed.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from mocap.rigid import close_pairs
from mocap.trajectories import Trajectories

__all__ = ["ExchangeConfig", "undo_exchanges"]


@dataclass(frozen=True)
class ExchangeConfig:
    """Settings of the exchange repair.

    Attributes:
        near_m: two identities closer than this pass each other, m.
        window: frames over which distances are taken on each side of a passage ...
        gap: ... this many frames away from it (the passage's own frames can be garbled).
        reach_m: an identity within this distance, m ...
        steady_m: ... whose distance held within this over the window before is attached, m.
        fit_m: the exchanged tails' distances must match those before within this on average, m ...
        step_m: ... and the kept tails' must have changed by more than this on average, m.
    """

    near_m: float = 0.06
    window: int = 6
    gap: int = 2
    reach_m: float = 0.25
    steady_m: float = 0.004
    fit_m: float = 0.004
    step_m: float = 0.008


def undo_exchanges(traj: Trajectories, config: ExchangeConfig | None = None) -> int:
    """Exchange back, in place, the tails of identities that exchanged markers where they passed close (see the
    module docstring); returns how many exchanges were undone."""
    cfg = config or ExchangeConfig()
    undone = 0
    for frame, a, b in _passages(traj.positions, cfg.near_m):
        if _exchanged(traj.positions, frame, a, b, cfg):
            start = smoothest_split(traj.positions, frame - 2, frame, np.array([a, b]), np.array([b, a]))
            traj.permute_tails(start, [b, a], [a, b])
            undone += 1
    return undone


def _passages(P: np.ndarray, near_m: float) -> list[tuple[int, int, int]]:
    """(frame, a, b) with a < b, in time order: the closest frame of every run of consecutive frames in which
    identities a and b of ``P`` (F, M, 3) are closer than ``near_m``."""
    hits = list(close_pairs(P, near_m))
    hits = np.concatenate(hits) if hits else np.zeros((0, 3), dtype=np.intp)
    if not len(hits):
        return []
    hits = hits[np.lexsort((hits[:, 0], hits[:, 2], hits[:, 1]))]  # by pair, then frame
    new_run = np.ones(len(hits), dtype=bool)
    new_run[1:] = (hits[1:, 1] != hits[:-1, 1]) | (hits[1:, 2] != hits[:-1, 2]) | (hits[1:, 0] != hits[:-1, 0] + 1)
    dist = np.linalg.norm(P[hits[:, 0], hits[:, 1]] - P[hits[:, 0], hits[:, 2]], axis=1)
    out = []
    for run in np.split(np.arange(len(hits)), np.flatnonzero(new_run)[1:]):
        f, a, b = hits[run[np.argmin(dist[run])]]
        out.append((int(f), int(a), int(b)))
    return sorted(out)


def _exchanged(P: np.ndarray, frame: int, a: int, b: int, cfg: ExchangeConfig) -> bool:
    """Whether identities ``a`` and ``b`` of ``P`` (F, M, 3) exchanged markers at ``frame`` by their attached
    identities' distances (steps 2 and 3 of the module docstring)."""
    before = slice(frame - cfg.gap - cfg.window + 1, frame - cfg.gap + 1)
    after = slice(frame + cfg.gap, frame + cfg.gap + cfg.window)
    if before.start < 0 or after.stop > len(P):
        return False
    pair = [a, b]
    enough = cfg.window - 2  # samples a window needs
    if min(np.isfinite(P[window, pair, 0]).sum(axis=0).min() for window in (before, after)) < enough:
        return False  # (one of them held no marker on one side: nothing to exchange)
    others = np.flatnonzero((np.isfinite(P[before, :, 0]).sum(axis=0) >= enough)
                            & (np.isfinite(P[after, :, 0]).sum(axis=0) >= enough))  # (n,) those that can be attached
    others = others[(others != a) & (others != b)]
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # (all-NaN windows: no distance)
        d_before = np.linalg.norm(P[before, pair, None] - P[before, None, others], axis=3)  # (window, 2, n)
        d_after = np.linalg.norm(P[after, pair, None] - P[after, None, others], axis=3)
        was = np.nanmedian(d_before, axis=0)  # (2, n)
        now = np.nanmedian(d_after, axis=0)
        attached = ((np.isfinite(d_before).sum(axis=0) >= enough) & (was < cfg.reach_m)
                    & (np.nanmax(d_before, axis=0) - np.nanmin(d_before, axis=0) < cfg.steady_m))
    attached &= (np.isfinite(d_after).sum(axis=0) >= enough).all(axis=0)  # both tails measured after
    if not attached.any():
        return False
    kept = np.abs(now - was)[attached]
    swapped = np.abs(now[::-1] - was)[attached]
    return bool(swapped.mean() < cfg.fit_m and kept.mean() > cfg.step_m)


def roughness(P: np.ndarray) -> float:
    """Summed squared accelerations (second differences) of the tracks ``P`` (F, g, 3), missing samples skipped,
    m^2/frame^4."""
    return float(np.nansum((P[2:] - 2 * P[1:-1] + P[:-2]) ** 2))


def smoothest_split(P: np.ndarray, first: int, last: int, ids: np.ndarray, tails: np.ndarray) -> int:
    """The frame from which identities ``ids`` take the tails of ``tails`` (both (g,)): the one of ``first`` + 1 ..
    ``last`` + 1 that gives their tracks in ``P`` (F, M, 3) the smallest summed squared accelerations over frames
    ``first`` - 2 .. ``last`` + 3 (a passage of two markers, or a burst of hops: :mod:`mocap.scramble`)."""
    frames = np.arange(max(first - 2, 0), min(last + 4, len(P)))
    best, best_cost = last + 1, np.inf
    for split in range(first + 1, last + 2):
        path = np.where((frames >= split)[:, None, None], P[frames][:, tails], P[frames][:, ids])  # (n, g, 3)
        cost = roughness(path)
        if cost < best_cost:
            best, best_cost = split, cost
    return best
