"""Markers of a rigid plate are labelled by its shape: identities rotated after a gap come back; symmetric
plates, twin plates and skin markers are left alone."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_engine import scripted_motion, simulate
from helpers_rigid import FRAMES, PLATE, SQUARE, TRIANGLE, columns_follow, moving, skin

from mocap.errors import MocapError
from mocap.evaluate import evaluate
from mocap.plates import PlateConfig, _destinations, _distances, _evicted, _plates, _SortedPairs, label_plates
from mocap.relabel import repair_identities
from mocap.rigid import placement_jumps
from mocap.synth import SynthSettings, ring_rig
from mocap.tracker import Tracker
from mocap.trajectories import Trajectories, UnconfirmedPoints

HIDDEN, BACK = 360, 400  # the plate is hidden from frame 360 and comes back, a marker every 5 frames, from 400


def _rotated_after_gaps(truth: np.ndarray, plate: np.ndarray, gaps: list[tuple[int, int, np.ndarray]]
                        ) -> Trajectories:
    """The tracker's output: for every gap (hidden, back, order), the ``plate`` markers' columns are empty from
    frame ``hidden``, and from ``back`` on (a marker every 5 frames) column ``plate[order[k]]`` holds marker
    ``plate[k]`` (each returning marker re-identified as a neighbour)."""
    P = truth.copy()
    for hidden, back, order in gaps:
        P[hidden:, plate] = np.nan
        for k, marker in enumerate(plate):
            start = back + 5 * k
            P[start:, plate[order[k]]] = truth[start:, marker]
    return Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P)


def _rotated_after_the_gap(truth: np.ndarray, plate: np.ndarray, order: np.ndarray) -> Trajectories:
    """:func:`_rotated_after_gaps` for one gap, from HIDDEN to BACK."""
    return _rotated_after_gaps(truth, plate, [(HIDDEN, BACK, order)])


def _samples_per_frame(traj: Trajectories) -> list[np.ndarray]:
    """Every frame's measured positions, sorted (what a relabelling must keep)."""
    return [np.sort(row[np.isfinite(row[:, 0])], axis=0) for row in traj.positions]


def test_a_plate_back_from_a_gap_with_its_identities_rotated_is_labelled_by_its_shape():
    rng = np.random.default_rng(11)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    traj = _rotated_after_the_gap(truth, np.arange(4), np.array([1, 2, 3, 0]))
    before = _samples_per_frame(traj)
    assert label_plates(traj) == 4 * 200 - 5 * (0 + 1 + 2 + 3)  # every sample after the gap
    assert columns_follow(traj, truth)[:4] == [0, 1, 2, 3]
    after = _samples_per_frame(traj)
    assert all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))  # samples moved, none changed


def test_a_plate_rotated_after_every_absence_is_learned_from_a_stretch_of_the_take():
    """Hidden three times and mixed up after each: no labelling holds for most of the take, so no pair of
    identities keeps its distance over it; within the longest stint one does."""
    rng = np.random.default_rng(18)
    truth = np.concatenate([moving(PLATE, rng, 0.0), skin(3, rng)], axis=1)
    gaps = [(100, 130, np.array([1, 2, 3, 0])), (330, 360, np.array([2, 0, 3, 1])), (470, 500, np.array([3, 2, 1, 0]))]
    traj = _rotated_after_gaps(truth, np.arange(4), gaps)
    before = _samples_per_frame(traj)
    assert label_plates(traj) > 0
    assert sorted(columns_follow(traj, truth)) == list(range(7))  # one column per marker, whole take
    after = _samples_per_frame(traj)
    assert all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))


def test_the_identity_repair_labels_plates_last():
    rng = np.random.default_rng(12)
    truth = np.concatenate([moving(PLATE, rng, 0.0), skin(3, rng)], axis=1)
    traj = _rotated_after_the_gap(truth, np.arange(4), np.array([3, 0, 1, 2]))
    stats = repair_identities(traj)
    assert stats.plate_samples > 0
    assert sorted(columns_follow(traj, truth)) == list(range(7))  # one column per marker, whole take


def test_a_square_plate_is_left_alone():
    """Its four rotations fit alike: the shape names no marker."""
    rng = np.random.default_rng(13)
    truth = np.concatenate([moving(SQUARE, rng, 0.0), skin(3, rng)], axis=1)
    traj = _rotated_after_the_gap(truth, np.arange(4), np.array([1, 2, 3, 0]))
    assert label_plates(traj) == 0


