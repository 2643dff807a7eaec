"""Two identities of one marker that take turns are merged; two markers that take turns are not."""

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


def test_identities_one_after_the_other_are_left_to_the_relinking():
    traj, truth = _turns(0, 0)
    traj.positions[110:, 0] = np.nan  # column 0 before, column 1 after: one junction, not turns
    assert merge_alternating(traj) == 0
