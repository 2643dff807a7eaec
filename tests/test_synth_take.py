"""Rendered takes against their truth: decoded blob centres, occlusion, artefacts, files, CLI, determinism."""

from __future__ import annotations

import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from mocap.camera import load_rig
from mocap.cli import main
from mocap.errors import MocapError
from mocap.synth import (
    SynthSettings,
    marching_motion,
    motion_from_file,
    render_take,
    rig_for_motion,
    ring_rig,
    simulate,
    writer,
)
from mocap.synth.simulate import plan_take, render_frame
from mocap.synth.wand import centroid_frames
from mocap.truth import Truth, load_truth
from tests.conftest import require_shared_data
from tests.helpers_engine import scripted_motion, walk_positions

FRAMES = 16


def read_frames(take: Path, camera: str) -> np.ndarray:
    """(F, H, W) uint8 grey frames of one camera, from ``<camera>.mkv`` or ``<camera>/*.png``."""
    video = take / f"{camera}.mkv"
    if video.exists():
        cap = cv2.VideoCapture(str(video))
        frames = []
        while True:
            ok, image = cap.read()
            if not ok:
                break
            assert (image[..., 0] == image[..., 2]).all()  # grey in three equal channels
            frames.append(image[..., 0])
        cap.release()
        return np.stack(frames)
    return np.stack([cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((take / camera).glob("*.png"))])


def isolated(truth: Truth, f: int, c: int, m: int, gap_px: float = 10.0) -> bool:
    """No other marker (drawn or not) and no ghost within ``gap_px`` of marker m's truth uv."""
    uv = truth.uv[f, c]
    d = np.linalg.norm(uv - uv[m], axis=1)
    d[m] = np.inf
    ghosts = np.asarray(truth.settings["ghosts_uv"][c]).reshape(-1, 2)
    near_ghost = len(ghosts) and np.linalg.norm(ghosts - uv[m], axis=1).min() < gap_px
    return not (np.nanmin(d) < gap_px) and not near_ghost


def centroid_errors(take: Path, truth: Truth) -> np.ndarray:
    """Distances (px) between background-subtracted weighted centroids and truth uv of isolated visible blobs."""
    errors = []
    for c, name in enumerate(truth.camera_names):
        frames = read_frames(take, name)
        assert frames.shape[0] == truth.n_frames
        background = np.median(frames.reshape(len(frames), -1)[:, ::7], axis=1)
        for f, m in zip(*np.nonzero(truth.visible[:, c]), strict=True):
            if not isolated(truth, f, c, m):
                continue
            x0, y0 = np.rint(truth.uv[f, c, m]).astype(int)
            patch = frames[f, y0 - 6:y0 + 7, x0 - 6:x0 + 7].astype(np.float64)
            if patch.shape != (13, 13):
                continue
            signal = patch - background[f]
            ys, xs = np.mgrid[y0 - 6:y0 + 7, x0 - 6:x0 + 7]
            est = np.array([(signal * xs).sum(), (signal * ys).sum()]) / signal.sum()
            errors.append(np.linalg.norm(est - truth.uv[f, c, m]))
    return np.array(errors)


@pytest.fixture(scope="module")
def clean_take(tmp_path_factory) -> tuple[Path, Truth]:
    root = tmp_path_factory.mktemp("clean")
    truth = render_take(root / "take", ring_rig(seed=3), marching_motion(FRAMES, seed=3),
                        SynthSettings(seed=3, format="png").clean(), progress=False)
    return root / "take", truth


@pytest.fixture(scope="module")
def noisy_take(tmp_path_factory) -> tuple[Path, Truth]:
    root = tmp_path_factory.mktemp("noisy")
    settings = SynthSettings(seed=5, ghosts=4, ghost_blink=0.5)
    truth = render_take(root / "take", ring_rig(seed=5), marching_motion(FRAMES, seed=5), settings, progress=False)
    return root / "take", truth


def test_clean_take_blob_centres_match_truth(clean_take):
    take, truth = clean_take
    errors = centroid_errors(take, truth)
    assert len(errors) > 500
    assert np.median(errors) < 0.05 and errors.max() < 0.1


