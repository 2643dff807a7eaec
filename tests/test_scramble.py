"""Identities scrambled in a burst of hops get their markers back by the distances that held through it."""

from __future__ import annotations

import functools
import itertools
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.scramble import (
    ScrambleConfig,
    _choose,
    _hops,
    _range_terms,
    _rechecked,
    _rigid_terms,
    _steady,
    _Tables,
    _window_ranges,
    unscramble_bursts,
)
from tests.test_relabel import _traj

FPS = 50.0  # (the frame rate of tests.test_relabel._traj)
JUMP = 0.1  # m/frame^2: the repair's jump threshold at 50 Hz
UPPER = np.array([[0.0, 0.0, 0.0], [0.16, 0.0, 0.0], [0.26, 0.02, 0.0]])  # shoulder, upper arm, elbow; m
FORE = np.array([[0.0, 0.0, 0.0], [0.154, 0.0, 0.0], [0.1018, 0.0841, 0.0]])  # forearm, wrist bar A and B (scalene)


def _arm(frames: int = 100, seed: int = 0) -> np.ndarray:
    """(F, 6, 3) at 50 Hz: shoulder, upper arm, elbow, forearm and a wrist bar's two markers of an arm turning about
    the shoulder at 6 rad/s, the elbow opening from 90 to 10 degrees over frames 40-60; 0.3 mm noise."""
    t = np.arange(frames) / FPS
    arm = Rotation.from_rotvec(np.c_[np.zeros(frames), 0.3 * np.sin(2 * t), 6.0 * t])
    bend = np.deg2rad(90 - 80 * np.clip((np.arange(frames) - 40) / 20, 0, 1))
    fore = arm * Rotation.from_rotvec(np.c_[np.zeros(frames), np.zeros(frames), bend])
    shoulder = np.array([0.0, 0.0, 1.4])
    upper = np.einsum("fij,nj->fni", arm.as_matrix(), UPPER) + shoulder
    elbow = upper[:, 2] + arm.apply([0.04, 0.0, 0.0])
    forearm = np.einsum("fij,nj->fni", fore.as_matrix(), FORE + [0.05, 0.0, 0.0]) + elbow[:, None]
    P = np.concatenate([upper, forearm], axis=1)
    return P + np.random.default_rng(seed).normal(0, 0.0003, P.shape)


def _scrambled(P: np.ndarray, frame: int) -> np.ndarray:
    """``P`` with the upper arm's, the elbow's and the forearm's tails permuted in a cycle from ``frame`` on, as
    the tracker left them after the swing: the upper arm's identity on the forearm marker, the elbow's on the upper
    arm marker, the forearm's on the elbow marker."""
    seen = P.copy()
    seen[frame:, [1, 2, 3]] = P[frame:, [3, 1, 2]]
    return seen


def test_three_identities_permuted_in_a_swing_get_their_markers_back():
    """The three tails hop by 100-250 mm at frame 50 (accelerations far over the threshold); the wrist bar keeps
    150 and 130 mm to the forearm marker and the upper arm marker 100 mm to the elbow: only one permutation fits."""
    P = _arm()
    traj = _traj(_scrambled(P, 50))
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, P)



def test_hops_inside_a_burst_before_the_tails_were_permuted_are_settled_too():
    """The forearm's and the upper arm's identities exchange markers for frames 50-51 before the cycle of three from
    frame 52 (the two players at seed 1 had six switches inside such bursts). The tails go back from one frame of
    the burst; the frames before it are given to the identities whose paths through the burst (from their last two
    samples before it to their first two after) they lie on: every sample is its marker's again."""
    P = _arm()
    seen = P.copy()
    seen[50:52, [1, 3]] = P[50:52, [3, 1]]
    seen[52:, [1, 2, 3]] = P[52:, [3, 1, 2]]
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, P)

def test_an_arm_that_kept_its_identities_is_left_alone():
    P = _arm()
    traj = _traj(P)
    assert unscramble_bursts(traj, JUMP) == 0
    np.testing.assert_array_equal(traj.positions, P)


