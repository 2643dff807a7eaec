"""``mocap export`` and ``mocap info`` through the command-line entry point."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_shared_data
from helpers_export import synthetic_trajectories

from mocap.camera import save_rig
from mocap.cli import main
from mocap.export.c3d import read_c3d, write_c3d
from mocap.export.info import gap_runs
from mocap.export.mcap import read_mcap_take, read_mcap_trajectories
from mocap.export.trc import read_trc


def test_gap_runs_counts_and_longest_against_a_loop():
    rng = np.random.default_rng(4)
    valid = rng.random((200, 7)) < 0.7
    valid[:, 3] = True
    valid[:, 4] = False
    counts, longest = gap_runs(valid)
    for m in range(7):
        runs, run = [], 0
        for v in valid[:, m]:
            if not v:
                run += 1
            elif run:
                runs.append(run)
                run = 0
        runs += [run] if run else []
        assert counts[m] == len(runs) and longest[m] == max(runs, default=0)


def test_export_to_every_format_then_info(tmp_path, capsys):
    traj = synthetic_trajectories(n_frames=50, n_markers=3, seed=2)
    traj.camera_masks &= 0x7F
    write_c3d(traj, tmp_path / "in.c3d")
    outs = {s: tmp_path / f"out.{s}" for s in ("trc", "csv", "mcap")}
    assert main(["export", str(tmp_path / "in.c3d"), "--y-up", "--units", "m",
                 *[a for s, p in outs.items() for a in (f"--{s}", str(p))]]) == 0
    assert "3 markers, 50 frames at 120 Hz" in capsys.readouterr().out
    source = read_c3d(tmp_path / "in.c3d")
    np.testing.assert_array_equal(read_trc(outs["trc"], y_up=True).positions, source.positions)
    assert main(["export", str(outs["csv"]), "--c3d", str(tmp_path / "back.c3d")]) == 0  # CSV says 'Up Axis,Y'
    np.testing.assert_allclose(read_c3d(tmp_path / "back.c3d").positions, source.positions, rtol=1e-7, atol=1e-12)
    np.testing.assert_array_equal(read_mcap_trajectories(outs["mcap"]).positions, source.positions)
    capsys.readouterr()
    assert main(["info", str(tmp_path / "in.c3d")]) == 0
    out = capsys.readouterr().out
    counts, longest = gap_runs(source.valid)
    assert "markers    3" in out and "frames     50 (first 0)" in out and "rate       120 Hz" in out
    assert "duration   0.417 s" in out and "units      mm" in out
    for m, label in enumerate(source.labels):
        row = next(line for line in out.splitlines() if line.startswith(label))
        assert row.split()[2:4] == [str(counts[m]), str(longest[m])]


def test_export_carries_the_cameras_into_mcap(tmp_path, rig):
    save_rig(rig, tmp_path / "calibration.toml")
    traj = synthetic_trajectories(n_frames=20, n_markers=2, seed=2)
    write_c3d(traj, tmp_path / "in.c3d")
    assert main(["export", str(tmp_path / "in.c3d"), "--mcap", str(tmp_path / "a.mcap"),
                 "--calibration", str(tmp_path / "calibration.toml")]) == 0
    assert read_mcap_take(tmp_path / "a.mcap").camera_names == rig.names


def test_info_on_the_real_walking_file(capsys):
    path = require_shared_data("c3d") / "walkingOptiTrack.c3d"
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "markers    12" in out and "frames     3361" in out and "rate       160 Hz" in out
    assert "samples    92.6 % present" in out  # the README's 7.4 % real gaps


@pytest.mark.parametrize("argv, message", [
    (["export", "missing.c3d", "--trc", "x.trc"], "missing.c3d: C3D file not found"),
    (["export", "in.c3d"], "no output given"),
    (["export", "in.c3d", "--c3d", "in.c3d"], "would overwrite the input"),
    (["export", "in.c3d", "--trc", "nodir/x.trc"], "does not exist; create it first"),
    (["info", "in.txt"], "unknown trajectory file type '.txt'"),
    (["info", "."], "is a folder, not a trajectory file"),
    (["plot", ".", "--out", "x.png"], "is a folder, not a trajectory file"),
])
def test_cli_errors_are_one_line_and_exit_2(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    write_c3d(synthetic_trajectories(n_frames=5, n_markers=1), tmp_path / "in.c3d")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
