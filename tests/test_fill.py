"""Unconfirmed points that continue an identity's path join it; far or ambiguous ones do not."""

from __future__ import annotations

import numpy as np
from helpers_engine import scripted_motion, simulate
from helpers_rigid import FRAMES, skin

from mocap.evaluate import evaluate
from mocap.fill import FillConfig, fill_from_unconfirmed
from mocap.relabel import repair_identities
from mocap.synth import SynthSettings, ring_rig
from mocap.tracker import Tracker
from mocap.trajectories import Trajectories, UnconfirmedPoints


def _unconfirmed(rows: np.ndarray, positions: np.ndarray) -> UnconfirmedPoints:
    n = len(rows)
    return UnconfirmedPoints(np.asarray(rows), np.asarray(positions, dtype=float), np.full(n, 0.2),
                             np.full(n, 0b111, dtype=np.uint32))


def _line(frames: int, start: tuple[float, float, float], step: tuple[float, float, float]) -> np.ndarray:
    """(F, 3) a marker moving ``step`` m per frame."""
    return np.asarray(start) + np.arange(frames)[:, None] * np.asarray(step)


def test_points_on_an_identity_path_fill_its_gap_and_extend_its_end():
    rng = np.random.default_rng(3)
    truth = _line(40, (0.0, 0.0, 1.0), (0.004, 0.001, 0.0)) + rng.normal(0, 0.0002, (40, 3))
    P = truth.copy()[:, None]
    P[10:14] = np.nan  # a gap the points fill (frames 10-13)
    P[30:] = np.nan  # an end they extend (frames 30-34), then nothing
    rows = np.r_[10:14, 30:35, 20]
    points = truth[rows].copy()
    points[-1] += (0.0, 0.03, 0.0)  # frame 20: a point 3 cm off the path (the identity has a sample there anyway)
    far = _unconfirmed(np.r_[rows, 36], np.r_[points, truth[[36]] + (0.0, 0.0, 0.03)])  # frame 36: 3 cm off
    traj = Trajectories(["M001"], 100.0, P)
    added = fill_from_unconfirmed(traj, far)
    assert added == 9
    filled = np.isfinite(traj.positions[:, 0, 0])
    assert filled[:35].all() and not filled[35:].any()
    np.testing.assert_array_equal(traj.positions[rows[:-1], 0], truth[rows[:-1]])
    assert (traj.camera_masks[rows[:-1], 0] == 0b111).all() and np.allclose(traj.residuals[rows[:-1], 0], 0.2)


def test_a_point_between_two_identities_predictions_is_left_alone():
    """Two hidden markers 8 mm apart at frame 10: a point 3 mm from one prediction and 5 mm from the other is not
    clearly either's; a point 1 mm from one is."""
    a = _line(20, (0.0, 0.0, 1.0), (0.003, 0.0, 0.0))
    b = a + (0.0, 0.008, 0.0)
    P = np.stack([a, b], axis=1)
    P[10] = np.nan
    ambiguous = _unconfirmed(np.array([10]), a[[10]] + (0.0, 0.003, 0.0))
    traj = Trajectories(["M001", "M002"], 100.0, P.copy())
    assert fill_from_unconfirmed(traj, ambiguous) == 0
    clear = _unconfirmed(np.array([10]), a[[10]] + (0.0, 0.001, 0.0))
    assert fill_from_unconfirmed(traj, clear) == 1 and np.isfinite(traj.positions[10, 0, 0])
    assert not np.isfinite(traj.positions[10, 1, 0])


def test_reach_limits_how_far_a_prediction_goes():
    a = _line(30, (0.0, 0.0, 1.0), (0.003, 0.0, 0.0))
    P = a.copy()[:, None]
    P[10:20] = np.nan
    lone = _unconfirmed(np.array([15]), a[[15]])  # 5 frames from either side
    assert fill_from_unconfirmed(Trajectories(["M001"], 100.0, P.copy()), lone) == 0
    assert fill_from_unconfirmed(Trajectories(["M001"], 100.0, P.copy()), lone, FillConfig(reach_frames=5)) == 1


def test_a_marker_back_in_bursts_shorter_than_the_confirmation_is_output_in_every_burst():
    """A marker hidden for 0.4 s comes back in bursts of three frames, one frame apart, for 0.4 s: no burst
    is confirmed (4 frames), so the tracker re-identifies it only when it stays. The bursts join its identity."""
    rng = np.random.default_rng(23)
    positions = skin(4, rng)
    hidden = np.zeros((FRAMES, 6, 4), dtype=bool)
    hidden[100:140, :, 2] = True
    hidden[143:180:4, :, 2] = True  # seen 140-142, 144-146, ... 176-178
    take = simulate("bursts", ring_rig(seed=7), scripted_motion(positions, 100.0), SynthSettings(seed=7, ghosts=0),
                    hidden=hidden, seed=7)
    tracker = Tracker(take.rig, 100.0)
    for k, frame in enumerate(take.frames):
        tracker.step(k, frame)
    traj = tracker.finish()
    unconfirmed = tracker.unconfirmed()
    without = Trajectories(traj.labels, traj.fps, traj.positions.copy(), traj.residuals.copy(),
                           traj.camera_masks.copy())
    repair_identities(without)
    stats = repair_identities(traj, unconfirmed=unconfirmed)
    bursts = np.flatnonzero(~hidden[140:180, 0, 2]) + 140
    found = [int((np.linalg.norm(t.positions[bursts] - positions[bursts, None, 2], axis=2) < 0.002).any(axis=1)
                 .sum()) for t in (without, traj)]
    before, after = evaluate(without, take.truth), evaluate(traj, take.truth)
    print(f"marker output in {found[0]} -> {found[1]} of {bursts.size} burst frames ({stats.filled} filled); "
          f"switches {before.switches} -> {after.switches}, IDF1 {before.idf1:.4f} -> {after.idf1:.4f}")
    assert found[0] <= 3 and found[1] == bursts.size and stats.filled >= bursts.size - 3
    assert after.switches == 0 and after.idf1 > before.idf1 and after.ghost_rate == 0


def test_points_that_repeat_samples_or_lie_outside_the_take_add_nothing():
    a = _line(10, (0.0, 0.0, 1.0), (0.003, 0.0, 0.0))
    traj = Trajectories(["M001"], 100.0, a.copy()[:, None])
    repeats = _unconfirmed(np.array([2, 5, -1, 10]), np.r_[a[[2, 5]] + 0.0005, a[[0, 9]]])
    assert fill_from_unconfirmed(traj, repeats) == 0
    np.testing.assert_array_equal(traj.positions[:, 0], a)
    assert fill_from_unconfirmed(traj, _unconfirmed(np.zeros(0, dtype=np.intp), np.zeros((0, 3)))) == 0
