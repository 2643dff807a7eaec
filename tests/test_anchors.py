"""Fragments rejoined by their distances to rigid neighbours (mocap.anchors) on scripted segments."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.anchors import AnchorConfig, move_refuted_samples, rejoin_by_anchors
from mocap.plates import PlateConfig, label_plates
from mocap.trajectories import Trajectories

F = 600
FPS = 120.0


def _segment(local: np.ndarray, seed: int, noise_m: float = 0.0003) -> np.ndarray:
    """(F, n, 3) markers at ``local`` (n, 3) m on a segment that turns and travels, with noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(F) / FPS
    turn = Rotation.from_rotvec(np.stack([0.9 * np.sin(2.1 * t), 0.6 * np.cos(1.3 * t), 0.8 * t], axis=1))
    centre = np.stack([0.5 * np.sin(0.7 * t), 0.4 * np.cos(0.9 * t), 1.0 + 0.1 * t], axis=1)
    world = np.stack([turn.apply(p) for p in local], axis=1) + centre[:, None, :]
    return world + rng.normal(scale=noise_m, size=world.shape)


def _columns(truth: np.ndarray, pieces: list[list[tuple[int, int, int]]], fps: float = FPS) -> Trajectories:
    """Identity columns made of pieces (truth marker, first frame, end frame) of ``truth`` (F, n, 3)."""
    P = np.full((F, len(pieces), 3), np.nan)
    for col, parts in enumerate(pieces):
        for marker, a, b in parts:
            P[a:b, col] = truth[a:b, marker]
    return Trajectories([f"id{k}" for k in range(len(pieces))], fps, P)


def _holder(traj: Trajectories, truth: np.ndarray, marker: int) -> dict[int, int]:
    """{column: samples} of the output samples that are truth ``marker``'s."""
    d = np.linalg.norm(traj.positions - truth[:, marker, None, :], axis=2)
    cols, counts = np.unique(np.nonzero(d < 1e-9)[1], return_counts=True)
    return dict(zip(cols.tolist(), counts.tolist(), strict=True))


# The forearm of the sprint take: A1 and A2 49 mm apart; X 75 mm from A1 and 46 mm from A2, so that A2 is
# nearly equidistant from A1 and X (the plate pass refuses such a triangle); Y 60 and 64 mm from them.
FOREARM = np.array([[0.0, 0.0, 0.0], [0.049, 0.0, 0.0], [0.060, 0.045, 0.0], [0.020, 0.040, 0.040]])
A1, A2, X, Y = range(4)


def test_fragments_of_a_marker_join_it_and_its_neighbours_fragments_do_not():
    truth = np.concatenate([_segment(FOREARM, seed=1), _segment(np.array([[0.0, 0.0, 0.15]]), seed=2)[:, :, ::-1]],
                           axis=1)  # + a marker 0.15 m off on another, unrelated motion (not an anchor)
    other = 4
    traj = _columns(truth, [
        [(A1, 0, F)], [(A2, 0, F)],
        [(X, 0, 200)],  # X's identity, lost at frame 200
        [(X, 250, 300)], [(X, 400, 430)],  # X back twice as new identities
        [(Y, 0, 300), (Y, 450, F)],  # Y's identity
        [(Y, 330, 360)],  # Y back for a while as a new identity
        [(other, 0, F)],
    ])
    before = np.isfinite(traj.positions[..., 0]).sum()
    joined = rejoin_by_anchors(traj)
    assert joined == 3
    assert _holder(traj, truth, X) == {2: 280}
    assert _holder(traj, truth, Y) == {5: 480}
    assert np.isfinite(traj.positions[..., 0]).sum() == before  # nothing dropped
    # The plate pass cannot do it: the triangle A1-A2-X has two labellings.
    plates = _columns(truth, [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 200)], [(X, 250, 300)], [(X, 400, 430)]])
    label_plates(plates, PlateConfig(min_frames=30))
    assert 3 in _holder(plates, truth, X) and 4 in _holder(plates, truth, X)


