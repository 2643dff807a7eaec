"""Rigid clusters back after a long absence get their identities back; ambiguous shapes are left alone."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from helpers_rigid import FRAMES, PLATE, SQUARE, TRIANGLE, columns_follow, moving, skin
from scipy.spatial.transform import Rotation

from mocap.relabel import repair_identities
from mocap.reunite import SKIN_CLUSTERS, ReuniteConfig, reunite_clusters
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


def test_a_cluster_away_longer_than_max_absence_stays_new_identities():
    """The gap is 2 s (the last marker back 2.06 s after): allowed 1.5 s, nothing is joined; 2.5 s, all of it."""
    rng = np.random.default_rng(3)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    traj = _split_at_the_gap(truth, np.arange(7))
    assert reunite_clusters(traj, ReuniteConfig(max_absence_s=1.5)) == 0
    assert reunite_clusters(traj, ReuniteConfig(max_absence_s=2.5)) == 7
    assert sorted(columns_follow(traj, truth)) == list(range(10))


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



def _arm(rng: np.random.Generator) -> np.ndarray:
    """(F, 7, 3) a forearm's skin cluster, an isosceles triangle (76 mm base, 1 mm skin wobble), then an upper
    arm's plate hinged to it at an elbow 0.12 m behind the cluster's first marker, bending 0.3-1.1 rad."""
    cluster = np.array([[0.0, 0.0, 0.0], [0.076, 0.0, 0.0], [0.038, 0.034, 0.0]])
    elbow = np.array([-0.12, 0.017, -0.03])
    t = np.arange(FRAMES) / 100.0
    bend = Rotation.from_rotvec(np.c_[np.zeros(FRAMES), np.zeros(FRAMES), 0.7 + 0.4 * np.sin(1.3 * t)])
    upper = np.stack([elbow + bend[k].apply(PLATE - [0.16, 0.0, 0.0]) for k in range(FRAMES)])  # (F, 4, 3)
    local = np.concatenate([np.broadcast_to(cluster, (FRAMES, 3, 3)), upper], axis=1)  # in the forearm's frame
    turn = Rotation.from_rotvec(np.c_[0.8 * np.sin(0.7 * t), 0.5 * np.cos(0.4 * t), 0.6 * t])
    path = np.c_[0.7 * t, 0.2 * np.sin(t), np.ones(FRAMES)]
    world = np.einsum("fij,fnj->fni", turn.as_matrix(), local) + path[:, None]
    world[:, :3] += rng.normal(0, 0.001, (FRAMES, 3, 3))
    world[:, 3:] += rng.normal(0, 0.0003, (FRAMES, 4, 3))
    return world


def test_a_symmetric_skin_cluster_back_after_a_gap_is_told_apart_by_its_neighbours():
    """The forearm's isosceles cluster is hidden for 2 s and comes back as new identities: its shape fits its
    mirror image as well, but the upper arm's markers stand nearer its first marker than its second, before the
    gap and after it. The repair's skin-cluster pass gives each marker its identity back; the shape alone
    (the first pass's settings, without the context) leaves them alone."""
    rng = np.random.default_rng(9)
    truth = _arm(rng)
    traj = _split_at_the_gap(truth, np.arange(3))
    assert reunite_clusters(_split_at_the_gap(truth, np.arange(3)), replace(SKIN_CLUSTERS, context_reach_m=0.0)) == 0
    assert reunite_clusters(traj, SKIN_CLUSTERS) == 3
    assert sorted(columns_follow(traj, truth)) == list(range(7))


def test_the_repair_reunites_the_skin_cluster_and_nothing_without_neighbours_near():
    rng = np.random.default_rng(10)
    truth = _arm(rng)
    traj = _split_at_the_gap(truth, np.arange(3))
    stats = repair_identities(traj)
    assert stats.reunited == 3 and traj.n_markers == 7
    assert sorted(columns_follow(traj, truth)) == list(range(7))
    alone = _split_at_the_gap(truth[:, :3], np.arange(3))  # no upper arm: the mirror image cannot be ruled out
    assert reunite_clusters(alone, SKIN_CLUSTERS) == 0


def test_a_skin_cluster_seen_in_a_glimpse_between_two_gaps_chains_up_in_time_order():
    """The forearm's cluster is gone for 1 s, seen for 0.2 s, gone again for 0.8 s: three sets of identities. In
    the glimpse the skin is pressed (the cluster 3 % smaller), so by shape alone the return fits the cluster's past
    better than the glimpse, and joining it there would leave the glimpse out; the pass joins the nearest in time
    first, and every marker ends with one identity for the whole take."""
    rng = np.random.default_rng(11)
    truth = _arm(rng)
    stints = [slice(0, 200), slice(300, 320), slice(400, FRAMES)]
    columns = [truth[:, 3:]]  # the upper arm, never away
    for stint in stints:
        part = np.full((FRAMES, 3, 3), np.nan)
        part[stint] = truth[stint, :3]
        columns.append(part)
    glimpse = columns[2][stints[1]]
    glimpse -= 0.03 * (glimpse - glimpse.mean(axis=1, keepdims=True))
    truth[stints[1], :3] = glimpse
    P = np.concatenate(columns, axis=1)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P)
    assert reunite_clusters(traj, SKIN_CLUSTERS) == 6
    assert sorted(columns_follow(traj, truth)) == list(range(7))