def test_default_noise_take_blob_centres_match_truth(noisy_take):
    take, truth = noisy_take
    errors = centroid_errors(take, truth)
    assert len(errors) > 500
    assert np.median(errors) < 0.2


def test_occluded_markers_leave_no_light(clean_take):
    take, truth = clean_take
    hidden = lit = 0
    rig = load_rig(take / "calibration.toml")
    for c, name in enumerate(truth.camera_names):
        frames = read_frames(take, name)
        w, h = rig[c].size
        for f, m in zip(*np.nonzero(np.isfinite(truth.uv[:, c, :, 0])), strict=True):
            x, y = np.rint(truth.uv[f, c, m]).astype(int)
            if not isolated(truth, f, c, m) or not (4 <= x < w - 4 and 4 <= y < h - 4):
                continue
            window = frames[f, y - 2:y + 3, x - 2:x + 3]
            if truth.visible[f, c, m]:
                lit += 1
                assert window.max() > 150
            else:
                hidden += 1
                assert (window == 12).all()  # background only: the marker was not drawn
    assert hidden > 100 and lit > 500
    assert 0.2 < truth.settings["occluded_fraction"] < 0.6


def test_truth_records_the_rig_and_settings_and_sits_outside_the_take(clean_take):
    take, truth = clean_take
    assert sorted(p.name for p in take.iterdir()) == ["calibration.toml", *truth.camera_names, "take.toml"]
    assert (take / "calibration.toml").read_text() == truth.settings["calibration_toml"]
    assert tomllib.loads((take / "take.toml").read_text())["fps"] == truth.fps == 120.0
    saved = load_truth(take.with_name("take.truth.npz"))
    np.testing.assert_array_equal(saved.visible, truth.visible)
    assert saved.settings["noise"] == 0 and saved.settings["marker_mm"] == 14.0
    rig = load_rig(take / "calibration.toml")
    assert rig.names == truth.camera_names
    sigma = truth.sigma_px
    assert np.isfinite(sigma[truth.visible]).all() and np.isnan(sigma[~truth.visible]).all()
    assert 0.0005 < np.median(sigma[truth.visible]) < 0.05  # clean: only 8-bit rounding noise
    views = truth.views
    assert np.mean(views >= 2) > 0.95  # the default ring sees nearly every marker from 2+ cameras


def test_ghosts_static_and_flickering(noisy_take):
    take, truth = noisy_take
    ghosts = np.asarray(truth.settings["ghosts_uv"])  # (C, G, 2)
    blinking = truth.settings["ghosts_blinking"]
    assert ghosts.shape == (6, 4, 2) and blinking == 2
    seen = np.zeros((6, 4, FRAMES), dtype=bool)
    for c, name in enumerate(truth.camera_names):
        frames = read_frames(take, name)
        for g, (u, v) in enumerate(np.rint(ghosts[c]).astype(int)):
            seen[c, g] = frames[:, v - 1:v + 2, u - 1:u + 2].max(axis=(1, 2)) > 12 + 15
    assert seen[:, blinking:].all()  # the steady reflections are always there
    on = seen[:, :blinking].mean(axis=2)
    assert (on < 1).any() and (on > 0).any()  # the flickering ones come and go


def test_dropouts_are_temporally_correlated_at_the_stated_rate():
    settings = SynthSettings(dropout_rate=0.2, dropout_frames=5.0, occlusion=False, seed=9)
    truth = simulate(ring_rig(seed=9), marching_motion(300, n_markers=20, seed=9), settings)
    in_view = np.isfinite(truth.uv[..., 0])
    missing = in_view & ~truth.visible
    assert missing.sum() / in_view.sum() == pytest.approx(0.2, abs=0.03)
    runs = np.diff(missing.astype(np.int8), axis=0)
    starts = (runs == 1).sum()
    assert missing.sum() / max(starts, 1) == pytest.approx(5.0, rel=0.2)  # mean run length