def test_where_the_target_held_a_neighbour_the_fitting_sample_stays_and_the_other_moves_out():
    truth = _segment(FOREARM, seed=3)
    traj = _columns(truth, [
        [(A1, 0, F)], [(A2, 0, F)],
        [(X, 0, 150), (Y, 150, 170), (X, 170, 300)],  # X's identity hopped onto Y for 20 frames
        [(X, 150, 170), (X, 500, 540)],  # X under a new identity meanwhile, and again later
        [(Y, 0, 150), (Y, 170, F)],
    ])
    before = np.isfinite(traj.positions[..., 0]).sum()
    one_pass = _columns(truth, [
        [(A1, 0, F)], [(A2, 0, F)], [(X, 0, 150), (Y, 150, 170), (X, 170, 300)], [(X, 150, 170), (X, 500, 540)],
        [(Y, 0, 150), (Y, 170, F)]])
    assert rejoin_by_anchors(one_pass, AnchorConfig(loose_spread_m=0.0)) == 1
    assert _holder(one_pass, truth, X) == {2: 340}
    held = _holder(one_pass, truth, Y)
    assert held.pop(4) == 580 and list(held.values()) == [20] and list(held)[0] >= 5  # to a new identity
    assert one_pass.labels[-1].startswith("fragment")
    # the second pass (loose anchors) joins the samples moved out to Y's identity: its anchors fit them too
    assert rejoin_by_anchors(traj) == 2
    assert _holder(traj, truth, X) == {2: 340} and _holder(traj, truth, Y) == {4: 600}
    assert np.isfinite(traj.positions[..., 0]).sum() == before


def test_where_no_anchor_is_seen_in_a_shared_frame_it_goes_with_the_frames_around_it():
    """As above, with both anchors unseen over frames 155-160: those frames tell nothing, and they go with the
    shared frames around them (X's samples to X's identity), not to the target's own sample (the serve's fresh
    5 %-hidden seed 37: LASI's and RBAK's samples alternated between two identities wherever the one anchor was
    unseen, 16 switches)."""
    truth = _segment(FOREARM, seed=3)
    traj = _columns(truth, [
        [(A1, 0, 155), (A1, 161, F)], [(A2, 0, 155), (A2, 161, F)],
        [(X, 0, 150), (Y, 150, 170), (X, 170, 300)],
        [(X, 150, 170), (X, 500, 540)],
        [(Y, 0, 150), (Y, 170, F)],
    ])
    assert rejoin_by_anchors(traj, AnchorConfig(loose_spread_m=0.0)) == 1
    assert _holder(traj, truth, X) == {2: 340}
    held = _holder(traj, truth, Y)
    assert held.pop(4) == 580 and list(held.values()) == [20]


def test_a_fragment_that_fits_two_markers_seen_together_is_left_alone():
    mirror = np.array([[0.0, 0.0, 0.0], [0.049, 0.0, 0.0], [0.030, 0.050, 0.0], [0.030, -0.050, 0.0]])
    truth = _segment(mirror, seed=4)  # markers 2 and 3: the same distances to 0 and 1
    traj = _columns(truth, [[(0, 0, F)], [(1, 0, F)], [(2, 0, 300)], [(3, 0, 300)], [(2, 400, 450)]])
    assert rejoin_by_anchors(traj) == 0
    assert _holder(traj, truth, 2) == {2: 300, 4: 50}


def test_one_anchor_is_not_enough_and_the_tolerance_decides():
    truth = _segment(FOREARM, seed=5)
    one = _columns(truth, [[(A1, 0, F)], [(X, 0, 200)], [(X, 300, 350)]])
    assert rejoin_by_anchors(one) == 0
    two = [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 200)], [(X, 300, 350)]]
    assert rejoin_by_anchors(_columns(truth, two)) == 1
    # A marker 8 mm farther out than X is another marker at a 6 mm tolerance, the same one at 10 mm.
    out = FOREARM[X] * (1.0 + 0.008 / np.linalg.norm(FOREARM[X]))  # (7 mm farther from A2)
    moved = np.concatenate([truth, _segment(out[None], seed=5)], axis=1)
    near = [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 200)], [(4, 300, 350)]]
    assert rejoin_by_anchors(_columns(moved, near)) == 0
    assert rejoin_by_anchors(_columns(moved, near), AnchorConfig(tolerance_m=0.010)) == 1