def test_a_skin_cluster_glimpsed_in_its_identities_gap_joins_them():
    """The whole sprint's forearm at frames 2439-2458: its identities are known before a 1 s gap and after another
    (other passes joined those), and in between the cluster is seen for 0.2 s as new identities, its two ends in
    the order of the mirror image. Those never started after the old ones ended; they lie in their gap. The
    skin-cluster pass joins them, each to its own marker by the upper arm's distances; without ``fill_holes`` it
    leaves them alone."""
    rng = np.random.default_rng(12)
    truth = _arm(rng)
    away = np.r_[200:300, 320:400]
    kept = truth[:, :3].copy()
    kept[away] = np.nan
    kept[300:320] = np.nan
    glimpse = np.full((FRAMES, 3, 3), np.nan)
    glimpse[300:320] = truth[300:320, [1, 0, 2]]  # (new identities, their first two in the mirror's order)
    P = np.concatenate([kept, truth[:, 3:], glimpse], axis=1)
    assert reunite_clusters(Trajectories([f"M{k + 1:03d}" for k in range(10)], 100.0, P.copy()),
                            replace(SKIN_CLUSTERS, fill_holes=False)) == 0
    traj = Trajectories([f"M{k + 1:03d}" for k in range(10)], 100.0, P)
    assert reunite_clusters(traj, SKIN_CLUSTERS) == 3
    assert sorted(columns_follow(traj, truth)) == list(range(7))


def test_a_skin_cluster_whose_marker_left_two_pieces_before_the_gap_is_reunited():
    """The whole sprint at seed 1: ForearmL:Marker4's track before the forearm's gap was left in pieces (the
    tracker's glimpses in the hand's cluster), seen together in one frame. Maps of the return onto either piece fit
    alike, shape and context, and were taken for a symmetric shape's two labellings: nothing was joined, and the
    forearm's last 1,000 frames went to new identities. Pieces seen together in fewer frames than the pass measures a
    pair over are one marker's: the return joins the later piece, and the others their identities."""
    rng = np.random.default_rng(9)
    truth = _arm(rng)
    P = _split_at_the_gap(truth, np.arange(3)).positions
    piece = np.full((FRAMES, 1, 3), np.nan)
    piece[119:GONE.start, 0] = P[119:GONE.start, 0]  # marker 0 before the gap in two pieces, one frame shared
    P[120:GONE.start, 0] = np.nan
    traj = Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1] + 1)], 100.0, np.concatenate([P, piece], axis=1))
    assert reunite_clusters(traj, SKIN_CLUSTERS) == 3
    follows = columns_follow(traj, truth)
    assert sorted(follows) == [0, 0, *range(1, 7)]  # marker 0: its first piece, and its second with the return
    back = np.isfinite(traj.positions[GONE.stop + 20, :, 0])
    assert np.isfinite(traj.positions[GONE.start - 1, back, 0]).sum() == 7  # every return joined a track before
