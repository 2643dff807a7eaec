"""Samples off their identity's own path are withheld: a hop onto a neighbour, not a hard turn of the marker itself;
a single hop that lies on the path of an identity missing only its frame is given to that identity, and a glimpse at
the end of an identity's run, off its path, to the identity whose path it continues."""

from pathlib import Path

import numpy as np
import pytest

from mocap.export.formats import read_trajectories
from mocap.offpath import OffPathConfig, give_end_hops_back, give_hops_back, withhold_off_path
from mocap.relabel import RelabelConfig
from mocap.trajectories import Trajectories

FPS = 120.0
SPRINT = Path(__file__).resolve().parents[2] / "shared" / "data" / "c3d" / "kinematics_basket_sprint.c3d"


def _hand_and_rim(frames: int = 240) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) a hand circling at 1.3 m/s and (F, 3) a rim marker 60 mm from it turning with the wheel, m."""
    t = np.arange(frames) / FPS
    hand = np.stack([0.2 * np.cos(2 * np.pi * t), 0.2 * np.sin(2 * np.pi * t), 0.8 + 0.0 * t], axis=1)
    rim = hand + 0.06 * np.stack([np.cos(5 * t), np.sin(5 * t), 0.0 * t], axis=1)
    return hand, rim


def test_a_hop_onto_a_neighbour_is_withheld_and_the_rest_kept():
    hand, rim = _hand_and_rim()
    P = np.stack([hand, rim], axis=1)  # (F, 2, 3)
    P[[100, 102], 0] = rim[[100, 102]]  # the hand's identity holds the rim marker's point twice ...
    P[101, 0] = np.nan  # ... while the hand is hidden
    P[90:115, 1] = np.nan  # and the rim marker's own track is lost
    traj = Trajectories(["M001", "M002"], FPS, P.copy())
    assert withhold_off_path(traj) == 2
    assert np.isnan(traj.positions[[100, 101, 102], 0]).all()
    kept = np.isfinite(P[..., 0])
    kept[[100, 102], 0] = False
    np.testing.assert_array_equal(traj.positions[kept], P[kept])
    assert (traj.camera_masks[[100, 102], 0] == 0).all() and np.isnan(traj.residuals[[100, 102], 0]).all()


def test_a_marker_that_stops_dead_or_jitters_keeps_every_sample():
    rng = np.random.default_rng(7)
    hand, _ = _hand_and_rim()
    stop = hand.copy()
    stop[120:] = stop[120]  # 1.3 m/s to standstill in one frame (a hand landing on the rim)
    noisy = hand + rng.normal(0.0, 0.0005, hand.shape)  # 0.5 mm noise, ten times a good system's
    traj = Trajectories(["M001", "M002"], FPS, np.stack([stop, noisy], axis=1))
    assert withhold_off_path(traj) == 0


def test_a_hop_the_path_cannot_tell_is_kept():
    hand, rim = _hand_and_rim()
    P = hand[:, None].copy()
    P[100] = hand[100] + np.array([0.0, 0.0, 0.025])  # 25 mm off: within the far_m of the default settings
    assert withhold_off_path(Trajectories(["M001"], FPS, P.copy())) == 0
    assert withhold_off_path(Trajectories(["M001"], FPS, P.copy()), OffPathConfig(far_m=0.02)) == 1


def test_a_glimpsed_rim_markers_identity_gives_the_hand_back_to_the_hands():
    """The whole sprint, frame 1869: the rim marker's identity, glimpsed for three frames, holds the hand passing by
    in the middle one (60 mm out and back) while the hand's identity misses it: the sample goes to the hand's
    identity, whose path runs through it. Where two gaps could take it, or the sample is off every path, nothing
    moves."""
    hand, rim = _hand_and_rim()
    P = np.full((240, 2, 3), np.nan)
    P[:, 0] = hand
    P[99:102, 1] = rim[99:102]
    P[100] = [np.nan, np.nan, np.nan], hand[100]
    traj = Trajectories(["M001", "M002"], FPS, P.copy())
    traj.residuals[100, 1], traj.camera_masks[100, 1] = 0.3, 0b101
    assert give_hops_back(traj) == 1
    np.testing.assert_array_equal(traj.positions[:, 0], hand)
    assert np.isnan(traj.positions[100, 1]).all() and (traj.camera_masks[100] == [0b101, 0]).all()
    assert traj.residuals[100, 0] == 0.3
    off = P.copy()
    off[100, 1] = hand[100] + [0.0, 0.0, 0.01]  # 10 mm off the hand's path
    assert give_hops_back(Trajectories(["M001", "M002"], FPS, off)) == 0
    twin = np.concatenate([P, P[:, :1] + [0.0, 0.0, 0.002]], axis=1)  # a second gap 2 mm away
    twin[100, 2] = np.nan
    assert give_hops_back(Trajectories(["M001", "M002", "M003"], FPS, twin)) == 0


def _forearm(frames: int = 160) -> np.ndarray:
    """(F, 3, 3) three markers of a forearm pushing a wheel at 120 Hz (the wrist's circle, 1.3 m/s), 48-76 mm
    apart, m."""
    hand, _ = _hand_and_rim(frames)
    return hand[:, None] + np.array([[0.0, 0.0, 0.0], [0.0, 0.048, 0.0], [0.076, 0.0, 0.0]])


def test_a_glimpse_at_the_end_of_a_run_goes_to_the_identity_whose_path_it_continues():
    """The whole sprint, frames 2135 and 2144: the forearm's markers are seen in glimpses, and one identity's run ends
    with a sample of a neighbour just lost (its path runs on through it) or starts with one of a neighbour that comes
    back a frame later. With no samples of its own on the glimpse's far side, the identity's path is only told by
    its run's other side; the neighbour's path, extrapolated over the frame or two, takes the sample."""
    x = _forearm()
    P = x.copy()
    P[61:, 0] = np.nan  # marker 0 hidden after frame 60 ...
    P[61, 0] = x[61, 2]  # ... and its identity takes marker 2's point there,
    P[60:80, 2] = np.nan  # while marker 2's own identity is lost from frame 60 (it is seen again at 80)
    P[80:100, 1] = np.nan  # marker 1 hidden 80-99: its identity ...
    P[100:120, 0] = x[100:120, 0]  # (marker 0 back at 100)
    P[99, 0] = x[99, 1]  # ... is glimpsed in marker 0's identity the frame before marker 0 is back
    P[99, 1] = np.nan
    traj = Trajectories(["M001", "M002", "M003"], FPS, P.copy())
    traj.residuals[61, 0], traj.camera_masks[61, 0] = 0.2, 0b11
    assert give_end_hops_back(traj) == 2
    assert np.isnan(traj.positions[[61, 99], 0]).all()
    np.testing.assert_array_equal(traj.positions[61, 2], x[61, 2])
    np.testing.assert_array_equal(traj.positions[99, 1], x[99, 1])
    assert traj.residuals[61, 2] == 0.2 and traj.camera_masks[61, 2] == 0b11
    spike = P.copy()
    spike[61, 0] = x[60, 0] + [0.0, 0.0, 0.04]  # 40 mm off every path (a recording's glitch): nothing moves
    spike[99, 0] = np.nan
    assert give_end_hops_back(Trajectories(["M001", "M002", "M003"], FPS, spike)) == 0
    longer = P.copy()  # four samples of marker 2 at the end of marker 0's run (the whole sprint's seed 72)
    longer[61:65, 0] = x[61:65, 2]
    longer[99, 0] = np.nan
    traj = Trajectories(["M001", "M002", "M003"], FPS, longer)
    assert give_end_hops_back(traj) == 4
    np.testing.assert_array_equal(traj.positions[61:65, 2], x[61:65, 2])
    twin = np.concatenate([P, P[:, 2:] + [0.0, 0.0, 0.003]], axis=1)  # a second lost identity 3 mm away: whose?
    twin[99, 0] = np.nan
    assert give_end_hops_back(Trajectories(["M001", "M002", "M003", "M004"], FPS, twin)) == 0


def test_the_pass_runs_only_where_hops_are_clear():
    cfg = RelabelConfig()
    assert cfg.hops_clear(120.0) and cfg.hops_clear(100.0) and not cfg.hops_clear(50.0)


@pytest.mark.skipif(not SPRINT.is_file(), reason=f"real data not found at {SPRINT} (../shared/data is not in a clone)")
def test_recorded_wheelchair_sprint_keeps_all_but_a_handful_of_samples():
    # The recording's own trajectories (OptiTrack, 120 Hz, wheel, hand and forearm clusters): a real marker's path
    # is smooth at this rate; what is withheld is the recording's own 1-3 frame glitches.
    traj = read_trajectories(SPRINT)
    valid = int(np.isfinite(traj.positions[..., 0]).sum())
    withheld = withhold_off_path(traj)
    assert withheld <= 1e-4 * valid
