"""``mocap track-head`` / ``mocap track-hand`` on small rendered colour takes, and their bad-input errors."""

from __future__ import annotations

import importlib.util

import cv2
import numpy as np
import pytest

from mocap.cli import main
from mocap.export.c3d import read_c3d
from mocap.frontends.render_hand import hand_clip
from mocap.frontends.render_head import head_take
from mocap.frontends.scenes import hand_rig, head_rig, write_colour_take

HAVE_MCAP = importlib.util.find_spec("mocap.export.mcap") is not None


@pytest.fixture(scope="module")
def head(tmp_path_factory):
    rig = head_rig(6)
    take = head_take(rig, frames=12, seed=4)
    folder = write_colour_take(tmp_path_factory.mktemp("head") / "take", rig, take.videos, take.fps)
    return folder, take


@pytest.fixture(scope="module")
def hand(tmp_path_factory):
    rig = hand_rig(3)
    clip = hand_clip(rig, "F", hold=8, seed=4)
    folder = write_colour_take(tmp_path_factory.mktemp("hand") / "take", rig, clip.videos, clip.fps)
    return folder, clip


def test_track_head_writes_a_c3d_near_the_truth(head, tmp_path):
    folder, take = head
    out = tmp_path / "head.c3d"
    argv = ["track-head", str(folder), "--c3d", str(out)]
    if HAVE_MCAP:
        argv += ["--mcap", str(tmp_path / "head.mcap")]
    assert main(argv) == 0
    traj = read_c3d(out)
    assert traj.labels == ["head"] and traj.fps == pytest.approx(30.0) and traj.n_frames == 12
    err = np.linalg.norm(traj.positions[:, 0] - take.position, axis=1)
    assert np.nanmax(err) < 0.04  # metres; about 2 px at 1.5 m with f = 180 px
    assert HAVE_MCAP is (tmp_path / "head.mcap").exists()


def test_track_head_with_boxes_per_camera(head, tmp_path):
    folder, take = head
    argv = ["track-head", str(folder), "--c3d", str(tmp_path / "h.c3d"), "--mode", "shape", "--particles", "100"]
    for name, c, a in zip(head_rig(6).names, take.centre[:, 0], take.axes[:, 0], strict=True):
        argv += ["--box", f"{name}={c[0] - a[0]:.1f},{c[1] - a[1]:.1f},{2 * a[0]:.1f},{2 * a[1]:.1f}"]
    assert main(argv) == 0
    err = np.linalg.norm(read_c3d(tmp_path / "h.c3d").positions[:, 0] - take.position, axis=1)
    assert np.nanmedian(err) < 0.02


def test_track_hand_writes_fingertips_and_palm(hand, tmp_path):
    folder, clip = hand
    out = tmp_path / "hand.c3d"
    assert main(["track-hand", str(folder), "--c3d", str(out)]) == 0
    traj = read_c3d(out)
    assert traj.labels == ["thumb", "index", "middle", "ring", "little", "palm"]
    err = np.linalg.norm(traj.positions[:, :5] - clip.tips_world, axis=2)
    assert np.nanmax(err) < 0.006 and np.isfinite(err).mean() > 0.9


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["track-head", "{take}", "--c3d", "{tmp}/o.c3d", "--box", "cam9=1,2,30,30"], "cam9"),
        (["track-head", "{take}", "--c3d", "{tmp}/o.c3d", "--box", "1,2,x,30"], "--box"),
        (["track-head", "{tmp}/missing", "--c3d", "{tmp}/o.c3d"], "not found"),
        (["track-head", "{take}", "--c3d", "{tmp}/no/such/dir/o.c3d"], "does not exist"),
        (["track-hand", "{take}", "--c3d", "{tmp}/o.c3d", "--model", "{tmp}/none.json"], "posture model"),
    ],
)
def test_bad_arguments_are_one_line_errors(head, tmp_path, capsys, argv, message):
    folder, _ = head
    argv = [a.format(take=folder, tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_missing_recording_and_grey_video_are_reported(hand, tmp_path, capsys):
    folder, clip = hand
    broken = tmp_path / "take"
    broken.mkdir()
    (broken / "calibration.toml").write_bytes((folder / "calibration.toml").read_bytes())
    assert main(["track-hand", str(broken), "--c3d", str(tmp_path / "o.c3d"), "--fps", "30"]) == 2
    assert "no recording for camera 'cam1'" in capsys.readouterr().err
    for c in range(3):  # grey PNG folders
        (broken / f"cam{c + 1}").mkdir()
        for k in range(3):
            grey = cv2.cvtColor(clip.videos[c, k], cv2.COLOR_BGR2GRAY)
            cv2.imwrite(str(broken / f"cam{c + 1}" / f"{k:04d}.png"), grey)
    assert main(["track-hand", str(broken), "--c3d", str(tmp_path / "o.c3d"), "--fps", "30"]) == 2
    err = capsys.readouterr().err
    assert "needs 8-bit colour video" in err and "cam1" in err
    assert main(["track-head", str(broken), "--c3d", str(tmp_path / "o.c3d"), "--fps", "30"]) == 2
    assert "--box" in capsys.readouterr().err
    assert not (tmp_path / "o.c3d").exists()
