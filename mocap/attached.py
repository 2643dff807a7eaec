"""The tracker's memory of each identity's distances to the identities around it.

Markers of one body segment keep their distances; a neighbour a few centimetres away usually does not keep
the same distances to them. So where a hidden marker's track (or a lost identity) is offered a point, the point's
distances to the identity's steady neighbours, measured this frame, tell whether it is that marker or a
neighbour that has just come into view (the sprint's forearm: its markers 45-75 mm apart are hidden in turn,
and each one's widening search region holds the others).

Per identity, ``slots`` neighbouring identities within ``reach_m`` with the running mean of their distance. A
slot is steady once its distance has held within ``tolerance_m`` for ``steady_frames`` frames in which both were
measured. A distance off by more halves that count (one wrong point of either marker does not erase what many
frames showed; a distance that really changed soon stops counting). A slot whose count reaches zero takes another
neighbour not yet held: the nearest the first time, the next nearer ones after each failure, so that a close
neighbour across a joint does not keep the slot from a farther one on the same segment. Arrays indexed by
identity, grown as identities are created.

When an identity stops being measured, where its steady neighbours were in its last frame is kept: while it is
lost, those measured now tell where their segment carried it (:meth:`AttachedDistances.carried`).
"""

from __future__ import annotations

import numpy as np

from mocap import kernels

__all__ = ["AttachedDistances", "verdicts"]

_WIDE_M = 0.02  # neighbours that carry an identity span at least this (RMS) across their main line, m