# A wheelchair frame's markers: 0.45-0.8 m apart, none within the 0.3 m reach of another.
FRAME = np.array([[0.0, 0.0, 0.0], [0.80, 0.0, 0.0], [0.30, 0.55, 0.10], [0.60, 0.40, -0.20]])


def test_a_marker_with_no_anchor_within_reach_takes_its_anchors_farther_out():
    truth = np.concatenate([_segment(FRAME, seed=7), _segment(np.array([[0.0, 0.0, 0.5]]), seed=8)[:, :, ::-1]],
                           axis=1)  # + a marker on another, unrelated motion
    other = 4
    pieces = [[(0, 0, F)], [(1, 0, F)], [(2, 0, F)],
              [(3, 0, 200)], [(3, 300, F)],  # marker 3 back as a new identity after a gap
              [(other, 0, 350)], [(other, 420, F)]]  # the other marker back as a new identity too
    near_only = _columns(truth, pieces)
    assert rejoin_by_anchors(near_only, AnchorConfig(far_reach_m=0.3)) == 0
    traj = _columns(truth, pieces)
    assert rejoin_by_anchors(traj) == 1
    assert list(_holder(traj, truth, 3).values()) == [500]  # (the shorter piece joins the longer)
    assert _holder(traj, truth, other) == {5: 350, 6: 180}  # (nothing rigid to it: no anchors, left alone)


def test_far_neighbours_that_only_sat_still_with_a_marker_are_not_its_anchors():
    """The athlete sits still for 60 % of the take: three wheel markers 0.5 m off keep their distances to the frame
    then (the median and MAD over the take say rigid) and turn after. Judged over the frames in which the marker
    moves, they are not its anchors, so its fragment after a gap joins it (with them it would be 3 against 3)."""
    moving = _segment(FRAME, seed=9)
    still = 360
    frame = np.concatenate([np.repeat(moving[:1], still, axis=0), moving[:F - still]], axis=0)
    rng = np.random.default_rng(9)
    spin = Rotation.from_rotvec(np.outer(np.r_[np.zeros(still), np.linspace(0.0, 6.0, F - still)], [0.0, 0.0, 1.0]))
    hub = frame[:, 3] + np.array([0.4, 0.0, 0.1])
    wheel = np.stack([hub + spin.apply(np.array(off)) for off in ([0.2, 0.0, 0.0], [0.0, 0.2, 0.0], [-0.2, 0.0, 0.0])],
                     axis=1)
    truth = np.concatenate([frame, wheel], axis=1) + rng.normal(scale=0.0003, size=(F, 7, 3))
    pieces = [[(0, 0, F)], [(1, 0, F)], [(2, 0, F)], [(3, 0, 420)], [(3, 480, F)],  # marker 3 back after a gap
              [(4, 0, F)], [(5, 0, F)], [(6, 0, F)]]
    assert rejoin_by_anchors(_columns(truth, pieces), AnchorConfig(moving_mps=0.0)) == 0
    traj = _columns(truth, pieces)
    assert rejoin_by_anchors(traj) == 1
    assert list(_holder(traj, truth, 3).values()) == [540]


def test_a_sample_no_anchor_of_its_own_identity_can_judge_goes_where_anchors_fit_it():
    """Marker 2's identity holds marker 5's point for frames 300-309 while marker 2's plate is hidden; marker 5's
    plate is seen there and fits it, so those samples go to marker 5's identity."""
    plate = np.concatenate([_segment(FOREARM[:3], seed=10), _segment(FOREARM[:3] * 1.3, seed=11)[:, :, ::-1]], axis=1)
    hidden = np.arange(300, 310)
    traj = _columns(plate, [[(0, 0, F)], [(1, 0, F)], [(2, 0, 295), (5, 300, 310), (2, 320, F)],
                            [(3, 0, F)], [(4, 0, F)], [(5, 0, 300), (5, 310, F)]])
    traj.positions[hidden, :2] = np.nan  # marker 2's plate hidden
    assert move_refuted_samples(traj) == 10
    assert _holder(traj, plate, 5) == {5: F}


