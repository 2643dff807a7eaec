"""tools/replay_repair.py: a replay of the captured repair input gives what the pipeline gives."""

from __future__ import annotations

import importlib.util
import pickle
from pathlib import Path

import numpy as np

from mocap.pipeline import ReconstructOptions, reconstruct
from mocap.relabel import RelabelConfig, repair_identities
from mocap.truth import load_truth

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
        traj, config, unconfirmed, withheld = pickle.load(fh)
    assert traj.n_frames == 24 and config.confirm_frames == 4
    repair_identities(traj, RelabelConfig(confirm_frames=config.confirm_frames), unconfirmed=unconfirmed)
    withheld.apply(traj)
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


def test_the_trace_shows_the_pass_that_gave_two_exchanged_markers_back(tmp_path, capsys):
    """tools/trace_repair.py: the heel markers' identities exchanged from frame 12 in the captured input read
    exchanged in the input row at frame 20 and back after the swap repair (columns keep their numbers until the
    repair's end)."""
    out = tmp_path / "sample.pkl"
    assert _tool().main(["capture", str(SAMPLE), str(out)]) == 0
    with open(out, "rb") as fh:
        traj, config, unconfirmed, withheld = pickle.load(fh)
    truth_path = SAMPLE.with_name("march_sample.truth.npz")
    truth = load_truth(truth_path)
    a, b = truth.labels.index("LHEE"), truth.labels.index("RHEE")
    col = [int(np.nanargmin(np.linalg.norm(traj.positions[5] - truth.positions[5, m], axis=1))) for m in (a, b)]
    traj.positions[12:, col] = traj.positions[12:, col[::-1]]
    with open(out, "wb") as fh:
        pickle.dump((traj, config, unconfirmed, withheld), fh)
    spec = importlib.util.spec_from_file_location("trace_repair", ROOT / "tools" / "trace_repair.py")
    trace = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(trace)
    capsys.readouterr()
    assert trace.main([str(out), str(truth_path), "--markers", "HEE", "--frames", "5,20"]) == 0
    rows = {line.split("|")[0].split(" -> ")[0].strip(): line.split("|")[1:] for line in capsys.readouterr().out
            .splitlines() if "|" in line}
    right, exchanged = f"{col[0]} {col[1]:3d}", f"{col[1]} {col[0]:3d}"
    assert [cell.strip() for cell in rows["(input)"]] == [right, exchanged]
    assert [cell.strip() for cell in rows["repair_swaps"]] == [right, right]
