"""The whole job on short rendered takes: accuracy, MCAP replay, and bad input without tracebacks."""

from __future__ import annotations

import logging
import shutil
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from mocap import pipeline, relabel
from mocap.camera import Rig, load_rig, save_rig
from mocap.cli import main
from mocap.evaluate import evaluate
from mocap.export.c3d import read_c3d
from mocap.pipeline import ReconstructOptions, reconstruct
from mocap.synth import SynthSettings, marching_motion, render_take, ring_rig
from mocap.tracker import Tracker
from mocap.truth import load_truth

FRAMES = 40


@pytest.fixture(scope="module")
def png_take(tmp_path_factory) -> tuple[Path, Path]:
    """A short default-realism take of the marching body, as PNG folders (easy to tamper with)."""
    root = tmp_path_factory.mktemp("pipeline")
    take, truth = root / "take", root / "take.truth.npz"
    render_take(take, ring_rig(6, seed=3), marching_motion(FRAMES, fps=120.0, seed=3),
                SynthSettings(seed=3, format="png"), truth_path=truth, progress=False)
    return take, truth


def _copy(take: Path, dest: Path) -> Path:
    shutil.copytree(take, dest)
    return dest


def test_rendered_take_is_reconstructed_accurately(png_take):
    take, truth_path = png_take
    traj = reconstruct(take, ReconstructOptions(progress=False))
    report = evaluate(traj, load_truth(truth_path))
    assert report.rmse_mm < 0.5
    assert report.completeness > 0.97
    assert report.ghost_rate < 0.005
    assert report.switches == 0
    assert traj.camera_names == load_rig(take / "calibration.toml").names


@pytest.mark.parametrize("stop", [1, 3])
def test_a_window_shorter_than_the_confirmation_keeps_the_markers_seen_throughout(png_take, stop, caplog):
    """A new marker needs 4 frames for an identity; a 1- or 3-frame window gives identities to the markers seen in
    every one of its frames instead of nothing, and says so."""
    take, truth_path = png_take
    with caplog.at_level(logging.INFO, logger="mocap.pipeline"):
        traj = reconstruct(take, ReconstructOptions(progress=False, stop=stop))
    report = evaluate(traj, load_truth(truth_path))
    assert traj.n_frames == stop
    assert report.completeness > 0.85 and report.ghost_rate == 0.0 and report.rmse_mm < 0.5
    assert any(f"{stop} frames, fewer than the 4" in r.getMessage() for r in caplog.records)


def test_mcap_replay_reproduces_the_trajectories(png_take, tmp_path):
    take, _ = png_take
    first = reconstruct(take, ReconstructOptions(progress=False), mcap=tmp_path / "run.mcap")
    again = reconstruct(tmp_path / "run.mcap", ReconstructOptions(progress=False))
    assert again.labels == first.labels
    np.testing.assert_array_equal(again.positions, first.positions)
    np.testing.assert_array_equal(again.residuals, first.residuals)
    np.testing.assert_array_equal(again.camera_masks, first.camera_masks)


def test_cli_reconstruct_writes_every_format(png_take, tmp_path, capsys):
    take, _ = png_take
    out = {ext: tmp_path / f"out.{ext}" for ext in ("c3d", "trc", "csv", "mcap")}
    code = main(["reconstruct", str(take), "--c3d", str(out["c3d"]), "--trc", str(out["trc"]), "--csv",
                 str(out["csv"]), "--mcap", str(out["mcap"]), "--no-progress"])
    assert code == 0
    assert all(p.stat().st_size > 0 for p in out.values())
    traj = read_c3d(out["c3d"])
    assert traj.n_frames == FRAMES and traj.fps == 120.0
    assert "markers" in capsys.readouterr().out