def test_a_fragment_of_a_marker_by_a_joint_joins_it():
    # An elbow marker 0.12 m from A1 and A2: its distances to them change by +-6 mm with the joint over the take
    # (spread about 6 mm, over the 5 mm of a loose anchor), but hardly over a fragment of 50 frames.
    base = _segment(np.vstack([FOREARM[[A1, A2]], [0.02, -0.12, 0.0]]), seed=6)
    outward = base[:, 2] - base[:, :2].mean(axis=1)
    truth = base.copy()
    truth[:, 2] += 0.006 * np.sin(2 * np.pi * np.arange(F) / 300)[:, None] * outward / np.linalg.norm(
        outward, axis=1, keepdims=True)
    pieces = [[(0, 0, F)], [(1, 0, F)], [(2, 0, 300)], [(2, 400, 450)]]
    assert rejoin_by_anchors(_columns(truth, pieces), AnchorConfig(joint_spread_m=0.003)) == 0
    traj = _columns(truth, pieces)
    assert rejoin_by_anchors(traj) == 1
    assert _holder(traj, truth, 2) == {2: 350}


def test_the_identity_repair_runs_it():
    from mocap.relabel import RelabelConfig, repair_identities

    truth = _segment(FOREARM, seed=6)
    traj = _columns(truth, [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 200)], [(X, 260, 330)], [(Y, 0, F)]])
    # (the re-linking joins this clean scene by itself across the gap: limited here to short gaps)
    stats = repair_identities(traj, RelabelConfig(shape_max_s=0.05, lone_max_s=0.05))
    assert stats.stitches == 0 and stats.rejoined == 1
    assert traj.n_markers == 4 and traj.labels == ["M001", "M002", "M003", "M004"]
    assert list(_holder(traj, truth, X).values()) == [270]


def test_the_identity_repair_joins_a_fragment_whose_identity_a_later_pass_freed():
    """The two players' fresh 5 %-hidden seed 38 at 50 Hz: LTOE, lost for 1.4 s, came back under a new identity,
    and the tracker had given LTOE's own identity to LTIB, back from a gap of its own meanwhile. The anchors could
    not join the two (the identity held LTIB over the fragment's frames); the bridge gave LTIB back to its identity
    later in the repair, and the fragment has to be offered to the anchors again then. Here X is a skin marker whose
    distances to A1 and A2 spread 4-5 mm (too loose for the re-linking's distances, within the loose anchors'), Z a
    marker of another, wobbling segment drifting away from the arm."""
    from mocap.relabel import RelabelConfig, repair_identities

    arm = _segment(FOREARM[[A1, A2, X]], seed=11)
    along = arm[:, 2] - arm[:, 0]
    arm[:, 2] += 0.0045 * np.sin(2 * np.pi * np.arange(F) / 17)[:, None] * along / np.linalg.norm(
        along, axis=1, keepdims=True)
    other = _segment(np.vstack([FOREARM[:3], FOREARM[:2] + [0.0, 0.0, 0.08]]) + [0.2, 0.0, 0.0], seed=12)
    t = np.arange(F)[:, None]
    other += 0.02 * np.sin(2 * np.pi * t / np.array([15, 11, 9, 13, 17]) + np.arange(5))[:, :, None] * np.array(
        [1.0, 0.5, -0.7])
    other += np.linspace(0.0, 0.1, F)[:, None, None] * np.array([1.0, 0.0, 0.0])
    truth = np.concatenate([arm, other], axis=1)  # A1, A2, X, then the other segment's five markers, Z the third
    x, z = 2, 5
    traj = _columns(truth, [[(0, 0, F)], [(1, 0, F)], [(3, 0, F)], [(4, 0, F)], [(6, 0, F)], [(7, 0, F)],
                            [(x, 0, 250), (z, 430, F)],  # X's identity, given to Z after X was lost
                            [(z, 0, 300)],  # Z's own identity
                            [(x, 520, F)]],  # X back under a new identity
                    fps=50.0)
    stats = repair_identities(traj, RelabelConfig())
    assert stats.bridged == 1
    assert list(_holder(traj, truth, x).values()) == [330]
    assert list(_holder(traj, truth, z).values()) == [470]


