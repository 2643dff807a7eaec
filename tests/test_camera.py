"""Camera model against OpenCV, and calibration.toml round trips and errors."""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import pytest
import tomli_w
from hypothesis import given, settings
from hypothesis import strategies as st

from mocap.camera import Camera, load_rig, save_rig
from mocap.errors import MocapError
from tests.conftest import ring_rig


def _volume_points(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform([-1.0, -1.0, 0.0], [1.0, 1.0, 2.0], size=(n, 3))


def test_project_matches_opencv(rig):
    X = _volume_points(200)
    for cam in rig:
        ref, _ = cv2.projectPoints(X, cam.rotation, cam.translation, cam.matrix, cam.distortions)
        np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), atol=1e-9)


def test_fisheye_project_matches_opencv():
    base = ring_rig(1)[0]
    cam = Camera("fe", base.size, base.matrix, [0.05, -0.01, 0.002, 0.0], base.rotation, base.translation, True)
    X = _volume_points(100)
    ref, _ = cv2.fisheye.projectPoints(X.reshape(-1, 1, 3), cam.rotation, cam.translation, cam.matrix, cam.distortions)
    np.testing.assert_allclose(cam.project(X), ref.reshape(-1, 2), atol=1e-8)


def test_points_beyond_the_lens_models_fold_are_not_imaged():
    """With k1 = 0.038, k2 = -0.009 the radial polynomial turns back at 2.5 (68 degrees off axis): OpenCV's formula
    puts a point 75 degrees off axis inside the image, where no lens images it; within the fold nothing changes."""
    base = ring_rig(1)[0]
    cam = Camera("wide", base.size, base.matrix, [0.038, -0.009, 0.0, 0.0, 0.0], base.rotation, base.translation)
    assert 2.4 < cam.fold_radius < 2.6
    outside = cam.camera_to_world(np.array([[3.66, 0.34, 1.0], [-2.6, 0.0, 1.0]]))
    formula, _ = cv2.projectPoints(outside, cam.rotation, cam.translation, cam.matrix, cam.distortions)
    assert cam.in_image(formula.reshape(-1, 2))[0]  # drawn 350 px inside the left edge
    assert np.isnan(cam.project(outside)).all()
    inside = cam.camera_to_world(np.array([[0.5, -0.3, 2.0], [2.3, 0.1, 1.0]]))
    ref, _ = cv2.projectPoints(inside, cam.rotation, cam.translation, cam.matrix, cam.distortions)
    np.testing.assert_allclose(cam.project(inside), ref.reshape(-1, 2), atol=1e-9)
    assert Camera("mild", base.size, base.matrix, [-0.05, 0.007, 0, 0, 0], base.rotation,
                  base.translation).fold_radius == np.inf
    fisheye = Camera("fe", base.size, base.matrix, [0.0, 0.0, 0.0, -0.05], base.rotation, base.translation, True)
    assert 1.95 < fisheye.fold_radius < 2.05  # theta (1 - 0.05 theta^8) turns back at 63 degrees


def test_undistort_inverts_distortion_and_matches_opencv(rig):
    X = _volume_points(200, seed=1)
    for cam in rig:
        uv = cam.project(X)
        ideal = cam.undistort(uv)
        ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.matrix, cam.distortions, P=cam.matrix).reshape(-1, 2)
        np.testing.assert_allclose(ideal, ref, atol=1e-3)
        pinhole = (cam.projection_matrix @ np.c_[X, np.ones(len(X))].T).T
        np.testing.assert_allclose(ideal, pinhole[:, :2] / pinhole[:, 2:], atol=1e-6)
        np.testing.assert_allclose(cam.ideal_to_distorted(ideal), uv, atol=1e-9)


def test_undistort_keeps_nan_rows_and_never_aliases_its_input(rig):
    X = _volume_points(20, seed=2)
    for cam in rig:
        uv = cam.project(X)
        full = cam.undistort(uv)
        holey = uv.copy()
        holey[[3, 7]] = np.nan
        got = cam.undistort(holey)
        assert np.isnan(got[[3, 7]]).all()
        keep = np.setdiff1d(np.arange(len(X)), [3, 7])
        np.testing.assert_array_equal(got[keep], full[keep])
        assert np.isnan(cam.undistort(np.full((2, 2), np.nan))).all()
        assert cam.undistort(np.zeros((0, 2))).shape == (0, 2)
    pinhole = Camera("p", rig[0].size, rig[0].matrix, np.zeros(5), rig[0].rotation, rig[0].translation)
    uv = pinhole.project(X)
    ideal = pinhole.undistort(uv)
    np.testing.assert_array_equal(ideal, uv)
    ideal[0] = -1.0
    assert uv[0, 0] != -1.0  # a copy, not a view of the input


