"""C3D frame ranges beyond the header's 16-bit words (65,535): reading other writers' long files, truncation,
takes without markers, late first frames. The long round trip itself is in test_export_formats.py."""

from __future__ import annotations

import warnings

import c3d as c3d_package
import numpy as np
import pytest
from helpers_export import synthetic_trajectories

from mocap.errors import MocapError
from mocap.export.c3d import read_c3d, write_c3d
from mocap.trajectories import Trajectories

LONG = 70_000


def test_a_long_file_written_by_the_c3d_package_is_read_in_full(tmp_path):
    writer = c3d_package.Writer(point_rate=100.0, point_scale=-0.01, point_units="mm")
    writer.set_point_labels(["a", "b"])
    frames = np.zeros((LONG, 2, 5), dtype=np.float32)
    frames[:, :, 0] = np.arange(LONG)[:, None]  # x = frame index (mm), exact in float32; read as mm * 1e-3
    frames[:, 1, 1] = 7.0
    frames[::3, 0, 3] = -1.0  # every third sample of marker a is invalid
    writer.add_frames([(f, np.zeros((0, 0), np.float32)) for f in frames])
    with open(tmp_path / "w.c3d", "wb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no analog data"
        writer.write(f)
    traj = read_c3d(tmp_path / "w.c3d")
    assert (traj.n_frames, traj.first_frame, traj.labels) == (LONG, 0, ["a", "b"])
    np.testing.assert_array_equal(traj.valid[:, 0], np.arange(LONG) % 3 != 0)
    np.testing.assert_array_equal(traj.positions[1::3, 0, 0], np.arange(1, LONG, 3) * 1e-3)
    np.testing.assert_array_equal(traj.positions[:, 1],
                                  np.column_stack([np.arange(LONG) * 1e-3, np.full(LONG, 7 * 1e-3), np.zeros(LONG)]))


def test_a_truncated_long_file_is_reported_with_the_trial_frame_count(tmp_path):
    write_c3d(Trajectories(["a"], 120.0, np.ones((LONG, 1, 3))), tmp_path / "long.c3d")
    data = (tmp_path / "long.c3d").read_bytes()
    (tmp_path / "cut.c3d").write_bytes(data[: len(data) - 1000 * 16])  # 1000 frames of one point short
    with pytest.raises(MocapError, match=f"cut.c3d: the file is truncated: TRIAL.* declares {LONG} frames but it "
                                         f"holds {LONG - 1000}"):
        read_c3d(tmp_path / "cut.c3d")


def test_a_long_take_without_markers_keeps_its_frame_count(tmp_path):
    write_c3d(Trajectories([], 120.0, np.zeros((LONG, 0, 3)), first_frame=12), tmp_path / "e.c3d")
    back = read_c3d(tmp_path / "e.c3d")
    assert (back.n_markers, back.n_frames, back.first_frame) == (0, LONG, 12)


def test_a_take_starting_after_frame_65535_keeps_its_first_frame(tmp_path):
    traj = synthetic_trajectories(n_frames=1000, n_markers=3, seed=5, first_frame=70_000)
    write_c3d(traj, tmp_path / "late.c3d")
    back = read_c3d(tmp_path / "late.c3d")
    assert (back.n_frames, back.first_frame) == (1000, 70_000)  # the header's 16-bit first frame cannot hold it
    np.testing.assert_array_equal(back.valid, traj.valid)
    np.testing.assert_allclose(back.positions, traj.positions, rtol=6e-8)  # float32 storage
    with open(tmp_path / "late.c3d", "rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no analog data"
        samples = np.array([points for _, points, _ in c3d_package.Reader(f).read_frames()])  # (F, M, 5) mm
    np.testing.assert_allclose(samples[traj.valid][:, :3] / 1000.0, traj.positions[traj.valid], rtol=2e-7)