def test_gaps_hide_a_marker_from_every_camera_at_once_and_leave_the_rest_of_the_take_as_it_was():
    rig, motion = ring_rig(seed=9), marching_motion(400, n_markers=20, seed=9)
    plain = simulate(rig, motion, SynthSettings(occlusion=False, seed=9))
    gappy = simulate(rig, motion, SynthSettings(occlusion=False, seed=9, hidden_rate=0.1, hidden_frames=20.0))
    np.testing.assert_array_equal(plain.positions, gappy.positions)  # the markers are still there, only unseen
    gone = ~gappy.visible.any(axis=1) & plain.visible.any(axis=1)  # (F, M): hidden in every view by the gaps alone
    assert gone.mean() == pytest.approx(0.1, abs=0.03)
    starts = (np.diff(gone.astype(np.int8), axis=0) == 1).sum()
    assert gone.sum() / max(starts, 1) == pytest.approx(20.0, rel=0.3)  # mean gap length
    # Outside the gaps every view is as without them (the dropouts' and ghosts' seeds are unchanged).
    np.testing.assert_array_equal(gappy.visible | gone[:, None, :], plain.visible | gone[:, None, :])
    assert gappy.settings["hidden_fraction"] == pytest.approx(0.1, abs=0.03)


def test_mkv_is_lossless_and_equals_png(tmp_path):
    motion = marching_motion(6, seed=1)
    truths = [render_take(tmp_path / fmt, ring_rig(seed=1), motion, SynthSettings(seed=1, format=fmt),
                          progress=False) for fmt in ("mkv", "png")]
    np.testing.assert_array_equal(truths[0].uv, truths[1].uv)
    for name in truths[0].camera_names:
        np.testing.assert_array_equal(read_frames(tmp_path / "mkv", name), read_frames(tmp_path / "png", name))


def test_same_seed_same_take_other_seed_other_take(tmp_path):
    def render(name: str, seed: int) -> tuple[Truth, np.ndarray]:
        truth = render_take(tmp_path / name, ring_rig(seed=2), marching_motion(4, seed=2),
                            SynthSettings(seed=seed, format="png"), progress=False)
        return truth, read_frames(tmp_path / name, "cam1")

    a, frames_a = render("a", 7)
    b, frames_b = render("b", 7)
    c, frames_c = render("c", 8)
    np.testing.assert_array_equal(frames_a, frames_b)
    np.testing.assert_array_equal(a.visible, b.visible)
    np.testing.assert_array_equal(a.sigma_px, b.sigma_px)
    assert not np.array_equal(frames_a, frames_c)


def test_failed_render_leaves_nothing_behind(tmp_path, monkeypatch):
    calls = {"n": 0}
    real = writer.render_frame

    def failing(*args):
        calls["n"] += 1
        if calls["n"] > 8:
            raise MocapError("disk full (simulated)")
        return real(*args)

    monkeypatch.setattr(writer, "render_frame", failing)
    with pytest.raises(MocapError, match="simulated"):
        render_take(tmp_path / "take", ring_rig(), marching_motion(5), SynthSettings(format="png"), progress=False)
    assert list(tmp_path.iterdir()) == []


_VIDEO_WRITER = cv2.VideoWriter


class _DroppingWriter:
    """A ``cv2.VideoWriter`` that silently stops writing after 3 frames, as OpenCV's does on a full disk."""

    def __init__(self, *args):
        self._writer, self._written = _VIDEO_WRITER(*args), 0

    def isOpened(self):  # noqa: N802 (OpenCV's name)
        return self._writer.isOpened()

    def write(self, image):
        self._written += 1
        if self._written <= 3:
            self._writer.write(image)

    def release(self):
        self._writer.release()