def test_two_plates_of_one_design_seen_together_are_left_alone():
    """A left and a right cluster alike: the shape cannot tell which plate a marker is on."""
    rng = np.random.default_rng(14)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(PLATE, rng, 0.6), skin(3, rng)], axis=1)
    traj = _rotated_after_the_gap(truth, np.arange(4), np.array([1, 2, 3, 0]))
    assert label_plates(traj) == 0


def test_skin_markers_form_no_plate():
    rng = np.random.default_rng(15)
    truth = skin(6, rng)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(6)], 100.0, truth.copy())
    traj.positions[300:, [0, 1]] = traj.positions[300:, [1, 0]]
    assert label_plates(traj) == 0



def test_a_plate_marker_back_flickering_is_given_its_points_the_tracker_never_confirmed():
    """A plate marker hidden for a second comes back in every other frame only: each of its returns is a
    one-frame tentative track, never confirmed. Its plate's shape names those points."""
    rng = np.random.default_rng(17)
    positions = np.concatenate([moving(PLATE, rng, 0.0), skin(2, rng)], axis=1)
    hidden = np.zeros((FRAMES, 6, positions.shape[1]), dtype=bool)
    hidden[100:180, :, 3] = True  # (the ring sees the plate from all six cameras until frame ~270)
    hidden[181:260:2, :, 3] = True
    take = simulate("flicker", ring_rig(seed=5), scripted_motion(positions, 100.0), SynthSettings(seed=5, ghosts=0),
                    hidden=hidden, seed=5)
    tracker = Tracker(take.rig, 100.0)
    with pytest.raises(MocapError):
        tracker.unconfirmed()
    for k, frame in enumerate(take.frames):
        tracker.step(k, frame)
    traj = tracker.finish()
    unconfirmed = tracker.unconfirmed()
    assert ((unconfirmed.rows >= 180) & (unconfirmed.rows < 260) & (unconfirmed.rows % 2 == 0)).sum() >= 30
    without = Trajectories(traj.labels, traj.fps, traj.positions.copy(), traj.residuals.copy(),
                           traj.camera_masks.copy())
    repair_identities(without)
    stats = repair_identities(traj, unconfirmed=unconfirmed)
    before, after = evaluate(without, take.truth), evaluate(traj, take.truth)
    flicker = np.arange(180, 260, 2)  # the frames it is in view while flickering
    found = [int((np.linalg.norm(t.positions[flicker] - positions[flicker, None, 3], axis=2) < 0.002).any(axis=1)
                 .sum()) for t in (without, traj)]
    print(f"flickering marker output in {found[0]} -> {found[1]} of {flicker.size} frames; switches "
          f"{before.switches} -> {after.switches}, IDF1 {before.idf1:.4f} -> {after.idf1:.4f}")
    assert found[0] <= 5 and found[1] >= 35 and stats.plate_samples >= 35
    assert after.switches <= before.switches and after.idf1 > before.idf1 and after.ghost_rate == 0


@pytest.mark.parametrize("hidden", [slice(300, 301), slice(299, 302)])
def test_a_plate_mirrored_in_the_floor_is_not_given_to_the_plate_where_it_jumps(hidden):
    """The plate is hidden around frame 300, where its mirror image in a shiny floor (the same distances) is seen
    and never confirmed: that image would make the plate's identities jump 2 m for a frame. The plate itself seen
    there (unconfirmed) is given to them."""
    rng = np.random.default_rng(19)
    truth = np.concatenate([moving(PLATE, rng, 0.0), skin(2, rng)], axis=1)  # the plate at z ~ 1 m
    plate = np.arange(len(PLATE))
    P = truth.copy()
    P[hidden, :len(PLATE)] = np.nan
    mirror = truth[300, plate] * (1.0, 1.0, -1.0)

    def label(points: np.ndarray, jump_acc: float) -> tuple[int, np.ndarray]:
        traj = Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P.copy())
        n = len(points)
        extra = UnconfirmedPoints(np.full(n, 300), points, np.full(n, 0.1), np.ones(n, dtype=np.uint32))
        return label_plates(traj, extra=extra, jump_acc=jump_acc), traj.positions[300, plate]

    assert label(mirror, np.inf)[0] == len(PLATE)  # the shape alone names the image's points
    added, got = label(mirror, 0.06)
    assert added == 0 and np.isnan(got).all()
    added, got = label(truth[300, plate], 0.06)
    assert added == len(PLATE)
    np.testing.assert_array_equal(got, truth[300, plate])


