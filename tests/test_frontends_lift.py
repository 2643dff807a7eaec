"""Lifting per-camera 2D tracks to 3D: exact on exact projections, outlying cameras voted out."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.frontends.lift import lift_tracks
from tests.conftest import ring_rig

RIG = ring_rig(6)


def _tracks(X: np.ndarray) -> np.ndarray:
    """(F, L, 3) world points -> (C, F, L, 2) distorted pixels."""
    F, L = X.shape[:2]
    return RIG.project(X.reshape(-1, 3)).reshape(len(RIG), F, L, 2)


@pytest.fixture
def points():
    rng = np.random.default_rng(0)
    return rng.uniform([-0.5, -0.5, 0.5], [0.5, 0.5, 1.5], (8, 3, 3))


def test_exact_projections_lift_exactly(points):
    traj = lift_tracks(RIG, _tracks(points), ["a", "b", "c"], 50.0)
    np.testing.assert_allclose(traj.positions, points, atol=1e-7)
    assert traj.labels == ["a", "b", "c"] and traj.fps == 50.0
    assert (traj.camera_masks == 0b111111).all()
    assert np.nanmax(traj.residuals) < 1e-4


def test_cameras_that_lost_the_target_are_voted_out(points):
    tracks = _tracks(points)
    tracks[0, :, 0] += [40.0, -25.0]  # camera 1 tracks something else
    tracks[3, :4, 1] += [0.0, 30.0]  # camera 4 loses label b for four frames
    tracks[1, :, 2] = np.nan  # camera 2 never sees label c
    traj = lift_tracks(RIG, tracks, ["a", "b", "c"], 50.0)
    np.testing.assert_allclose(traj.positions, points, atol=1e-6)
    assert (traj.camera_masks[:, 0] == 0b111110).all()
    assert (traj.camera_masks[:4, 1] == 0b110111).all() and (traj.camera_masks[4:, 1] == 0b111111).all()
    assert (traj.camera_masks[:, 2] == 0b111101).all()


def test_two_disagreeing_cameras_give_no_point_and_residuals_are_in_mm(points):
    tracks = _tracks(points)
    tracks[2:] = np.nan
    tracks[1, 0, 0] += 20.0
    rng = np.random.default_rng(1)
    tracks[:, 1:] += rng.normal(0.0, 0.5, tracks[:, 1:].shape)
    traj = lift_tracks(RIG, tracks, ["a", "b", "c"], 50.0, max_error_px=4.0)
    assert np.isnan(traj.positions[0, 0]).all() and traj.camera_masks[0, 0] == 0
    assert np.isfinite(traj.positions[1:]).all()
    # Residual: RMS reprojection error (px) x depth / focal length, in mm: ~0.5 px at ~4 m / 1000 px ~ 1-2 mm.
    assert 0.05 < np.nanmedian(traj.residuals[1:]) < 3.0
