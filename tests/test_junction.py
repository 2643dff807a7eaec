"""Three markers whose identities the tracker rotated at a junction get theirs back."""

from __future__ import annotations

import numpy as np
from helpers_rigid import FRAMES, PLATE, moving

from mocap.junction import JunctionConfig, undo_junctions
from mocap.trajectories import Trajectories

# A hand: three markers 60-95 mm apart (0-2) and three more on its segment (3-5), all distances distinct.
HAND = np.array([[0.0, 0.0, 0.0], [0.06, 0.0, 0.0], [0.02, 0.09, 0.0], [0.15, 0.03, 0.02], [-0.08, 0.12, 0.05],
                 [0.05, -0.1, 0.15]])
JUMP_ACC = 0.02  # m/frame^2: the 60 mm step from marker 1 to marker 0 is a jump


def _junction_take(truth: np.ndarray, rotated: bool) -> Trajectories:
    """Identities 0 and 2 end at frame 300 and two new ones start: column 7 at 301, column 6 at 302. ``rotated``:
    identity 1 jumps onto marker 0 at 302, column 6 holds marker 1 and column 7 marker 2 (the tracker's rotation);
    else identity 1 keeps marker 1 and the new ones hold markers 0 and 2."""
    P = np.concatenate([truth, np.full((FRAMES, 2, 3), np.nan)], axis=1)
    P[300:, [0, 2]] = np.nan
    if rotated:
        P[302:, 1], P[302:, 6] = truth[302:, 0], truth[302:, 1]
    else:
        P[302:, 6] = truth[302:, 0]
    P[301:, 7] = truth[301:, 2]
    return Trajectories([f"M{k + 1:03d}" for k in range(8)], 100.0, P)


def test_three_identities_rotated_at_a_junction_get_their_markers_back():
    truth = moving(HAND, np.random.default_rng(5), 0.0)
    traj = _junction_take(truth, rotated=True)
    samples = np.isfinite(traj.positions[..., 0]).sum()
    assert undo_junctions(traj) == 0  # (without the jump rule identity 1 has no event: two members only)
    assert undo_junctions(traj, jump_acc=JUMP_ACC) == 1
    np.testing.assert_array_equal(traj.positions[302:, :6], truth[302:])
    np.testing.assert_array_equal(traj.positions[301, 7], truth[301, 2])  # (inside the junction: left)
    assert np.isfinite(traj.positions[..., 0]).sum() == samples  # no sample lost


def test_identities_ended_and_started_at_a_junction_are_joined():
    """Identity 1 keeps its marker; markers 0 and 2 come back under new identities (columns 6 and 7)."""
    truth = moving(HAND, np.random.default_rng(5), 0.0)
    traj = _junction_take(truth, rotated=False)
    assert undo_junctions(traj, jump_acc=JUMP_ACC) == 1
    np.testing.assert_array_equal(traj.positions[302:, :6], truth[302:])
    assert np.isnan(traj.positions[302:, 6:]).all()


def test_identities_the_tracker_kept_through_a_junction_are_left_alone():
    """The three hand markers hidden for a frame or two at once, each back under its own identity."""
    truth = moving(HAND, np.random.default_rng(5), 0.0)
    P = truth.copy()
    P[300:302, [0, 2]] = np.nan
    P[301, 1] = np.nan
    traj = Trajectories([f"M{k + 1:03d}" for k in range(6)], 100.0, P)
    assert undo_junctions(traj, jump_acc=JUMP_ACC) == 0
    np.testing.assert_array_equal(traj.positions, P)


def test_a_junction_no_matching_fits_is_left_alone():
    """From the junction on the segment's other markers (3-5) stand 20 mm farther out: the rotation back fits the
    hand's own distances only, 3 of 5 references off, and scores better than the tracker's links without fitting."""
    truth = moving(HAND, np.random.default_rng(5), 0.0)
    bent = truth.copy()
    bent[302:, 3:] += 0.02 * (truth[302:, 3:] - truth[302:, :1]) / np.linalg.norm(truth[302:, 3:] - truth[302:, :1],
                                                                                  axis=2, keepdims=True)
    assert undo_junctions(_junction_take(bent, rotated=True), jump_acc=JUMP_ACC) == 0
    loose = JunctionConfig(worst_fit=np.inf)
    assert undo_junctions(_junction_take(bent, rotated=True), loose, jump_acc=JUMP_ACC) == 1


def test_a_junction_s_exchange_stops_where_all_its_markers_are_hidden_for_a_window():
    """The hand is hidden for 1.5 s from frame 400 and comes back under the identities before the junction: what
    the other passes linked across that gap stays as it is."""
    truth = moving(HAND, np.random.default_rng(5), 0.0)
    traj = _junction_take(truth, rotated=True)
    traj.positions[400:550, [0, 1, 2, 6, 7]] = np.nan
    traj.positions[550:, :3] = truth[550:, :3]
    traj.positions[550:, 6:] = np.nan
    assert undo_junctions(traj, jump_acc=JUMP_ACC) == 1
    np.testing.assert_array_equal(traj.positions[302:400, :3], truth[302:400, :3])
    np.testing.assert_array_equal(traj.positions[550:, :3], truth[550:, :3])


def test_a_junction_whose_markers_hid_in_turn_before_it_is_widened_to_their_identities():
    """Markers 0 and 2 hid 0.2 s before the junction (their identities end at frame 280, outside its 0.1 s); at
    301-302 marker 2 comes back under a new identity, identity 1 jumps onto marker 0 and marker 1 goes on under
    another new one. The junction's own members (1, 6, 7) have one window before it: undecided; widened by the
    identities that ended 0.2 s before, every marker gets its identity back."""
    truth = moving(HAND, np.random.default_rng(5), 0.0)
    traj = _junction_take(truth, rotated=True)
    traj.positions[280:300, [0, 2]] = np.nan
    samples = np.isfinite(traj.positions[..., 0]).sum()
    assert undo_junctions(traj, JunctionConfig(widen_s=0.0), jump_acc=JUMP_ACC) == 0
    assert undo_junctions(traj, jump_acc=JUMP_ACC) == 1
    np.testing.assert_array_equal(traj.positions[302:, :6], truth[302:])
    assert np.isnan(traj.positions[302:, 6:]).all()
    assert np.isfinite(traj.positions[..., 0]).sum() == samples  # no sample lost


def test_a_widened_junction_makes_no_link_none_of_whose_references_fits():
    """The serve's 5 %-hidden seed 62: the forearm's identity ended at the follow-through by the hip, and the hip's
    marker, back 0.1 s later under its own identity, was the only identity the widened junction could join it to: the
    forearm's identity took the hip's marker, every reference off by the clip. Here marker 0 is hidden for good from
    frame 300 (markers 1 and 2 blink there), and a marker of another body 0.1 m beside comes back at 305: no link."""
    hand = moving(HAND, np.random.default_rng(5), 0.0)
    other = moving(PLATE + [0.1, 0.15, 0.0], np.random.default_rng(6), 0.1)  # (its own turn)
    P = np.concatenate([hand, other], axis=1)
    P[300:, 0] = np.nan
    P[300:302, 1] = np.nan
    P[301:303, 2] = np.nan
    P[200:305, 6] = np.nan
    traj = Trajectories([f"M{k + 1:03d}" for k in range(10)], 100.0, P.copy())
    assert undo_junctions(traj, jump_acc=JUMP_ACC) == 0
    np.testing.assert_array_equal(traj.positions, P)
