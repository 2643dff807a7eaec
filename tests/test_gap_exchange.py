"""Two markers that came back from a shared gap each under the other's identity are given theirs back."""

from __future__ import annotations

import numpy as np

from mocap.gap_exchange import GapExchangeConfig, undo_gap_exchanges
from mocap.trajectories import Trajectories

FPS = 100.0


def _segment(layout: np.ndarray, n_frames: int = 700, noise_m: float = 0.0003) -> np.ndarray:
    """(F, M, 3) markers of one segment (``layout`` (M, 3) or (F, M, 3) m in its frame) that turns about z and walks
    along x, with seeded noise, m."""
    layout = np.broadcast_to(layout, (n_frames, *layout.shape[-2:]))
    t = np.arange(n_frames) / FPS
    angle = 0.6 * np.sin(2 * np.pi * 0.4 * t)
    c, s, zero = np.cos(angle), np.sin(angle), np.zeros_like(angle)
    R = np.stack([np.stack([c, -s, zero], -1), np.stack([s, c, zero], -1), np.stack([zero, zero, zero + 1], -1)],
                 axis=1)  # (F, 3, 3)
    centre = np.stack([1.2 * t, 0.1 * np.sin(2 * np.pi * 0.9 * t), 0.5 + 0.02 * np.sin(2 * np.pi * 1.8 * t)], axis=1)
    rng = np.random.default_rng(3)
    return centre[:, None] + np.einsum("fij,fmj->fmi", R, layout) + rng.normal(0, noise_m, layout.shape)


# A shank: the two markers 36 mm apart (0, 1) and four more (2-5); their distances to 0 and 1 differ by 10-30 mm.
SHANK = np.array([[0.0, 0.0, 0.0], [0.0, 0.036, 0.0], [0.17, 0.02, 0.05], [0.12, -0.09, 0.03],
                  [-0.05, 0.1, -0.12], [0.02, -0.05, 0.2]])


def _exchanged_take(truth: np.ndarray, hidden0: tuple[int, int], hidden1: tuple[int, int], back: int,
                    piece: tuple[int, int] | None = None) -> Trajectories:
    """Identities 0 and 1 hold markers 0 and 1, both hidden over the frame ranges ``hidden0`` / ``hidden1``; from
    frame ``back`` on each holds the other's marker (identity 1 also its own marker over ``piece``, inside its
    gap). The others hold their own throughout."""
    P = truth.copy()
    P[hidden0[0]:hidden0[1], 0] = np.nan
    P[hidden1[0]:hidden1[1], 1] = np.nan
    if piece is not None:
        P[piece[0]:piece[1], 1] = truth[piece[0]:piece[1], 1]
    P[back:, [0, 1]] = P[back:, [1, 0]]
    return Trajectories([f"M{k + 1:03d}" for k in range(truth.shape[1])], FPS, P)


def test_two_markers_back_from_a_shared_gap_each_under_the_other_s_identity_get_theirs_back():
    truth = _segment(SHANK)
    traj = _exchanged_take(truth, (300, 362), (300, 362), 362)
    assert undo_gap_exchanges(traj) == 1
    seen = np.isfinite(traj.positions[..., 0])
    np.testing.assert_array_equal(traj.positions[seen], truth[seen])
    assert seen.sum() == truth.shape[0] * truth.shape[1] - 2 * 62  # no sample lost


def test_identities_right_across_a_shared_gap_are_left_alone():
    truth = _segment(SHANK)
    traj = _exchanged_take(truth, (300, 362), (310, 350), 700)  # (no exchange: "back" past the end)
    before = traj.positions.copy()
    assert undo_gap_exchanges(traj) == 0
    np.testing.assert_array_equal(traj.positions, before)


def test_distances_that_differ_by_less_than_a_millimetre_are_not_evidence():
    """Markers 0 and 1, 36 mm apart, with neighbours near the plane between them: each neighbour's distances to the
    two differ by 0.6-1.3 mm, under the spread a distance is scored with (1.5 mm)."""
    near_plane = np.array([[0.15, 0.003, 0.0], [-0.1, 0.004, 0.05], [0.05, 0.003, 0.18], [0.0, 0.003, -0.14]])
    truth = _segment(np.concatenate([[[0.0, 0.018, 0.0], [0.0, -0.018, 0.0]], near_plane]))
    traj = _exchanged_take(truth, (300, 362), (300, 362), 362)
    assert undo_gap_exchanges(traj) == 0


