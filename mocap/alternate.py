"""Two identities of one marker that take turns are merged (offline).

The re-linking decides each return of a marker in time order: where the distances at a return changed by more than
its gate (an elbow bent meanwhile) it starts a new identity, and at a later return it may link the marker back to
the old one. The marker then has two identities that are never seen in the same frame and take turns (A, B, A ...),
which no pass joins: each looks at one junction at a time. Over the whole take the two show what they are: a
marker's median distances to the neighbours seen with it, over hundreds of frames, agree within millimetres with
its own, while two markers a few centimetres apart differ by centimetres to some neighbour at least.

:func:`merge_alternating` merges such pairs: never seen together, taking turns (their spans overlap, so one has
samples before and after one of the other's), with ``min_neighbours`` neighbours or more seen ``min_shared`` frames
or more with each (and within ``radius_m`` of one), whose median distances to the two differ by less than
``agree_m`` in the median; the best-agreeing pairs first, each identity merged once per call. Only whole samples
move (positions, residuals and camera masks together). The thresholds: on 45 captured takes the two such pairs of
one marker differ by 1.6 and 2.6 mm, the closest pairs of two markers (a forearm's, 40-65 mm apart) by 7 mm.
"""

from __future__ import annotations

import numpy as np

from mocap.rigid import pair_statistics
from mocap.trajectories import Trajectories


def merge_alternating(traj: Trajectories, min_shared: int = 20, min_neighbours: int = 3, radius_m: float = 0.25,
                      agree_m: float = 0.004) -> int:
    """Merge, in place, the identities of one marker that take turns (see the module docstring); the merged
    identity's column is left empty. Returns how many pairs were merged."""
    P = traj.positions
    seen = np.isfinite(P[..., 0])  # (F, M)
    median, _, together = pair_statistics(P, min_shared)  # (M, M) median distances, m, and frames seen together
    size = np.diag(together)
    F = len(seen)
    first, last = seen.argmax(axis=0), F - 1 - seen[::-1].argmax(axis=0)
    # Never seen together, yet their spans overlap: one has samples before and after one of the other's (two turns).
    a_idx, b_idx = np.nonzero(np.triu(together == 0, 1) & (size[:, None] >= min_shared) & (size[None] >= min_shared)
                              & (first[:, None] < last[None]) & (first[None] < last[:, None]))
    found = []
    for a, b in zip(a_idx, b_idx, strict=True):
        # the neighbours seen min_shared frames with both, within radius_m of one: their median distances compared
        both = (together[a] >= min_shared) & (together[b] >= min_shared) & (
            np.fmin(median[a], median[b]) < radius_m)
        if np.count_nonzero(both) >= min_neighbours:
            agreement = float(np.median(np.abs(median[a, both] - median[b, both])))
            if agreement < agree_m:
                found.append((agreement, a, b))
    merged = 0
    used: set[int] = set()
    for _, a, b in sorted(found):
        if a in used or b in used:
            continue
        used.update((a, b))
        rows = seen[:, b]
        for array, empty in ((traj.positions, np.nan), (traj.residuals, np.nan), (traj.camera_masks, 0)):
            array[rows, a] = array[rows, b]
            array[rows, b] = empty
        merged += 1
    return merged
