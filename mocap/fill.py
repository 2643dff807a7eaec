"""Unconfirmed points that continue an identity's path join it (offline).

The tracker gives a new marker an identity only after ``confirm_frames`` consecutive frames, and a lost
identity goes back to a marker only when a tentative track there is confirmed. A marker that comes back
in bursts shorter than that (seen for three frames, hidden for one, seen again) is measured in every
burst, but the bursts before the one that is confirmed never reach the output: they are the tracker's
unconfirmed points (:meth:`mocap.tracker.Tracker.unconfirmed`), right next to the identity's own samples.

:func:`fill_from_unconfirmed` predicts each identity at the frames where it has no sample, from its own
samples at most ``reach_frames`` away: by linear interpolation where it has a sample on both sides, else
by extrapolating the velocity of the two nearest samples on one side. An unconfirmed point joins the
identity when it lies within ``gate_m`` of that prediction, and both the point and the prediction are
clearly matched (the next-nearest prediction to the point and the next-nearest point to the prediction are
``margin`` times farther). One pass fills one frame next to each sample; passes repeat until none adds a
sample, so a burst is followed point by point from the identity's side.

Only unconfirmed points are placed; no sample of an identity moves, and no position changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.trajectories import Trajectories, UnconfirmedPoints

__all__ = ["FillConfig", "fill_from_unconfirmed"]


@dataclass(frozen=True)
class FillConfig:
    """Settings of the fill from unconfirmed points.

    Attributes:
        gate_m: largest distance between a point and the identity's predicted position, m.
        margin: the next-nearest prediction to the point, and the next-nearest point to the prediction, must be
            this many times farther than the pair's own distance.
        reach_frames: predictions use samples at most this many frames away, and two samples at most this far apart.
        apart_m: an unconfirmed point this close to a sample of the frame is that marker measured twice, m.
        max_passes: most passes (each fills at most one more frame next to a sample).
    """

    gate_m: float = 0.006
    margin: float = 2.0
    reach_frames: int = 3
    apart_m: float = 0.0025
    max_passes: int = 100


def fill_from_unconfirmed(traj: Trajectories, extra: UnconfirmedPoints, config: FillConfig | None = None) -> int:
    """Give unconfirmed points ``extra`` to the identities whose paths they continue (module docstring), in place.

    Returns the number of samples added.
    """
    cfg = config or FillConfig()
    P = traj.positions
    F, M = P.shape[:2]
    if M == 0 or len(extra.rows) == 0:
        return 0
    E, slot = extra.as_columns(P, cfg.apart_m)  # (F, K, 3), (n, 2)
    K = E.shape[1]
    source = np.full((F, K), -1, dtype=np.intp)  # index into ``extra`` of each column entry
    placed = np.flatnonzero(slot[:, 0] >= 0)
    source[slot[placed, 0], slot[placed, 1]] = placed
    added = 0
    for _ in range(cfg.max_passes):
        rows = np.flatnonzero(np.isfinite(E[..., 0]).any(axis=1))  # frames with points left
        if rows.size == 0:
            break
        pred = _predicted(P, rows, cfg.reach_frames)  # (R, M, 3)
        d = np.linalg.norm(pred[:, :, None] - E[rows][:, None], axis=3)  # (R, M, K)
        d = np.where(np.isfinite(d), d, np.inf)
        point = d.argmin(axis=2)  # (R, M) nearest point to each prediction
        best = np.take_along_axis(d, point[..., None], axis=2)[..., 0]
        r, m = np.nonzero(best < cfg.gate_m)
        k = point[r, m]
        next_point = np.sort(d[r, m], axis=1)[:, 1] if K > 1 else np.full(r.size, np.inf)
        to_point = d[r, :, k]  # (n, M) every prediction's distance to the chosen point
        next_ident = np.sort(to_point, axis=1)[:, 1] if M > 1 else np.full(r.size, np.inf)
        clear = ((to_point.argmin(axis=1) == m) & (next_point > cfg.margin * best[r, m])
                 & (next_ident > cfg.margin * best[r, m]))
        r, m, k = rows[r[clear]], m[clear], k[clear]
        if r.size == 0:
            break
        n = source[r, k]
        P[r, m] = extra.positions[n]
        traj.residuals[r, m] = extra.residuals[n]
        traj.camera_masks[r, m] = extra.camera_masks[n]
        E[r, k] = np.nan
        added += r.size
    return added


def _predicted(P: np.ndarray, rows: np.ndarray, reach: int) -> np.ndarray:
    """(R, M, 3) each identity's position at the frames ``rows`` (R,) where ``P`` (F, M, 3) has no sample, from its
    samples at most ``reach`` frames away: interpolated between the nearest samples on both sides, else extrapolated
    from the two nearest on one side (at most ``reach`` frames apart); NaN where neither is possible and at samples."""
    F, M = P.shape[:2]
    seen = np.isfinite(P[..., 0])
    before = _latest(seen)  # (F, M) latest sample at or before each frame, -1 if none
    after = F - 1 - _latest(seen[::-1])[::-1]  # earliest at or after, F if none
    cols = np.arange(M)
    frame = rows[:, None]
    a1 = np.where(rows[:, None] > 0, before[np.maximum(rows - 1, 0)], -1)  # (R, M) latest sample before the frame
    b1 = np.where(rows[:, None] < F - 1, after[np.minimum(rows + 1, F - 1)], F)  # earliest after it
    a2 = np.where(a1 > 0, before[np.maximum(a1 - 1, 0), cols], -1)  # the sample before that
    b2 = np.where(b1 < F - 1, after[np.minimum(b1 + 1, F - 1), cols], F)
    free = ~seen[rows]
    near_a = free & (a1 >= 0) & (frame - a1 <= reach)
    near_b = free & (b1 < F) & (b1 - frame <= reach)
    pred = np.full((len(rows), M, 3), np.nan)
    for use, p1, p2 in ((near_a & (a2 >= 0) & (a1 - a2 <= reach), a1, a2),
                        (near_b & (b2 < F) & (b2 - b1 <= reach), b1, b2)):
        r, m = np.nonzero(use & ~np.isfinite(pred[..., 0]))
        x1, x2 = P[p1[r, m], m], P[p2[r, m], m]
        pred[r, m] = x1 + (x1 - x2) * ((rows[r] - p1[r, m]) / (p1[r, m] - p2[r, m]))[:, None]
    r, m = np.nonzero(near_a & near_b)
    w = ((rows[r] - a1[r, m]) / (b1[r, m] - a1[r, m]))[:, None]
    pred[r, m] = (1 - w) * P[a1[r, m], m] + w * P[b1[r, m], m]
    return pred


def _latest(seen: np.ndarray) -> np.ndarray:
    """(F, M) int32 index of the latest True of ``seen`` (F, M) at or before each frame, -1 if none."""
    index = np.where(seen, np.arange(len(seen), dtype=np.int32)[:, None], np.int32(-1))
    return np.maximum.accumulate(index, axis=0)
