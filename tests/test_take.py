"""Take reader: videos, PNG folders and centroid files; every documented check and degradation."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
import tomli_w
from conftest import ring_rig

from mocap.camera import save_rig
from mocap.centroids import write_centroids
from mocap.detections import Detections
from mocap.errors import MocapError
from mocap.take import open_take

SIZE = (64, 48)  # w, h


def frames_for(camera: int, n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(camera)
    return [rng.integers(0, 256, (SIZE[1], SIZE[0]), dtype=np.uint8) for _ in range(n)]


def write_video(path: Path, frames: list[np.ndarray], fps: float = 100.0, colour: bool = False) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), fps, (frames[0].shape[1], frames[0].shape[0]),
                             colour)
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR) if colour else f)
    writer.release()


def write_pngs(folder: Path, frames: list[np.ndarray], pattern: str = "{:06d}.png") -> None:
    folder.mkdir()
    for k, f in enumerate(frames):
        assert cv2.imwrite(str(folder / pattern.format(k)), f)


def make_take(tmp_path: Path, kind: str = "mkv", n: int = 5, fps: float | None = None, cameras: int = 2) -> Path:
    take = tmp_path / "take"
    take.mkdir()
    save_rig(ring_rig(cameras, size=SIZE, f=60.0), take / "calibration.toml")
    if fps is not None:
        (take / "take.toml").write_text(tomli_w.dumps({"fps": fps}))
    for c in range(cameras):
        name = f"cam{c + 1}"
        if kind == "png":
            write_pngs(take / name, frames_for(c, n))
        else:
            write_video(take / f"{name}.{kind}", frames_for(c, n), colour=(c == 1))
    return take


@pytest.mark.parametrize("kind", ["mkv", "avi", "png"])
def test_images_round_trip(tmp_path, kind):
    take = open_take(make_take(tmp_path, kind, fps=None if kind != "png" else 50.0))
    assert take.kind == "images" and take.n_frames == 5 and take.camera_names == ["cam1", "cam2"]
    assert take.fps == (100.0 if kind != "png" else 50.0)
    seen = list(take.images())
    assert [k for k, _ in seen] == list(range(5))
    for k, images in seen:
        for c, image in enumerate(images):
            assert image.dtype == np.uint8 and image.shape == (SIZE[1], SIZE[0])
            np.testing.assert_array_equal(image, frames_for(c, 5)[k])  # lossless, colour -> exact grey
    part = list(take.images(2, 4))
    assert [k for k, _ in part] == [2, 3]
    np.testing.assert_array_equal(part[0][1][0], frames_for(0, 5)[2])


def test_fps_precedence(tmp_path):
    folder = make_take(tmp_path, "mkv", fps=120.0)
    assert open_take(folder).fps == 120.0  # take.toml over the video's 100
    assert open_take(folder, fps=30.0).fps == 30.0  # argument over take.toml


def test_missing_fps(tmp_path):
    with pytest.raises(MocapError, match="take.toml.*--fps"):
        open_take(make_take(tmp_path, "png"))


def test_png_natural_order(tmp_path):
    take = tmp_path / "take"
    take.mkdir()
    save_rig(ring_rig(1, size=SIZE), take / "calibration.toml")
    frames = frames_for(0, 12)
    write_pngs(take / "cam1", frames, "frame{}.png")  # frame2.png must come before frame10.png
    got = [im[0] for _, im in open_take(take, fps=10).images()]
    for a, b in zip(got, frames, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("bits", [12, 16])
def test_16_bit_pngs_are_scaled_to_8_bits_by_their_bit_depth(tmp_path, caplog, bits):
    """A 12-bit sensor's frames in 16-bit PNGs (values up to 4095) and full 16-bit ones: both read as the 8-bit
    frames they were made from (the low bits dropped), with one info line naming the depth."""
    take = tmp_path / "take"
    take.mkdir()
    save_rig(ring_rig(1, size=SIZE), take / "calibration.toml")
    frames = frames_for(0, 4)
    frames[0][0, 0] = 255  # the first frame's brightest pixel sets the depth
    wide = [f.astype(np.uint16) << (bits - 8) | 3 for f in frames]  # (low bits: noise below 8-bit resolution)
    write_pngs(take / "cam1", wide)
    with caplog.at_level(logging.INFO, logger="mocap.take"):
        got = [im[0] for _, im in open_take(take, fps=10).images()]
    for a, b in zip(got, frames, strict=True):
        np.testing.assert_array_equal(a, b)
    assert f"{bits}-bit values" in caplog.text


def test_camera_without_recording(tmp_path):
    folder = make_take(tmp_path, "mkv")
    (folder / "cam2.mkv").unlink()
    with pytest.raises(MocapError, match=r"no recording for camera\(s\) \['cam2'\]"):
        open_take(folder)


def test_recording_without_camera_is_ignored(tmp_path, caplog):
    folder = make_take(tmp_path, "mkv")
    write_video(folder / "cam9.mkv", frames_for(9, 3))
    with caplog.at_level(logging.WARNING):
        take = open_take(folder)
    assert take.camera_names == ["cam1", "cam2"]
    assert "cam9.mkv" in caplog.text and "no camera" in caplog.text


def test_two_recordings_for_one_camera(tmp_path):
    folder = make_take(tmp_path, "mkv")
    write_pngs(folder / "cam1", frames_for(0, 5))
    with pytest.raises(MocapError, match="several recordings"):
        open_take(folder)


def test_frame_counts_differ(tmp_path, caplog):
    folder = make_take(tmp_path, "mkv")
    write_video(folder / "cam2.mkv", frames_for(1, 3))
    with caplog.at_level(logging.WARNING):
        take = open_take(folder)
    assert take.n_frames == 3
    assert "cam1.mkv: 5" in caplog.text and "cam2.mkv: 3" in caplog.text
    assert len(list(take.images())) == 3


def test_image_size_differs_from_calibration(tmp_path):
    folder = make_take(tmp_path, "mkv")
    write_video(folder / "cam1.mkv", [np.zeros((40, 80), np.uint8)] * 2)
    with pytest.raises(MocapError, match=r"cam1.mkv: image size 80x40 differs .* 64x48"):
        open_take(folder)


def test_corrupt_png_frame_is_none(tmp_path, caplog):
    folder = make_take(tmp_path, "png", fps=25.0)
    (folder / "cam2" / "000003.png").write_bytes(b"\x89PNG garbage")
    take = open_take(folder)
    with caplog.at_level(logging.WARNING):
        frames = list(take.images())
    assert frames[3][1][1] is None and frames[3][1][0] is not None
    assert "000003.png" in caplog.text and "frame 3" in caplog.text


def test_a_png_missing_from_the_numbering_is_a_blind_frame_and_the_rest_keep_their_place(tmp_path, caplog):
    """cam2 lacks 000002.png: its frame 2 is None, its frames 3-4 are still frames 3-4 (not moved up one, out of
    step with cam1), and the take keeps its 5 frames."""
    folder = make_take(tmp_path, "png", fps=25.0)
    (folder / "cam2" / "000002.png").unlink()
    with caplog.at_level(logging.WARNING):
        take = open_take(folder)
        frames = [images for _, images in take.images()]
    assert take.n_frames == 5 and frames[2][1] is None and frames[2][0] is not None
    for k in (0, 1, 3, 4):
        np.testing.assert_array_equal(frames[k][1], frames_for(1, 5)[k])
    assert "1 frame(s) missing from the files' numbering (first: frame 2)" in caplog.text


@pytest.mark.parametrize("gone, blind", [(["000000.png"], [0]), (["000000.png", "000001.png"], [0, 1])])
def test_a_camera_whose_first_pngs_are_missing_starts_blind_in_step_with_the_others(tmp_path, caplog, gone, blind):
    folder = make_take(tmp_path, "png", fps=25.0)
    for name in gone:
        (folder / "cam2" / name).unlink()
    with caplog.at_level(logging.WARNING):
        take = open_take(folder)
        frames = [images for _, images in take.images()]
    assert take.n_frames == 5 and [k for k in range(5) if frames[k][1] is None] == blind
    for k in range(len(gone), 5):
        np.testing.assert_array_equal(frames[k][1], frames_for(1, 5)[k])
    assert f"numbering starts {len(gone)} frame(s) after the other cameras'" in caplog.text


def test_cameras_numbered_by_independent_counters_are_matched_by_position(tmp_path, caplog):
    """cam1's files are numbered from 0, cam2's from 5000: no padding, frame k of each is its k-th file."""
    folder = make_take(tmp_path, "png", fps=25.0)
    for png in sorted((folder / "cam2").glob("*.png")):
        png.rename(png.with_name(f"{int(png.stem) + 5000:06d}.png"))
    with caplog.at_level(logging.WARNING):
        frames = [images for _, images in open_take(folder).images()]
    assert len(frames) == 5 and "numbering starts" not in caplog.text
    for k in range(5):
        np.testing.assert_array_equal(frames[k][1], frames_for(1, 5)[k])


@pytest.mark.parametrize("pattern, numbers", [("img_{:04d}.png", [10, 12, 14, 16]), ("{}.png", [1, 2, 3, 4]),
                                              ("t{}.png", [1700000000123, 1700000008456, 1700000016790])])
def test_pngs_numbered_in_steps_or_from_one_are_consecutive_frames(tmp_path, pattern, numbers, caplog):
    """Every other frame exported (10, 12, 14 ...), numbered from 1, or named by timestamps (irregular steps): each
    file is the next frame, none blind."""
    take = tmp_path / "take"
    take.mkdir()
    save_rig(ring_rig(1, size=SIZE), take / "calibration.toml")
    frames = frames_for(0, len(numbers))
    (take / "cam1").mkdir()
    for n, f in zip(numbers, frames, strict=True):
        assert cv2.imwrite(str(take / "cam1" / pattern.format(n)), f)
    with caplog.at_level(logging.WARNING):
        got = [im[0] for _, im in open_take(take, fps=10).images()]
    assert len(got) == len(frames) and "missing" not in caplog.text
    for a, b in zip(got, frames, strict=True):
        np.testing.assert_array_equal(a, b)


def test_not_a_video(tmp_path):
    folder = make_take(tmp_path, "mkv")
    (folder / "cam1.mkv").write_bytes(b"definitely not a video")
    with pytest.raises(MocapError, match="cam1.mkv: not a video"):
        open_take(folder)


def test_folder_problems(tmp_path):
    with pytest.raises(MocapError, match="no such take folder"):
        open_take(tmp_path / "nowhere")
    (tmp_path / "file.txt").write_text("x")
    with pytest.raises(MocapError, match="not a file"):
        open_take(tmp_path / "file.txt")
    folder = make_take(tmp_path, "mkv")
    (folder / "calibration.toml").unlink()
    with pytest.raises(MocapError, match="calibration.toml: calibration file not found"):
        open_take(folder)


def test_recordings_shorter_than_take_toml_says_are_read_with_a_warning(tmp_path, caplog):
    folder = make_take(tmp_path, "png", fps=100.0)
    (folder / "take.toml").write_text(tomli_w.dumps({"fps": 100.0, "frames": 8}))
    with caplog.at_level(logging.WARNING):
        take = open_take(folder)
    assert take.n_frames == 5 and len(list(take.images())) == 5
    assert "take.toml says 8 frames, the recordings hold 5" in caplog.text
    (folder / "take.toml").write_text(tomli_w.dumps({"fps": 100.0, "frames": "many"}))
    with pytest.raises(MocapError, match="take.toml: 'frames' must be a whole number"):
        open_take(folder)


def test_bad_take_toml(tmp_path):
    folder = make_take(tmp_path, "mkv")
    (folder / "take.toml").write_text("fps = 'fast'\n")
    with pytest.raises(MocapError, match="take.toml: 'fps' must be"):
        open_take(folder)


def test_centroid_take(tmp_path):
    folder = tmp_path / "take"
    folder.mkdir()
    save_rig(ring_rig(2, size=SIZE), folder / "calibration.toml")
    (folder / "take.toml").write_text("fps = 240.0\nframes = 6\n")
    written = {}
    for c, suffix in ((0, ".centroids.csv"), (1, ".centroids.npz")):
        rng = np.random.default_rng(c)
        frames = [(k, Detections(rng.uniform(0, 60, (k % 3, 2)))) for k in range(4)]
        write_centroids(folder / f"cam{c + 1}{suffix}", frames)
        written[c] = dict(frames)
    take = open_take(folder)
    assert take.kind == "centroids" and take.fps == 240.0 and take.n_frames == 6  # take.toml's frames count
    got = list(take.centroids())
    assert len(got) == 6
    for k, dets in got:
        for c in range(2):
            want = written[c].get(k, Detections.empty())
            np.testing.assert_allclose(dets[c].xy, want.xy, atol=1e-6)
    with pytest.raises(MocapError, match="centroid files, not images"):
        next(take.images())


def test_empty_centroid_take(tmp_path):
    folder = tmp_path / "take"
    folder.mkdir()
    save_rig(ring_rig(1, size=SIZE), folder / "calibration.toml")
    (folder / "cam1.centroids.csv").write_text("frame,x,y\n")
    with pytest.raises(MocapError, match="empty"):
        open_take(folder, fps=100)