def test_a_video_written_incompletely_fails_the_render_and_leaves_nothing_behind(tmp_path, monkeypatch):
    monkeypatch.setattr(writer.cv2, "VideoWriter", _DroppingWriter)
    with pytest.raises(MocapError, match=r"cam1\.mkv: the video was written incompletely \(3 of 6 frames"):
        render_take(tmp_path / "take", ring_rig(), marching_motion(6), SynthSettings(format="mkv"), progress=False)
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_stops_the_render_with_a_clear_error(tmp_path, monkeypatch):
    real = writer.shutil.disk_usage
    monkeypatch.setattr(writer.shutil, "disk_usage", lambda path: real(path)._replace(free=2**20))
    with pytest.raises(MocapError, match="the disk is full \\(1 MiB left after 0 of 5 frames\\)"):
        render_take(tmp_path / "take", ring_rig(), marching_motion(5), SynthSettings(format="png"), progress=False)
    assert list(tmp_path.iterdir()) == []


def test_real_motion_take_keeps_gaps(tmp_path):
    motion = motion_from_file(require_shared_data("c3d") / "walkingOptiTrack.c3d")
    gappy = int(np.argmax((~np.isfinite(motion.positions[..., 0])).sum(axis=1) > 0))
    window = motion.window(max(0, gappy - 2), 6).centred()
    truth = simulate(ring_rig(), window, SynthSettings())
    gap = ~np.isfinite(window.positions[..., 0])
    assert gap.any()
    assert not truth.visible.transpose(0, 2, 1)[gap].any()
    assert np.isnan(truth.uv[..., 0].transpose(0, 2, 1)[gap]).all()


def test_cli_renders_and_reports_user_errors(tmp_path, capsys):
    out = tmp_path / "t"
    args = ["synth", str(out), "--frames", "3", "--clean", "--format", "png", "--cameras", "3", "--size", "640x480",
            "--focal", "700", "--markers", "30", "--seed", "4", "--no-progress"]
    assert main(args) == 0
    truth = load_truth(tmp_path / "t.truth.npz")
    assert truth.n_frames == 3 and len(truth.camera_names) == 3 and len(truth.labels) == 30
    assert truth.settings["noise"] == 0 and truth.settings["ghosts"] == 0 and truth.settings["seed"] == 4
    assert load_rig(out / "calibration.toml")[0].size == (640, 480)
    assert "take written" in capsys.readouterr().out
    assert main(args) == 2 and "--force" in capsys.readouterr().err  # will not overwrite silently
    assert main(args + ["--force", "--noise", "3"]) == 0  # explicit flags beat --clean
    assert load_truth(tmp_path / "t.truth.npz").settings["noise"] == 3
    assert main(["synth", str(tmp_path / "u"), "--motion", str(tmp_path / "none.c3d")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "v"), "--truth", str(tmp_path / "v" / "x.npz"), "--frames", "2"]) == 2
    assert "inside the take" in capsys.readouterr().err
    assert main(["synth", str(tmp_path / "w"), "--noise", "-1"]) == 2
    assert "--noise" in capsys.readouterr().err
    assert not (tmp_path / "u").exists() and not (tmp_path / "v").exists() and not (tmp_path / "w").exists()


def test_committed_sample_take_matches_its_truth():
    sample = Path(__file__).resolve().parents[1] / "datasets" / "samples" / "march_sample"
    truth = load_truth(sample.with_name("march_sample.truth.npz"))
    assert (sample / "calibration.toml").read_text() == truth.settings["calibration_toml"]
    assert truth.n_frames == 24 and truth.settings["noise"] == 0
    errors = centroid_errors(sample, truth)
    assert len(errors) > 300 and np.median(errors) < 0.05


def test_centroid_stand_in_merges_each_group_of_touching_discs_into_one_flagged_blob():
    """The detector stand-in of the centroid-level tests: two pairs of markers, each pair touching in the images,
    the pairs far apart, plus a lone marker: three blobs per camera, the two pair blobs flagged merged and each
    at its own pair's mean (not one blob at the mean of all four)."""
    pos = np.array([[0.0, 0.0, 1.0], [0.004, 0.0, 1.0], [0.5, 0.3, 1.2], [0.5, 0.304, 1.2], [-0.4, 0.2, 0.8]])
    rig = ring_rig(seed=1)
    plan = plan_take(rig, scripted_motion(np.repeat(pos[None], 2, axis=0), 100.0),
                     SynthSettings(seed=1, ghosts=0, dropout_rate=0.0))
    for c, det in enumerate(centroid_frames(plan, seed=1)[0]):
        uv = plan.truth.uv[0, c]
        assert len(det) == 3 and det.merged.sum() == 2
        for pair in ((0, 1), (2, 3)):
            centre = uv[list(pair)].mean(axis=0)
            assert np.linalg.norm(det.xy[det.merged] - centre, axis=1).min() < 0.5
        assert np.linalg.norm(det.xy[~det.merged][0] - uv[4]) < 0.5