def test_a_fast_marker_seen_every_other_frame_does_not_jump_between_its_samples():
    """0.2 m per frame, samples two frames apart: a point on its path is no jump; one 0.3 m off it is; with a sample
    on one side only, the point is judged as if the marker were at rest there."""
    path = np.arange(10)[:, None] * np.array([0.2, 0.0, 0.0])  # (10, 3)
    P = np.full((10, 1, 3), np.nan)
    P[[2, 6], 0] = path[[2, 6]]
    rows, member = np.array([4, 4, 8]), np.zeros(3, dtype=np.intp)
    X = np.stack([path[4], path[4] + (0.0, 0.3, 0.0), path[8]])
    np.testing.assert_array_equal(placement_jumps(P, rows, member, X, 0.06), [False, True, True])
    np.testing.assert_array_equal(placement_jumps(P, rows, member, X, np.inf), [False, False, False])


def test_a_short_tracklet_between_disagreeing_neighbours_follows_the_one_its_own_votes_name():
    """A plate marker's identity: 10 frames voted for member 5, a 1-frame gap, 3 frames with one vote, then
    (after the plate was away) 10 frames voted for member 7. The 3 frames follow their own vote when it sides
    with a neighbour, and stay put when it names neither."""
    vote = np.full((100, 1), -1)
    vote[0:10, 0], vote[80:90, 0] = 5, 7
    runs = [(0, np.arange(0, 10)), (0, np.arange(11, 14)), (0, np.arange(80, 90))]
    for own, expected in ((5, 5), (7, 7), (9, -1)):
        vote[13, 0] = own
        assert _destinations(runs, vote, PlateConfig())[0] == [5, expected, 7]


@pytest.mark.parametrize("late", [False, True])
def test_a_short_tracklet_without_votes_follows_the_neighbour_a_short_gap_away(late):
    """As above, with no vote on the 3 frames: 2 frames after the run voted 5 and 67 before the one voted 7, they
    continue the marker the identity held before its short gap (the identity went on to another marker after the
    long one). Mirrored in time, the near neighbour is the later one. Both far: left where they are."""
    vote = np.full((100, 1), -1)
    vote[0:10, 0], vote[80:90, 0] = 5, 7
    runs = [(0, np.arange(0, 10)), (0, np.arange(76, 79) if late else np.arange(11, 14)), (0, np.arange(80, 90))]
    assert _destinations(runs, vote, PlateConfig())[0] == [5, 7 if late else 5, 7]
    assert _destinations(runs, vote, PlateConfig(near_frames=1))[0] == [5, -1, 7]


def test_the_distances_are_those_of_every_pair_of_points():
    rng = np.random.default_rng(19)
    P = rng.normal(0.0, 1.0, (40, 12, 3)) + np.array([5.0, -3.0, 1.0])
    P[rng.random((40, 12)) < 0.3] = np.nan
    P[7] = np.nan  # a frame with nothing seen
    expected = np.linalg.norm(P[:, :, None] - P[:, None], axis=3)
    D = _distances(P)
    assert np.array_equal(np.isnan(D), np.isnan(expected))
    assert np.nanmax(np.abs(D - expected)) < 1e-6


