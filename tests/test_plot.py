"""``mocap plot`` (PNG) and the geometry of ``mocap view`` (tested without a window)."""

from __future__ import annotations

import subprocess
import sys

import cv2
import numpy as np
import pytest
from helpers_export import synthetic_trajectories

from mocap.cli import main
from mocap.errors import MocapError
from mocap.export.c3d import write_c3d
from mocap.plot import plot_trajectories
from mocap.view import frame_geometry


def test_plot_writes_a_png_whose_gap_chart_is_the_validity_matrix(tmp_path):
    traj = synthetic_trajectories(n_frames=120, n_markers=5, seed=8)
    fig = plot_trajectories(traj, tmp_path / "p.png")
    image = cv2.imread(str(tmp_path / "p.png"))
    assert image is not None and image.shape[:2] == (800, 1500)
    assert image.std() > 10  # something was drawn
    gap_chart = fig.axes[1].images[0].get_array()
    np.testing.assert_array_equal(np.asarray(gap_chart), traj.valid.T)
    assert [t.get_text().split(" (")[0] for t in fig.axes[1].get_yticklabels()] == traj.labels


def test_plot_cli_default_output_and_matplotlib_stays_out_of_the_library(tmp_path):
    write_c3d(synthetic_trajectories(n_frames=30, n_markers=2), tmp_path / "t.c3d")
    assert main(["plot", str(tmp_path / "t.c3d")]) == 0
    assert cv2.imread(str(tmp_path / "t.png")) is not None
    probe = ("import sys, mocap.cli, mocap.plot, mocap.view, mocap.export.mcap, mocap.export.convert; "
             "mocap.cli.build_parser(); print(sorted(m for m in sys.modules if m.startswith('matplotlib')))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"  # matplotlib is imported only when a plot is drawn


def test_view_geometry_holds_present_markers_and_their_recent_paths():
    traj = synthetic_trajectories(n_frames=50, n_markers=4, gap_fraction=0.2, seed=11)
    g = frame_geometry(traj, 40, trail=10)
    present = np.flatnonzero(traj.valid[40])
    np.testing.assert_array_equal(g.markers, present)
    np.testing.assert_array_equal(g.points, traj.positions[40, present])
    assert g.colors.shape == (len(present), 3) and (g.colors >= 0).all() and (g.colors <= 1).all()
    segments = g.trail_points[g.trail_lines]  # (L, 2, 3)
    assert np.isfinite(segments).all()
    expected = sum(int(traj.valid[t, m] & traj.valid[t + 1, m]) for t in range(30, 40) for m in range(4))
    assert len(g.trail_lines) == expected
    steps = np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1)
    assert steps.max() < 0.05  # consecutive frames of one marker, never a jump between markers
    with pytest.raises(ValueError):
        frame_geometry(traj, 50)


def test_view_without_open3d_says_how_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "open3d", None)  # import open3d -> ImportError
    write_c3d(synthetic_trajectories(n_frames=5, n_markers=1), tmp_path / "t.c3d")
    assert main(["view", str(tmp_path / "t.c3d")]) == 2
    assert "pip install 'mocap[viz]'" in capsys.readouterr().err
    with pytest.raises(MocapError):
        from mocap.view import _open3d

        _open3d()