class AttachedDistances:
    """Steady distances of each identity to up to ``slots`` neighbouring identities.

    Args:
        slots: neighbours remembered per identity.
        reach_m: a free slot takes the nearest measured identity within this distance, m.
        tolerance_m: a distance within this of its running mean holds, m.
        steady_frames: frames a distance must have held before it can refute a point.
        forget_frames: a slot whose neighbour has not been measured with the identity for this many frames is
            emptied (that neighbour was retired, or left the volume).
        alpha: smoothing factor of the running mean distance (skin markers drift slowly).
    """

    def __init__(self, slots: int, reach_m: float, tolerance_m: float, steady_frames: int, forget_frames: int,
                 alpha: float = 0.1) -> None:
        self._J = slots
        self._reach = reach_m
        self._tol = tolerance_m
        self._steady = steady_frames
        self._forget = forget_frames
        self._alpha = alpha
        self._frame = 0
        self.neighbour = np.full((0, slots), -1, dtype=np.intp)  # (I, J) neighbouring identity, -1: free slot
        self.distance = np.zeros((0, slots))  # (I, J) running mean distance, m
        self.held = np.zeros((0, slots), dtype=np.intp)  # (I, J) frames the distance has held
        self.last = np.zeros((0, slots), dtype=np.intp)  # (I, J) frame the two were last measured together
        self.tries = np.zeros((0, slots), dtype=np.intp)  # (I, J) times the slot was emptied
        # where each identity's steady neighbours were in the last frame it was measured in:
        self.left_with = np.full((0, slots), -1, dtype=np.intp)  # (I, J) the neighbouring identity, -1: none
        self.left_at = np.zeros((0, slots, 3))  # (I, J, 3) its position then, m
        self._previous = (np.zeros(0, dtype=np.intp), np.zeros((0, 3)))  # the last frame's identities, positions

    def _grow(self, n_ident: int) -> None:
        I = len(self.neighbour)
        if n_ident <= I:
            return
        n = max(n_ident, 2 * I, 64) - I
        self.neighbour = np.concatenate([self.neighbour, np.full((n, self._J), -1, dtype=np.intp)])
        self.distance = np.concatenate([self.distance, np.zeros((n, self._J))])
        self.held = np.concatenate([self.held, np.zeros((n, self._J), dtype=np.intp)])
        self.last = np.concatenate([self.last, np.zeros((n, self._J), dtype=np.intp)])
        self.tries = np.concatenate([self.tries, np.zeros((n, self._J), dtype=np.intp)])
        self.left_with = np.concatenate([self.left_with, np.full((n, self._J), -1, dtype=np.intp)])
        self.left_at = np.concatenate([self.left_at, np.zeros((n, self._J, 3))])

    def learn(self, ident: np.ndarray, X: np.ndarray) -> None:
        """One frame: the identities ``ident`` (n,) measured at ``X`` (n, 3) m (each identity once)."""
        self._frame += 1
        if ident.size:
            self._grow(int(ident.max()) + 1)
        self._leave(ident)
        self._previous = (ident, X)
        if ident.size == 0:
            return
        if kernels.HAVE_NUMBA:
            kernels.attached_learn(kernels.contiguous(ident, np.intp), kernels.contiguous(X), self.neighbour,
                                   self.distance, self.held, self.last, self.tries, self._frame, self._tol,
                                   self._alpha, self._forget)
        else:
            self._learn(ident, X)
        rows = np.flatnonzero((self.neighbour[ident] < 0).any(axis=1))
        if rows.size:
            self._fill(ident, X, rows)

    def _leave(self, ident: np.ndarray) -> None:
        """The identities of the previous frame missing from ``ident`` (n,): where their steady neighbours were then
        (before this frame's update of the slots)."""
        was, X = self._previous
        present = np.zeros(len(self.neighbour), dtype=bool)
        present[ident] = True
        gone = was[~present[was]]
        if gone.size == 0:  # (most frames)
            return
        at, _, usable = self.steady_here(gone, was, X)
        self.left_with[gone] = np.where(usable, self.neighbour[gone], -1)
        self.left_at[gone] = at

    def carried(self, ident: np.ndarray, last_X: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray,
                min_neighbours: int) -> tuple[np.ndarray, np.ndarray]:
        """Where the lost identities ``ident`` (n,), last seen at ``last_X`` (n, 3) m, are now if they moved rigidly
        with the steady neighbours they had when last seen, ``min_neighbours`` or more of them measured now (among
        ``here_ident`` (h,) at ``here_X`` (h, 3) m), not in a line and fitted within ``tolerance_m`` RMS (as
        :meth:`turns`). Returns (n,) bool (carried) and (n, 3) m (``last_X`` where not)."""
        out = last_X.copy()
        ok = np.zeros(len(ident), dtype=bool)
        known = ident < len(self.left_with)
        if not known.any() or here_ident.size == 0:
            return ok, out
        i = np.flatnonzero(known)
        row = _rows_in(self.left_with[ident[i]], here_ident)
        good, R, a, b = _rigid_turns(self.left_at[ident[i]], here_X[np.maximum(row, 0)], row >= 0, min_neighbours,
                                     self._tol)
        ok[i] = good
        rows = i[good]
        out[rows] = np.einsum("nij,nj->ni", R[good], last_X[rows] - a[good]) + b[good]
        return ok, out

    def _learn(self, ident: np.ndarray, X: np.ndarray) -> None:
        """The slots' update of :meth:`learn` (numpy; :func:`mocap.kernels.attached_learn` compiled)."""
        here = np.full((len(self.neighbour), 3), np.nan)
        here[ident] = X
        nb = self.neighbour[ident]  # (n, J)
        d = np.linalg.norm(X[:, None, :] - here[np.maximum(nb, 0)], axis=2)
        both = (nb >= 0) & np.isfinite(d)
        mean, held = self.distance[ident], self.held[ident]
        fresh = both & (held == 0)
        holds = both & (held > 0) & (np.abs(d - mean) <= self._tol)
        fails = both & ~fresh & ~holds
        mean = np.where(fresh, d, np.where(holds, mean + self._alpha * (d - mean), mean))
        held = np.where(fresh | holds, held + 1, np.where(fails, held // 2, held))
        last = np.where(both, self._frame, self.last[ident])
        free = (nb < 0) | (fails & (held == 0)) | (self._frame - last > self._forget)
        self.tries[ident] += free & (nb >= 0)
        nb = np.where(free, -1, nb)
        held = np.where(free, 0, held)
        self.neighbour[ident], self.distance[ident], self.held[ident], self.last[ident] = nb, mean, held, last

    def _fill(self, ident: np.ndarray, X: np.ndarray, rows: np.ndarray) -> None:
        """Every free slot of ``ident[rows]`` takes a measured identity within reach not yet held: the nearest, or
        after failures of that slot (``tries``) the next nearer ones, cyclically."""
        if kernels.HAVE_NUMBA:
            kernels.attached_fill(kernels.contiguous(ident, np.intp), kernels.contiguous(X), rows, self.neighbour,
                                  self.tries, self.last, self._frame, self._reach * self._reach)
            return
        gap = X[rows, None, :] - X[None, :, :]
        d = (gap * gap).sum(axis=2)  # (r, n) squared distances
        r = np.arange(rows.size)
        d[r, rows] = np.inf
        nb = self.neighbour[ident[rows]]
        d[(ident[None, None, :] == nb[:, :, None]).any(axis=1)] = np.inf
        d[d > self._reach * self._reach] = np.inf
        avail = np.isfinite(d).sum(axis=1)
        if not avail.any():  # (identities with no other measured neighbour within reach)
            return
        tries, last = self.tries[ident[rows]], self.last[ident[rows]]
        for n, j in enumerate(np.flatnonzero((nb < 0).any(axis=0))):
            if n:
                avail = np.isfinite(d).sum(axis=1)
            ok = (nb[:, j] < 0) & (avail > 0)
            if not ok.any():
                continue
            pick = np.argsort(d, axis=1)[r, tries[:, j] % np.maximum(avail, 1)]
            nb[ok, j] = ident[pick[ok]]
            last[ok, j] = self._frame
            d[r[ok], pick[ok]] = np.inf
        self.neighbour[ident[rows]], self.last[ident[rows]] = nb, last

    def judge(self, ident: np.ndarray, points: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
        """(n,) bool twice, for point ``points[i]`` (n, 3) m offered to identity ``ident[i]`` (n,), from the
        identity's steady neighbours among ``here_ident`` (h,), measured this frame at ``here_X`` (h, 3) m, at
        least two of them: ``misfit``, every such neighbour's distance to the point is off by more than
        ``tolerance_m``; ``fits``, most are not (a neighbour across a joint may have moved)."""
        return verdicts(*self._tally(ident, points, here_ident, here_X))

    def tally_pairs(self, ident: np.ndarray, points: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_tally` for every point of ``points`` (L, 3) m offered to every identity of ``ident`` (T,): how many
        of the identity's steady neighbours measured this frame (among ``here_ident`` (h,) at ``here_X`` (h, 3) m)
        hold their distance to the point, and how many are off, (L, T) int each."""
        L, T = len(points), len(ident)
        n_ok, n_off = self._tally(np.tile(ident, L), np.repeat(points, T, axis=0), here_ident, here_X)
        return n_ok.reshape(L, T), n_off.reshape(L, T)

    def _tally(self, ident: np.ndarray, points: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """(n,) int twice, for point ``points[i]`` (n, 3) m and identity ``ident[i]`` (n,): how many of the
        identity's steady neighbours measured this frame hold their distance to it, and how many are off by more
        than ``tolerance_m``."""
        at, mean, usable = self.steady_here(ident, here_ident, here_X)
        off = np.abs(np.linalg.norm(points[:, None, :] - at, axis=2) - mean) > self._tol
        return (usable & ~off).sum(axis=1), (usable & off).sum(axis=1)

    def steady_here(self, ident: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The steady neighbours of each identity ``ident`` (n,) among ``here_ident`` (h,), measured at ``here_X``
        (h, 3) m: their positions (n, J, 3) m, their running mean distances (n, J) m, and which slots hold one
        (n, J) bool."""
        n = len(ident)
        at, mean = np.zeros((n, self._J, 3)), np.zeros((n, self._J))
        usable = np.zeros((n, self._J), dtype=bool)
        known = ident < len(self.neighbour)
        if not known.any() or here_ident.size == 0:
            return at, mean, usable
        i = np.flatnonzero(known)
        row = _rows_in(self.neighbour[ident[i]], here_ident)
        usable[i] = (row >= 0) & (self.held[ident[i]] >= self._steady)
        at[i] = here_X[np.maximum(row, 0)]
        mean[i] = self.distance[ident[i]]
        return at, mean, usable

    def judge_pairs(self, ident: np.ndarray, points: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`judge` for every point of ``points`` (L, 3) m offered to every identity of ``ident`` (T,):
        ``misfit`` and ``fits``, (L, T) bool each."""
        return verdicts(*self.tally_pairs(ident, points, here_ident, here_X))

    def turns(self, ident: np.ndarray, before_ident: np.ndarray, before_X: np.ndarray, here_ident: np.ndarray,
              here_X: np.ndarray, min_neighbours: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """How each identity ``ident`` (n,) moved if rigidly with its steady neighbours: the rotation and translation
        (Kabsch) taking those measured at ``before_X`` (b, 3) m (identities ``before_ident``) in the previous frame
        to ``here_X`` (h, 3) m (``here_ident``) now; a point p then goes to R (p - a) + b. Returns (n,) bool (
        ``min_neighbours`` or more seen both times, not in a line: a turn about it would be free, a bar's row of
        markers; fitted within ``tolerance_m`` RMS) and R (n, 3, 3), a (n, 3) m, b (n, 3) m (the identity where
        not)."""
        at, _, usable = self.steady_here(ident, here_ident, here_X)
        was, _, usable_before = self.steady_here(ident, before_ident, before_X)
        return _rigid_turns(was, at, usable & usable_before, min_neighbours, self._tol)


def verdicts(n_ok: np.ndarray, n_off: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`AttachedDistances.judge`'s ``misfit`` and ``fits`` from the counts of steady neighbours whose
    distance holds (``n_ok``) and is off (``n_off``), any shape."""
    return (n_off >= 2) & (n_ok == 0), (n_ok >= 2) & (n_ok > n_off)


def _rows_in(neighbours: np.ndarray, here_ident: np.ndarray) -> np.ndarray:
    """(m, J) the row of ``here_ident`` (h,) holding each identity of ``neighbours`` (m, J), -1 where it is not
    there or the slot is empty (-1)."""
    top = max(int(neighbours.max(initial=-1)), int(here_ident.max(initial=-1))) + 1
    where = np.full(top, -1, dtype=np.intp)
    where[here_ident] = np.arange(here_ident.size)
    return np.where(neighbours >= 0, where[np.maximum(neighbours, 0)], -1)


def _rigid_turns(P: np.ndarray, Q: np.ndarray, used: np.ndarray, min_points: int, tolerance_m: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per set n, the rotation and translation (Kabsch) taking points ``P`` (n, J, 3) m to ``Q`` (n, J, 3) m over
    the ``used`` (n, J) ones: p goes to R (p - a) + b. Returns (n,) bool (``min_points`` or more used, not in a
    line: a turn about it would be free, a bar's row of markers; fitted within ``tolerance_m`` RMS) and
    R (n, 3, 3), a (n, 3) m, b (n, 3) m (the identity where not)."""
    n = len(P)
    R, a, b = np.tile(np.eye(3), (n, 1, 1)), np.zeros((n, 3)), np.zeros((n, 3))
    w = used.astype(float)
    ok = w.sum(axis=1) >= min_points
    if not ok.any():
        return ok, R, a, b
    P, Q, w = P[ok], Q[ok], w[ok]
    m = w.sum(axis=1)[:, None]
    cp = (P * w[:, :, None]).sum(axis=1) / m
    cq = (Q * w[:, :, None]).sum(axis=1) / m
    P0, Q0 = P - cp[:, None], Q - cq[:, None]  # (k, J, 3) about the centroids
    U, _, Vt = np.linalg.svd(np.einsum("mj,mji,mjk->mik", w, P0, Q0))
    Vt[:, 2] *= np.sign(np.linalg.det(np.einsum("mij,mjk->mik", U, Vt)))[:, None]
    turn = np.einsum("mij,mjk->mki", U, Vt)  # (V U^T, with the reflection removed)
    miss = np.einsum("mik,mjk->mji", turn, P0) - Q0
    rms = np.sqrt(((miss * miss).sum(axis=2) * w).sum(axis=1) / m[:, 0])
    spread = np.einsum("mj,mji,mjk->mik", w, P0, P0) / m[:, :, None]
    wide = np.linalg.eigvalsh(spread)[:, 1] >= _WIDE_M**2
    rows = np.flatnonzero(ok)
    ok[rows] = good = (rms <= tolerance_m) & wide
    rows = rows[good]
    R[rows], a[rows], b[rows] = turn[good], cp[good], cq[good]
    return ok, R, a, b
