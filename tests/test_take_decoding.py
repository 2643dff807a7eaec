"""Take reader speed paths: grey videos decoded straight to grey, cameras decoded in threads ahead of the caller."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest
from test_take import SIZE, frames_for, make_take, write_video

from mocap.take import _open_video, open_take


def test_grey_video_is_decoded_without_a_colour_round_trip(tmp_path):
    frames = frames_for(3, 4)
    write_video(tmp_path / "grey.mkv", frames)
    write_video(tmp_path / "colour.mkv", frames, colour=True)
    grey = _open_video(tmp_path / "grey.mkv")
    ok, first = grey.read()
    assert ok and first.shape == (SIZE[1], SIZE[0])  # (H, W) from the decoder itself
    np.testing.assert_array_equal(first, frames[0])
    colour = _open_video(tmp_path / "colour.mkv")
    ok, first = colour.read()
    assert ok and first.shape == (SIZE[1], SIZE[0], 3)  # a colour stream still comes as BGR
    np.testing.assert_array_equal(cv2.cvtColor(first, cv2.COLOR_BGR2GRAY), frames[0])


@pytest.mark.parametrize("kind", ["mkv", "png"])
def test_threaded_decoding_gives_the_same_frames_in_order(tmp_path, kind):
    take = open_take(make_take(tmp_path, kind, n=7, fps=50.0, cameras=3))
    serial = list(take.images(1, 6, threads=0))
    for threads in (2, 3):
        threaded = list(take.images(1, 6, threads=threads))
        assert [k for k, _ in threaded] == [1, 2, 3, 4, 5]
        for (_, a), (_, b) in zip(serial, threaded, strict=True):
            for c in range(3):
                np.testing.assert_array_equal(a[c], b[c])
    for k, images in serial:
        for c, image in enumerate(images):
            np.testing.assert_array_equal(image, frames_for(c, 7)[k])


def test_threaded_decoding_keeps_undecodable_frames_as_none(tmp_path, caplog):
    take_dir = make_take(tmp_path, "png", n=4, fps=50.0)
    (take_dir / "cam2" / "000002.png").write_bytes(b"not a png")
    take = open_take(take_dir)
    seen = list(take.images(threads=2))
    assert [k for k, _ in seen] == [0, 1, 2, 3]
    assert seen[2][1][1] is None and seen[2][1][0] is not None
    assert "000002.png" in caplog.text


def test_stopping_early_closes_the_decoders(tmp_path):
    take = open_take(make_take(tmp_path, "mkv", n=6, fps=50.0))
    frames = take.images(threads=2)
    k, images = next(frames)
    assert k == 0 and len(images) == 2
    frames.close()  # waits for the frame decoded ahead and ends the pool
    assert not [t for t in threading.enumerate() if t.name.startswith("mocap-decode")]
    assert list(take.images(4, threads=2))[0][0] == 4