def test_a_run_where_an_identity_hopped_onto_a_neighbour_moves_to_the_neighbours_identity():
    truth = _segment(FOREARM, seed=7)
    traj = _columns(truth, [
        [(A1, 0, F)], [(A2, 0, F)],
        [(X, 0, 150), (Y, 150, 170), (X, 170, F)],  # X's identity on Y for 20 frames while X is hidden
        [(Y, 0, 150), (Y, 170, F)],  # Y's identity lost meanwhile
    ])
    assert move_refuted_samples(traj) == 20
    assert _holder(traj, truth, X) == {2: 580} and _holder(traj, truth, Y) == {3: F}
    # A neighbour's identity already seen in those frames: nowhere to go.
    kept = _columns(truth, [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 150), (Y, 150, 170), (X, 170, F)], [(Y, 0, F)]])
    assert move_refuted_samples(kept) == 0


def test_a_run_that_continues_the_identitys_path_stays():
    """A marker 10 mm beyond X, away from its anchors (8-10 mm farther from each): X's identity on it for 3 frames is
    a step of 10 mm there and back. Under the 15 mm hop those frames are 3 of X's piece of 600; at 5 mm they are a
    piece of their own, and move."""
    away = FOREARM[X] - FOREARM[[A1, A2, Y]].mean(axis=0)
    near = FOREARM[X] + 0.010 * away / np.linalg.norm(away)
    truth = np.concatenate([_segment(FOREARM, seed=8), _segment(near[None], seed=8)], axis=1)
    pieces = [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 300), (4, 300, 303), (X, 303, F)], [(Y, 0, F)],
              [(4, 0, 300), (4, 303, F)]]
    assert move_refuted_samples(_columns(truth, pieces)) == 0
    assert move_refuted_samples(_columns(truth, pieces), AnchorConfig(hop_m=0.005)) == 3


def test_a_sample_some_anchors_agree_with_is_not_refuted():
    """X's identity stays on X while its anchor Y's identity holds a point 30 mm off (frames 400-410); a second
    identity of X (frames 100-300) fits X's samples there too: even with every piece cut at each reversal
    (``hop_m`` 0), nothing moves, because two of three anchors agree."""
    truth = _segment(FOREARM, seed=10)
    traj = _columns(truth, [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, F)], [(Y, 0, F)], [(X, 100, 300)]])
    traj.positions[400:410, 3] += [0.03, 0.0, 0.0]
    assert move_refuted_samples(traj, AnchorConfig(hop_m=0.0)) == 0


def test_pieces_of_an_identity_without_anchors_go_where_they_fit_whole():
    """The tracker's identity for X and Y seen in turn (frames 250-400, 75 samples each) has no anchors: its distances
    spread. Its pieces go to X's and Y's identities, whole: two samples 8 mm off (a merged blob), out of the
    tolerance, go with their piece."""
    truth = _segment(FOREARM, seed=11)
    pieces = [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 250), (X, 400, F)], [(Y, 0, 250), (Y, 400, F)],
              [(X, 250, 300), (Y, 300, 375), (X, 375, 400)]]
    traj = _columns(truth, pieces)
    traj.positions[[270, 271], 4] += [0.008, 0.0, 0.0]
    assert move_refuted_samples(traj) == 150
    assert _holder(traj, truth, X) == {2: 523} and _holder(traj, truth, Y) == {3: 525}
    assert np.isfinite(traj.positions[[270, 271], 2, 0]).all() and not np.isfinite(traj.positions[:, 4, 0]).any()


def test_a_hop_on_the_first_sample_after_a_gap_moves():
    """X's identity comes back from a gap on Y for one frame, then goes on with X: no acceleration shows the hop (the
    sample before it is missing), but the votes change there, and X's path does not go through Y's sample."""
    truth = _segment(FOREARM, seed=12)
    pieces = [[(A1, 0, F)], [(A2, 0, F)], [(X, 0, 200), (Y, 210, 211), (X, 211, F)], [(Y, 0, 210), (Y, 211, F)]]
    traj = _columns(truth, pieces)
    assert move_refuted_samples(traj) == 1
    assert _holder(traj, truth, X) == {2: 589} and _holder(traj, truth, Y) == {3: F}