def test_points_behind_camera_are_nan(rig):
    cam = rig[0]
    behind = cam.center + 2 * (cam.center - np.array([0.0, 0.0, 1.0]))
    assert np.isnan(cam.project(behind[None])).all()


def test_world_camera_round_trip_and_center(rig):
    X = _volume_points(50)
    for cam in rig:
        np.testing.assert_allclose(cam.camera_to_world(cam.world_to_camera(X)), X, atol=1e-12)
        np.testing.assert_allclose(cam.world_to_camera(cam.center[None]), 0.0, atol=1e-12)


def test_projection_jacobian_matches_opencv(rig):
    X = _volume_points(5)
    cam = rig[2]
    for x in X:
        _, jac = cv2.projectPoints(x[None], cam.rotation, cam.translation, cam.matrix, cam.distortions)
        # OpenCV gives d/d(rvec, tvec, ...); d/dX_world = d/dtvec @ R.
        ref = jac[:, 3:6] @ cam.R
        np.testing.assert_allclose(cam.projection_jacobian(x[None])[0], ref, rtol=1e-5, atol=1e-3)


@settings(max_examples=25, deadline=None)
@given(k1=st.floats(-0.3, 0.3), p1=st.floats(-0.01, 0.01), k3=st.floats(-0.05, 0.05))
def test_calibration_toml_round_trip_is_exact(tmp_path_factory, k1, p1, k3):
    rig = ring_rig(3, distortions=(k1, 0.02, p1, 0.0, k3))
    rig.extra_tables["fundamental"] = {"cam1-cam2": [[0.1, 0.2, 0.3]] * 3}
    path = tmp_path_factory.mktemp("cal") / "calibration.toml"
    save_rig(rig, path)
    back = load_rig(path)
    assert back.names == rig.names and back.metadata == rig.metadata and back.extra_tables == rig.extra_tables
    for a, b in zip(rig, back, strict=True):
        assert a.size == b.size and a.fisheye == b.fisheye
        for attr in ("matrix", "distortions", "rotation", "translation"):
            np.testing.assert_array_equal(getattr(a, attr), getattr(b, attr))


def test_unknown_tables_ignored(tmp_path, rig):
    path = tmp_path / "calibration.toml"
    save_rig(rig, path)
    path.write_text(path.read_text() + '\n[something_new]\nvalue = 3\n[other]\nx = "y"\n')
    assert load_rig(path).names == rig.names


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda s: s.replace("matrix = ", "matrixx = ", 1), "missing field(s) ['matrix']"),
        (lambda s: s.replace("size = [\n    1024,", "size = [\n    -1024,", 1), "field 'size'"),
        (lambda s: s.replace("rotation = [", 'rotation = ["a", ', 1), "field 'rotation'"),
        (lambda s: s.replace("[cam_1]", "[cam_1", 1), "not valid TOML"),
    ],
)
def test_malformed_calibration_names_file_and_field(tmp_path, rig, edit, expected):
    path = tmp_path / "calibration.toml"
    save_rig(rig, path)
    path.write_text(edit(path.read_text()))
    with pytest.raises(MocapError) as info:
        load_rig(path)
    assert str(path) in str(info.value) and expected in str(info.value)


def test_a_rotation_matrix_is_read_as_well_as_a_rodrigues_vector(tmp_path, rig):
    """Some tools write the 3x3 world -> camera matrix; it reads to the same camera (OpenCV's Rodrigues), and a
    3x3 that is not a rotation is refused by name."""
    path = tmp_path / "calibration.toml"
    save_rig(rig, path)
    data = tomllib.loads(path.read_text())
    data["cam_1"]["rotation"] = rig.cameras[0].R.tolist()
    path.write_text(tomli_w.dumps(data))
    back = load_rig(path)
    np.testing.assert_allclose(back.cameras[0].rotation, rig.cameras[0].rotation, atol=1e-12)
    X = np.array([[0.1, -0.2, 1.1]])
    np.testing.assert_allclose(back.cameras[0].project(X), rig.cameras[0].project(X), atol=1e-9)
    data["cam_1"]["rotation"] = (2.0 * np.eye(3)).tolist()
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(MocapError, match="not a rotation"):
        load_rig(path)


def test_missing_calibration_file(tmp_path):
    with pytest.raises(MocapError, match="not found"):
        load_rig(tmp_path / "nope.toml")
