"""Two identities of one marker that take turns, or follow each other, are merged; two markers are not."""

from __future__ import annotations

import numpy as np

from mocap.alternate import merge_alternating
from mocap.trajectories import Trajectories


def _segment(n_frames: int = 160) -> np.ndarray:
    """(F, 5, 3) markers of one moving segment, m: the marker followed (0), a neighbour 30 mm from it (1), three
    more 80-150 mm away (2-4); the segment turns about z and travels."""
    layout = np.array([[0.0, 0.0, 0.0], [0.03, 0.0, 0.0], [0.08, 0.05, 0.0], [-0.06, 0.1, 0.02], [0.0, -0.12, 0.05]])
    t = np.arange(n_frames) / 100.0
    angle = 0.8 * np.sin(2 * np.pi * 0.5 * t)
    c, s = np.cos(angle), np.sin(angle)
    R = np.stack([np.stack([c, -s, 0 * c], -1), np.stack([s, c, 0 * c], -1), np.stack([0 * c, 0 * c, 1 + 0 * c], -1)],
                 axis=1)  # (F, 3, 3)
    centre = np.stack([0.5 * t, 0.2 * np.sin(2 * np.pi * 0.3 * t), 1.0 + 0 * t], axis=1)
    return centre[:, None] + np.einsum("fij,mj->fmi", R, layout)


def _turns(first: int, second: int) -> tuple[Trajectories, np.ndarray]:
    """Truth marker ``first`` in column 0 on frames 0-49 and 110-159, marker ``second`` in column 1 on 60-99, the
    neighbours 2-4 in columns 2-4 throughout."""
    truth = _segment()
    P = np.full((len(truth), 5, 3), np.nan)
    P[:50, 0], P[110:, 0] = truth[:50, first], truth[110:, first]
    P[60:100, 1] = truth[60:100, second]
    P[:, 2:] = truth[:, 2:]
    return Trajectories([f"M{k + 1:03d}" for k in range(5)], 100.0, P), truth


def test_two_identities_of_one_marker_that_take_turns_are_merged():
    traj, truth = _turns(0, 0)
    assert merge_alternating(traj) == 1
    rows = np.r_[0:50, 60:100, 110:160]
    np.testing.assert_array_equal(traj.positions[rows, 0], truth[rows, 0])
    assert np.isnan(traj.positions[:, 1]).all()
    assert (traj.camera_masks[:, 1] == 0).all()


def test_two_markers_30_mm_apart_that_take_turns_are_not_merged():
    traj, _ = _turns(0, 1)
    before = traj.positions.copy()
    assert merge_alternating(traj) == 0
    np.testing.assert_array_equal(traj.positions, before)


def test_a_marker_with_two_neighbours_under_two_identities_taking_turns_is_merged():
    """A knee marker has two neighbours within 0.25 m (the thigh's and the shin's): taking turns (A, B, A) is
    evidence enough with two; two markers 30 mm apart with the same two neighbours are still told apart."""
    for first, second, merged in ((0, 0, 1), (0, 1, 0)):
        traj, truth = _turns(first, second)
        traj.positions[:, 4] = np.nan
        assert merge_alternating(traj, turn_neighbours=3) == 0
        assert merge_alternating(traj) == merged


def _rotated_about(p: np.ndarray, a: np.ndarray, b: np.ndarray, angle: float) -> np.ndarray:
    """(F, 3) points ``p`` turned by ``angle`` rad about the lines through ``a`` and ``b`` (F, 3): their distances to
    ``a`` and ``b`` kept."""
    axis = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    v = p - a
    return (a + v * np.cos(angle) + np.cross(axis, v) * np.sin(angle)
            + axis * np.sum(axis * v, axis=1, keepdims=True) * (1 - np.cos(angle)))


def _follow(second: np.ndarray, n_frames: int = 400) -> tuple[Trajectories, np.ndarray]:
    """Truth marker 0 in column 0 on frames 0-149, ``second`` (F, 3) in column 1 on 250-399 (1.5 s each at
    100 Hz), the neighbours 2-4 in columns 2-4 throughout (the 30 mm neighbour 1 unseen)."""
    truth = _segment(n_frames)
    P = np.full((n_frames, 5, 3), np.nan)
    P[:150, 0] = truth[:150, 0]
    P[250:, 1] = second[250:]
    P[:, 2:] = truth[:, 2:]
    return Trajectories([f"M{k + 1:03d}" for k in range(5)], 100.0, P), truth


def test_a_marker_back_after_a_long_gap_under_a_new_identity_is_merged():
    truth = _segment(400)
    traj, _ = _follow(truth[:, 0])
    assert merge_alternating(traj) == 1
    rows = np.r_[0:150, 250:400]
    np.testing.assert_array_equal(traj.positions[rows, 0], truth[rows, 0])
    assert np.isnan(traj.positions[:, 1]).all()


def test_a_stray_sample_of_another_marker_long_before_does_not_keep_a_marker_s_identities_apart():
    truth = _segment(400)
    traj, _ = _follow(truth[:, 0])
    traj.positions[20:22, 1] = truth[20:22, 4] + 0.01  # the tracker gave the later identity two samples of a neighbour
    assert merge_alternating(traj) == 1
    rows = np.r_[0:150, 250:400]
    np.testing.assert_array_equal(traj.positions[rows, 0], truth[rows, 0])
    np.testing.assert_array_equal(traj.positions[20:22, 1], truth[20:22, 4] + 0.01)  # left where they were
    assert np.isnan(traj.positions[250:, 1]).all()


def test_a_marker_that_keeps_two_of_three_neighbour_distances_is_not_taken_for_the_one_before():
    truth = _segment(400)
    mirror = _rotated_about(truth[:, 0], truth[:, 2], truth[:, 3], 1.0)  # 71 mm away; 15 mm off to neighbour 4
    traj, _ = _follow(mirror)
    differ = [abs(np.median(np.linalg.norm(mirror - truth[:, o], axis=1))
                  - np.median(np.linalg.norm(truth[:, 0] - truth[:, o], axis=1))) for o in (2, 3, 4)]
    assert np.median(differ) < 0.001 and max(differ) > 0.012  # the median agrees; one neighbour refutes
    before = traj.positions.copy()
    assert merge_alternating(traj) == 0
    np.testing.assert_array_equal(traj.positions, before)


def test_identities_one_after_the_other_seen_under_a_second_each_are_left_apart():
    traj, truth = _turns(0, 0)
    traj.positions[110:, 0] = np.nan  # column 0 on 0-49, column 1 on 60-99 (0.5 and 0.4 s): one junction
    assert merge_alternating(traj) == 0