def test_a_fault_in_the_identity_repair_keeps_the_take_and_says_so(png_take, tmp_path, monkeypatch, caplog):
    """A pass of the offline repair that raises (a bug of this software: the rejoin of orphans once raised "SVD did
    not converge" on a moved column) costs the run neither its trajectories nor a traceback: the outputs are written
    with the identities as the failing pass left them, its emptied columns dropped, and the error is logged."""
    def failing(traj, *args, **kwargs):
        traj.positions[:, 0] = np.nan  # (a pass that had moved a column's samples, then failed)
        raise np.linalg.LinAlgError("SVD did not converge")

    take, truth_path = png_take
    monkeypatch.setattr(relabel, "rejoin_orphans", failing)
    out = tmp_path / "out.c3d"
    with caplog.at_level(logging.ERROR, logger="mocap.pipeline"):
        code = main(["reconstruct", str(take), "--c3d", str(out), "--no-progress"])
    assert code == 0
    assert any("identity repair failed (LinAlgError: SVD did not converge)" in r.getMessage() for r in caplog.records)
    traj = read_c3d(out)
    assert np.isfinite(traj.positions[..., 0]).any(axis=0).all()  # (no empty column written)
    report = evaluate(traj, load_truth(truth_path))
    assert report.completeness > 0.9 and report.rmse_mm < 0.5


@pytest.mark.parametrize(("scan_every", "named"), [
    (0, "camera cam3 saw no blob in 15 frames (10-24)"),
    (5, "camera cam3 saw no blob in 3 full-frame scans (one every 5 frames) (10-20)")])
def test_camera_black_for_a_while(png_take, tmp_path, caplog, scan_every, named):
    """Camera 3 black in frames 10-24: the other cameras carry on, and one warning names the camera and frames
    (searching predicted windows, its full-frame scans)."""
    take = _copy(png_take[0], tmp_path / "take")
    black = np.zeros(cv2.imread(str(next((take / "cam3").iterdir())), cv2.IMREAD_GRAYSCALE).shape, np.uint8)
    frames = sorted((take / "cam3").iterdir())
    for f in frames[10:25]:
        cv2.imwrite(str(f), black)
    with caplog.at_level(logging.WARNING, logger="mocap.pipeline"):
        traj = reconstruct(take, ReconstructOptions(progress=False, roi_scan_every=scan_every))
    blind = [r.getMessage() for r in caplog.records if "saw no blob" in r.getMessage()]
    assert len(blind) == 1 and named in blind[0]
    truth = load_truth(png_take[1])
    report = evaluate(traj, truth)
    assert report.switches == 0 and report.ghost_rate < 0.005
    assert report.completeness > 0.9
    cam3_bit = np.uint32(1 << 2)
    assert not np.any(traj.camera_masks[10:25] & cam3_bit)
    assert np.any(traj.camera_masks[30:] & cam3_bit)


def test_predicted_windows_that_miss_are_not_a_blind_camera(png_take, monkeypatch, caplog):
    """Between full-frame scans a camera searches the tracker's windows only; windows that hold no blob (here: none
    at all for camera 3) do not make it blind."""
    predicted = Tracker.predicted_rois

    def none_for_cam3(self: Tracker) -> list[np.ndarray]:
        rois = predicted(self)
        rois[2] = rois[2][:0]
        return rois

    monkeypatch.setattr(Tracker, "predicted_rois", none_for_cam3)
    with caplog.at_level(logging.WARNING, logger="mocap.pipeline"):
        traj = reconstruct(png_take[0], ReconstructOptions(progress=False, roi_scan_every=4))
    assert not [r for r in caplog.records if "saw no blob" in r.getMessage()]
    cam3_bit = np.uint32(1 << 2)
    assert np.any(traj.camera_masks[8::4] & cam3_bit) and not np.any(traj.camera_masks[9::4] & cam3_bit)


def test_marker_free_take_gives_empty_output_and_a_warning(tmp_path, caplog):
    take = tmp_path / "empty"
    take.mkdir()
    rig = ring_rig(3, size=(320, 240), focal_px=300.0, seed=0)
    save_rig(rig, take / "calibration.toml")
    (take / "take.toml").write_text("fps = 100.0\n")
    rng = np.random.default_rng(0)
    for cam in rig:
        (take / cam.name).mkdir()
        for k in range(8):
            noise = np.clip(rng.normal(12, 2, (240, 320)), 0, 255).astype(np.uint8)
            cv2.imwrite(str(take / cam.name / f"{k:06d}.png"), noise)
    with caplog.at_level(logging.WARNING):
        code = main(["reconstruct", str(take), "--c3d", str(tmp_path / "out.c3d"), "--no-progress"])
    assert code == 0
    assert "no markers were reconstructed: no camera saw a blob in 8 frames" in caplog.text
    traj = read_c3d(tmp_path / "out.c3d")
    assert traj.n_markers == 0 and traj.n_frames == 8