def test_a_pair_one_rigid_distance_cannot_tell_apart_is_told_by_the_loose_ones():
    """Without the shoulder and the wrist bar, the upper arm and elbow markers' one rigid distance reads the same both
    ways round: the permutations putting the forearm back tie. The one whose distances changed least in all (the
    forearm marker stays nearer the elbow's than the upper arm's) puts all three back; where that is not clear enough
    (a gap over the whole drift), the one moving the fewest identities wins: the forearm's identity gets its marker
    back and the upper arm pair keeps what the tracker gave it."""
    P = _arm()[:, 1:4]
    seen = _scrambled(np.concatenate([P[:, :1], P], axis=1), 50)[:, 1:]  # (the same cycle on these three)
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, P)
    unclear = _traj(seen)
    assert unscramble_bursts(unclear, JUMP, ScrambleConfig(drift_gap_m=1e3)) == 1
    np.testing.assert_array_equal(unclear.positions[:, 2], P[:, 2])
    np.testing.assert_array_equal(unclear.positions[50:, [0, 1]], P[50:, [1, 0]])
    strict = _traj(seen)
    assert unscramble_bursts(strict, JUMP, ScrambleConfig(margin_nats=1e3)) == 0
    np.testing.assert_array_equal(strict.positions, seen)


def test_loose_distances_a_few_millimetres_apart_do_not_decide():
    """A rigid pair (100 mm) and a marker wobbling 109-121 mm from it (not rigid), 3 mm nearer one end than the
    other: both ways round fit the pair, and the loose distances differ by too little to trust, so the fewest moves
    win."""
    frames = 100
    t = np.arange(frames) / FPS
    turn = Rotation.from_rotvec(np.c_[np.zeros(frames), np.zeros(frames), 5.0 * t])
    reach = 0.115 + 0.006 * np.sin(2 * np.pi * 3.1 * t)
    local = np.zeros((frames, 3, 3))
    local[:, 1, 0] = 0.1
    local[:, 2, 0] = 0.054  # 4 mm off the pair's middle: 3 mm nearer one end
    local[:, 2, 1] = reach
    P = np.einsum("fij,fnj->fni", turn.as_matrix(), local) + [0.0, 0.0, 1.0]
    P += np.random.default_rng(3).normal(0, 0.0003, P.shape)
    seen = P.copy()
    seen[50:] = P[50:, [2, 0, 1]]
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions[:, 2], P[:, 2])
    np.testing.assert_array_equal(traj.positions[50:, [0, 1]], P[50:, [1, 0]])


def test_a_burst_right_after_garbled_labels_is_left_alone():
    """The recording's labels garbled before a burst: the forearm's and the wrist bar's first marker exchanged for
    frames 40-49 after a 2-frame gap (no hop where it starts), then their own again. The window before the hop at 50
    is mostly the garbled labels, and alone it would 'put back' the exchange; the window ending 0.16 s earlier
    disagrees, so nothing moves."""
    P = _arm()
    seen = P.copy()
    seen[40:50, [3, 4]] = P[40:50, [4, 3]]
    seen[38:40, [3, 4]] = np.nan
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 0
    np.testing.assert_array_equal(traj.positions, seen)
    unchecked = _traj(seen)  # (the earlier window one frame back: the same witness)
    assert unscramble_bursts(unchecked, JUMP, ScrambleConfig(recheck_s=0.0)) == 1


def _single_tables(costs: np.ndarray) -> _Tables:
    """Score tables of g members scored by their own tails alone: ``costs`` (g, g) nats, no drift."""
    g = len(costs)
    return _Tables(np.stack([costs, np.zeros((g, g))]), np.zeros((2, g, g, g, g)), np.zeros((0, 2), dtype=np.intp))


def test_where_the_earlier_window_breaks_a_tie_of_the_window_before_its_choice_is_taken():
    """The two players at seed 71 (5 % hidden), Viktor's swing: the window before tells the arm's permutation (members
    0 and 1 exchange tails) but not members 2 and 3 (one of them held another marker in the frames between the two
    windows), so the fewest moves leave them; the window ending 0.16 s earlier tells them too (2 and 3 exchange).
    Both windows accept that permutation, so it is applied (the arm stayed scrambled before: IDF1 0.9869 -> 0.9988).
    Where the window before refutes the earlier window's choice, nothing is."""
    cfg = ScrambleConfig()
    swap = np.array([[0.0, -10.0, 0.0, 0.0], [-10.0, 0.0, 0.0, 0.0], [0.0] * 4, [0.0] * 4])
    before = _single_tables(swap)
    earlier_costs = swap.copy()
    earlier_costs[2, 3] = earlier_costs[3, 2] = -10.0
    earlier = _single_tables(earlier_costs)
    choice = _choose(before, cfg)
    np.testing.assert_array_equal(choice, [1, 0, 2, 3])
    np.testing.assert_array_equal(_rechecked(choice, before, earlier, cfg), [1, 0, 3, 2])
    np.testing.assert_array_equal(_rechecked(choice, before, before, cfg), choice)  # (the same witness agrees)
    refuting = swap.copy()
    refuting[2, 3] = refuting[3, 2] = 50.0
    assert _rechecked(_choose(_single_tables(refuting), cfg), _single_tables(refuting), earlier, cfg) is None


