"""Fundamental matrices: robust estimation against the rig's F, and the calibration.toml table."""

from __future__ import annotations

import numpy as np
import pytest

from calibration.fundamental import TABLE, epipolar_stats, estimate_fundamental, fundamental_table
from mocap.camera import Rig, load_rig, save_rig
from mocap.errors import MocapError
from mocap.geometry import fundamental_from_cameras


def _correspondences(rig: Rig, n: int, noise: float, outliers: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    X = rng.uniform([-1.5, -1.5, 0.2], [1.5, 1.5, 2.0], (n, 3))
    x1 = rig[0].undistort(rig[0].project(X)) + rng.normal(0, noise, (n, 2))
    x2 = rig[1].undistort(rig[1].project(X)) + rng.normal(0, noise, (n, 2))
    x2[:outliers] = rng.uniform(0, 700, (outliers, 2))
    return x1, x2


def test_robust_fundamental_matches_the_rig(rig):
    x1, x2 = _correspondences(rig, 400, 0.1, 60)
    fit = estimate_fundamental(x1, x2)
    assert fit.inliers[60:].mean() > 0.98 and fit.inliers[:60].mean() < 0.1
    F_true = fundamental_from_cameras(rig[0], rig[1])
    s_true = epipolar_stats(F_true, x1[60:], x2[60:])
    # Fitted to the noise, the estimate explains the inliers at least as well as the truth does.
    assert fit.stats.mean_px <= s_true.mean_px * 1.02
    assert fit.stats.mean_px < 0.12
    assert np.linalg.svd(fit.F, compute_uv=False)[2] < 1e-12
    # And it is the same geometry: clean points fit it to a fraction of the noise.
    xc1, xc2 = _correspondences(rig, 200, 0.0, 0, seed=2)
    assert epipolar_stats(fit.F, xc1, xc2).mean_px < 0.05


def test_too_few_correspondences():
    with pytest.raises(MocapError, match="only 5 points"):
        estimate_fundamental(np.zeros((5, 2)), np.zeros((5, 2)), where="cam1-cam2")


def test_fundamental_table_survives_calibration_toml(rig, tmp_path):
    x1, x2 = _correspondences(rig, 50, 0.0, 0)
    rig.extra_tables[TABLE] = fundamental_table(rig, correspondences={(0, 1): (x1, x2)})
    save_rig(rig, tmp_path / "calibration.toml")
    back = load_rig(tmp_path / "calibration.toml")
    table = back.extra_tables[TABLE]
    assert len(table) == 15
    entry = table["cam1-cam2"]
    assert entry["from"] == "cam1" and entry["n_points"] == 50 and entry["mean_px"] < 1e-6
    np.testing.assert_allclose(np.array(entry["F"]), fundamental_from_cameras(back[0], back[1]), atol=1e-12)


def test_cli_adds_fundamentals_and_compares(rig, tmp_path, capsys):
    from mocap.cli import main

    path = tmp_path / "calibration.toml"
    save_rig(rig, path)
    assert main(["calibrate", "fundamental", str(path)]) == 0
    assert len(load_rig(path).extra_tables[TABLE]) == 15
    assert main(["calibrate", "compare", str(path), str(path), "--json", str(tmp_path / "c.json")]) == 0
    assert "cam6" in capsys.readouterr().out
    assert main(["calibrate", "wand", str(tmp_path / "missing"), "--wand", "0,0.25,0.5", "--out",
                 str(tmp_path / "o.toml")]) == 2
    assert "too close to the centre" in capsys.readouterr().err
