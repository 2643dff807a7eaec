"""Identities that ended joined to the later identity their rigid neighbours carry them to (:mod:`mocap.orphans`)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_rigid import FRAMES, PLATE, TRIANGLE, columns_follow, moving

from mocap.orphans import OrphanConfig, rejoin_orphans
from mocap.trajectories import Trajectories

FPS = 100.0


def _scene(seed: int) -> np.ndarray:
    """(F, 10, 3) m: a seven-marker rigid body (a plate beside a triangle) tumbling and travelling 0.7 m/s, and a
    three-marker plate of another body moving its own way 0.3 m beside it."""
    rng = np.random.default_rng(seed)
    body = moving(np.concatenate([PLATE, TRIANGLE + [0.15, 0.0, 0.05]]), rng, 0.0)
    other = moving(PLATE[:3], rng, 0.3)
    return np.concatenate([body, other], axis=1)


def _identities(truth: np.ndarray, pieces: list[tuple[int, int, int]]) -> Trajectories:
    """One identity per piece (marker, first, last) of ``truth`` (F, M, 3)."""
    P = np.full((len(truth), len(pieces), 3), np.nan)
    for k, (m, first, last) in enumerate(pieces):
        P[first:last + 1, k] = truth[first:last + 1, m]
    seen = np.isfinite(P[..., 0])
    return Trajectories([f"M{k}" for k in range(len(pieces))], FPS, P, np.where(seen, 0.1, np.nan),
                        seen.astype(np.uint32))


def _whole(markers: range, skip: set[int]) -> list[tuple[int, int, int]]:
    return [(m, 0, FRAMES - 1) for m in markers if m not in skip]


@pytest.mark.parametrize("seed", [1, 2])
def test_markers_back_from_a_long_gap_rejoin_their_identities(seed):
    """Markers 0 and 4 are hidden for 1.5 s, while their body turns and travels a metre, and come back as new
    identities: each is carried by its rigid neighbours to its own return, not to the other's."""
    truth = _scene(seed)
    pieces = _whole(range(10), {0, 4}) + [(0, 0, 199), (4, 0, 199), (0, 350, FRAMES - 1), (4, 350, FRAMES - 1)]
    traj = _identities(truth, pieces)
    assert np.linalg.norm(truth[350, 0] - truth[199, 0]) > 0.8  # far from where the marker was last seen
    samples = np.isfinite(traj.positions[..., 0]).sum()
    assert rejoin_orphans(traj) == 2
    assert sorted(columns_follow(traj, truth)) == list(range(10))  # one identity per marker, each pure
    assert np.isfinite(traj.positions[..., 0]).sum() == samples  # no sample lost or made


def test_a_return_taken_by_another_lost_identity_goes_back_to_its_own():
    """Markers 0 and 4 are hidden for 1.5 s; marker 0 comes back under marker 4's old identity (the tracker
    re-identified it there), marker 4 as a new identity. The tail goes to marker 0's identity, which ended, and
    the new identity then joins marker 4's, which the move ended."""
    truth = _scene(4)
    pieces = _whole(range(10), {0, 4}) + [(0, 0, 199), (4, 0, 199), (4, 350, FRAMES - 1)]
    traj = _identities(truth, pieces)
    traj.positions[350:, 9] = truth[350:, 0]  # marker 4's old identity holds marker 0's return
    samples = np.isfinite(traj.positions[..., 0]).sum()
    assert rejoin_orphans(traj) == 2
    assert sorted(columns_follow(traj, truth)) == list(range(10))
    assert np.isfinite(traj.positions[..., 0]).sum() == samples


def test_a_new_marker_of_another_body_is_not_joined_to_an_identity_that_ended():
    """Marker 0's identity ends for good; marker 7, on the other body, enters the volume 1.5 s later."""
    truth = _scene(3)
    traj = _identities(truth, _whole(range(10), {0, 7}) + [(0, 0, 199), (7, 350, FRAMES - 1)])
    assert rejoin_orphans(traj) == 0
    assert sorted(columns_follow(traj, truth)) == list(range(10))


def test_a_return_after_more_than_the_longest_gap_is_left():
    truth = _scene(1)
    pieces = _whole(range(10), {0}) + [(0, 0, 199), (0, 350, FRAMES - 1)]
    assert rejoin_orphans(_identities(truth, pieces), OrphanConfig(max_gap_s=1.0)) == 0
    assert rejoin_orphans(_identities(truth, pieces), OrphanConfig(max_gap_s=2.0)) == 1


@pytest.mark.parametrize("seed", [1, 2])
def test_a_return_measured_after_a_join_moved_one_of_its_neighbours_does_not_crash_the_round(seed):
    """Marker 0 comes back as a new identity at frame 350, and marker 1 comes back under its own identity at 450
    after a 0.5 s gap. The round joins marker 0's return first (its frame comes first), moving its samples; marker
    1's return is then measured against its rigid neighbours, marker 0's new identity among them. That measurement
    once read the moved (now empty) column where the round's record of what is seen still had samples: NaN into an
    SVD, which raised "SVD did not converge" out of ``mocap reconstruct`` (the whole sprint replayed from frame
    2000, seed 0). Every measurement of a round is now made on the state the round started from."""
    truth = _scene(seed)
    pieces = _whole(range(10), {0, 1}) + [(0, 0, 199), (0, 350, FRAMES - 1), (1, 0, 399)]
    traj = _identities(truth, pieces)
    traj.positions[450:, -1] = truth[450:, 1]  # marker 1's own identity, back after 0.5 s
    traj.residuals[450:, -1], traj.camera_masks[450:, -1] = 0.1, 1
    samples = np.isfinite(traj.positions[..., 0]).sum()
    assert rejoin_orphans(traj) == 1
    assert sorted(columns_follow(traj, truth)) == list(range(10))
    assert np.isfinite(traj.positions[..., 0]).sum() == samples