def test_a_fast_turn_without_a_hop_is_left_alone():
    """A finger marker turns round the wrist marker 110 mm away, its acceleration over the threshold (2.9 mm/frame^2
    against 2 in this scene, whose markers stay under 0.6 otherwise) but changing smoothly, under 1.5 mm/frame^2 from
    one frame to the next (the serve's finger: 110 mm/frame^2 against 100, changing by 72 at most): fast motion, no
    hop, both seen throughout. Two markers nearby that are in no burst (an elbow's and a forearm's) come back from a
    one-frame gap at 306 under each other's identities, and the finger's tail then happens to sit at the wrist's
    old distance to the elbow's identity (the serve's 5 %-hidden seed 34 exchanged RFIN and RWRB on this, IDF1
    0.9622). Nothing moves, also where a marker beside the wrist is first seen just after the turn (a newcomer the
    burst takes in: the serve's seed 41 shifted five arm identities by one marker in such a burst, IDF1 0.9753).
    Had the finger's identity hopped onto the wrist marker for two frames, its accelerations there would have changed
    by twice the hop."""
    frames = np.arange(400)
    t = frames / FPS
    late = 1 / (1 + np.exp(-(frames - 300) / 2.4))  # the turn, over frames 290-310
    theta = (np.pi / 2 + 0.4 * np.sin(3 * np.pi * t)) * (1 - late) + (0.1 + 0.05 * np.sin(3 * np.pi * t)) * late
    P = np.zeros((400, 5, 3))
    P[..., 2] = 1.0
    P[:, 0, 0] = 0.243 + 0.019 * np.sin(1.4 * np.pi * t)  # wrist
    P[:, 1, :2] = P[:, 0, :2] + 0.11 * np.c_[np.cos(theta), np.sin(theta)]  # finger
    P[:, 3, 0] = 0.12  # forearm (the elbow at the origin)
    P[:, 4] = P[:, 0] + np.array([0.0, -0.08, 0.03])  # beside the wrist
    P += np.random.default_rng(5).normal(0, 0.00005, P.shape)
    seen = P.copy()
    seen[306:, [2, 3]] = P[306:, [3, 2]]
    seen[306, [2, 3]] = np.nan
    for first_seen in (0, 306):  # the marker beside the wrist seen throughout; first seen after the turn
        newcomer = seen.copy()
        newcomer[:first_seen, 4] = np.nan
        traj = _traj(newcomer)
        assert unscramble_bursts(traj, 0.002) == 0
        np.testing.assert_array_equal(traj.positions, newcomer)
    assert _steady(seen, 297, 303, np.arange(2), 0.002).all()
    hopped = seen.copy()
    hopped[200:202, [0, 1]] = seen[200:202, [1, 0]]
    assert _hops(hopped, 0.002)[:, 0].min() == 199
    assert not _steady(hopped, 199, 202, np.arange(2), 0.002).any()


def test_markers_with_no_steady_distance_are_left_alone():
    """Three markers that move independently and hop between each other: no permutation is likelier than another."""
    t = np.arange(100)[:, None] / FPS
    rng = np.random.default_rng(1)
    P = 0.08 * np.sin(2 * np.pi * rng.uniform(0.5, 2.0, (1, 3, 3)) * t[..., None] + rng.uniform(0, 6, (1, 3, 3)))
    P += np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0], [0.0, 0.1, 1.0]])
    seen = P.copy()
    seen[50:] = P[50:, [2, 0, 1]]
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 0
    np.testing.assert_array_equal(traj.positions, seen)


