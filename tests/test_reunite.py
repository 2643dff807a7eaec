"""Rigid clusters back after a long absence get their identities back; ambiguous shapes are left alone."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.relabel import repair_identities
from mocap.reunite import reunite_clusters
from mocap.trajectories import Trajectories

FRAMES, GONE = 600, slice(200, 400)  # the plates leave the volume for 2 s at 100 Hz
# local marker coordinates, m: an asymmetric 4-marker plate and a larger triangle
PLATE = np.array([[0.0, 0.0, 0.0], [0.082, 0.0, 0.0], [0.03, 0.054, 0.0], [0.07, 0.045, 0.02]])
TRIANGLE = np.array([[0.0, 0.0, 0.0], [0.21, 0.0, 0.0], [0.05, 0.3, 0.0]])
SQUARE = np.array([[0.0, 0.0, 0.0], [0.08, 0.0, 0.0], [0.08, 0.08, 0.0], [0.0, 0.08, 0.0]])


def _moving(local: np.ndarray, rng: np.random.Generator, offset: float) -> np.ndarray:
    """(F, n, 3) a rigid body's markers: tumbling and travelling 4 m over the take, 0.3 mm noise."""
    t = np.arange(FRAMES) / 100.0
    turn = Rotation.from_rotvec(np.c_[0.8 * np.sin(0.7 * t + offset), 0.5 * np.cos(0.4 * t), 0.6 * t])
    path = np.c_[0.7 * t, offset + 0.2 * np.sin(t), 1.0 + 0.1 * np.cos(2 * t)]
    world = np.einsum("fij,nj->fni", turn.as_matrix(), local) + path[:, None]
    return world + rng.normal(0, 0.0003, world.shape)


def _skin(n: int, rng: np.random.Generator) -> np.ndarray:
    """(F, n, 3) markers that move independently (no rigid pairs), never hidden."""
    t = np.arange(FRAMES)[:, None, None] / 100.0
    walk = np.c_[0.7 * t[:, 0, 0], np.zeros(FRAMES), np.ones(FRAMES)]  # (F, 3) beside the plates
    base = walk[:, None] + np.c_[np.zeros(n), 1.0 + 0.15 * np.arange(n), np.zeros(n)]
    return base + 0.05 * np.sin(2 * np.pi * rng.uniform(0.2, 1.0, (1, n, 3)) * t + rng.uniform(0, 6, (1, n, 3)))


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


def _columns_follow(traj: Trajectories, truth: np.ndarray) -> list[int]:
    """For every non-empty column, the truth marker it follows; asserts it follows only that one."""
    out = []
    for col in np.flatnonzero(np.isfinite(traj.positions[..., 0]).any(axis=0)):
        rows = np.isfinite(traj.positions[:, col, 0])
        d = np.linalg.norm(truth[rows] - traj.positions[rows, col][:, None], axis=2)
        owner = d.argmin(axis=1)
        assert (owner == owner[0]).all() and d.min(axis=1).max() < 1e-12
        out.append(int(owner[0]))
    return out


def test_a_plate_and_a_triangle_back_after_two_seconds_get_their_identities_back():
    rng = np.random.default_rng(3)
    truth = np.concatenate([_moving(PLATE, rng, 0.0), _moving(TRIANGLE, rng, 0.6), _skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(7))
    assert reunite_clusters(traj) == 7
    assert sorted(_columns_follow(traj, truth)) == list(range(10))  # one column per marker, whole take


def test_the_identity_repair_reunites_them_and_drops_the_emptied_columns():
    rng = np.random.default_rng(4)
    truth = np.concatenate([_moving(PLATE, rng, 0.0), _moving(TRIANGLE, rng, 0.6), _skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(7))
    stats = repair_identities(traj)
    assert stats.reunited == 7 and traj.n_markers == 10
    assert sorted(_columns_follow(traj, truth)) == list(range(10))
    assert traj.labels == [f"M{k + 1:03d}" for k in range(10)]


def test_a_square_plate_is_left_alone():
    """Four rotations of a square fit equally: no identity can be told, so none is moved."""
    rng = np.random.default_rng(5)
    truth = np.concatenate([_moving(SQUARE, rng, 0.0), _skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(4))
    before = traj.positions.copy()
    assert reunite_clusters(traj) == 0
    np.testing.assert_array_equal(traj.positions, before)


def test_two_identical_plates_are_left_alone():
    """Two plates of one design, both hidden together: which came back where cannot be told from shape."""
    rng = np.random.default_rng(6)
    truth = np.concatenate([_moving(PLATE, rng, 0.0), _moving(PLATE, rng, 0.8), _skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(8))
    assert reunite_clusters(traj) == 0


def test_plates_that_never_left_are_untouched():
    rng = np.random.default_rng(7)
    truth = np.concatenate([_moving(PLATE, rng, 0.0), _moving(TRIANGLE, rng, 0.6), _skin(3, rng)], axis=1)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(10)], 100.0, truth.copy())
    assert reunite_clusters(traj) == 0
    np.testing.assert_array_equal(traj.positions, truth)


def test_a_plate_away_four_times_chains_up_into_one_identity_per_marker():
    """The plate and the triangle each leave and come back three times (four stints of 120 frames, gaps of 30):
    every stint started new identities. Repeated passes chain them: one identity per marker for the whole take."""
    rng = np.random.default_rng(8)
    truth = np.concatenate([_moving(PLATE, rng, 0.0), _moving(TRIANGLE, rng, 0.6), _skin(3, rng)], axis=1)
    columns = [truth[:, 7:]]  # the skin markers, never away
    for start in range(0, FRAMES, 150):
        stint = np.full((FRAMES, 7, 3), np.nan)
        stint[start:start + 120] = truth[start:start + 120, :7]
        columns.append(stint)
    P = np.concatenate(columns, axis=1)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P)
    skin = [int(np.argmin(np.linalg.norm(truth[0] - P[0, k], axis=1))) for k in range(3)]
    assert reunite_clusters(traj) == 21  # 7 markers x 3 joins
    assert sorted(_columns_follow(traj, truth)) == sorted(list(range(7)) + skin)