def test_a_segment_that_bent_in_the_gap_is_not_relabelled_by_one_neighbour_that_fits_the_exchange():
    """Over the gap neighbours 2 and 4-7 move a quarter farther out (no distance fits either way) and neighbour 3
    moves to its mirror image across the plane between markers 0 and 1 (its distances, 23 mm apart, fit the
    exchange): one neighbour of six is not enough."""
    layout = np.concatenate([SHANK, [[-0.08, -0.06, 0.1], [0.1, 0.1, -0.05]]])
    middle = np.array([0.0, 0.018, 0.0])
    bent = layout.copy()
    bent[[2, 4, 5, 6, 7]] = middle + 1.25 * (layout[[2, 4, 5, 6, 7]] - middle)
    bent[3, 1] = 2 * middle[1] - layout[3, 1]
    truth = _segment(np.where(np.arange(700)[:, None, None] < 331, layout, bent))
    traj = _exchanged_take(truth, (300, 362), (300, 362), 700)
    assert undo_gap_exchanges(traj) == 0


def test_a_short_piece_of_a_marker_between_two_shared_gaps_stays_with_its_identity():
    """Identity 1 holds its own marker for 7 frames inside the gap; the exchange starts after that piece."""
    truth = _segment(SHANK)
    traj = _exchanged_take(truth, (300, 355), (300, 362), 355, piece=(320, 327))
    assert undo_gap_exchanges(traj) == 1
    seen = np.isfinite(traj.positions[..., 0])
    np.testing.assert_array_equal(traj.positions[seen], truth[seen])
    assert seen[320:327, 1].all()


def test_a_marker_back_under_the_identity_of_a_neighbour_whose_own_ended_returns_to_its_own():
    """Marker 0's identity ends where both markers are hidden; marker 1's identity comes back holding marker 0, and
    marker 1 comes back under a new identity (column 6). Marker 0's samples after the gap go back to its own."""
    truth = _segment(SHANK)
    P = np.concatenate([truth, np.full((len(truth), 1, 3), np.nan)], axis=1)
    P[300:, 0] = np.nan
    P[300:362, 1] = np.nan
    P[362:, 1], P[362:, 6] = truth[362:, 0], truth[362:, 1]
    traj = Trajectories([f"M{k + 1:03d}" for k in range(7)], FPS, P)
    assert undo_gap_exchanges(traj) == 1
    np.testing.assert_array_equal(traj.positions[362:, 0], truth[362:, 0])
    assert np.isnan(traj.positions[300:, 1]).all()


def test_two_markers_exchanged_between_consecutive_frames_by_a_jump_get_theirs_back():
    """No gap: from frame 362 each identity holds the other's marker (a 36 mm step, a jump at 20 mm/frame^2)."""
    truth = _segment(SHANK)
    traj = _exchanged_take(truth, (0, 0), (0, 0), 362)
    assert undo_gap_exchanges(traj) == 0  # (gaps only)
    assert undo_gap_exchanges(traj, jump_acc=0.02) == 1
    np.testing.assert_array_equal(traj.positions, truth)


def test_a_marker_taken_in_a_one_frame_gap_by_a_neighbour_that_jolted_gets_its_identity_back():
    """Marker 1's identity misses frame 362; there identity 0 steps onto marker 1 (36 mm: an acceleration of 36
    mm/frame^2, under this scene's jump threshold of 40, as a 50 Hz swing's own acceleration hides such a hop) and
    from 363 identity 1 holds marker 0: no shared gap, no jump. The short gap beside a neighbour that accelerated
    over 0.8 of the threshold makes them a pair (the serve's 5 %-hidden seed 34: RELB and RFRM at frame 204, IDF1
    0.9770 -> 0.9869)."""
    truth = _segment(SHANK)
    P = truth.copy()
    P[362:, [0, 1]] = truth[362:, [1, 0]]
    P[362, 1] = np.nan
    traj = Trajectories([f"M{k + 1:03d}" for k in range(truth.shape[1])], FPS, P)
    assert undo_gap_exchanges(traj) == 0  # (gaps only)
    assert undo_gap_exchanges(traj, GapExchangeConfig(beside_jolt=1.0), jump_acc=0.04) == 0
    assert undo_gap_exchanges(traj, jump_acc=0.04) == 1
    seen = np.isfinite(traj.positions[..., 0])
    np.testing.assert_array_equal(traj.positions[seen], truth[seen])
    assert seen.sum() == truth.size // 3 - 1


