"""Gaps in every view bridged by where the neighbours carry the hidden marker (:mod:`mocap.bridge`)."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.bridge import BridgeConfig, bridge_gaps, carried_miss
from mocap.relabel import RelabelConfig
from mocap.trajectories import Trajectories

FPS = 50.0


def _swinging_arm(seed: int, frames: int = 200) -> np.ndarray:
    """(F, 10, 3) m: ten markers of a forearm-sized cluster (within 0.15 m) turning half a turn a second about a
    moving, tilting axis and sliding 1.5 m/s, at 50 Hz, with 0.5 mm of skin noise: between two frames 0.4 s apart
    every marker has moved 0.3-0.7 m and its neighbours have turned 70 degrees."""
    rng = np.random.default_rng(seed)
    local = rng.normal(scale=0.06, size=(10, 3))
    t = np.arange(frames) / FPS
    angle = np.pi * t
    tilt = 0.4 * np.sin(2.0 * t)
    c, s, ct, st = np.cos(angle), np.sin(angle), np.cos(tilt), np.sin(tilt)
    R = np.zeros((frames, 3, 3))  # about z by angle, then about x by tilt
    R[:, 0, 0], R[:, 0, 1] = c, -s
    R[:, 1, 0], R[:, 1, 1], R[:, 1, 2] = ct * s, ct * c, -st
    R[:, 2, 0], R[:, 2, 1], R[:, 2, 2] = st * s, st * c, ct
    centre = np.stack([1.5 * t, 0.3 * np.sin(3.0 * t), 1.0 + 0.2 * t], axis=1)
    return np.einsum("fij,mj->fmi", R, local) + centre[:, None] + rng.normal(scale=0.0005, size=(frames, 10, 3))


def _trajectories(columns: list[list[tuple[int, int, int]]], truth: np.ndarray) -> Trajectories:
    """Identities made of pieces (marker, first, last) of ``truth`` (F, M, 3)."""
    F = len(truth)
    P = np.full((F, len(columns), 3), np.nan)
    for k, pieces in enumerate(columns):
        for m, first, last in pieces:
            P[first:last + 1, k] = truth[first:last + 1, m]
    seen = np.isfinite(P[..., 0])
    return Trajectories([f"M{k}" for k in range(len(columns))], FPS, P, np.where(seen, 0.1, np.nan),
                        seen.astype(np.uint32))


def _columns_of(traj: Trajectories, truth: np.ndarray) -> list[set[int]]:
    """Per truth marker, the identity columns holding its samples."""
    out = []
    for m in range(truth.shape[1]):
        d = np.linalg.norm(traj.positions - truth[:, m:m + 1], axis=2)
        out.append(set(np.flatnonzero((d < 1e-9).any(axis=0)).tolist()))
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_two_markers_hidden_from_every_view_get_their_identities_back(seed):
    """Markers 0 and 1 are hidden for 0.4 s; the identities made marker 1's return continue marker 0 and
    marker 0's return a new identity (a lost identity re-identified a marker that came back near it). The
    neighbours' motion links each piece to its own marker: one identity per marker."""
    truth = _swinging_arm(seed)
    columns = [[(0, 0, 99), (1, 126, 199)], [(1, 0, 104)]] + [[(m, 0, 199)] for m in range(2, 10)] + [[(0, 120, 199)]]
    traj = _trajectories(columns, truth)
    jump = np.linalg.norm(truth[120, 0] - truth[99, 0])
    assert jump > 0.3  # far beyond where a prediction of the marker itself would look
    before = _columns_of(traj, truth)
    assert before[0] == {0, 10} and before[1] == {0, 1}
    made = bridge_gaps(traj)
    assert made == 2
    after = _columns_of(traj, truth)
    assert all(len(c) == 1 for c in after) and len(set().union(*after)) == 10  # one identity per marker
    kept = np.isfinite(traj.positions[..., 0]).sum()
    assert kept == np.isfinite(_trajectories(columns, truth).positions[..., 0]).sum()  # no sample lost or made