def test_markers_seen_by_one_camera_only_are_named_as_the_cause_of_an_empty_output(png_take, tmp_path, caplog):
    """Every camera but cam1 is black: cam1's blobs match nothing, and the warning says blobs were seen."""
    take = _copy(png_take[0], tmp_path / "take")
    for folder in sorted(take.iterdir()):
        if folder.is_dir() and folder.name != "cam1":
            for png in folder.glob("*.png"):
                cv2.imwrite(str(png), np.zeros_like(cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)))
    with caplog.at_level(logging.WARNING):
        traj = reconstruct(take, ReconstructOptions(progress=False, stop=10))
    assert traj.n_markers == 0
    assert "no markers were reconstructed from" in caplog.text and "seen by two cameras at least" in caplog.text


def test_calibration_that_does_not_fit_is_warned_about(png_take, tmp_path, caplog):
    take = _copy(png_take[0], tmp_path / "take")
    rig = load_rig(take / "calibration.toml")
    cams = list(rig.cameras)
    cams[1], cams[4] = (cams[1].with_pose(cams[4].rotation, cams[4].translation),
                        cams[4].with_pose(cams[1].rotation, cams[1].translation))
    save_rig(Rig(cams, rig.metadata), take / "calibration.toml")
    with caplog.at_level(logging.WARNING):
        reconstruct(take, ReconstructOptions(progress=False, stop=15))
    assert "calibration does not seem to fit" in caplog.text
    assert "cam2" in caplog.text and "cam5" in caplog.text


@pytest.mark.parametrize("case", ["missing_take", "missing_output_folder", "empty_range", "negative_scan"])
def test_cli_errors_are_one_clear_line(png_take, tmp_path, capsys, case):
    take = png_take[0]
    args = {
        "missing_take": ["reconstruct", str(tmp_path / "nope"), "--c3d", str(tmp_path / "o.c3d")],
        "missing_output_folder": ["reconstruct", str(take), "--c3d", str(tmp_path / "no" / "o.c3d")],
        "empty_range": ["reconstruct", str(take), "--c3d", str(tmp_path / "o.c3d"), "--start", "500"],
        "negative_scan": ["reconstruct", str(take), "--c3d", str(tmp_path / "o.c3d"), "--roi-scan-every", "-1"],
    }[case]
    assert main(args + ["--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocap reconstruct: error:") and "Traceback" not in err
    assert not (tmp_path / "o.c3d").exists()


@pytest.mark.parametrize("first_frame_s, notice_s, expected", [(1.0, 0.2, 1), (0.0, 2.0, 0)])
def test_a_slow_first_frame_with_numba_says_the_kernels_are_compiling(png_take, monkeypatch, caplog, first_frame_s,
                                                                       notice_s, expected):
    monkeypatch.setattr(pipeline, "kernels", SimpleNamespace(HAVE_NUMBA=True))
    monkeypatch.setattr(pipeline, "COMPILE_NOTICE_S", notice_s)
    step = Tracker.step

    def slow_first(self, frame_index, dets):
        if frame_index == 0:
            time.sleep(first_frame_s)
        return step(self, frame_index, dets)

    monkeypatch.setattr(Tracker, "step", slow_first)
    with caplog.at_level(logging.INFO, logger="mocap"):
        reconstruct(png_take[0], ReconstructOptions(progress=False, stop=3, relabel=False))
        time.sleep(notice_s + 0.1)  # (a notice the run failed to cancel would be logged by now)
    assert sum("compiling the numba kernels" in r.message for r in caplog.records) == expected


def test_opencv_and_blas_run_on_one_thread_while_streaming_and_are_restored(png_take, monkeypatch):
    from threadpoolctl import threadpool_info

    def blas_threads() -> list[int]:
        return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]

    before_cv, before_blas = cv2.getNumThreads(), blas_threads()
    seen = []
    step = Tracker.step

    def watched(self, frame_index, dets):
        seen.append((cv2.getNumThreads(), blas_threads()))
        return step(self, frame_index, dets)

    monkeypatch.setattr(Tracker, "step", watched)
    reconstruct(png_take[0], ReconstructOptions(progress=False, stop=3, relabel=False))
    assert seen and all(cv == 1 and all(n == 1 for n in blas) for cv, blas in seen)
    assert cv2.getNumThreads() == before_cv and blas_threads() == before_blas