def test_a_marker_taken_by_a_far_identity_that_jumped_to_it_returns_to_its_own_ended_identity():
    """Marker 0's identity ends at frame 300 (marker 0 hidden to 339); at 340 marker 6, 0.6 m away on the same body
    with its own neighbours 7 and 8, is hidden and its identity jumps onto marker 0. The two were never seen near
    each other: the jump, with marker 0's identity in its gap, makes them a pair."""
    far = np.array([[0.6, 0.0, 0.0], [0.65, 0.05, 0.02], [0.58, -0.06, 0.05]])
    truth = _segment(np.concatenate([SHANK, far]))
    P = truth.copy()
    P[300:, 0] = np.nan
    P[340:, 6] = truth[340:, 0]
    traj = Trajectories([f"M{k + 1:03d}" for k in range(truth.shape[1])], FPS, P)
    assert undo_gap_exchanges(traj) == 0  # (gaps only)
    assert undo_gap_exchanges(traj, jump_acc=0.02) == 1
    np.testing.assert_array_equal(traj.positions[340:, 0], truth[340:, 0])
    assert np.isnan(traj.positions[340:, 6]).all() and np.isnan(traj.positions[300:340, 0]).all()


def test_two_markers_0_6_m_apart_back_from_a_shared_gap_exchanged_get_theirs_back():
    """A wrist and a shoulder marker 0.6 m apart (as a 50 Hz serving arm's, which moves a metre in a gap), each with
    its own neighbours, both hidden over frames 300-329 and back each under the other's identity."""
    far = np.array([[0.6, 0.0, 0.0], [0.65, 0.05, 0.02], [0.58, -0.06, 0.05]])
    truth = _segment(np.concatenate([SHANK, far]))
    P = truth.copy()
    P[300:330, [0, 6]] = np.nan
    P[330:, [0, 6]] = P[330:, [6, 0]]
    traj = Trajectories([f"M{k + 1:03d}" for k in range(truth.shape[1])], FPS, P)
    assert undo_gap_exchanges(traj) == 1
    seen = np.isfinite(traj.positions[..., 0])
    np.testing.assert_array_equal(traj.positions[seen], truth[seen])


def _wobbling(layout: np.ndarray, wobble: list[int], amplitude_m: float, n_frames: int = 700) -> np.ndarray:
    """(F, M, 3) layout (M, 3) m whose markers ``wobble`` (skin over a swinging arm) move to and from the first two
    markers' midpoint by ``amplitude_m`` at 2.3 Hz, each in its own phase."""
    t = np.arange(n_frames) / FPS
    out = np.repeat(layout[None], n_frames, axis=0)
    middle = layout[:2].mean(axis=0)
    for k, marker in enumerate(wobble):
        away = (layout[marker] - middle) / np.linalg.norm(layout[marker] - middle)
        out[:, marker] += amplitude_m * np.sin(2 * np.pi * 2.3 * t + 1.3 * k)[:, None] * away
    return out


def test_an_elbow_and_an_upper_arm_marker_exchanged_get_theirs_back_by_references_that_spread_a_centimetre():
    """Markers 0 and 1, 10 cm apart, whose neighbours (2-4) wobble by 10 mm (their distances spread 9-10 mm: none
    steady to 5 mm, as around a 50 Hz serving elbow), both hidden over frames 300-329 and back each under the
    other's identity. The loose references (15 mm) score them: their distances differ by centimetres."""
    arm = np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.12, 0.05, 0.0], [-0.1, 0.12, 0.03], [0.05, -0.12, 0.02]])
    truth = _segment(_wobbling(arm, [2, 3, 4], 0.01))
    traj = _exchanged_take(truth, (300, 330), (300, 330), 330)
    strict = GapExchangeConfig(loose_spread_m=0.005)
    assert undo_gap_exchanges(traj, strict) == 0
    assert undo_gap_exchanges(traj) == 1
    seen = np.isfinite(traj.positions[..., 0])
    np.testing.assert_array_equal(traj.positions[seen], truth[seen])


def test_loose_references_leave_identities_that_are_right_alone():
    arm = np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.12, 0.05, 0.0], [-0.1, 0.12, 0.03], [0.05, -0.12, 0.02]])
    truth = _segment(_wobbling(arm, [2, 3, 4], 0.01))
    traj = _exchanged_take(truth, (300, 330), (300, 330), 700)
    assert undo_gap_exchanges(traj) == 0
    np.testing.assert_array_equal(traj.positions, _exchanged_take(truth, (300, 330), (300, 330), 700).positions)