def test_calm_bystanders_of_a_crowded_burst_are_left_out():
    """Four standing markers (a head's) within 0.2 m of the swing make ten identities, over a limit of nine: they did
    not move through the burst, so they are left out and the arm's six are put back."""
    P = _arm()
    rng = np.random.default_rng(2)
    head = P[50, 2] + np.array([[0.1, 0.0, 0.05], [0.0, 0.1, 0.05], [-0.1, 0.0, 0.05], [0.0, -0.1, 0.05]])
    head = np.broadcast_to(head, (len(P), 4, 3)) + rng.normal(0, 0.0003, (len(P), 4, 3))
    truth = np.concatenate([P, head], axis=1)
    seen = np.concatenate([_scrambled(P, 50), head], axis=1)
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP, ScrambleConfig(max_identities=9)) == 1
    np.testing.assert_array_equal(traj.positions, truth)
    crowded = _traj(seen)
    assert unscramble_bursts(crowded, JUMP, ScrambleConfig(max_identities=9, calm=0.0)) == 0


def test_a_burst_of_twelve_identities_is_put_back_and_one_over_the_limit_left_alone():
    """Two players' serve: after the swing the arm's identities and its neighbours' hop in one burst. Two arms, the
    second 0.7 times the first's size 0.15 m beside it, have all twelve tails shifted by one at frame 50; the search
    finds the one permutation fitting every rigid distance among the 12! and puts them back. With the limit at 11
    the burst is left as it is."""
    arm = _arm()
    other = _arm(seed=1)
    P = np.concatenate([arm, 0.7 * (other - other[:, :1]) + other[:, :1] + [0.0, 0.15, 0.0]], axis=1)
    seen = P.copy()
    seen[50:] = P[50:, np.roll(np.arange(12), 1)]
    traj = _traj(seen.copy())
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, P)
    limited = _traj(seen.copy())
    assert unscramble_bursts(limited, JUMP, ScrambleConfig(max_identities=11)) == 0
    np.testing.assert_array_equal(limited.positions, seen)


def test_a_distance_that_never_varied_scores_without_warnings():
    """Prior 1 (spread 0) and a tail far off made a likelihood ratio of 0: log(0) warned and scored infinity. The wrist
    bar's second marker here is an exact copy of the first 99 mm along x (no noise): the swing is put back as
    before, silently."""
    P = _arm()
    P[:, 5] = P[:, 4] + [0.099, 0.0, 0.0]
    traj = _traj(_scrambled(P, 50))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, P)


def test_a_marker_found_again_as_a_new_identity_after_the_burst_is_a_burst_identity():
    """Two players, seed 74: in the swing the forearm marker's and the wrist bar's second marker's tails exchange,
    and the bar's first marker is lost for 4 frames and comes back as another identity. Without it the burst's two
    identities keep one rigid distance between them, the same both ways round, and nothing moves; with the newcomer
    among the burst's identities (first seen 4 frames after the burst, next to its markers) the bar's distances put
    all three tails back: the newcomer's onto the lost marker's identity."""
    P = _arm()
    seen = np.concatenate([P, np.full((len(P), 1, 3), np.nan)], axis=1)
    seen[50:, [3, 5]] = P[50:, [5, 3]]
    seen[50:, 4] = np.nan
    seen[54:, 6] = P[54:, 4]
    expected = np.concatenate([P, np.full((len(P), 1, 3), np.nan)], axis=1)
    expected[50:54, 4] = np.nan
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, expected)
    alone = _traj(seen)  # (newcomers only up to 1 frame after the burst's gap: this one is not)
    assert unscramble_bursts(alone, JUMP, ScrambleConfig(newcomer_s=0.0)) == 0
    np.testing.assert_array_equal(alone.positions, seen)


