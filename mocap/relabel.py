"""Offline identity repair on finished trajectories: duplicates, swaps and fragments.

The online tracker decides each frame's identities from the past alone. Once the take is done,
the frames on both sides of a decision are known, and these identity errors are easy to see and undo:

* **Duplicates.** Two identities hold one point in a frame: one took the other's marker (its own was hidden
  and the other's track missed a frame). :func:`drop_duplicates` keeps the point in the identity whose smooth
  run through that frame is longer (the thief jumped onto the marker, and mostly off it again), deletes the
  thief's copy, and gives the owner the thief's neighbouring samples that it continues.
* **Swaps.** Two identities exchange markers between frame ``f`` and ``f + 1`` (fast motion next to
  a close neighbour). Relabelling the tails after ``f`` with a permutation ``pi`` changes the
  second differences (accelerations, m/frame^2) at ``f`` and ``f + 1`` of the tracks involved.
  For every frame, :func:`repair_swaps` finds the permutation of the tracks alive on
  ``f - 1 .. f + 2`` that minimises the summed squared accelerations (Hungarian,
  ``scipy.optimize.linear_sum_assignment``) and applies it only when it is far smoother than
  keeping the labels (ratio and absolute margin), so real hard accelerations are left alone.
* **Fragments and swaps through gaps.** An identity is lost and the marker comes back as a new one,
  or two identities exchange markers across a missing frame. :func:`relink_tracklets` cuts every
  identity into tracklets (at gaps and at acceleration spikes) and re-links them in time order:
  tracklets starting together are assigned (Hungarian; one is left unlinked rather than force the others
  into links that cost ``unlinked_cost_m`` more) to identities that ended before. Where
  both ends have markers rigidly attached to them (the same segment: distances steady over a few
  frames) that are seen at both ends, and those distances agree (``shape_gate_m``), the cost is how
  much they changed, over any gap up to ``shape_max_s``: distances within a segment do not depend on
  how it moved meanwhile, and they tell apart markers a few centimetres apart that come back in turn.
  Otherwise the cost is how well the constant-velocity extrapolations of both ends agree across a
  short gap (an identity ending on a single sample moves at its velocity from the sample before), unless a distance
  the identity held to within ``shape_drift_m`` is more than ``shape_refuse_m`` (and both spreads) off the tracklet's
  (:func:`_contradicted`; below the rates where hops are clear, where a gap's gate spans a neighbour on the same foot,
  any of the tracklet's distances refutes, near or far, steady or not); over a longer
  one (up to ``lone_max_s``), one attached marker nearby seen at both ends is enough
  when its distance held to a few millimetres. Distances are kept per identity (not per output column), so a
  neighbour that was itself relinked still counts. A cluster that comes back in view together (a leg's markers
  after the leg was hidden) is assigned jointly: the distances between its own markers must match those between the
  identities they take, which no marker-by-marker cost can check. The tracker's own link is
  preferred and kept across any gap unless the distances clearly disagree (``shape_refuse_m``: a new
  marker next to a hidden one took its identity); it is the fallback when nothing else fits, but not for one sample
  the identity jumped onto (no gap), off its path, and left again, at frame rates where such a jump cannot be the
  body's own acceleration (:meth:`RelabelConfig.hops_clear`); below those rates such a sample stays with its
  identity however far off the extrapolation (a 50 Hz serve's wrist whipping at 280 m/s^2 is cut at the jump rule
  into a sample of its own, which no other identity, ended frames before and half a metre away, may take). Across a
  short gap it
  is refused too where the extrapolation misses the tracklet and the tracklet holds its distances to two identities
  or more that the identity moved against (``loose_refuse``: a marker of another segment). A newcomer
  whose distances changed less than that can still have taken the identity: when the marker itself comes
  back and its distances fit the identity's from before the gap clearly better (``usurp_margin_m``), it
  takes the identity back and the newcomer becomes an identity of its own. Below the rates where hops are clear
  it does so even where the extrapolation had linked it elsewhere (a 50 Hz gap's gate spans half a metre: another
  identity ended frames before fits it as well), if its distances fit within ``usurp_extrapolated_m``.

A third pass, :mod:`mocap.exchange`, gives back markers two identities exchanged where the markers passed close,
by the distances to the markers attached to them; a fourth, :mod:`mocap.scramble`, puts back jointly the tails of
identities permuted in a burst of hops (a serve's swing), by every distance that held through it; a fifth,
:mod:`mocap.reunite`, rejoins rigid clusters that come back after a long absence, far from every gate, by the
distances between their markers; a sixth, :mod:`mocap.plates`, labels the markers of rigid plates frame by frame by
the plate's shape; a seventh, :mod:`mocap.anchors`, joins fragments of a marker's track to the identity whose rigid
neighbours they keep the same distances to; an eighth, :mod:`mocap.fill`, gives the tracker's unconfirmed points to
the identities whose paths they continue; :mod:`mocap.bridge` re-links the pieces of the identities across gaps in
every view by where their neighbours carry the hidden marker; :mod:`mocap.offpath` withholds a hop of one
to three samples onto a neighbour that the identity's own path clearly misses (at 100 Hz and more); the last,
:mod:`mocap.alternate`, merges two identities of one marker that take turns or follow each other (never seen
together, the same median distances to their neighbours).

All passes only move whole samples between identity columns (positions, residuals and camera
masks together), the first deletes the second copy of a point and the off-path pass empties the samples it
withholds; they never change a position.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap.alternate import merge_alternating
from mocap.anchors import move_refuted_samples, rejoin_by_anchors
from mocap.bridge import bridge_gaps
from mocap.exchange import undo_exchanges
from mocap.fill import fill_from_unconfirmed
from mocap.gap_exchange import undo_gap_exchanges
from mocap.junction import undo_junctions
from mocap.offpath import give_end_hops_back, give_hops_back, withhold_off_path
from mocap.orphans import rejoin_orphans
from mocap.plates import label_plates
from mocap.quickstats import quick_median
from mocap.reunite import SKIN_CLUSTERS, centred_change, reunite_clusters
from mocap.rigid import split_tracklets
from mocap.scramble import unscramble_bursts
from mocap.skin import undo_skin_exchanges
from mocap.trajectories import Trajectories, UnconfirmedPoints

__all__ = ["RelabelConfig", "RelabelStats", "drop_duplicates", "relink_tracklets", "repair_identities", "repair_swaps",
           "withdraw_scattered"]

ANCHOR_ROUNDS = 4  # turns of moves by anchors and rejoins (the whole sprint settles after two or three)


@dataclass(frozen=True)
class RelabelConfig:
    """Settings of the offline identity repair.

    Attributes:
        swap_ratio: a tail permutation is applied when its acceleration cost is below this fraction
            of the cost of keeping the labels.
        swap_margin_m: ... and below it by at least this acceleration, m/frame^2 (squared internally),
            so that noise-level differences never relabel anything.
        max_gap: longest gap, frames, a fragment may be stitched across.
        stitch_gate_m: extrapolation disagreement allowed for a one-frame gap, metres.
        stitch_acc_mps2: extra disagreement allowed per squared second of gap (unmodelled acceleration),
            m/s^2; half the speed times the gap is allowed too.
        own_link_weight: the tracker's own link (same identity before and after) costs this fraction
            of its disagreement, and is kept across any gap (the tracker re-identified it).
        split_acc_m: a track is cut where its acceleration exceeds this on two consecutive samples,
            m/frame^2 (a jump to another marker), and the pieces are re-linked ...
        split_acc_mps2: ... and exceeds this real acceleration, m/s^2 (a serve's wrist reaches ~200 m/s^2:
            at 50 Hz that is 80 mm/frame^2, which must not read as a jump) ...
        split_reversal_m: ... or, where the two accelerations point opposite ways, exceeds this, m/frame^2 (and
            ``split_acc_mps2``): a step onto a marker this far away and on along it, or back. Real motion does
            not reverse a centimetres-per-frame^2 acceleration from one frame to the next; neighbouring markers
            of a cluster, 40-50 mm apart, step below ``split_acc_m``.
        shape_window: samples at each tracklet end over which the distances to its neighbours are taken.
        shape_radius_m: neighbours within this distance ...
        shape_steady_m: ... whose distance varies less than this over the window count as attached ...
        shape_history_s: ... and, on an identity's side of a gap, whose distance also stayed within
            ``shape_drift_m`` of that over the last this many seconds they were seen together (a hand, a few
            centimetres from a forearm's markers, can hold its distance for a few frames while the wrist turns) ...
        shape_drift_m: ... m, in a fraction ``shape_held`` of those samples at least (a glitch is not a drift).
        shape_min: attached neighbours seen at both ends needed to compare distances.
        shape_gate_m: a link is made on distances when their weighted mean change is below this, m ...
        shape_refuse_m: ... and refused, the tracker's own link included, above this (between the two, the
            extrapolation rules decide).
        shape_max_s: longest gap, seconds, a link by distances may span.
        cluster_margin_m: a cluster's joint assignment replaces the marker-by-marker one when its summed
            distance change is lower by more than this per marker, m.
        usurp_margin_m: a marker back after a gap takes its identity back from the one that continued it
            (a newcomer next to it) when its distances fit the identity's from before by this much better, m.
        usurp_extrapolated_m: ... and, below the rates where hops are clear (:meth:`hops_clear`), a marker the
            extrapolation alone linked to another identity (no distance fits that one) does so too when its
            distances fit within this, m (at 50 Hz a gap's gate spans another marker's identity ended frames before).
        duplicate_m: two identities' samples of one frame closer than this are one marker (below any marker's
            diameter: two markers' centres cannot be this close), m.
        lone_gate_m: a tracklet back after a gap too long or too fast to extrapolate (over ``max_gap`` frames, or an
            extrapolation gate wider than the distance to that neighbour: a serve's wrist back after 8 frames at
            10 m/s) with one attached identity seen at both ends, not ``shape_min``, is linked by that one distance
            when it changed less than this, m ...
        lone_reach_m: ... that neighbour is nearer than this (a nearer neighbour's sphere holds fewer markers; a
            wrist bar's two markers are ~100 mm apart), m ...
        lone_max_s: ... and the gap is at most this long, s.
        coast_frames: a tracklet into which an identity's extrapolation runs across a gap this short at most, frames,
            ...
        coast_fraction: ... within this fraction of its gate, is not linked on one neighbour's distance (the lone
            rule) to any identity: chance matches one distance (the whole sprint seed 3's hand, back after a frame on
            its own path within 7 mm, went to a forearm marker's identity ended 37 frames before, whose distance to a
            neighbour the hand's matched to 0.5 mm).
        unlinked_cost_m: the assignment leaves a tracklet to the fallbacks (the tracker's own link, a take-back)
            rather than make links that cost this much more, m. It is above the gated links' costs at camera rates
            (a 12-frame gap at 5 m/s and 100 Hz gates at 0.7 m), so what it stops is an own link over a long gap,
            extrapolated metres off, pushing the markers back from a short one onto each other's identities.
        loose_refuse: the tracker's own link across a short gap is refused where the extrapolation misses (beyond the
            gate) and the tracklet is attached to this many identities or more that the identity, seen with them over
            ``shape_window`` samples, moved loosely against (robust spread over ``shape_steady_m``; a hop of the
            identity's last samples onto a neighbour does not count): a marker of another segment, next to
            where a hidden one was predicted (a forearm marker the tracker gave a wheelchair marker's identity
            while the hand pushed the wheel).
        end_velocity_frames: an identity ending on a tracklet of one sample (no velocity of its own: its
            extrapolation gate was a standing marker's) takes its velocity from its sample before, when at most this
            many frames before.
        cluster_tie_m: joint assignments of a cluster whose summed distance change is within this per marker of the
            best's are ties (a near-symmetric cluster and its mirror image), m ...
        context_reach_m: ... told apart by the identities within this of the cluster's members, m ...
        context_margin_m: ... the one whose neighbours' (centred) distances changed least winning where it beats every
            other by this much, m (else the best stands).
        glimpse_members: a cluster glimpsed twice a short gap apart (:meth:`_Linker._assign_glimpses`) needs this many
            markers on each side ...
        glimpse_reach_m: ... within this of each other across the gap, m ...
        glimpse_tol_m: ... and is matched by one common step where every marker's step deviates less than this from
            it, m ...
        glimpse_ratio: ... and every other matching's deviates this many times as much ...
        glimpse_margin_m: ... plus this, m.
        clear_hop_ratio: where a body's accelerations stay this many times below ``split_acc_m`` (:meth:`hops_clear`),
            one sample its identity jumped onto (no gap), off its path, and left again does not keep the identity;
            at lower rates it does, at the cost of its miss.
        confirm_frames: an identity the passes leave without a run of this many consecutive samples, and with
            fewer than twice as many in all, is withdrawn (:func:`withdraw_scattered`): the tracker's confirmation
            (``mocap.reconstruct`` passes :attr:`TrackerConfig.confirm_frames`), which the repair's pieces must meet
            too.
    """

    swap_ratio: float = 0.25
    swap_margin_m: float = 0.01
    max_gap: int = 12
    stitch_gate_m: float = 0.02
    stitch_acc_mps2: float = 25.0
    own_link_weight: float = 0.5
    split_acc_m: float = 0.06
    split_acc_mps2: float = 250.0
    split_reversal_m: float = 0.035
    shape_window: int = 6
    shape_radius_m: float = 0.25
    shape_steady_m: float = 0.004
    shape_history_s: float = 0.4
    shape_drift_m: float = 0.008
    shape_held: float = 0.8
    shape_min: int = 2
    shape_gate_m: float = 0.008
    shape_refuse_m: float = 0.024
    shape_max_s: float = 10.0
    cluster_margin_m: float = 0.001
    usurp_margin_m: float = 0.003
    usurp_extrapolated_m: float = 0.003
    duplicate_m: float = 0.003
    lone_gate_m: float = 0.003
    lone_reach_m: float = 0.12
    lone_max_s: float = 1.0
    coast_frames: int = 2
    coast_fraction: float = 0.5
    unlinked_cost_m: float = 1.0
    loose_refuse: int = 2
    end_velocity_frames: int = 3
    confirm_frames: int = 4
    cluster_tie_m: float = 0.0005
    context_reach_m: float = 0.4
    context_margin_m: float = 0.01
    glimpse_members: int = 3
    glimpse_reach_m: float = 0.15
    glimpse_tol_m: float = 0.012
    glimpse_ratio: float = 2.0
    glimpse_margin_m: float = 0.015
    clear_hop_ratio: float = 2.0

    def jump_acc(self, fps: float) -> float:
        """The acceleration, m/frame^2, above which a track jumped at ``fps`` Hz (``split_acc_m`` and
        ``split_acc_mps2``)."""
        return max(self.split_acc_m, self.split_acc_mps2 / fps**2)

    def reversal_acc(self, fps: float) -> float:
        """The acceleration, m/frame^2, above which two consecutive opposite accelerations are a jump at ``fps``
        Hz (``split_reversal_m`` and ``split_acc_mps2``)."""
        return max(self.split_reversal_m, self.split_acc_mps2 / fps**2)

    def hops_clear(self, fps: float) -> bool:
        """Whether at ``fps`` Hz a body's own accelerations (``split_acc_mps2``) stay ``clear_hop_ratio`` times
        below the jump threshold the markers' spacing sets (``split_acc_m``): a jump is then surely a hop to
        another marker (100 Hz and more with the defaults; a 50 Hz swing reaches the threshold)."""
        return self.split_acc_mps2 / fps**2 * self.clear_hop_ratio <= self.split_acc_m


@dataclass
class RelabelStats:
    """What the repair changed: duplicate samples deleted, tail permutations applied, identities saved by the
    re-linking (``stitches``: fragments joined minus tracks cut at jumps, so negative where the cuts outnumber the
    joins), exchanges undone where two markers passed close, bursts of hops unscrambled, cluster members reunited,
    samples moved to the plate member their shape names, fragments rejoined by their anchors, samples moved to the
    identity whose anchors they fit, unconfirmed points that joined an identity's path, links made across gaps by
    where the neighbours carry a marker, exchanges undone where two markers came back from a shared gap each under
    the other's identity, exchanges undone between a skin-mounted cluster's identities, samples that hopped off their
    identity's path given to the identity whose path they lie on, samples withheld off their identity's path (hops
    onto a neighbour), identities of one marker that took turns or followed each other merged,
    identities that ended joined to later ones their rigid neighbours carry them to, scattered identities
    withdrawn."""

    duplicates: int = 0
    swaps: int = 0
    stitches: int = 0
    exchanges: int = 0
    unscrambled: int = 0
    reunited: int = 0
    plate_samples: int = 0
    rejoined: int = 0
    anchor_moves: int = 0
    filled: int = 0
    bridged: int = 0
    gap_exchanges: int = 0
    junctions: int = 0
    skin_exchanges: int = 0
    hops_given: int = 0
    off_path: int = 0
    merged: int = 0
    orphans: int = 0
    withdrawn: int = 0


def _smooth_run(P: np.ndarray, f: int, col: int, split_acc: float) -> int:
    """Length (samples) of identity ``col``'s run through frame ``f`` in ``P`` (F, M, 3): consecutive samples, broken
    where either sample of a step has an acceleration (second difference) above ``split_acc`` m/frame^2."""
    valid = np.isfinite(P[:, col, 0])

    def jumps(k: int) -> bool:  # sample k, with both neighbours present, accelerates above split_acc
        return 0 < k < len(P) - 1 and valid[k - 1] and valid[k + 1] and bool(
            np.linalg.norm(P[k + 1, col] - 2 * P[k, col] + P[k - 1, col]) > split_acc)

    lo = f
    while lo > 0 and valid[lo - 1] and not (jumps(lo - 1) or jumps(lo)):
        lo -= 1
    hi = f
    while hi < len(P) - 1 and valid[hi + 1] and not (jumps(hi) or jumps(hi + 1)):
        hi += 1
    return hi - lo + 1


def drop_duplicates(traj: Trajectories, config: RelabelConfig | None = None) -> int:
    """Where two identities hold one point (closer than ``duplicate_m``: one took the other's marker), keep it in
    the identity whose smooth run through that frame is longer (:func:`_smooth_run`: the thief jumped onto the
    marker, and off it) and delete it from the other; the thief's samples next to it that the owner misses and
    continues (:func:`_continues`) move to the owner. In place; returns how many samples were deleted."""
    cfg = config or RelabelConfig()
    P = traj.positions
    split = cfg.jump_acc(traj.fps)
    dropped = 0
    F = len(P)
    for f in range(F):
        seen = np.flatnonzero(np.isfinite(P[f, :, 0]))
        x = P[f, seen]
        close = np.argwhere(np.triu(np.linalg.norm(x[:, None] - x[None], axis=2) < cfg.duplicate_m, 1))
        for a, b in seen[close]:
            if not (np.isfinite(P[f, a, 0]) and np.isfinite(P[f, b, 0])):  # one of them lost it already
                continue
            owner, thief = (a, b) if _smooth_run(P, f, a, split) >= _smooth_run(P, f, b, split) else (b, a)
            columns = ((P, np.nan), (traj.residuals, np.nan), (traj.camera_masks, 0))
            for array, empty in columns:
                array[f, thief] = empty
            dropped += 1
            for side in (-1, 1):  # the thief's samples next to it that the owner, missing there, continues
                k = f + side
                while 0 <= k < F and np.isfinite(P[k, thief, 0]) and not np.isfinite(P[k, owner, 0]):
                    if not _continues(P, k, owner, thief, -side, split):
                        break
                    traj.move_samples(k, thief, owner)
                    k += side
    return dropped


def _continues(P: np.ndarray, k: int, owner: int, thief: int, back: int, split_acc: float) -> bool:
    """Whether the thief's sample at frame ``k`` continues the owner's track from the side ``back`` (-1: before, 1:
    after) within ``split_acc`` m, and better than the thief's own track from the other side. A track continues
    from its two samples nearest ``k`` on that side by constant velocity, from one by standing still."""
    def miss(col: int, side: int) -> float:
        a, b = k + side, k + 2 * side
        if not 0 <= a < len(P) or not np.isfinite(P[a, col, 0]):
            return np.inf
        guess = 2 * P[a, col] - P[b, col] if 0 <= b < len(P) and np.isfinite(P[b, col, 0]) else P[a, col]
        return float(np.linalg.norm(P[k, thief] - guess))
    mine = miss(owner, back)
    return mine < split_acc and mine < miss(thief, -back)


def repair_swaps(traj: Trajectories, config: RelabelConfig | None = None) -> int:
    """Undo identity swaps in place (see the module docstring); returns how many frames were relabelled."""
    cfg = config or RelabelConfig()
    P = traj.positions
    F = traj.n_frames
    swaps = 0
    margin = cfg.swap_margin_m**2
    for f in range(1, F - 2):
        alive = np.flatnonzero(np.isfinite(P[f - 1 : f + 3, :, 0]).all(axis=0))
        if alive.size < 2:
            continue
        a, b, c, d = (P[f + k, alive] for k in (-1, 0, 1, 2))  # (K, 3) each
        # cost[i, k]: track i keeps its head (f-1, f) and takes track k's tail (f+1, f+2).
        acc_f = c[None, :, :] - 2 * b[:, None, :] + a[:, None, :]
        acc_f1 = d[None, :, :] - 2 * c[None, :, :] + b[:, None, :]
        cost = (acc_f**2).sum(axis=2) + (acc_f1**2).sum(axis=2)
        keep = np.diag(cost)
        # Only pairs that could plausibly swap matter: cheap pre-check before the assignment.
        if not np.any(cost < cfg.swap_ratio * keep[:, None] - margin):
            continue
        rows, cols = linear_sum_assignment(cost)
        moved = rows != cols
        if not moved.any():
            continue
        new, old = cost[rows[moved], cols[moved]].sum(), keep[rows[moved]].sum()
        if new < cfg.swap_ratio * old and old - new > margin:
            traj.permute_tails(f + 1, alive[cols[moved]], alive[rows[moved]])
            swaps += 1
    return swaps


def _end_state(P: np.ndarray, run: np.ndarray, at_start: bool) -> tuple[int, np.ndarray, np.ndarray]:
    """Frame, position and velocity (m/frame, pointing forward in time) at one end of a tracklet."""
    frame, col = run[0] if at_start else run[-1]
    pos = P[frame, col]
    if run.shape[0] < 2:
        return int(frame), pos, np.zeros(3)
    if at_start:
        return int(frame), pos, P[run[1][0], run[1][1]] - pos
    return int(frame), pos, pos - P[run[-2][0], run[-2][1]]


def _chain_distances(P: np.ndarray, samples: np.ndarray, owner: np.ndarray, chain: int, cfg: RelabelConfig,
                     keep: int, radius: float | None = None) -> dict[int, np.ndarray]:
    """Distances from a tracklet's samples (n, 2) (frame, column) to the identities (chains) seen in the same
    frames: ``{chain: (k,) distances, m}``, the last ``keep`` both were seen in, for those whose last
    ``shape_window`` lie within ``radius`` m (default ``shape_radius_m``; ``chain`` itself left out; ``owner``
    (F, M) maps samples to chains)."""
    frames, cols = samples[:, 0], samples[:, 1]
    own = owner[frames]
    ok = (own >= 0) & (own != chain)
    if not ok.any():
        return {}
    rows, where = np.nonzero(ok)  # an identity has one sample per frame at most: one entry per row and identity
    others = own[rows, where]
    order = np.argsort(others, kind="stable")  # grouped by identity, each group in time order
    rows, where, others = rows[order], where[order], others[order]
    values = np.linalg.norm(P[frames[rows], where] - P[frames[rows], cols[rows]], axis=1)
    ends = np.append(np.flatnonzero(others[1:] != others[:-1]) + 1, len(others))
    limit = cfg.shape_radius_m if radius is None else radius
    out = {}
    for start, end in zip(np.append(0, ends[:-1]), ends, strict=True):
        v = values[max(start, end - keep):end]
        if quick_median(v[-cfg.shape_window:]) < limit:
            out[int(others[start])] = v
    return out


def _steady(distances: np.ndarray | None, cfg: RelabelConfig) -> bool:
    """A distance that held still (attached markers): three samples or more, the last ``shape_window`` spread below
    ``shape_steady_m``, and a fraction ``shape_held`` of all of them within ``shape_drift_m`` of their median."""
    if distances is None or distances.size < 3:
        return False
    recent = distances[-cfg.shape_window:]
    if np.ptp(recent) >= cfg.shape_steady_m:
        return False
    held = np.count_nonzero(np.abs(distances - quick_median(recent)) < cfg.shape_drift_m)
    return held >= cfg.shape_held * distances.size


def _recent(distances: np.ndarray, cfg: RelabelConfig) -> float:
    """The median of the last ``shape_window`` distances, m."""
    return quick_median(distances[-cfg.shape_window:])


def _shape_misfit(pairs: list[tuple[float, float]]) -> float:
    """Mean change of distances (m) over (then, now) pairs, weighted by 1 / distance^2 (the nearest are the
    most likely on the same segment)."""
    then, now = np.array(pairs).T
    w = 1.0 / (0.5 * (then + now)) ** 2
    return float((w * np.abs(then - now)).sum() / w.sum())


def relink_tracklets(traj: Trajectories, config: RelabelConfig | None = None) -> int:
    """Re-link identities globally, in place; returns the number of identities saved.

    Tracklets (see :func:`mocap.rigid.split_tracklets`) are taken in order of their first frame; those starting at
    the same frame are assigned together (Hungarian) to identities that ended before: by how much
    their distances to attached identities changed, else by the mean disagreement of the two
    constant-velocity extrapolations across a short gap (the identity's forwards, the tracklet's
    backwards). Tracklets starting together that are attached to each other (a cluster back in view)
    are then assigned jointly, by their distances to each other as well (near-ties, a symmetric cluster and its
    mirror image, by the identities around it), and a cluster glimpsed twice a short gap apart by the one step that
    carries it (:meth:`_Linker._assign_glimpses`); one that fits no identity may take one back from a newcomer that
    continued it (:meth:`_Linker.take_back`), else it starts a new one. Output columns are the resulting identities.
    """
    cfg = config or RelabelConfig()
    runs = split_tracklets(traj.positions, cfg.jump_acc(traj.fps), cfg.reversal_acc(traj.fps))
    if not runs:
        return 0
    runs.sort(key=lambda r: int(r[0, 0]))
    linker = _Linker(traj.positions, max(int(round(cfg.shape_max_s * traj.fps)), cfg.max_gap), cfg, traj.fps)
    i = 0
    while i < len(runs):
        start = int(runs[i][0, 0])
        group = []
        while i < len(runs) and int(runs[i][0, 0]) == start:
            group.append(runs[i])
            i += 1
        linker.link(start, group)
    before = traj.n_markers
    F = traj.n_frames
    chains = linker.chains
    positions = np.full((F, len(chains), 3), np.nan)
    residuals = np.full((F, len(chains)), np.nan)
    masks = np.zeros((F, len(chains)), dtype=np.uint32)
    for c, pieces in enumerate(chains):
        idx = np.concatenate(pieces)
        positions[idx[:, 0], c] = traj.positions[idx[:, 0], idx[:, 1]]
        residuals[idx[:, 0], c] = traj.residuals[idx[:, 0], idx[:, 1]]
        masks[idx[:, 0], c] = traj.camera_masks[idx[:, 0], idx[:, 1]]
    traj.positions, traj.residuals, traj.camera_masks = positions, residuals, masks
    traj.labels = [f"M{k + 1:03d}" for k in range(len(chains))]
    return before - len(chains)


def _comparable(memory: dict[int, np.ndarray], head: dict[int, np.ndarray], chain: int, cfg: RelabelConfig
                ) -> list[tuple[float, float]]:
    """(then, now) median distances, m, to the identities steady in both an identity's ``memory`` and a
    tracklet's ``head`` (the identity ``chain`` itself left out)."""
    return [(_recent(memory[o], cfg), quick_median(h)) for o, h in head.items()
            if o != chain and _steady(h, cfg) and _steady(memory.get(o), cfg)]


def _loose(memory: dict[int, np.ndarray], head: dict[int, np.ndarray], chain: int, cfg: RelabelConfig) -> int:
    """How many identities a tracklet's ``head`` holds steady that an identity's ``memory`` holds loosely (seen with
    it over ``shape_window`` samples at least, robust spread over ``shape_steady_m``: another segment); ``chain``
    itself left out."""
    return sum(1 for o, h in head.items() if o != chain and _steady(h, cfg) and o in memory
               and memory[o].size >= cfg.shape_window and _robust_spread(memory[o]) > cfg.shape_steady_m)


def _contradicted(memory: dict[int, np.ndarray], head: dict[int, np.ndarray], chain: int, cfg: RelabelConfig,
                  gap: int, steady_head: bool = True) -> bool:
    """Whether a tracklet's ``head`` has a distance to an identity that an identity's ``memory`` held near a value
    more than ``shape_refuse_m`` away, beyond what the memory's spread over its last ``shape_window`` samples (and
    that drift carried across the ``gap``, frames) and the head's own spread allow: another marker (``chain`` itself
    left out). With ``steady_head`` only the head's steady distances count."""
    for o, h in head.items():
        then = memory.get(o)
        if o == chain or then is None or then.size < cfg.shape_window or steady_head and not _steady(h, cfg):
            continue
        recent = then[-cfg.shape_window:]
        spread = float(np.ptp(recent))
        if spread >= cfg.shape_drift_m:  # (not held: a wheel's marker, another segment)
            continue
        allowed = cfg.shape_refuse_m + spread * (1.0 + gap / (cfg.shape_window - 1)) + float(np.ptp(h))
        if abs(quick_median(h) - quick_median(recent)) > allowed:
            return True
    return False


def _robust_spread(distances: np.ndarray) -> float:
    """1.4826 x the median absolute deviation of ``distances`` (n,) m: a hop of a few samples at the end of an
    identity (onto a neighbour) leaves it at the marker's own spread."""
    middle = quick_median(distances)
    return 1.4826 * quick_median(np.abs(distances - middle))


def _cheapest_links(cost: np.ndarray, unlinked: float) -> list[tuple[int, int]]:
    """(row, column) links of the least total cost (rows x columns, inf: no link), where leaving a row unlinked costs
    ``unlinked``: a link is made when the assignment gains more than that by it."""
    if not np.isfinite(cost).any():
        return []
    n = len(cost)
    rows, cols = linear_sum_assignment(np.hstack([cost, np.where(np.eye(n, dtype=bool), unlinked, np.inf)]))
    return [(int(g), int(j)) for g, j in zip(rows, cols, strict=True) if j < cost.shape[1]]


class _Linker:
    """The identities (chains of tracklets) :func:`relink_tracklets` builds in time order, and what it
    remembers of them.

    Attributes:
        chains: per identity, its tracklets ((n, 2) frame, column samples) in time order.
        ends: per identity, its last frame, position and velocity (m, m/frame).
        memory: per identity, its distances (m) to the other identities seen with it, the last ``shape_history_s``
            seconds' worth of samples.
        owner: (F, M) the identity each sample was given (-1: not yet).
        junction: per identity, its last link across a gap: the index of the tracklet it starts, the memory
            before it, how much the distances changed (m; inf where they could not be compared), the frame.
    """

    def __init__(self, P: np.ndarray, shape_max: int, cfg: RelabelConfig, fps: float) -> None:
        self.P, self.shape_max, self.cfg = P, shape_max, cfg
        self.acc_per_frame2 = cfg.stitch_acc_mps2 / (fps * fps)  # m/frame^2
        self.lone_max = int(round(cfg.lone_max_s * fps))  # frames
        self.hops_clear = cfg.hops_clear(fps)
        self.history = max(cfg.shape_window, int(round(cfg.shape_history_s * fps)))  # distances remembered, samples
        self.chains: list[list[np.ndarray]] = []
        self.ends: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.memory: list[dict[int, np.ndarray]] = []
        self.owner = np.full(P.shape[:2], -1, dtype=np.intp)
        self.junction: dict[int, tuple[int, dict[int, np.ndarray], float, int]] = {}

    def link(self, start: int, group: list[np.ndarray]) -> None:
        """Give each tracklet of ``group`` (all starting at frame ``start``) an identity."""
        cfg = self.cfg
        columns = {int(run[0, 1]) for run in group}
        open_chains = [c for c, (e, _, _) in enumerate(self.ends)
                       if 0 < start - e and (start - e <= cfg.max_gap or self._column(c) in columns
                                             or (start - e <= self.shape_max and self._attached(c)))]
        # every identity's distances to each tracklet's first samples; the heads: those within shape_radius_m
        firsts = [_chain_distances(self.P, run[: cfg.shape_window], self.owner, -1, cfg, cfg.shape_window, np.inf)
                  for run in group]
        heads = [{o: v for o, v in d.items() if quick_median(v) < cfg.shape_radius_m} for d in firsts]
        assigned: dict[int, int] = {}
        refused: set[tuple[int, int]] = set()  # (group index, chain): the distances disagree
        changes: dict[tuple[int, int], float] = {}  # (group index, chain): measured distance change, m
        if open_chains:
            self._assign(start, group, heads, firsts, open_chains, assigned, refused, changes)
            self._assign_cluster(start, group, heads, open_chains, assigned, refused)
            self._assign_glimpses(start, group, open_chains, assigned, changes)
        taken = set(assigned.values())
        for g in range(len(group)):
            if heads[g] and (g not in assigned or not self.hops_clear and not self._fits(assigned[g], heads[g])):
                c = self._usurped(start, heads[g], extrapolated=g in assigned)
                if c is not None and c not in taken:
                    self._take_back(c)
                    taken.discard(assigned.get(g))
                    assigned[g] = c
                    taken.add(c)
        for g, run in enumerate(group):
            c = assigned.get(g)
            if c is None:  # nothing fits: keep the tracker's own link if that identity is free and not refused
                own = [c for c in open_chains if self._column(c) == int(run[0, 1]) and c not in taken
                       and (g, c) not in refused]
                c = own[0] if own else None
                if c is not None:
                    taken.add(c)
            if c is None:
                c = len(self.chains)
                self.chains.append([])
                self.ends.append(None)
                self.memory.append({})
            elif self.chains[c] and ((g, c) in changes or start - self.ends[c][0] > 1):
                # (a link across a gap that no distances measured: the tracker's re-identification, which a newcomer
                # next to the hidden marker, or far from it in the widened radius after a long gap, may have taken)
                self.junction[c] = (len(self.chains[c]), dict(self.memory[c]), changes.get((g, c), np.inf), start)
            self.chains[c].append(run)
            self.ends[c] = self._end(c)
            self.owner[run[:, 0], run[:, 1]] = c
        for run in group:  # distances to the identities seen with it, both ways
            c = int(self.owner[run[0, 0], run[0, 1]])
            for other, d in _chain_distances(self.P, run, self.owner, c, cfg, self.history).items():
                d = np.concatenate([self.memory[c].get(other, d[:0]), d])[-self.history:]
                self.memory[c][other] = self.memory[other][c] = d

    def _end(self, c: int) -> tuple[int, np.ndarray, np.ndarray]:
        """Identity ``c``'s last frame, position and velocity (m/frame): its last tracklet's, or for a tracklet of one
        sample (no velocity of its own) from the identity's sample before it (``end_velocity_frames`` at most)."""
        run = self.chains[c][-1]
        frame, pos, velocity = _end_state(self.P, run, at_start=False)
        if len(run) == 1 and len(self.chains[c]) > 1:
            before, col = self.chains[c][-2][-1]
            if frame - before <= self.cfg.end_velocity_frames:
                velocity = (pos - self.P[before, col]) / (frame - before)
        return frame, pos, velocity

    def _column(self, c: int) -> int:
        """The output column of identity ``c``'s last tracklet (the tracker's identity there)."""
        return int(self.chains[c][-1][0, 1])

    def _attached(self, c: int) -> bool:
        """Identity ``c`` had an identity attached to it (a steady distance) when last seen with it."""
        return any(_steady(d, self.cfg) for d in self.memory[c].values())

    def _assign(self, start: int, group: list[np.ndarray], heads: list[dict], firsts: list[dict],
                open_chains: list[int], assigned: dict[int, int], refused: set[tuple[int, int]],
                changes: dict[tuple[int, int], float]) -> None:
        """Marker by marker (Hungarian): by the change of the distances to attached identities where they
        can be compared (over a gap beyond ``max_gap``, or one whose extrapolation cannot tell the two markers apart,
        one near attached identity is enough if its distance held within ``lone_gate_m``), else by how the
        extrapolations of both ends across the gap agree. ``heads``: each tracklet's distances within
        ``shape_radius_m``; ``firsts``: all of them."""
        cfg = self.cfg
        cost = np.full((len(group), len(open_chains)), np.inf)
        # What refutes an extrapolation link: the steady distances nearby where hops are clear; below those rates,
        # whose gates span a segment, every distance of the tracklet's first samples, steady or not, near or far.
        refuting = heads if self.hops_clear else firsts
        lone = np.zeros(cost.shape, dtype=bool)  # links made on one neighbour's distance
        coasting = np.zeros(len(group), dtype=bool)  # tracklets an identity's path runs into across a short gap
        for g, run in enumerate(group):
            _, p0, v0 = _end_state(self.P, run, at_start=True)
            for j, c in enumerate(open_chains):
                e, pe, ve = self.ends[c]
                gap = start - e
                same = self._column(c) == int(run[0, 1])  # the tracker's own link
                pairs = _comparable(self.memory[c], heads[g], c, cfg)
                if len(pairs) >= cfg.shape_min:
                    change = changes[g, c] = _shape_misfit(pairs)
                    if change < cfg.shape_gate_m and gap <= self.shape_max:
                        cost[g, j] = (cfg.own_link_weight if same else 1.0) * change
                        continue
                    if change > cfg.shape_refuse_m:
                        refused.add((g, c))
                        continue
                miss = 0.5 * (np.linalg.norm(pe + ve * gap - p0) + np.linalg.norm(p0 - v0 * gap - pe))
                speed = 0.5 * (np.linalg.norm(ve) + np.linalg.norm(v0))
                gate = cfg.stitch_gate_m + speed * 0.5 * gap + self.acc_per_frame2 * gap * gap
                if (len(pairs) == 1 and gap <= self.lone_max and pairs[0][0] < cfg.lone_reach_m
                        and (gap > cfg.max_gap or gate > pairs[0][0])):  # (too long or too fast to extrapolate)
                    change = abs(pairs[0][0] - pairs[0][1])
                    if change < cfg.lone_gate_m:
                        cost[g, j] = (cfg.own_link_weight if same else 1.0) * change
                        lone[g, j] = True
                        continue
                coasting[g] |= gap <= cfg.coast_frames and miss < cfg.coast_fraction * gate
                if same and gap <= cfg.max_gap and miss >= gate and (
                        _loose(self.memory[c], heads[g], c, cfg) >= cfg.loose_refuse):
                    refused.add((g, c))  # (a marker of another segment, where the extrapolation says it is not)
                elif same and gap == 1 and len(run) == 1:  # (one sample the identity jumped onto and left again)
                    if miss >= gate and self.hops_clear:
                        refused.add((g, c))  # (off its path: a hop)
                    else:
                        cost[g, j] = cfg.own_link_weight * miss  # (under 100 Hz: a swing's own sample, however far)
                elif same:
                    cost[g, j] = cfg.own_link_weight * miss if gap > cfg.max_gap or miss < gate else np.inf
                elif gap <= cfg.max_gap and miss < gate:
                    if _contradicted(self.memory[c], refuting[g], c, cfg, gap, steady_head=self.hops_clear):
                        refused.add((g, c))  # (a distance the identity held, far from the tracklet's)
                    else:
                        cost[g, j] = miss
        cost[lone & coasting[:, None]] = np.inf  # (one distance, which chance can match, against a clear path)
        for g, j in _cheapest_links(cost, cfg.unlinked_cost_m):
            assigned[g] = open_chains[j]

    def _fits(self, c: int, head: dict[int, np.ndarray]) -> bool:
        """A tracklet's ``head`` distances fit identity ``c``'s memory (a link by distances, not by extrapolation
        alone): one attached identity at least seen at both ends, weighted mean change under ``shape_gate_m``."""
        pairs = _comparable(self.memory[c], head, c, self.cfg)
        return bool(pairs) and _shape_misfit(pairs) < self.cfg.shape_gate_m

    def _usurped(self, start: int, head: dict[int, np.ndarray], extrapolated: bool = False) -> int | None:
        """The identity a tracklet starting at ``start`` takes back, if any: one re-linked after a gap within
        ``shape_max`` frames to a continuation whose distances changed by ``usurp_margin_m`` more than this
        tracklet's ``head`` distances differ from the identity's before the gap (and those by less than
        ``shape_gate_m``), or whose distances could not be compared. A newcomer next to a marker that had just
        vanished took its identity (a hand marker 5 cm from a hidden forearm marker at 60 Hz), or one far from it
        through the tracker's widened re-identification radius. A tracklet the extrapolation already linked
        (``extrapolated``) takes back only an identity whose distances fit within ``usurp_extrapolated_m`` and whose
        continuation was still seen the frame before (another marker, then, than this one)."""
        cfg = self.cfg
        best, best_change = None, np.inf
        for c, (_, before, continued, frame) in self.junction.items():
            if start - frame > self.shape_max:
                continue
            pairs = _comparable(before, head, c, cfg)
            if len(pairs) < cfg.shape_min:
                continue
            change = _shape_misfit(pairs)
            if extrapolated and (change >= cfg.usurp_extrapolated_m or self.ends[c][0] < start - 1):
                continue
            if change < cfg.shape_gate_m and change + cfg.usurp_margin_m < continued and change < best_change:
                best, best_change = c, change
        return best

    def _take_back(self, c: int) -> None:
        """Identity ``c``'s continuation after its last junction becomes an identity of its own (a newcomer),
        and ``c`` is left as it was before the junction."""
        piece, before, _, _ = self.junction.pop(c)
        n = len(self.chains)
        self.chains.append(self.chains[c][piece:])
        del self.chains[c][piece:]
        self.ends.append(self.ends[c])
        moved = np.concatenate(self.chains[n])
        self.owner[moved[:, 0], moved[:, 1]] = n
        self.memory.append(self.memory[c])
        for other in self.memory[n]:
            self.memory[other][n] = self.memory[other].pop(c)
        self.memory[c] = dict(before)
        for other, d in before.items():
            self.memory[other][c] = d

    def _assign_cluster(self, start: int, group: list[np.ndarray], heads: list[dict], open_chains: list[int],
                        assigned: dict[int, int], refused: set[tuple[int, int]]) -> None:
        """Tracklets starting together and attached to each other (a cluster back in view) are assigned jointly.

        Every injective assignment of the cluster to identities ended within ``shape_max`` frames is scored by
        the change of all the distances it makes comparable (to identities in view, and within the cluster);
        the best is taken, in place of ``assigned``'s, when every member has one of them at least, the cluster
        as many as it has members, every member's changed less than ``shape_gate_m``, and it is clearly better
        than the Hungarian's (or that one could not be scored).
        """
        cfg, P, memory = self.cfg, self.P, self.memory
        n = len(group)
        if n < 2:
            return
        # Distances between the cluster's tracklets over their first common frames.
        within: dict[tuple[int, int], float] = {}  # median distance, m
        for a in range(n):
            for b in range(a + 1, n):
                fa = group[a][: cfg.shape_window]
                fb = group[b][: cfg.shape_window]
                common = np.intersect1d(fa[:, 0], fb[:, 0])
                if common.size < 3:
                    continue
                v = np.linalg.norm(P[common, fa[0, 1]] - P[common, fb[0, 1]], axis=1)
                middle = quick_median(v)
                if middle < cfg.shape_radius_m and _steady(v, cfg):
                    within[a, b] = within[b, a] = middle
        members = sorted({a for a, _ in within})
        chains = [c for c in open_chains if start - self.ends[c][0] <= self.shape_max and self._attached(c)]
        if len(members) < 2 or len(members) > 6 or len(chains) < len(members):
            return
        if math.perm(len(chains), len(members)) > 20000:
            return

        outside: dict[tuple[int, int], list[tuple[float, float]]] = {}  # (member, chain) -> its comparable pairs
        held: dict[tuple[int, int], float | None] = {}  # (chain, chain) -> recent distance where steady

        def recent_if_steady(c: int, d: int) -> float | None:
            if (c, d) not in held:
                held[c, d] = _recent(memory[c][d], cfg) if _steady(memory[c].get(d), cfg) else None
            return held[c, d]

        def score(choice: tuple[int, ...]) -> float:
            total, relations = 0.0, 0.0
            for k, g in enumerate(members):
                c = choice[k]
                if (g, c) in refused:
                    return np.inf
                if (g, c) not in outside:  # (the same whatever the other members are given)
                    outside[g, c] = _comparable(memory[c], heads[g], c, cfg)
                pairs = list(outside[g, c])
                relations += len(pairs)
                inside = [(then, within[g, h]) for m, h in enumerate(members)
                          if m != k and (g, h) in within and (then := recent_if_steady(c, choice[m])) is not None]
                relations += 0.5 * len(inside)
                pairs += inside
                if not pairs:
                    return np.inf
                change = _shape_misfit(pairs)
                if change >= cfg.shape_gate_m:
                    return np.inf
                total += change
            return total if relations >= len(members) else np.inf

        scored = [(score(choice), choice) for choice in itertools.permutations(chains, len(members))]
        best_score, best = min(scored, key=lambda sc: sc[0], default=(np.inf, None))
        if not np.isfinite(best_score):
            return
        # A near-symmetric cluster (an isosceles triangle of skin markers) fits its mirror image within noise: such
        # ties go to the choice the markers around the cluster stand towards as they stood before the gap.
        tied = [choice for value, choice in scored if value <= best_score + cfg.cluster_tie_m * len(members)]
        by_context = False
        if len(tied) > 1:
            context = np.array([self._context_change([group[g] for g in members], choice) for choice in tied])
            order = np.argsort(context)  # (NaN last)
            if np.isfinite(context).all() and context[order[1]] > context[order[0]] + cfg.context_margin_m:
                best, by_context = tied[int(order[0])], True
        current = tuple(assigned.get(g, -1) for g in members)
        if current == best:
            return
        if not by_context and -1 not in current and len(set(current)) == len(current) and all(
                c in chains for c in current):
            if score(current) <= best_score + cfg.cluster_margin_m * len(members):
                return
        for other, c in list(assigned.items()):
            if c in best and other not in members:
                del assigned[other]
        for g, c in zip(members, best, strict=True):
            assigned[g] = c

    def _assign_glimpses(self, start: int, group: list[np.ndarray], open_chains: list[int],
                         assigned: dict[int, int], changes: dict[tuple[int, int], float]) -> None:
        """A cluster glimpsed twice a short gap apart keeps its layout.

        Markers of a cluster seen in single frames (a forearm in glimpses, each too short for a velocity, moving 20
        mm a frame with its markers 47 mm apart) defeat the extrapolations. Tracklets starting here and identities
        ended together within ``max_gap`` frames, ``glimpse_members`` or more on each side within
        ``glimpse_reach_m`` of the other, are matched by the one common step that carries the ones onto the
        others: each injective matching is scored by the worst deviation of its steps from their mean; the best
        replaces the links made where it deviates less than ``glimpse_tol_m`` and every other matching deviates
        ``glimpse_ratio`` times as much plus ``glimpse_margin_m``, unless a link distances measured is in the way.
        Three markers or more: two can be carried onto two others of a parallelogram plate by one step.
        """
        cfg, P = self.cfg, self.P
        if len(group) < cfg.glimpse_members:
            return
        first = np.array([P[run[0, 0], run[0, 1]] for run in group])  # (n, 3)
        ended: dict[int, list[int]] = {}
        for c in open_chains:
            if start - self.ends[c][0] <= cfg.max_gap:
                ended.setdefault(self.ends[c][0], []).append(c)
        for chains in ended.values():
            last = np.array([self.ends[c][1] for c in chains])  # (k, 3)
            near = np.linalg.norm(first[:, None] - last[None], axis=2) < cfg.glimpse_reach_m  # (n, k)
            members, candidates = np.flatnonzero(near.any(axis=1)), np.flatnonzero(near.any(axis=0))
            if min(len(members), len(candidates)) < cfg.glimpse_members or max(len(members), len(candidates)) > 6:
                continue
            fits = []  # (worst deviation of a step from the common one m, tracklets, identities)
            for g_idx, c_idx in _injections(members, candidates):
                step = first[g_idx] - last[c_idx]  # (m, 3)
                if (np.linalg.norm(step, axis=1) < cfg.glimpse_reach_m).all():
                    fits.append((float(np.linalg.norm(step - step.mean(axis=0), axis=1).max()), g_idx, c_idx))
            if not fits:
                continue
            fits.sort(key=lambda fit: fit[0])
            best = fits[0][0]
            if best >= cfg.glimpse_tol_m or (len(fits) > 1 and fits[1][0] <= cfg.glimpse_ratio * best
                                             + cfg.glimpse_margin_m):
                continue
            want = {int(g): chains[c] for g, c in zip(fits[0][1], fits[0][2], strict=True)}
            if any((g, assigned[g]) in changes for g in want if g in assigned):
                continue
            for other, c in list(assigned.items()):
                if c in want.values() and other not in want:
                    del assigned[other]
            assigned.update(want)

    def _profile(self, samples: np.ndarray, skip: set[int]) -> dict[int, float]:
        """Median distance, m, from a tracklet's samples (n, 2) (frame, column) to each identity seen with them
        within ``context_reach_m`` (the identities in ``skip`` left out)."""
        frames, cols = samples[:, 0], samples[:, 1]
        d = np.linalg.norm(self.P[frames] - self.P[frames, cols][:, None, :], axis=2)  # (n, M)
        own = self.owner[frames]
        out = {}
        for other in np.unique(own[own >= 0]).tolist():
            if other not in skip and (middle := quick_median(d[own == other])) < self.cfg.context_reach_m:
                out[other] = middle
        return out

    def _context_change(self, runs: list[np.ndarray], choice: tuple[int, ...]) -> float:
        """How the identities around a cluster stand towards its tracklets ``runs`` (first ``shape_history_s``) and
        towards the identities ``choice`` they would continue (last ``shape_history_s`` before the gap): the mean
        change of each neighbour's distances to the members (:func:`mocap.reunite.centred_change`), m; NaN where no
        neighbour is measured at every member on both sides."""
        then = [self._profile(np.concatenate(self.chains[c])[-self.history:], set(choice)) for c in choice]
        now = [self._profile(run[: self.history], set(choice)) for run in runs]
        common = sorted(set.intersection(*(set(p) for p in then + now)))
        if not common:
            return np.nan
        return centred_change(np.array([[p[o] for o in common] for p in then]),  # (members, neighbours)
                              np.array([[p[o] for o in common] for p in now]))


def _injections(rows: np.ndarray, cols: np.ndarray) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Every one-to-one matching of the smaller of ``rows`` and ``cols`` into the other: (row, column) index arrays of
    equal length."""
    if len(rows) <= len(cols):
        for perm in itertools.permutations(cols.tolist(), len(rows)):
            yield rows, np.array(perm)
    else:
        for perm in itertools.permutations(rows.tolist(), len(cols)):
            yield np.array(perm), cols


def withdraw_scattered(traj: Trajectories, config: RelabelConfig | None = None) -> int:
    """Empty, in place, the identity columns left without a run of ``confirm_frames`` consecutive samples and with
    fewer than twice that many samples in all: single samples the passes cut off from other markers' tracks (a hop
    inside a cluster) and gathered under an identity of their own, where each costs two identity switches. A
    marker seen only every other frame keeps its identity (it has many samples). Returns the columns emptied."""
    cfg = config or RelabelConfig()
    seen = np.isfinite(traj.positions[..., 0])
    edges = np.diff(seen.astype(np.int8), axis=0, prepend=0, append=0)  # (F + 1, M): +1 run starts, -1 run ends
    withdrawn = 0
    for col in np.flatnonzero(seen.any(axis=0) & (seen.sum(axis=0) < 2 * cfg.confirm_frames)):
        starts, ends = np.flatnonzero(edges[:, col] == 1), np.flatnonzero(edges[:, col] == -1)
        if (ends - starts).max() < cfg.confirm_frames:
            traj.positions[:, col] = np.nan
            traj.residuals[:, col] = np.nan
            traj.camera_masks[:, col] = 0
            withdrawn += 1
    return withdrawn


def repair_identities(traj: Trajectories, config: RelabelConfig | None = None,
                      unconfirmed: UnconfirmedPoints | None = None) -> RelabelStats:
    """Duplicates dropped (:func:`drop_duplicates`), swap repair, fragment stitching, exchanges undone where two
    markers passed close (:mod:`mocap.exchange`), bursts of hops unscrambled (:mod:`mocap.scramble`), the reunion
    of rigid clusters back after a long absence (:mod:`mocap.reunite`), then the labelling of rigid plates by their
    shape (:mod:`mocap.plates`), fragments rejoined by their distances to rigid neighbours and samples moved to the
    identity whose neighbours they fit (:mod:`mocap.anchors`, in turns: ``ANCHOR_ROUNDS`` at most), skin-mounted
    clusters reunited where their neighbours tell a symmetric shape's markers apart (:data:`SKIN_CLUSTERS`), the
    fill from unconfirmed points (:mod:`mocap.fill`), the bridging of gaps by where the neighbours carry a
    marker (:mod:`mocap.bridge`), two markers' identities given back where they came back from a shared gap each
    under the other's (:mod:`mocap.gap_exchange`), the exchanges between a skin-mounted cluster's identities undone
    by the references both keep (:mod:`mocap.skin`), fragments rejoined by anchors once more (the identity a
    fragment fits may have held another marker over its frames until those passes gave it back), where hops are
    clear (:meth:`RelabelConfig.hops_clear`), single samples that hopped off their identity's path given to the
    identity whose path they lie on, samples off their identity's own path withheld and glimpses at the ends of an
    identity's runs given to the identity whose path they continue (:mod:`mocap.offpath`),
    the identities of one marker that take turns or follow each other merged (:mod:`mocap.alternate`), and identities
    that ended joined to later ones their rigid neighbours carry them to (:mod:`mocap.orphans`), in place; empty
    identity columns are dropped.
    ``unconfirmed``: the tracker's points without identity (:meth:`mocap.tracker.Tracker.unconfirmed`), which the
    plate labelling and the fill may give one.

    Labels of the remaining identities are renumbered ``M001``, ``M002`` ... in column order.
    """
    stats = RelabelStats()
    if traj.n_markers == 0 or traj.n_frames < 4:
        return stats
    stats.duplicates = drop_duplicates(traj, config)
    stats.swaps = repair_swaps(traj, config)
    stats.stitches = relink_tracklets(traj, config)
    stats.exchanges = undo_exchanges(traj)
    limits = config or RelabelConfig()
    jump = limits.jump_acc(traj.fps)
    stats.unscrambled = unscramble_bursts(traj, jump)
    stats.reunited = reunite_clusters(traj)
    stats.plate_samples = label_plates(traj, extra=unconfirmed, jump_acc=jump)
    stats.rejoined = rejoin_by_anchors(traj)
    for _ in range(ANCHOR_ROUNDS):  # a move can make two fragments of one marker joinable, and a join new moves
        moved = move_refuted_samples(traj, jump_acc=jump)
        if moved == 0:
            break
        stats.anchor_moves += moved
        stats.rejoined += rejoin_by_anchors(traj)
    stats.reunited += reunite_clusters(traj, SKIN_CLUSTERS)
    if unconfirmed is not None:
        stats.filled = fill_from_unconfirmed(traj, unconfirmed)
    stats.bridged = bridge_gaps(traj, jump_acc=jump, reversal_acc=limits.reversal_acc(traj.fps))
    stats.gap_exchanges = undo_gap_exchanges(traj, jump_acc=jump, reversal_acc=limits.reversal_acc(traj.fps))
    # (widened only where a body's own accelerations reach the jump threshold, 50 Hz: there a swing hides the arm's
    # markers in turn for tenths of a second; at 100 Hz and more no capture changed)
    stats.junctions = undo_junctions(traj, jump_acc=jump, reversal_acc=limits.reversal_acc(traj.fps),
                                     widen=not limits.hops_clear(traj.fps))
    stats.skin_exchanges = undo_skin_exchanges(traj, jump_acc=jump, reversal_acc=limits.reversal_acc(traj.fps))
    # (a fragment whose identity held another marker over its frames, which the passes since gave back, can join
    # it now)
    stats.rejoined += rejoin_by_anchors(traj)
    if limits.hops_clear(traj.fps):  # (at 50 Hz a swing's own samples leave any smooth path through their neighbours)
        stats.off_path = withhold_off_path(traj)
        stats.hops_given = give_hops_back(traj)  # (a hop withheld above can leave the gap another hop fills)
        stats.hops_given += give_end_hops_back(traj)
    stats.merged = merge_alternating(traj)
    stats.orphans = rejoin_orphans(traj)
    stats.withdrawn = withdraw_scattered(traj, limits)
    if (stats.reunited or stats.rejoined or stats.plate_samples or stats.anchor_moves or stats.bridged
            or stats.junctions or stats.hops_given or stats.off_path or stats.merged or stats.orphans
            or stats.withdrawn):
        traj.drop_empty()  # (the re-linked identities are named M001 ... already: only a drop renames them)
    return stats
