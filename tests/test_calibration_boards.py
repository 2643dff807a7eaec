"""Boards, intrinsics and stereo: real OpenCV stereo images and synthetic boards with known truth."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import require_shared_data

from calibration.boards import Board, parse_board
from calibration.intrinsics import calibrate_intrinsics, find_views, read_images
from calibration.stereo import calibrate_stereo, read_image_list
from mocap.errors import MocapError
from mocap.synth.board import BoardSpec, board_poses, render_board
from mocap.synth.rig import ring_rig


@pytest.fixture(scope="module")
def stereo_result():
    folder = require_shared_data("stereo-chessboard")
    pairs = read_image_list(folder / "stereo_calib.xml")
    board = parse_board("checker:9x6:0.025")
    left = [board.detect(im, n) for n, im in read_images([p[0] for p in pairs])]
    right = [board.detect(im, n) for n, im in read_images([p[1] for p in pairs])]
    return calibrate_stereo(left, right, board, (640, 480), ("left", "right"))


def test_real_stereo_reaches_the_targets(stereo_result):
    r = stereo_result
    assert len(r.pairs) == 13
    assert r.rms_px <= 0.5
    assert r.rig_stats.mean_px <= 0.15
    assert r.fit.stats.mean_px <= 0.15
    assert r.fit.inliers.all()


def test_real_stereo_epipolar_distances_match_opencv(stereo_result):
    x1, x2 = stereo_result.corners
    F = stereo_result.fit.F
    lines = cv2.computeCorrespondEpilines(x1.reshape(-1, 1, 2).astype(np.float32), 1, F).reshape(-1, 3)
    d_cv = np.abs((lines[:, :2] * x2).sum(axis=1) + lines[:, 2])
    lines = cv2.computeCorrespondEpilines(x2.reshape(-1, 1, 2).astype(np.float32), 2, F).reshape(-1, 3)
    d_cv = np.concatenate([d_cv, np.abs((lines[:, :2] * x1).sum(axis=1) + lines[:, 2])])
    assert stereo_result.fit.stats.mean_px == pytest.approx(d_cv.mean(), rel=1e-4)
    assert np.linalg.matrix_rank(F, tol=1e-9 * np.abs(F).max()) == 2


@pytest.mark.parametrize("kind", ["checker", "charuco"])
def test_intrinsics_from_synthetic_boards_within_half_a_percent(kind):
    cam = ring_rig(size=(640, 480), focal_px=625.0, seed=3)[0]
    spec = BoardSpec(kind, 9 if kind == "checker" else 8, 6, 0.06)
    board = Board(kind, spec.cols, spec.rows, spec.square, spec.marker, spec.dictionary)
    np.testing.assert_allclose(board.object_points(), spec.corners())
    rng = np.random.default_rng(0)
    images = [(str(k), render_board(cam, spec, r, t, rng)) for k, (r, t) in enumerate(board_poses(cam, spec, 12, rng))]
    views, missed, size = find_views(iter(images), board)
    assert not missed and size == cam.size
    result = calibrate_intrinsics(views, board, size)
    assert abs(result.matrix[0, 0] / cam.matrix[0, 0] - 1) < 0.005
    assert abs(result.matrix[1, 1] / cam.matrix[1, 1] - 1) < 0.005
    assert np.abs(result.matrix[:2, 2] - cam.matrix[:2, 2]).max() < 3.0
    assert result.rms_px < 0.3


def test_folder_of_mixed_image_sizes_is_refused(tmp_path):
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((48, 64), np.uint8))
    cv2.imwrite(str(tmp_path / "b.png"), np.zeros((60, 80), np.uint8))
    with pytest.raises(MocapError, match=r"b\.png.*differs from a\.png"):
        list(read_images(tmp_path))


def test_images_without_a_board_are_refused(tmp_path):
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"{k}.png"), np.full((120, 160), 40, np.uint8))
    with pytest.raises(MocapError, match="found in none of the 3 images"):
        find_views(read_images(tmp_path), parse_board("checker:9x6:0.025"), str(tmp_path))


def test_too_few_views_and_bad_board_text():
    with pytest.raises(MocapError, match="--board"):
        parse_board("checker:9by6")
    with pytest.raises(MocapError, match="at least 4 views"):
        calibrate_intrinsics([], parse_board("checker:9x6:0.025"), (640, 480))
    with pytest.raises(MocapError, match="unknown ArUco dictionary"):
        parse_board("charuco:7x5:0.04:0.03:DICT_NOPE")