def test_the_carried_prediction_is_millimetres_off_for_the_marker_and_far_for_another():
    truth = _swinging_arm(3)
    cfg = BridgeConfig()
    P = _trajectories([[(m, 0, 99), (m, 120, 199)] for m in range(10)], truth).positions
    own = carried_miss(P, np.array([0, 0, 99]), np.array([0, 120, 199]), cfg)
    other = carried_miss(P, np.array([0, 0, 99]), np.array([1, 120, 199]), cfg)
    assert own < 0.005 and other > 0.03
    assert np.isnan(carried_miss(P[:, :3], np.array([0, 0, 99]), np.array([0, 120, 199]), cfg))  # 2 neighbours


def test_neighbours_that_do_not_carry_the_marker_measure_no_miss():
    """Marker 0 swings 0.15 m about the cluster's centre on a path of its own (a hand pushing a rim past the
    forearm's markers): no combination of the others' offsets gives its last 15 frames (0.15 m RMS off), so its
    prediction across the gap is not measured, where it would have been a number to link by."""
    truth = _swinging_arm(3)
    t = np.arange(len(truth)) / FPS
    truth[:, 0] = truth[:, 1:].mean(axis=1) + 0.15 * np.stack([np.sin(7 * t), np.cos(11 * t), np.sin(5 * t)], axis=1)
    P = _trajectories([[(m, 0, 99), (m, 120, 199)] for m in range(10)], truth).positions
    end, start = np.array([0, 0, 99]), np.array([0, 120, 199])
    assert np.isnan(carried_miss(P, end, start, BridgeConfig()))
    assert np.isfinite(carried_miss(P, end, start, BridgeConfig(fit_m=np.inf)))
    assert carried_miss(P, np.array([1, 0, 99]), np.array([1, 120, 199]), BridgeConfig()) < 0.005  # the others are


def test_links_without_evidence_stay_and_a_take_without_gaps_is_untouched():
    """A link the neighbours cannot judge (a piece of two samples) is kept; pieces too far apart in time are not
    linked; a take without gaps comes back unchanged."""
    truth = _swinging_arm(4)
    columns = [[(0, 0, 99), (0, 110, 111), (0, 130, 199)]] + [[(m, 0, 199)] for m in range(1, 10)]
    traj = _trajectories(columns, truth)
    original = traj.positions.copy()
    assert bridge_gaps(traj) == 0
    np.testing.assert_array_equal(traj.positions, original)
    far = _trajectories([[(0, 0, 29)]] + [[(m, 0, 199)] for m in range(1, 10)] + [[(0, 190, 199)]], truth)
    assert bridge_gaps(far, BridgeConfig(max_gap_s=1.0)) == 0  # 3.2 s apart
    assert bridge_gaps(far) == 0  # still over the default 3 s
    near = _trajectories([[(0, 0, 99)]] + [[(m, 0, 199)] for m in range(1, 10)] + [[(0, 150, 199)]], truth)
    assert bridge_gaps(near) == 1 and len(_columns_of(near, truth)[0]) == 1


def test_a_glimpse_of_another_marker_in_a_gap_does_not_hold_the_link():
    """Marker 0's identity, hidden for 0.5 s, took one sample of marker 5 in the gap (a one-frame glimpse the
    tracker gave the lost identity); marker 0 came back as a new identity. The one sample is measured too: the
    neighbours carry marker 0 far from it, so marker 0's pieces are linked and the glimpse goes back to a piece of
    its own."""
    truth = _swinging_arm(7)
    columns = ([[(0, 0, 99), (5, 110, 110)], [(0, 126, 199)], [(5, 0, 109), (5, 111, 199)]]
               + [[(m, 0, 199)] for m in (1, 2, 3, 4, 6, 7, 8, 9)])
    traj = _trajectories(columns, truth)
    assert _columns_of(traj, truth)[0] == {0, 1}
    assert bridge_gaps(traj) == 1
    after = _columns_of(traj, truth)
    assert len(after[0]) == 1 and not after[0] & after[5]