def test_sorted_pairs_find_what_a_scan_finds():
    """The votes' first edge is found by bisection in the chunk's sorted distances: the same (frame, i, j), in the
    same order, as scanning the whole array, NaN (unseen points) and entries beyond the reach left out."""
    rng = np.random.default_rng(4)
    P = rng.uniform(0, 0.4, (50, 12, 3))
    P[rng.random((50, 12)) < 0.2] = np.nan
    D = _distances(P)
    pairs = _SortedPairs(D, 0.3)
    for distance in (0.0, 0.05, 0.1234, 0.25, 0.297):
        with np.errstate(invalid="ignore"):
            scan = np.nonzero(np.abs(D - distance) < 0.003)
        found = pairs.near(distance, 0.003)
        assert len(scan[0]) > 0 or distance == 0.0
        for a, b in zip(found, scan, strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("order", [[0, 1, 2, 3, 4], [4, 3, 2, 1, 0], [2, 4, 0, 3, 1]])
def test_of_two_overlapping_plates_as_large_the_one_of_the_earlier_identities_is_taken_whatever_their_order(order):
    """Identities 1-3 are rigid with 0 and with 4 (0-4 are not): two cliques of four. Identity 4 was on its marker
    from the start, 0 only from frame 50 (a later identity that joined the plate): the plate with 4 must win
    however the identities are numbered (the take's plates, and so its labels, once depended on the order in
    which the tracker happened to number its tracks)."""
    rng = np.random.default_rng(3)
    points = rng.normal(scale=0.05, size=(5, 3))
    median = np.linalg.norm(points[:, None] - points[None], axis=2)
    rigid = ~np.eye(5, dtype=bool)
    rigid[0, 4] = rigid[4, 0] = False
    seen = np.ones((100, 5), dtype=bool)
    seen[:50, 0] = False
    plates = _plates(median[np.ix_(order, order)], rigid[np.ix_(order, order)], seen[:, order], 0.002)
    assert [sorted(np.array(order)[p.members].tolist()) for p in plates] == [[1, 2, 3, 4]]


def test_another_marker_on_a_plate_identity_while_the_plate_was_hidden_gives_it_back():
    """The plate is hidden from frame 360; a skin marker, lost at 360 too, is re-identified as the plate's first
    marker's identity from 400, and the plate comes back at 400 under new identities. The plate's shape names the
    returning markers; the skin marker has no vote for a member its identity would give it, while that member's
    marker is voted elsewhere: it leaves for an identity of its own, and the plate takes its identities back."""
    rng = np.random.default_rng(12)
    truth = np.concatenate([moving(PLATE, rng, 0.0), moving(TRIANGLE, rng, 0.6), skin(3, rng)], axis=1)
    P = np.concatenate([truth, np.full((FRAMES, 4, 3), np.nan)], axis=1)
    P[HIDDEN:, :4] = np.nan
    P[HIDDEN:, 7] = np.nan
    P[BACK:, 0] = truth[BACK:, 7]  # the skin marker on the plate's first identity
    P[BACK:, 10:14] = truth[BACK:, :4]  # the plate back under new identities
    traj = Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 100.0, P)
    before = _samples_per_frame(traj)
    label_plates(traj)
    follows = columns_follow(traj, truth)
    assert follows[:4] == [0, 1, 2, 3]  # each plate identity holds its own marker before and after the gap
    assert sorted(follows) == [0, 1, 2, 3, 4, 5, 6, 7, 7, 8, 9]  # the skin marker: two identities, one its own
    after = _samples_per_frame(traj)
    assert all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))


def test_a_tracklet_given_a_member_is_backed_by_its_own_votes_where_they_are_a_fifth_of_it():
    """A tracklet given member 5 by its identity's voted neighbour: with no votes of its own it is not backed by
    them, nor with a few that chance could give (4 in 40), and it is with 10 in 40 (a plate whose shape changed a
    little after a gap matches only some of its triangles)."""
    vote = np.full((100, 1), -1)
    vote[60:70, 0] = 5
    runs = [(0, np.arange(10, 50)), (0, np.arange(60, 70))]
    assert _destinations(runs, vote, PlateConfig()) == ([5, 5], [False, True])
    vote[[12, 20, 30, 40], 0] = 5
    assert _destinations(runs, vote, PlateConfig()) == ([5, 5], [False, True])
    vote[14:40:4, 0] = 5
    assert _destinations(runs, vote, PlateConfig()) == ([5, 5], [True, True])


def test_a_member_voted_elsewhere_for_a_few_frames_of_its_identity_s_long_track_leaves_it_in_place():
    """Member 5's identity holds a track of 100 samples without votes (a skin marker of the plate, a few
    millimetres off its shape); another identity's 9 samples are voted member 5 by chance. The long track stays;
    a 10-sample tracklet in the same frames, which the vote covers, leaves for an identity of its own."""
    claimant = (3, np.arange(40, 49))
    assert _evicted([(5, np.arange(100)), claimant], [-1, 5], [False, True], (100, 8)) == [False, False]
    assert _evicted([(5, np.arange(40, 50)), claimant], [-1, 5], [False, True], (100, 8)) == [True, False]
    assert _evicted([(5, np.arange(40, 50)), claimant], [-1, 5], [True, True], (100, 8)) == [False, False]