def test_the_identity_repair_moves_samples_by_anchors():
    from mocap.relabel import RelabelConfig, repair_identities

    truth = _segment(FOREARM, seed=9)
    traj = _columns(truth, [
        [(A1, 0, F)], [(A2, 0, F)],
        [(X, 0, 150), (Y, 150, 200), (X, 200, F)],  # X's identity on Y for 50 frames
        [(Y, 0, 100)], [(Y, 200, F)],  # Y in two identities
    ])
    # (the re-linking cuts and re-links this slow scene's 57 mm hops by itself: not here, as in a fast swing)
    stats = repair_identities(traj, RelabelConfig(shape_max_s=0.05, lone_max_s=0.05, split_acc_m=1.0,
                                                  split_reversal_m=1.0))
    assert stats.anchor_moves == 50 and stats.rejoined == 1
    assert _holder(traj, truth, X) == {2: 550} and _holder(traj, truth, Y) == {3: 550}


def test_a_skin_marker_whose_anchors_spread_a_few_millimetres_rejoins_after_a_long_gap():
    """The two players with 5 % of the views hidden (seed 5): an elbow's and a toe's skin markers, back after long
    gaps as new identities, keep their distances to their neighbours within 3-5 mm. Here a marker wobbles +-5 mm on
    a rigid segment of three (its distances spread 4.0-4.6 mm): its fragment after a 1 s gap joins its identity in
    the second pass; with anchors held to 3 mm in both it finds none."""
    trunk = np.array([[0.0, 0.0, 0.0], [0.17, 0.0, 0.0], [0.08, 0.14, 0.02], [0.06, 0.05, 0.12]])
    t = np.arange(F)[:, None] / FPS
    rng = np.random.default_rng(9)
    truth = _segment(trunk, seed=8)
    truth[:, 3] += 0.005 * np.sin(2 * np.pi * rng.uniform(0.3, 1.0, (1, 3)) * t + rng.uniform(0, 2 * np.pi, (1, 3)))
    pieces = [[(0, 0, F)], [(1, 0, F)], [(2, 0, F)], [(3, 0, 250)], [(3, 370, F)]]
    assert rejoin_by_anchors(_columns(truth, pieces), AnchorConfig(loose_spread_m=0.003)) == 0
    traj = _columns(truth, pieces)
    assert rejoin_by_anchors(traj) == 1
    assert _holder(traj, truth, 3) == {3: 480}


def test_the_samples_of_the_held_neighbour_in_the_frames_the_fragment_misses_move_out_with_the_others():
    """The whole sprint at seed 1, ForearmL Marker3 and Marker4 (frames 1911-1959): X's identity holds Y from frame
    153; X, back under a new identity in every other frame from 160 (hidden in between), is joined to it, and in
    the shared frames X's sample replaces Y's, which moves out. Y's samples in the frames between, which X misses,
    continue the moved-out ones (a frame away, nearer them than X's) and move out with them: X's identity no longer
    alternates between X and Y (17 switches in that window of the sprint); where no anchor is seen (153-185) the
    shared frames go with the nearest told one, as before."""
    truth = _segment(FOREARM, seed=3)
    traj = _columns(truth, [
        [(A1, 0, 153), (A1, 186, F)], [(A2, 0, 153), (A2, 186, F)],
        [(X, 0, 153), (Y, 153, 191), (X, 191, 300)],
        [(Y, 150, 153)] + [(X, f, f + 1) for f in range(160, 191, 2)] + [(X, 500, 540)],
        [(Y, 0, 150), (Y, 191, F)],
    ])
    before = np.isfinite(traj.positions[..., 0]).sum()
    assert rejoin_by_anchors(traj, AnchorConfig(loose_spread_m=0.0)) == 1
    on_x = np.linalg.norm(traj.positions[170:191, 2] - truth[170:191, Y], axis=1) < 1e-9
    assert not on_x.any()  # (without the rule: Y in every odd frame 171-189)
    spill = traj.positions[170:191, -1]
    np.testing.assert_array_equal(spill[np.isfinite(spill[:, 0])], truth[170:191, Y][np.isfinite(spill[:, 0])])
    assert np.isfinite(traj.positions[..., 0]).sum() == before