def test_an_identity_that_ended_just_before_the_burst_takes_its_marker_back():
    """The wrist bar's first marker's identity ends 3 frames before a burst (its marker unseen for two frames), and
    in the burst the forearm marker's identity takes that marker and the bar's second marker's identity the forearm
    marker (the second marker unseen after it). The ended identity is not a burst identity by its hops or gaps; as a
    leaver it is, and the tails go back: the bar's first marker to its own identity, the forearm marker to its own;
    without it nothing moves."""
    P = _arm()
    seen = P.copy()
    seen[48:, 4] = np.nan
    seen[50:, 3] = P[50:, 4]
    seen[50:, 5] = P[50:, 3]
    expected = P.copy()
    expected[48:50, 4] = np.nan
    expected[50:, 5] = np.nan
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, expected)
    alone = _traj(seen)  # (leavers only up to 1 frame before the burst's last hop: this one is not)
    assert unscramble_bursts(alone, JUMP, ScrambleConfig(newcomer_s=0.0)) == 0
    np.testing.assert_array_equal(alone.positions, seen)


def test_an_identity_that_ended_before_a_long_burst_began_is_a_leaver():
    """As above, and 8 frames later, in the same burst, the shoulder's and the elbow's tails exchange too: the burst
    ends 10 frames after the ended identity was last seen, past ``newcomer_s`` (6 frames) from its last hop but not
    from its first. It is a leaver still, and every tail goes back, from the frame the burst's permutation is applied
    at (one frame for the whole burst: its last hop's)."""
    P = _arm()
    seen = P.copy()
    seen[48:, 4] = np.nan
    seen[50:, 3] = P[50:, 4]
    seen[50:, 5] = P[50:, 3]
    seen[58:, [0, 2]] = P[58:, [2, 0]]
    expected = P.copy()
    expected[48:50, 4] = np.nan
    expected[50:, 5] = np.nan
    traj = _traj(seen)
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions[58:], expected[58:])
    np.testing.assert_array_equal(traj.positions[:50], seen[:50])


def _skin_arm(frames: int = 500, seed: int = 0, wobble_m: float = 0.003) -> np.ndarray:
    """(F, 9, 3) at 50 Hz: three torso markers (the torso turning 0.4 rad either way every 4 s), an upper arm and an
    elbow marker (the arm lifting 0.3-1.5 rad every 3.1 s), a forearm marker, a wrist bar's two markers and a hand
    marker (the elbow bending 0.4-2.0 rad every 2.3 s): skin markers, each wobbling ``wobble_m`` on its segment at
    its own 0.4-1.5 Hz; 0.3 mm noise."""
    t = np.arange(frames) / FPS
    rng = np.random.default_rng(seed)
    torso_local = np.array([[0.0, 0.0, 0.0], [0.0, -0.18, -0.05], [-0.08, -0.09, -0.25]])  # the shoulder second
    upper_local = np.array([[0.0, 0.0, -0.12], [0.02, 0.0, -0.27]])
    fore_local = np.array([[0.0, 0.03, -0.10], [0.02, 0.0, -0.24], [-0.02, 0.0, -0.24], [0.0, 0.0, -0.33]])
    zeros = np.zeros(frames)
    turn = Rotation.from_rotvec(np.c_[zeros, zeros, 0.4 * np.sin(2 * np.pi * t / 4.0)])
    torso = np.einsum("fij,nj->fni", turn.as_matrix(), torso_local) + [0.0, 0.0, 1.4]
    arm = turn * Rotation.from_rotvec(np.c_[0.9 + 0.6 * np.sin(2 * np.pi * t / 3.1), zeros, zeros])
    upper = np.einsum("fij,nj->fni", arm.as_matrix(), upper_local) + torso[:, 1:2]
    elbow = torso[:, 1] + arm.apply([0.0, 0.0, -0.28])
    fore = arm * Rotation.from_rotvec(np.c_[1.2 + 0.8 * np.sin(2 * np.pi * t / 2.3 + 1.0), zeros, zeros])
    forearm = np.einsum("fij,nj->fni", fore.as_matrix(), fore_local) + elbow[:, None]
    P = np.concatenate([torso, upper, forearm], axis=1)
    freq, phase = rng.uniform(0.4, 1.5, (2, 1, P.shape[1], 3))
    P = P + wobble_m * np.sin(2 * np.pi * freq * t[:, None, None] + 4 * np.pi * phase)
    return P + rng.normal(0, 0.0003, P.shape)


