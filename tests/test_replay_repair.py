"""tools/replay_repair.py: a replay of the captured repair input gives what the pipeline gives."""

from __future__ import annotations

import importlib.util
import pickle
from pathlib import Path

import numpy as np

from mocap.pipeline import ReconstructOptions, reconstruct
from mocap.relabel import RelabelConfig, repair_identities

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "datasets" / "samples" / "march_sample"


def _tool():
    spec = importlib.util.spec_from_file_location("replay_repair", ROOT / "tools" / "replay_repair.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_replayed_capture_gives_the_pipelines_trajectories(tmp_path, capsys):
    tool = _tool()
    out = tmp_path / "sample.pkl"
    assert tool.main(["capture", str(SAMPLE), str(out)]) == 0
    with open(out, "rb") as fh:
        traj, config, unconfirmed = pickle.load(fh)
    assert traj.n_frames == 24 and config.confirm_frames == 4
    repair_identities(traj, RelabelConfig(confirm_frames=config.confirm_frames), unconfirmed=unconfirmed)
    direct = reconstruct(SAMPLE, ReconstructOptions(progress=False))
    np.testing.assert_array_equal(traj.positions, direct.positions)
    np.testing.assert_array_equal(traj.camera_masks, direct.camera_masks)
    (tmp_path / "sample.truth.npz").write_bytes(SAMPLE.with_name("march_sample.truth.npz").read_bytes())
    capsys.readouterr()
    assert tool.main(["replay", str(out)]) == 0
    line = capsys.readouterr().out
    assert "completeness 100.0000%" in line and "switches 0 " in line and "IDF1 1.0000" in line


def test_a_missing_or_broken_capture_is_named(tmp_path, capsys):
    tool = _tool()
    assert tool.main(["replay", str(tmp_path / "none.pkl")]) == 2
    assert "none.pkl: no such capture" in capsys.readouterr().err
    (tmp_path / "cut.pkl").write_bytes(b"\x80\x04\x95")
    assert tool.main(["replay", str(tmp_path / "cut.pkl")]) == 2
    assert "cut.pkl: not a capture of this version" in capsys.readouterr().err
