"""Offline identity repair: swaps undone, fragments re-linked, clean identities untouched."""

from __future__ import annotations

import numpy as np
import pytest
from helpers_engine import body_take

from mocap.evaluate import evaluate
from mocap.relabel import (
    RelabelConfig,
    drop_duplicates,
    relink_tracklets,
    repair_identities,
    repair_swaps,
    withdraw_scattered,
)
from mocap.rigid import split_tracklets
from mocap.synth import SynthSettings
from mocap.tracker import Tracker
from mocap.trajectories import Trajectories


def _scene(n_frames: int = 120, n_markers: int = 6, seed: int = 0) -> np.ndarray:
    """(F, M, 3) smooth paths, markers >= 0.1 m apart, moving up to ~40 mm/frame."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None, None]
    base = np.stack([np.arange(n_markers) * 0.12, np.zeros(n_markers), np.ones(n_markers)], axis=1)
    freq = rng.uniform(0.02, 0.06, (1, n_markers, 3))
    amp = rng.uniform(0.05, 0.12, (1, n_markers, 3))
    return base[None] + amp * np.sin(2 * np.pi * freq * t + rng.uniform(0, 6, (1, n_markers, 3)))


def _traj(P: np.ndarray) -> Trajectories:
    return Trajectories([f"M{k + 1:03d}" for k in range(P.shape[1])], 50.0, P.copy())


def _same_identities(traj: Trajectories, truth: np.ndarray) -> bool:
    """Every output identity follows exactly one truth marker over all its samples."""
    for col in range(traj.n_markers):
        rows = np.isfinite(traj.positions[:, col, 0])
        d = np.linalg.norm(truth[rows] - traj.positions[rows, col][:, None], axis=2)  # (n, M)
        if not (d.argmin(axis=1) == d[0].argmin()).all() or d.min(axis=1).max() > 1e-12:
            return False
    return True


def test_clean_trajectories_are_left_alone():
    P = _scene()
    traj = _traj(P)
    stats = repair_identities(traj)
    assert stats.swaps == 0 and stats.stitches == 0
    np.testing.assert_array_equal(traj.positions, P)


def test_swapped_tails_are_swapped_back():
    P = _scene()
    swapped = P.copy()
    swapped[60:, [1, 2]] = P[60:, [2, 1]]
    traj = _traj(swapped)
    assert repair_swaps(traj) == 1
    np.testing.assert_array_equal(traj.positions, P)


def test_fragment_is_relinked_and_swap_through_a_gap_undone():
    P = _scene()
    broken = np.concatenate([P, np.full((P.shape[0], 2, 3), np.nan)], axis=1)
    broken[50:53, 0] = np.nan  # marker 0 lost for 3 frames ...
    broken[53:, 6] = P[53:, 0]  # ... and found again as a new identity
    broken[53:, 0] = np.nan
    broken[80, [3, 4]] = np.nan  # markers 3 and 4 missing one frame, then exchanged
    broken[81:, [3, 4]] = P[81:, [4, 3]]
    traj = _traj(broken)
    relink_tracklets(traj)
    assert traj.n_markers == 6
    assert _same_identities(traj, P)


def test_stitch_gate_allows_an_acceleration_in_real_time_not_per_frame():
    """At 120 Hz a 10-frame gap is 83 ms: a marker back on its path is stitched, a newcomer 0.4 m away is not.
    The gate's acceleration term was per squared frame, tuned at 50 Hz, so at 120 Hz it allowed 144 m/s^2 (1 m
    over this gap) and newcomers took the identities of markers lost nearby (the whole sprint: plates coming
    back after the recording's gap joined to forearm markers)."""
    t = np.arange(200)[:, None] / 120.0
    A = np.hstack([0.6 * t, 0.2 * np.sin(3 * t), np.ones_like(t)])  # 5 mm/frame, gently curving
    P = np.full((200, 3, 3), np.nan)
    P[:60, 0] = A[:60]  # marker A, lost at frame 60 ...
    P[70:120, 1] = A[70:120]  # ... back on its path 10 frames later, then gone for good
    P[130:, 2] = A[130:] + [0.0, 0.4, 0.0]  # a newcomer 10 frames later, 0.4 m from A's path
    traj = Trajectories(["M001", "M002", "M003"], 120.0, P.copy())
    relink_tracklets(traj)
    owner = {k: int(np.flatnonzero(np.isfinite(traj.positions[k, :, 0]))[0]) for k in (10, 100, 150)}
    assert owner[10] == owner[100]  # A's two pieces are one identity
    assert owner[150] != owner[10]  # the newcomer did not take it


def test_tracker_link_across_a_long_gap_is_kept():
    P = _scene()
    gappy = P.copy()
    gappy[30:70, 2] = np.nan  # 40 frames: beyond max_gap, but the tracker re-identified it
    traj = _traj(gappy)
    assert relink_tracklets(traj, RelabelConfig(max_gap=12)) == 0
    np.testing.assert_array_equal(traj.positions, gappy)


def _segment(n_frames: int = 160) -> np.ndarray:
    """(F, 5, 3): five markers of one rigid segment (30-90 mm apart) that translates and turns ~1 rad/s."""
    t = np.arange(n_frames) / 50.0
    local = np.array([[0.0, 0.0, 0.0], [0.06, 0.0, 0.0], [0.0, 0.05, 0.0], [0.03, 0.03, 0.04], [-0.04, 0.05, 0.02]])
    a = 1.0 * t
    R = np.zeros((n_frames, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a), 1.0
    centre = np.stack([0.3 * t, 0.1 * np.sin(2 * t), 1.0 + 0.05 * t], axis=1)
    return centre[:, None, :] + np.einsum("fij,mj->fmi", R, local)


def test_marker_back_after_a_long_gap_is_relinked_by_its_segment():
    """A marker of a rigid segment is hidden for 40 frames (beyond max_gap) and comes back as a new identity:
    the distances to its neighbours, unchanged by the segment's motion, link it to its old identity."""
    P = _segment()
    broken = np.concatenate([P, np.full((P.shape[0], 1, 3), np.nan)], axis=1)
    broken[60:, 5] = P[60:, 0]
    broken[20:, 0] = np.nan
    traj = _traj(broken)
    assert relink_tracklets(traj) == 1
    assert traj.n_markers == 5 and _same_identities(traj, P)


def test_new_marker_does_not_keep_a_hidden_neighbours_identity():
    """The tracker gave a new marker (never seen before, 64 mm from a marker that just vanished, within the
    extrapolation gate) that marker's identity; its distances to the segment's markers disagree by 34 mm, so it
    becomes an identity of its own."""
    P = _segment()
    newcomer = P[:, 0] + np.array([0.0, -0.05, -0.04])
    truth = np.concatenate([P, newcomer[:, None]], axis=1)
    seen = P.copy()
    seen[80:, 0] = newcomer[80:]  # marker 0 vanishes at frame 78; from 80 its column follows the newcomer
    seen[78:80, 0] = np.nan
    traj = _traj(seen)
    relink_tracklets(traj)
    assert traj.n_markers == 6
    assert _same_identities(traj, truth)


def test_cluster_back_in_view_together_is_relinked_by_its_own_distances():
    """A whole rigid segment is hidden for 40 frames while it turns; its five markers come back in the same
    frame with the tracker's identities rotated among them. With no marker in view on both sides, only the
    distances between the returning markers tell which is which."""
    P = _segment()
    hidden = P.copy()
    hidden[60:100] = np.nan
    rotated = hidden.copy()
    rotated[100:] = P[100:, [1, 2, 3, 4, 0]]
    traj = _traj(rotated)
    relink_tracklets(traj)
    assert traj.n_markers == 5
    assert _same_identities(traj, P)


def test_a_symmetric_cluster_back_in_view_is_told_from_its_mirror_image_by_its_neighbours():
    """The whole sprint's forearm: three skin markers on an isosceles triangle (here exactly: 50, 50 and 60 mm) are
    hidden for 80 frames at 120 Hz while the elbow opens, and come back with the tracker's identities of its two
    ends exchanged. Their own distances fit both ways; the upper arm's markers (0.3 m away, in view throughout)
    stand nearer one end than the other, and that decides."""
    F = 220
    s = np.linspace(0.0, 1.0, F)[:, None]
    elbow = np.array([0.0, 0.0, 1.0]) + s * np.array([0.3, 0.1, 0.0])
    u, w, n = np.eye(3)
    theta = np.radians(110.0 + 20.0 * s)
    v = np.cos(theta) * u + np.sin(theta) * w  # (F, 3) the forearm's direction
    upper = [0.12 * u + 0.03 * n, 0.16 * u - 0.03 * n, 0.20 * u + 0.03 * n]
    fore = [0.20 * v, 0.23 * v + 0.04 * n, 0.26 * v]
    P = np.stack([elbow + p for p in upper] + [elbow + p for p in fore], axis=1)  # (F, 6, 3)
    returned = P.copy()
    returned[60:140, 3:] = np.nan
    returned[140:, [3, 5]] = P[140:, [5, 3]]
    traj = Trajectories([f"M{k + 1:03d}" for k in range(6)], 120.0, returned)
    relink_tracklets(traj)
    assert traj.n_markers == 6
    assert _same_identities(traj, P)


def test_a_cluster_glimpsed_twice_keeps_its_layout():
    """The whole sprint's forearm at frames 2654 and 2656: three markers (47, 49 and 80 mm apart) moving 20 mm a
    frame at 120 Hz along their shortest side are seen for single frames two apart. A lone sample has no
    velocity, and its standing extrapolation lies nearer the marker ahead; the one step that carries all three
    onto their next glimpse links them."""
    triangle = np.array([[0.0, 0.0, 0.0], [0.047, 0.0, 0.0], [0.0655, 0.045, 0.0]])
    step = 0.02 * (triangle[1] - triangle[0]) / np.linalg.norm(triangle[1] - triangle[0])
    P = np.array([0.0, 0.0, 1.0]) + triangle[None] + np.arange(100)[:, None, None] * step
    seen = np.zeros(100, dtype=bool)
    seen[:40] = seen[[46, 48]] = seen[60:] = True
    glimpsed = np.where(seen[:, None, None], P, np.nan)
    for members, linked in ((3, True), (4, False)):  # (needing a fourth marker: no such rule)
        traj = Trajectories(["a", "b", "c"], 120.0, glimpsed.copy())
        relink_tracklets(traj, RelabelConfig(glimpse_members=members))
        assert (traj.n_markers == 3 and _same_identities(traj, P)) == linked


def _newcomer_took_the_identity(P: np.ndarray, newcomer: np.ndarray, vanish: int, follow: int, back: int
                                ) -> tuple[np.ndarray, np.ndarray]:
    """(truth, seen) of a newcomer keeping a vanished marker's identity: marker 0 of ``P`` vanishes at ``vanish``,
    its column follows ``newcomer`` (F, 3) from ``follow``, and the marker comes back at ``back`` as a new identity
    (column 5)."""
    truth = np.concatenate([P, newcomer[:, None]], axis=1)
    seen = np.concatenate([P, np.full((P.shape[0], 1, 3), np.nan)], axis=1)
    seen[vanish:, 0] = np.nan
    seen[follow:, 0] = newcomer[follow:]
    seen[back:, 5] = P[back:, 0]
    return truth, seen


def _assert_marker_0_has_its_identity_back(traj: Trajectories, P: np.ndarray, back: int) -> None:
    owner_of_0 = [c for c in range(traj.n_markers) if np.allclose(traj.positions[10, c], P[10, 0])][0]
    np.testing.assert_array_equal(traj.positions[back:, owner_of_0], P[back:, 0])


def test_marker_back_takes_its_identity_back_from_a_newcomer():
    """A newcomer on the same segment, 13 mm from a marker that just vanished, kept that marker's identity (its
    distances changed by 5.7 mm, within the gate); when the marker itself comes back, 20 frames later, its
    distances fit the identity's from before the gap exactly, and it takes the identity back."""
    P = _segment()
    newcomer = P[:, 0] + np.array([0.0, -0.01, -0.008])
    truth, seen = _newcomer_took_the_identity(P, newcomer, vanish=78, follow=80, back=100)
    traj = _traj(seen)
    relink_tracklets(traj)
    assert traj.n_markers == 6
    assert _same_identities(traj, truth)
    _assert_marker_0_has_its_identity_back(traj, P, 100)


def test_marker_back_takes_its_identity_back_from_a_far_newcomer():
    """The whole sprint's ScapularSpineL, hidden for 57 frames: a forearm marker first seen 0.42 m from where it
    vanished took its identity in the tracker (inside the widened re-identification radius); no distance to a
    common neighbour measured that link. When the marker itself comes back, its distances fit the identity's from
    before the gap, and it takes the identity back; the newcomer becomes an identity of its own."""
    P = _segment()
    far = P[:, 3] + np.array([0.0, 0.3, 0.15])  # a lone marker 0.3 m from the segment, moving with it
    # (the column follows the far newcomer 20 frames after the marker vanished: over max_gap)
    truth, seen = _newcomer_took_the_identity(P, far, vanish=40, follow=60, back=100)
    traj = _traj(seen)
    relink_tracklets(traj)
    assert traj.n_markers == 6
    assert _same_identities(traj, truth)
    _assert_marker_0_has_its_identity_back(traj, P, 100)


def test_marker_back_takes_its_identity_back_from_a_newcomer_no_distance_measured_over_a_short_gap():
    """As in the sprint start rendered at 60 Hz: a hand marker, swinging about the wrist so that none of its
    distances to the forearm holds, first seen 3 frames after a forearm marker 54 mm from it vanished, kept that
    marker's identity (the tracker's own link; nothing measured it). When the forearm marker comes back 6 frames
    later, its distances fit the identity's from before the gap, and it takes the identity back. (Only links over
    gaps beyond ``max_gap``, or measured ones, could be taken back before: the hand kept the identity.)"""
    P = _segment()
    t = np.arange(P.shape[0]) / 50.0
    swing = 0.8 * np.sin(2 * np.pi * 2.0 * t)  # the wrist's angle, rad
    hand = P[:, 0] + 0.054 * np.stack([np.cos(swing), np.zeros_like(t), np.sin(swing)], axis=1)
    truth, seen = _newcomer_took_the_identity(P, hand, vanish=80, follow=83, back=89)
    traj = _traj(seen)
    relink_tracklets(traj)
    assert _same_identities(traj, truth)
    _assert_marker_0_has_its_identity_back(traj, P, 89)


def test_a_marker_back_at_50_hz_takes_its_identity_back_from_where_extrapolation_put_it():
    """The serve's left wrist hidden at 50 Hz (5 %-hidden take, seed 4): a hand marker swinging about it, first seen
    5 frames after the wrist vanished, got the wrist's identity by extrapolation (nothing measured that link); when
    the wrist comes back, 22 frames after, the extrapolation also fits another marker's identity ended 8 frames
    before (at 50 Hz a gap's gate spans half a metre), which took it. Its distances to its segment fit the wrist's
    identity from before the gap exactly: it takes that identity back; the hand and the other marker keep their own.
    """
    P = _segment()
    t = np.arange(P.shape[0]) / 50.0
    swing = 0.8 * np.sin(2 * np.pi * 2.0 * t)  # the hand's angle about the wrist, rad
    hand = P[:, 0] + 0.06 * np.stack([np.cos(swing), np.zeros_like(t), np.sin(swing)], axis=1)
    frames = np.arange(P.shape[0])[:, None]
    other = P[100, 0] + (frames - 100) * np.array([0.0, -0.035, 0.0])  # heads for where the wrist comes back
    truth, seen = _newcomer_took_the_identity(P, hand, vanish=78, follow=83, back=100)
    seen[83:, 0], seen[83:, 5] = np.nan, hand[83:]  # (the hand as a new identity, the wrist back in column 0)
    seen[100:, 0], seen[100:, 5] = P[100:, 0], hand[100:]
    truth = np.concatenate([truth, other[:, None]], axis=1)
    seen = np.concatenate([seen, np.where(frames < 92, other, np.nan)[:, None]], axis=1)
    traj = _traj(seen)
    relink_tracklets(traj)
    assert _same_identities(traj, truth)
    _assert_marker_0_has_its_identity_back(traj, P, 100)


def test_a_fast_swing_at_50_hz_is_not_cut_where_a_jump_is():
    """A wrist on a 0.5 m circle at 3.2 turns per second (200 m/s^2, 80 mm/frame^2 at 50 Hz) is one tracklet
    at 50 Hz; a 150 mm jump off it cuts it. (Cut by 60 mm/frame^2 alone, a serve's fast arm was cut at each
    swing and a piece linked to a hidden neighbour's identity.)"""
    fps, turns = 50.0, 3.2
    t = np.arange(100) / fps
    angle = 2 * np.pi * turns * t
    P = np.stack([0.5 * np.cos(angle), 0.5 * np.sin(angle), np.ones_like(t)], axis=1)[:, None, :]
    cfg = RelabelConfig()
    split = cfg.jump_acc(fps)
    assert np.linalg.norm(P[2:] - 2 * P[1:-1] + P[:-2], axis=2).max() > cfg.split_acc_m  # above the old cut
    assert len(split_tracklets(P, split)) == 1
    P[50:, 0, 2] += 0.15
    assert len(split_tracklets(P, split)) == 2


def _curving(offsets: np.ndarray, fps: float = 120.0, n_frames: int = 120) -> np.ndarray:
    """(F, M, 3) markers at ``offsets`` (M, 3) m from a point moving at 2 m/s along a curve, at ``fps`` Hz."""
    t = np.arange(n_frames) / fps
    centre = np.stack([2.0 * t, 0.3 * np.sin(4.0 * t), np.ones_like(t)], axis=1)
    return centre[:, None, :] + offsets[None]


def _relinked_right(seen: np.ndarray, truth: np.ndarray, fps: float, config: RelabelConfig) -> bool:
    """Whether :func:`relink_tracklets` with ``config`` leaves every identity of ``seen`` on one marker of
    ``truth`` (a take at ``fps`` Hz)."""
    traj = _traj(seen)
    traj.fps = fps
    relink_tracklets(traj, config)
    return _same_identities(traj, truth)


def test_a_step_onto_a_neighbour_45_mm_away_and_back_is_cut():
    """The sprint start's forearm at 120 Hz: marker A's identity misses a frame and takes marker B, 45 mm away and
    just back in view, for 3 frames, then A again. The steps (45 mm/frame^2 there and back) stay below the 60 mm
    jump threshold, but the two accelerations of each step point opposite ways: the 3 samples are cut off and go to
    B's identity, A's keeps A alone. Without the reversal rule A's identity keeps B's samples."""
    fps = 120.0
    offsets = np.array([[0.0, 0.0, 0.0], [0.0, 0.045, 0.0], [0.06, 0.02, 0.0], [-0.05, 0.03, 0.01]])
    truth = _curving(offsets, fps)  # A, B and two markers of the same segment
    seen = truth.copy()
    seen[:65, 1] = np.nan  # B hidden until frame 65 ...
    seen[60, 0] = np.nan  # ... A missed at frame 60 ...
    seen[61:64, 0] = truth[61:64, 1]  # ... and its identity on B for frames 61-63
    cfg = RelabelConfig()
    step = np.linalg.norm(seen[62:64, 0] - 2 * seen[63:65, 0] + seen[64:66, 0], axis=1)  # at frames 63, 64
    assert cfg.reversal_acc(fps) < step.min() and step.max() < cfg.jump_acc(fps)
    assert _relinked_right(seen, truth, fps, cfg)
    assert not _relinked_right(seen, truth, fps, RelabelConfig(split_reversal_m=np.inf))


def test_one_sample_hopped_onto_at_120_hz_does_not_keep_the_identity():
    """The sprint start's forearm at 120 Hz (rendered with photon noise): marker B, 45 mm from A, comes back after
    23 frames hidden; A's identity holds it for one frame while A is missed, then A again, and B goes on under a
    new identity. The lone sample is off A's path and the jumps on both sides of it are clear at 120 Hz: it does
    not keep A's identity, which goes on with A. With the tracker's own link kept for it, the sample takes A's
    identity on to B's tracklet."""
    fps = 120.0
    truth = _curving(np.array([[0.0, 0.0, 0.0], [0.0, 0.045, 0.0]]), fps)  # A and B
    seen = np.concatenate([truth, np.full((120, 1, 3), np.nan)], axis=1)
    seen[41:64, 1] = np.nan  # B hidden over frames 41-63 ...
    seen[64, 0] = truth[64, 1]  # ... A missed at frame 64, its identity on B there ...
    seen[65:, 2] = truth[65:, 1]  # ... and B under a new identity after
    seen[64:, 1] = np.nan
    cfg = RelabelConfig()
    assert cfg.hops_clear(fps) and not cfg.hops_clear(50.0)
    assert _relinked_right(seen, truth, fps, cfg)
    assert not _relinked_right(seen, truth, fps, RelabelConfig(clear_hop_ratio=np.inf))


def test_a_whipping_wrists_own_sample_at_50_hz_is_not_given_to_a_far_identity():
    """A serve's wrist at 50 Hz: at 0.2 m/frame it whips down, three accelerations in a row over the jump threshold
    (110-150 mm/frame^2, 280-370 m/s^2), which cut its sample at frame 29 into a tracklet of its own; the other
    hand, 0.6 m away, vanished at frame 19. The sample stays with the wrist's identity. Refused like a hop (as at
    120 Hz), it went to the other hand's identity and cost two switches (the recording's serve, frame 558)."""
    fps, n = 50.0, 60
    v = np.zeros((n, 3))  # the wrist's steps, m/frame
    v[:, 1] = -0.2 * np.minimum(np.arange(n), 28) / 28.0
    v[29] = [0.0, -0.17, -0.145]
    v[30] = [0.0, -0.08, -0.21]
    v[31:] = np.array([0.0, 0.03, -0.19]) * np.linspace(1.0, 0.0, n - 31)[:, None] ** 0.2
    wrist = np.array([0.0, 0.5, 1.5]) + np.cumsum(v, axis=0)
    hand = wrist[29] + np.array([0.3, 0.3, -0.4]) + np.outer(np.arange(n), [0.002, 0.0, 0.0])
    truth = np.stack([wrist, hand], axis=1)
    seen = truth.copy()
    seen[19:, 1] = np.nan
    cfg = RelabelConfig()
    runs = split_tracklets(seen, cfg.jump_acc(fps), cfg.reversal_acc(fps))
    assert [(int(r[0, 0]), len(r)) for r in runs if r[0, 1] == 0] == [(0, 29), (29, 1), (30, 30)]
    assert not cfg.hops_clear(fps)
    traj = _traj(seen)
    relink_tracklets(traj, cfg)
    assert _same_identities(traj, truth)
    held = np.isfinite(traj.positions[:, :, 0]).sum(axis=0)
    assert sorted(held.tolist()) == [19, 60]  # the wrist's 60 samples in one identity, the hand's 19 in another


def test_a_marker_held_by_two_identities_stays_with_the_one_it_continues():
    """Marker 4 is hidden from frame 50 on and its identity's track takes marker 0 (frames 50-52), while marker 0's
    own identity misses frame 50 and holds it again from 51: two identities on one point in frames 51-52. The
    point stays with marker 0's identity, whose smooth run through those frames is the longer, and the thief's
    sample at frame 50, which that identity continues, moves to it; two markers 5 mm apart are left alone."""
    P = _scene()
    P[:, 2] = P[:, 3] + np.array([0.005, 0.0, 0.0])
    seen = P.copy()
    seen[50, 0] = np.nan
    seen[50:53, 4] = P[50:53, 0]
    seen[53:, 4] = np.nan
    assert np.linalg.norm(seen[50, 4] - 2 * seen[49, 4] + seen[48, 4]) > RelabelConfig().split_acc_mps2 / 50.0**2
    traj = _traj(seen)
    assert drop_duplicates(traj) == 2
    expected = P.copy()
    expected[50:, 4] = np.nan
    np.testing.assert_array_equal(traj.positions, expected)
    assert np.isnan(traj.residuals[50:, 4]).all() and (traj.camera_masks[50:, 4] == 0).all()


def test_repair_counts_the_duplicates_it_dropped():
    P = _scene()
    seen = np.concatenate([P, P[:, :1]], axis=1)  # a second identity on marker 0 throughout frames 40-44 only
    seen[:40, 6] = np.nan
    seen[45:, 6] = np.nan
    traj = _traj(seen)
    stats = repair_identities(traj)
    assert stats.duplicates == 5
    assert traj.n_markers == 6 and _same_identities(traj, P)


def test_marker_back_with_one_neighbour_is_relinked_by_that_distance():
    """The sprint start's ForearmL Marker3, hidden 43 frames (over max_gap), comes back while its neighbour Marker4
    is hidden too, and the tracker gives it Marker4's identity (hidden 10 frames: its extrapolation still reaches).
    Only one attached marker is seen at both ends; its distance, unchanged, links the marker to its own identity,
    and Marker4, back later, gets its own by its two distances. Without that rule the two swap identities."""
    P = _segment()[:, :3]  # N (0), A (1) 60 mm from N, B (2) 50 mm from N and 78 mm from A
    seen = np.concatenate([P, np.full((P.shape[0], 1, 3), np.nan)], axis=1)
    seen[40:, 1] = np.nan  # A hidden from frame 40 ...
    seen[74:, 2] = np.nan  # ... B from frame 74 ...
    seen[84:, 2] = P[84:, 1]  # ... A back at frame 84 in B's column ...
    seen[120:, 3] = P[120:, 2]  # ... and B back at frame 120 as a new identity
    traj = _traj(seen)
    relink_tracklets(traj)
    assert traj.n_markers == 3 and _same_identities(traj, P)
    without = _traj(seen)
    relink_tracklets(without, RelabelConfig(lone_gate_m=0.0))
    assert not _same_identities(without, P)


def test_a_fast_wrist_back_after_a_short_gap_is_relinked_by_its_one_neighbour():
    """The serve's wrist at 50 Hz: two markers of a wrist bar 100 mm apart swing on a 0.5 m circle at 10 m/s; one is
    hidden 9 frames and comes back as a new identity. The gap is within ``max_gap``, but over 9 frames the
    extrapolations miss by over a metre (their gate is wider than the bar): the one attached neighbour's unchanged
    distance links it (a finger marker beside it, not attached, cannot). Without that rule it stays a new identity."""
    fps, turns = 50.0, 3.2
    t = np.arange(150) / fps
    angle = 2 * np.pi * turns * t
    wrist = np.stack([0.5 * np.cos(angle), 0.5 * np.sin(angle), np.ones_like(t)], axis=1)
    bar = wrist + np.array([0.0, 0.0, 0.1])
    finger = wrist * (1.0 + 0.15 + 0.04 * np.sin(7.0 * t))[:, None] * np.array([1.0, 1.0, 0.0]) + [0.0, 0.0, 1.0]
    P = np.stack([wrist, bar, finger], axis=1)
    seen = np.concatenate([P, np.full((len(t), 1, 3), np.nan)], axis=1)
    seen[60:, 0] = np.nan  # the wrist hidden from frame 60 ...
    seen[69:, 3] = P[69:, 0]  # ... and back at 69 as a new identity
    traj = _traj(seen)
    relink_tracklets(traj)
    assert traj.n_markers == 3 and _same_identities(traj, P)
    without = _traj(seen)
    relink_tracklets(without, RelabelConfig(lone_gate_m=0.0))
    assert without.n_markers == 4


def test_a_neighbour_that_held_its_distance_only_briefly_does_not_decide_a_link():
    """The sprint start's ForearmL Marker3: hidden for 25 frames, it comes back in the column of another forearm
    marker hidden meanwhile (the tracker's own link). Its distances to the two forearm markers in view fit its
    identity exactly, but the hand beside it, which held its distance for the 6 frames before the gap after
    drifting 35 mm over the 20 before, is 40 mm nearer now. A neighbour counts as attached only if its distance
    held over the identity's last 0.4 s, so the hand is left out and the marker takes its identity back."""
    P = _segment()[:, [0, 1, 2, 4]]  # A, two neighbours, B
    t = np.arange(P.shape[0]) / 50.0
    a = 1.0 * t
    R = np.zeros((len(t), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a), 1.0
    reach = np.interp(np.arange(len(t)), [0, 50, 74, 80, 95, 160], [0.045, 0.045, 0.080, 0.080, 0.041, 0.041])
    hand = P[:, 0] + np.einsum("fij,fj->fi", R, np.stack([np.zeros_like(reach), np.zeros_like(reach), -reach], 1))
    truth = np.concatenate([P, hand[:, None]], axis=1)
    seen = truth.copy()
    seen[80:, 0] = np.nan  # A hidden from frame 80 ...
    seen[95:, 3] = np.nan  # ... B from frame 95 ...
    seen[105:, 3] = P[105:, 0]  # ... and A back at 105 in B's column
    traj = _traj(seen)
    relink_tracklets(traj)
    back = [c for c in range(traj.n_markers) if np.allclose(traj.positions[105, c], P[105, 0])][0]
    np.testing.assert_array_equal(traj.positions[:80, back], P[:80, 0])
    old = _traj(seen)
    relink_tracklets(old, RelabelConfig(shape_held=0.0))  # (the rule off: steady over 6 frames is enough)
    back = [c for c in range(old.n_markers) if np.allclose(old.positions[105, c], P[105, 0])][0]
    np.testing.assert_array_equal(old.positions[:95, back], P[:95, 3])  # B's identity


def test_a_long_gap_link_does_not_push_markers_back_from_a_short_gap_onto_each_other():
    """The whole sprint's forearm, frame 2957 (seed 1): three markers a few centimetres apart vanish for 4 frames
    and come back. The one back in a new column had an older identity in that column, last seen 3 m away 85
    frames before (the tracker's link, which nothing measured). Linking every tracklet at any cost gave that link,
    and the two others each other's identities; leaving one tracklet unlinked keeps A and B their own."""
    t = np.arange(140)[:, None] / 50.0
    A = np.hstack([1.5 * t, 0.1 * np.sin(4 * t), np.ones_like(t)])  # 30 mm/frame
    B = A + np.hstack([0.04 * np.cos(3 * t), 0.04 * np.sin(3 * t), np.zeros_like(t)])  # 40 mm off, turning
    D = A + np.hstack([0.02 * np.sin(5 * t), -0.05 + 0.01 * np.cos(7 * t), 0.02 * np.sin(2 * t)])
    C = A + [0.0, 3.0, 0.0]
    P = np.full((140, 5, 3), np.nan)
    P[:20, 3] = C[:20]  # C, in the column A comes back in, long gone
    P[30:100, 0] = A[30:100]  # A and B, hidden over frames 100-103 ...
    P[30:100, 1] = B[30:100]
    P[104:, 3] = A[104:]  # ... A back in C's old column,
    P[104:, 1] = B[104:]  # B back in its own
    P[:60, 2] = D[:60]  # D gone since frame 60 ...
    P[104:, 4] = D[104:]  # ... back with them in a new column (near enough to both to be linked to either)
    traj = _traj(P)
    relink_tracklets(traj)

    def owner(path: np.ndarray, frame: int) -> int:
        return int(np.flatnonzero(np.all(traj.positions[frame] == path[frame], axis=1))[0])

    assert owner(A, 50) == owner(A, 120) != owner(C, 10)
    assert owner(B, 50) == owner(B, 120)
    assert owner(D, 120) not in (owner(A, 50), owner(B, 50))


def _forearm_and_wheel(n: int = 150, fps: float = 120.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, 3, 3) three markers of a turning forearm, (F, 3) a wheel marker circling beside it (5 mm/frame relative to
    it, 0.1-0.25 m away), and the (F, 3, 3) rotations of the forearm, at ``fps`` Hz."""
    t = np.arange(n)[:, None] / fps
    centre = np.hstack([0.6 * t, 0.1 * np.sin(2 * t), np.ones_like(t)])  # 5 mm/frame
    a = 1.5 * t[:, 0]  # the forearm turns
    R = np.zeros((n, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = np.cos(a), -np.sin(a), np.sin(a), np.cos(a), 1.0
    local = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.02, 0.06, 0.0]])
    forearm = centre[:, None] + np.einsum("fij,mj->fmi", R, local)
    b = 4.0 * t[:, 0]
    wheel = centre + [0.06, 0.0, 0.03] + 0.15 * np.stack([np.cos(b), np.sin(b), np.zeros(n)], axis=1)
    return forearm, wheel, R


def test_a_marker_of_another_segment_does_not_keep_a_hidden_markers_identity():
    """The halo sprint start, frame 498: a wheelchair marker is hidden for 3 frames while the hand pushes the wheel,
    and a forearm marker appearing 0.1 m from its prediction got its identity from the tracker. The newcomer holds
    its distances to two forearm markers that the wheelchair marker moved against, and the extrapolation misses it:
    the link is refused, and the wheelchair marker, back 6 frames after it vanished, gets its identity back."""
    fps, n = 120.0, 150
    forearm, wheel, _ = _forearm_and_wheel(n, fps)
    P = np.full((n, 4, 3), np.nan)
    P[:, 0:2] = forearm[:, 0:2]
    P[:60, 2] = wheel[:60]  # the wheel marker, hidden over frames 60-65 ...
    P[63:, 2] = forearm[63:, 2]  # ... its identity continued on the forearm's third marker, first seen at 63
    P[66:, 3] = wheel[66:]  # ... and the wheel marker back as a new identity
    assert np.linalg.norm(forearm[63, 2] - (wheel[59] + 4 * (wheel[59] - wheel[58]))) > 0.08  # (its prediction)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(4)], fps, P.copy())
    relink_tracklets(traj)

    def owner(point: np.ndarray, frame: int) -> int:
        return int(np.flatnonzero(np.all(traj.positions[frame] == point, axis=1))[0])

    assert owner(wheel[30], 30) == owner(wheel[100], 100)
    assert owner(forearm[100, 2], 100) != owner(wheel[30], 30)
    refuse_nothing = RelabelConfig(loose_refuse=1000)
    traj = Trajectories([f"M{k + 1:03d}" for k in range(4)], fps, P.copy())
    relink_tracklets(traj, refuse_nothing)
    assert owner(forearm[100, 2], 100) == owner(wheel[30], 30)  # (the tracker's link, kept without the rule)


@pytest.mark.parametrize("c_xy", [(0.1, 0.09), (0.25, 0.1)], ids=["C near both", "C beyond A's shape radius"])
def test_a_marker_back_at_50_hz_does_not_take_a_neighbours_identity_whose_held_distance_it_misses(c_xy):
    """A foot's markers at 50 Hz: A hidden 1.5 s while the foot steps 0.5 m, B hidden just before A is back. B's
    extrapolation misses A by their 0.1 m spacing (a 50 Hz gap's gate is wider), but B held its distance to C
    (0.09 or 0.18 m) and A is 45 or 89 mm further from C (at 0.27 m beyond the radius of the distances a tracklet is
    linked by, which below 100 Hz still refute): A keeps the tracker's own link and B its identity."""
    F = 160
    step = 0.5 * np.clip((np.arange(F) - 20) / 40, 0, 1)[:, None] * np.array([1.0, 0.0, 0.0])  # (F, 3) foot, m
    layout = np.array([[0.0, 0.0, 0.05], [0.1, 0.0, 0.05], [*c_xy, 0.05]])  # A, B, C on the foot
    truth = step[:, None] + layout[None]
    captured = truth.copy()
    captured[20:95, 0] = np.nan  # A hidden, back in its own column (the tracker re-identified it)
    captured[90:131, 1] = np.nan  # B hidden, back in its own column
    traj = Trajectories(["A", "B", "C"], 50.0, captured)
    relink_tracklets(traj)
    assert traj.n_markers == 3
    assert _same_identities(traj, truth)


def test_a_marker_that_starts_moving_with_a_segment_keeps_its_identity():
    """The wheel marker, hidden for 3 frames, comes back moving with the forearm (the hand grips the wheel): it now
    holds its distances to the forearm markers it moved against before, but it is where its path predicts it, so the
    tracker's link stands."""
    fps, n = 120.0, 150
    forearm, wheel, R = _forearm_and_wheel(n, fps)
    held = np.einsum("ij,j->i", R[60].T, wheel[60] - forearm[60, 0])  # where on the forearm the hand holds it
    gripped = wheel.copy()
    gripped[60:] = forearm[60:, 0] + np.einsum("fij,j->fi", R[60:], held)
    P = np.full((n, 3, 3), np.nan)
    P[:, 0:2] = forearm[:, 0:2]
    P[:60, 2] = gripped[:60]
    P[63:, 2] = gripped[63:]
    traj = Trajectories(["M001", "M002", "M003"], fps, P.copy())
    relink_tracklets(traj)
    np.testing.assert_array_equal(traj.positions, P)


def test_single_samples_of_a_fast_marker_are_linked_by_its_velocity():
    """A marker at 3 m/s (25 mm/frame at 120 Hz) flickers: single samples at frames 62 and 64 between its track and
    its return at 66, each under a new identity. A single sample has no velocity of its own; taking the identity's
    from its sample before, the extrapolation gate is a moving marker's, not a standing one's (20 mm)."""
    fps = 120.0
    t = np.arange(120)[:, None] / fps
    path = np.hstack([3.0 * t, 0.05 * np.sin(5 * t), np.ones_like(t)])
    P = np.full((120, 4, 3), np.nan)
    P[:60, 0] = path[:60]
    P[62, 1] = path[62]
    P[64, 2] = path[64]
    P[66:, 3] = path[66:]
    traj = Trajectories(["M001", "M002", "M003", "M004"], fps, P.copy())
    relink_tracklets(traj)
    assert traj.n_markers == 1
    traj = Trajectories(["M001", "M002", "M003", "M004"], fps, P.copy())
    relink_tracklets(traj, RelabelConfig(end_velocity_frames=0))
    assert traj.n_markers > 1  # (the gate of a standing marker)


def test_a_hop_at_the_end_of_an_identity_does_not_make_its_neighbours_loose():
    """The halo sprint start at seed 5, frame 514: ForearmL Marker3's identity hopped onto the hand for its last 2
    samples before a 3-frame gap; the marker back after it held its distances to the forearm's markers, as its
    identity had for 0.4 s but those 2 samples. The relations are judged over everything remembered (robust spread),
    so the tracker's link stands."""
    fps, n = 120.0, 150
    forearm, _, _ = _forearm_and_wheel(n, fps)
    t = np.arange(n) / fps
    hand = forearm[:, 2] + 0.1 * np.stack([np.cos(9 * t), np.sin(9 * t), np.zeros(n)], axis=1)
    P = np.full((n, 3, 3), np.nan)
    P[:, 0:2] = forearm[:, 0:2]
    P[:58, 2] = forearm[:58, 2]
    P[58:60, 2] = hand[58:60]  # the hop
    P[63:, 2] = forearm[63:, 2]
    traj = Trajectories(["M001", "M002", "M003"], fps, P.copy())
    relink_tracklets(traj)

    def owner(frame: int) -> int:
        return int(np.flatnonzero(np.all(traj.positions[frame] == forearm[frame, 2], axis=1))[0])

    assert owner(30) == owner(100)


@pytest.mark.parametrize("seed", [3, 5])
def test_a_body_whose_markers_vanish_from_every_camera_for_a_while_keeps_one_identity_per_marker(seed):
    """The marching body with 4-5 % of its samples hidden from all cameras at once (``--hidden-rate 0.05``, gaps of
    20 frames on average at 120 Hz): the tracker alone gives some returns another identity; after the repair every
    marker's fragments are one identity again."""
    take = body_take(frames=480, fps=120.0, markers=40, seed=seed,
                     settings=SynthSettings(seed=seed, hidden_rate=0.05, hidden_frames=20.0))
    assert (~take.truth.visible.any(axis=1)).mean() > 0.03
    tracker = Tracker(take.rig, take.truth.fps)
    for k, dets in enumerate(take.frames):
        tracker.step(k, dets)
    traj = tracker.finish()
    alone = evaluate(traj, take.truth)
    repair_identities(traj, unconfirmed=tracker.unconfirmed())
    repaired = evaluate(traj, take.truth)
    assert alone.switches >= 1 and alone.idf1 < 0.999
    assert repaired.switches == 0 and repaired.idf1 > 0.999 and repaired.completeness > 0.999


def test_scattered_identities_are_withdrawn_and_a_marker_seen_every_other_frame_is_not():
    """Column 1 holds three lone samples (a hop each, cut off other tracks), column 2 two runs of three: no run of 4
    and fewer than 8 samples, both emptied; column 3, a marker seen every other frame (60 samples, runs of 1), and
    column 0, a whole track, stay."""
    P = _scene(n_frames=120, n_markers=4)
    P[:, 1] = np.nan
    P[[10, 40, 70], 1] = P[[10, 40, 70], 0] + 0.045
    P[:, 2] = np.nan
    P[20:23, 2] = P[50:53, 2] = 0.5
    P[1::2, 3] = np.nan
    traj = _traj(P)
    assert withdraw_scattered(traj) == 2
    assert not np.isfinite(traj.positions[:, 1:3]).any()
    np.testing.assert_array_equal(traj.positions[:, [0, 3]], P[:, [0, 3]])
    shorter = _traj(P)  # confirmed after 3 frames: column 2's runs of 3 are enough
    assert withdraw_scattered(shorter, RelabelConfig(confirm_frames=3)) == 1
    np.testing.assert_array_equal(shorter.positions[:, 2], P[:, 2])


def test_a_marker_back_on_its_own_path_after_a_frame_is_not_linked_on_one_neighbour_s_distance():
    """At 120 Hz a hand spirals in towards a wrist marker (150 mm to 44.9 mm over 79 frames, then circling it at
    44.9 mm, twice as fast: a push), missing frame 79; the tracker starts a new identity at 80. A forearm marker held
    44.4 mm from the wrist until frame 42 and was lost. Across 37 frames no extrapolation can tell, and one
    neighbour's distance would link the hand's return to the forearm's identity (0.5 mm off); the hand's own path
    runs into it within 7 mm across one frame, and that link is made."""
    fps, frames = 120.0, 140
    f = np.arange(frames)
    radius = np.where(f < 79, 0.150 - (0.150 - 0.0449) * f / 79, 0.0449)
    angle = np.cumsum(np.where(f < 79, 0.09, 0.2))
    wrist = np.tile([0.0, 0.0, 1.0], (frames, 1))
    hand = wrist + np.stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(frames)], axis=1)
    forearm = wrist + [0.0, -0.0444, 0.0]
    P = np.full((frames, 4, 3), np.nan)
    P[:79, 0] = hand[:79]
    P[80:, 3] = hand[80:]
    P[:43, 1] = forearm[:43]
    P[:, 2] = wrist
    traj = Trajectories([f"M{k + 1:03d}" for k in range(4)], fps, P)
    relink_tracklets(traj, RelabelConfig())
    holds = [set(np.flatnonzero(np.isfinite(traj.positions[rows, :, 0]).any(axis=0)).tolist())
             for rows in (slice(0, 79), slice(80, frames))]
    hand_columns = [np.flatnonzero(np.linalg.norm(traj.positions[k] - hand[k], axis=1) < 1e-12) for k in (10, 100)]
    assert hand_columns[0].tolist() == hand_columns[1].tolist()  # one identity for the hand
    assert holds[1] == {int(hand_columns[1][0]), 2}  # the forearm's identity holds nothing after its loss