def test_skin_markers_permuted_after_seconds_of_motion_get_their_markers_back_by_their_ranges():
    """The two players' swing, 5 % of the views hidden: an arm's skin markers (3 mm wobble: never rigid over a window
    of 0.3 s) permuted at frame 400, the upper arm's, the elbow's, the forearm's and the wrist's tails shifted by one.
    The ranges their distances kept over the 5 s before (a few millimetres within a segment, 1-2 cm from the elbow
    to the wrist whatever the bend) put all four back; the window before alone, scoring rigid distances, chooses
    another permutation."""
    P = _skin_arm()
    cycle = [3, 4, 5, 6]
    seen = P.copy()
    seen[400:, cycle] = P[400:, np.roll(cycle, 1)]
    traj = _traj(seen.copy())
    assert unscramble_bursts(traj, JUMP) == 1
    np.testing.assert_array_equal(traj.positions, P)
    window_only = _traj(seen.copy())
    unscramble_bursts(window_only, JUMP, ScrambleConfig(min_history_s=1e3))
    assert not np.array_equal(window_only.positions, P)



def test_a_range_is_taken_since_the_identity_was_last_missing_for_long():
    """An identity that held the hand marker, was missing for 0.6 s and then held the forearm marker (the tracker's
    re-identification after a long gap: the sprint's forearm, seed 1, frame 1868): its distances are ranged over the
    forearm marker's samples alone (cut at gaps of 0.5 s); cut at gaps of 0.8 s only, they span both markers'."""
    P = _skin_arm()
    seen = P.copy()
    seen[100:250, 5] = P[100:250, 8]
    seen[100:250, 8] = np.nan
    seen[250:280, 5] = np.nan
    frames = slice(0, 400)
    low, high, _, count = _window_ranges(seen, frames, np.array([5]), 0.01, 25)
    d = np.linalg.norm(P[280:400, 5] - P[280:400, 3], axis=1)
    assert count[0, 3] == 120
    np.testing.assert_allclose([low[0, 3], high[0, 3]], np.quantile(d, [0.01, 0.99]))
    low, high, _, count = _window_ranges(seen, frames, np.array([5]), 0.01, 40)
    assert count[0, 3] == 370 and high[0, 3] - low[0, 3] > 2 * (np.ptp(d))


@pytest.mark.parametrize("ranged", [False, True])
def test_the_search_chooses_what_enumeration_chooses(ranged):
    """On random bursts of 2-7 members whose tails were permuted at random (seeded), the branch and bound chooses
    the permutation that scoring all g! and applying step 4 to them chooses: of those within ``tie_nats`` of the
    best, the least drift where the next is ``drift_gap_m`` more, else the fewest moves, then the least cost. Both
    scores: the ranges kept (here median +- spread) and the window's rigid distances."""
    cfg = ScrambleConfig()
    terms = functools.partial(_range_terms if ranged else _rigid_terms, cfg=cfg)
    rng = np.random.default_rng(0)
    chosen = 0
    for _ in range(60):
        g = int(rng.integers(2, 8))
        n = g + int(rng.integers(0, 6))
        ids = np.sort(rng.choice(n, g, replace=False))
        was = rng.uniform(0.03, 0.3, (g, n))
        spread = rng.choice([0.0, 0.0003, 0.001, 0.003, 0.02], (g, n))
        near = rng.random((g, n)) < 0.6
        near[np.arange(g), ids] = False
        now = was[rng.permutation(g)] + rng.normal(0, 0.001, (g, n))
        stats = (was - spread, was + spread) if ranged else (was, spread)
        tables = _Tables.build(ids, near, stats, now, rng.random((g, n)) < 0.9, terms)
        every = np.array(list(itertools.permutations(range(g))))
        cost, drift = tables.cost(every), tables.drift(every)
        moves = (every != np.arange(g)).sum(axis=1)
        tied = np.flatnonzero(cost - cost.min() < cfg.tie_nats)
        steadiest = tied[np.lexsort((moves[tied], drift[tied]))]
        if steadiest.size == 1 or drift[steadiest[1]] - drift[steadiest[0]] >= cfg.drift_gap_m:
            k = steadiest[0]
        else:
            k = tied[np.lexsort((cost[tied], moves[tied]))[0]]
        want = None if moves[k] == 0 or cost[0] - cost[k] < cfg.margin_nats else every[k]
        got = _choose(tables, cfg)
        assert (got is None) == (want is None)
        if want is not None:
            np.testing.assert_array_equal(got, want)
            chosen += 1
    assert chosen >= 10  # (most random bursts are put back)
