"""Rigid clusters back after a long absence get their identities back; ambiguous shapes are left alone."""

from __future__ import annotations

import numpy as np
from helpers_rigid import FRAMES, PLATE, SQUARE, TRIANGLE, columns_follow, moving, skin

from mocap.relabel import repair_identities
from mocap.reunite import reunite_clusters
from mocap.trajectories import Trajectories

GONE = slice(200, 400)  # the plates leave the volume for 2 s at 100 Hz


def _split_at_the_gap(truth: np.ndarray, hidden: np.ndarray) -> Trajectories:
    """The tracker's output: ``hidden`` markers vanish during GONE and come back one by one, 7 frames apart, as
    new identities (so the relink pass, which assigns markers coming back in the same frame jointly, cannot)."""
    F, M = truth.shape[:2]
    P = np.concatenate([truth, np.full((F, len(hidden), 3), np.nan)], axis=1)
    for k, h in enumerate(hidden):
        back = GONE.stop + 7 * k
        P[GONE.start:, h] = np.nan
        P[back:, M + k] = truth[back:, h]
    return Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P)


def test_a_plate_and_a_triangle_back_after_two_seconds_get_their_identities_back():
    rng = np.random.default_rng(3)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(7))
    assert reunite_clusters(traj) == 7
    assert sorted(columns_follow(traj, truth)) == list(range(10))  # one column per marker, whole take


def test_the_identity_repair_reunites_them_and_drops_the_emptied_columns():
    rng = np.random.default_rng(4)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(7))
    stats = repair_identities(traj)
    assert stats.reunited == 7 and traj.n_markers == 10
    assert sorted(columns_follow(traj, truth)) == list(range(10))
    assert traj.labels == [f"M{k + 1:03d}" for k in range(10)]


def test_a_square_plate_is_left_alone():
    """Four rotations of a square fit equally: no identity can be told, so none is moved."""
    rng = np.random.default_rng(5)
    truth = np.concatenate([moving(SQUARE, rng, 0.0), skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(4))
    before = traj.positions.copy()
    assert reunite_clusters(traj) == 0
    np.testing.assert_array_equal(traj.positions, before)


def test_two_identical_plates_are_left_alone():
    """Two plates of one design, both hidden together: which came back where cannot be told from shape."""
    rng = np.random.default_rng(6)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(PLATE, rng, 0.8), skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(8))
    assert reunite_clusters(traj) == 0


def test_plates_that_never_left_are_untouched():
    rng = np.random.default_rng(7)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(10)], 100.0, truth.copy())
    assert reunite_clusters(traj) == 0
    np.testing.assert_array_equal(traj.positions, truth)


def test_a_plate_away_four_times_chains_up_into_one_identity_per_marker():
    """The plate and the triangle each leave and come back three times (four stints of 120 frames, gaps of 30):
    every stint started new identities. Repeated passes chain them: one identity per marker for the whole take."""
    rng = np.random.default_rng(8)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    columns = [truth[:, 7:]]  # the skin markers, never away
    for start in range(0, FRAMES, 150):
        stint = np.full((FRAMES, 7, 3), np.nan)
        stint[start:start + 120] = truth[start:start + 120, :7]
        columns.append(stint)
    P = np.concatenate(columns, axis=1)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P)
    skin_markers = [int(np.argmin(np.linalg.norm(truth[0] - P[0, k], axis=1))) for k in range(3)]
    assert reunite_clusters(traj) == 21  # 7 markers x 3 joins
    assert sorted(columns_follow(traj, truth)) == sorted(list(range(7)) + skin_markers)