def test_exposure_smears_a_moving_marker_along_its_motion_centred_on_the_truth():
    """A marker crossing the view at 6 m/s with a 2 ms shutter (12 mm, ~3 px at 4 m) is drawn as a streak along
    its image motion; its intensity-weighted centre stays on the mid-exposure truth, and an instantaneous
    shutter draws it round."""
    fps = 100.0
    rig = ring_rig(n_cameras=2, seed=2)
    across = cv2.Rodrigues(np.asarray(rig[0].rotation, dtype=np.float64))[0][0]  # camera 0's image x axis, world
    t = np.arange(5)[:, None] / fps
    pos = (np.array([0.0, 0.0, 1.0]) + 6.0 * (t - 0.02) * across)[:, None, :]
    shapes = []
    for exposure in (0.0, 2.0):
        plan = plan_take(rig, scripted_motion(pos, fps), SynthSettings(exposure_ms=exposure).clean())
        image = _frame_image(plan, frame=2, camera=0)
        level = image.astype(np.float64) - SynthSettings().background
        ys, xs = np.nonzero(level > 20)
        w = level[ys, xs]
        centre = np.array([(w * xs).sum(), (w * ys).sum()]) / w.sum()
        cov = np.cov(np.stack([xs, ys]), aweights=w)
        uv = plan.truth.uv[2, 0, 0]
        motion = plan.truth.uv[3, 0, 0] - plan.truth.uv[1, 0, 0]
        along = motion / np.linalg.norm(motion)
        spread_along = along @ cov @ along
        spread_across = np.array([-along[1], along[0]]) @ cov @ np.array([-along[1], along[0]])
        assert np.linalg.norm(centre - uv) < 0.05
        shapes.append(spread_along / spread_across)
    print(f"spread along / across the motion: instantaneous {shapes[0]:.2f}, 2 ms {shapes[1]:.2f}")
    assert shapes[0] == pytest.approx(1.0, abs=0.15) and shapes[1] > 1.5


def _frame_image(plan, frame: int, camera: int) -> np.ndarray:
    """(H, W) uint8 image of one camera-frame of a planned take."""
    return render_frame(plan, frame, camera, plan.noise_streams()[camera])


def test_a_long_straight_motion_gets_a_walkway_rig_that_gives_it_four_views():
    walk = walk_positions()  # 12 m along x
    rig = rig_for_motion(walk, seed=2)
    assert rig.metadata["layout"] == "walkway" and len(rig) >= 6 and len(rig) % 2 == 0
    pts = walk.reshape(-1, 3)
    views = sum(cam.in_image(cam.project(pts), 10.0).astype(int) for cam in rig.cameras)
    assert np.mean(views >= 4) >= 0.99
    fewer = rig_for_motion(walk, n_cameras=len(rig) - 2, seed=2)  # the fit took the fewest cameras
    views = sum(cam.in_image(cam.project(pts), 10.0).astype(int) for cam in fewer.cameras)
    assert np.mean(views >= 4) < 0.99
    assert rig_for_motion(marching_motion(60, seed=1).positions, seed=2).metadata["layout"] == "ring"
    ring = rig_for_motion(walk, layout="ring", seed=2)
    assert ring.metadata["layout"] == "ring" and len(ring) == 6 and ring.metadata["ring_radius_m"] > 6
    with pytest.raises(MocapError, match="layout"):
        rig_for_motion(walk, layout="circle")
    with pytest.raises(MocapError, match="no marker samples"):
        rig_for_motion(np.full((5, 2, 3), np.nan))