def test_a_link_over_a_long_gap_gives_way_to_the_link_the_neighbours_carry():
    """The identity of marker 0 went on, after 3.2 s, with another marker back from a long absence (the repair's
    distance rules join pieces that far apart); marker 0 came back after 0.4 s as a new identity. The long link is
    too long to search for but not to measure: the neighbours carry marker 0 to its own return, and the other
    marker keeps an identity of its own."""
    truth = _swinging_arm(5, frames=400)
    other = int(np.argmax(np.linalg.norm(truth[0] - truth[0, 0], axis=1)))  # the farthest marker from marker 0
    rest = [m for m in range(1, 10) if m != other]
    columns = [[(0, 0, 99), (other, 260, 399)], [(0, 120, 399)]] + [[(m, 0, 399)] for m in rest]
    traj = _trajectories(columns, truth)
    assert _columns_of(traj, truth)[0] == {0, 1}
    assert bridge_gaps(traj) == 1
    after = _columns_of(traj, truth)
    assert len(after[0]) == 1 and len(after[other]) == 1 and after[0] != after[other]


def test_an_identity_that_jumped_onto_another_marker_is_cut_there_and_both_markers_relinked():
    """Marker 0's identity jumped onto another marker, hidden for 0.2 s, when it came back (a hop, no gap); marker
    0 came back a frame later as a new identity. Cut at the jump (the repair's jump threshold), the pieces are
    linked by where the neighbours carry each marker; without the cut the mixed identity stays."""
    truth = _swinging_arm(6)
    other = int(np.argmax(np.linalg.norm(truth[0] - truth[0, 0], axis=1)))
    rest = [m for m in range(1, 10) if m != other]
    columns = [[(0, 0, 99), (other, 100, 199)], [(other, 0, 89)], [(0, 101, 199)]] + [[(m, 0, 199)] for m in rest]
    cfg = RelabelConfig()
    uncut = _trajectories(columns, truth)
    bridge_gaps(uncut)
    assert len(_columns_of(uncut, truth)[0]) == 2
    traj = _trajectories(columns, truth)
    assert bridge_gaps(traj, jump_acc=cfg.jump_acc(FPS), reversal_acc=cfg.reversal_acc(FPS)) == 2
    after = _columns_of(traj, truth)
    assert len(after[0]) == 1 and len(after[other]) == 1 and after[0] != after[other]


def test_a_short_piece_between_two_gaps_links_on_where_its_miss_is_clearly_the_best():
    """Marker 0 is seen for 6 frames between two gaps, and each of its three pieces holds an identity of its own.
    The 6-frame piece is too short for the full fit but long enough to link on: nothing else is a candidate."""
    truth = _swinging_arm(7)
    columns = [[(0, 0, 99)], [(0, 110, 115)], [(0, 130, 199)]] + [[(m, 0, 199)] for m in range(1, 10)]
    traj = _trajectories(columns, truth)
    assert bridge_gaps(traj) == 2
    assert len(_columns_of(traj, truth)[0]) == 1
    strict = _trajectories(columns, truth)
    assert bridge_gaps(strict, BridgeConfig(short_frames=10)) == 1  # only the long piece links on
    assert len(_columns_of(strict, truth)[0]) == 2


def test_a_marker_that_coasts_across_a_few_frames_keeps_its_link_whatever_its_neighbours_did():
    """At 120 Hz a wheelchair marker travelling 1 m/s is hidden for 4 frames while its four nearest neighbours (a
    pushing arm's) move 0.2 m sideways. Carried by them, the marker's return is 0.2 m off, and a newcomer 10 frames
    later is where they carry it. The marker's own path crosses the gap to the millimetre: its link stands and the
    newcomer stays an identity of its own."""
    fps, frames = 120.0, 80
    t = np.arange(frames) / fps
    marker = np.stack([t, np.zeros(frames), np.ones(frames)], axis=1)  # (F, 3)
    side = np.interp(np.arange(frames), [0, 30, 35, frames - 1], [0.0, 0.0, 0.2, 0.2])
    offsets = np.array([[0.1, 0.05, 0.0], [-0.05, 0.12, 0.03], [0.02, -0.1, 0.08], [0.0, 0.04, -0.15]])
    arm = marker[:, None] + offsets + side[:, None, None] * [0.0, 1.0, 0.0]
    newcomer = marker + [0.0, 0.21, 0.0]
    truth = np.concatenate([marker[:, None], arm, newcomer[:, None]], axis=1)  # (F, 6, 3)
    P = truth.copy()
    P[31:35, 0] = np.nan
    P[:40, 5] = np.nan
    traj = Trajectories([f"M{k}" for k in range(6)], fps, P.copy())
    assert bridge_gaps(traj) == 0
    np.testing.assert_array_equal(traj.positions, P)
