"""Round trips (write -> read) of every trajectory format, on synthetic and real recordings."""

from __future__ import annotations

import warnings

import c3d as c3d_package
import ezc3d
import numpy as np
import pytest
from conftest import require_shared_data
from helpers_export import synthetic_trajectories

from mocap.export.c3d import read_c3d, write_c3d
from mocap.export.common import y_up_to_z_up, z_up_to_y_up
from mocap.export.csv import read_csv, write_csv
from mocap.export.formats import FORMATS, read_trajectories, write_trajectories
from mocap.export.mcap import read_mcap_trajectories, write_mcap
from mocap.export.trc import read_trc, write_trc
from mocap.trajectories import Trajectories


def assert_same_samples(a: Trajectories, b: Trajectories, rtol: float = 0.0) -> None:
    assert a.labels == b.labels
    assert a.fps == b.fps
    assert a.first_frame == b.first_frame
    np.testing.assert_array_equal(a.valid, b.valid)
    if rtol == 0.0:
        np.testing.assert_array_equal(a.positions, b.positions)
    else:
        np.testing.assert_allclose(a.positions, b.positions, rtol=rtol, atol=1e-12)


@pytest.fixture
def traj() -> Trajectories:
    return synthetic_trajectories(n_frames=150, n_markers=9, gap_fraction=0.15, seed=3, first_frame=17)


@pytest.mark.parametrize("y_up", [False, True])
def test_trc_round_trip_is_exact_in_metres_and_to_one_ulp_in_mm(traj, tmp_path, y_up):
    write_trc(traj, tmp_path / "m.trc", units="m", y_up=y_up)
    assert_same_samples(read_trc(tmp_path / "m.trc", y_up=y_up), traj)
    write_trc(traj, tmp_path / "mm.trc", y_up=y_up)
    back = read_trc(tmp_path / "mm.trc", y_up=y_up)
    assert_same_samples(back, traj, rtol=5e-16)  # x * 1000 / 1000: at most one rounding each way
    assert back.metadata["units"] == "mm"


def test_trc_layout_is_opensims(traj, tmp_path):
    write_trc(traj, tmp_path / "a.trc", y_up=True)
    lines = (tmp_path / "a.trc").read_text().splitlines()
    assert lines[0].split("\t")[:3] == ["PathFileType", "4", "(X/Y/Z)"]
    assert lines[1].split("\t") == ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                                    "OrigDataStartFrame", "OrigNumFrames"]
    assert lines[2].split("\t")[2:5] == ["150", "9", "mm"]
    assert lines[3].split("\t")[:3] == ["Frame#", "Time", traj.labels[0]]
    assert lines[4].split("\t")[2:5] == ["X1", "Y1", "Z1"]
    row = lines[6].split("\t")
    assert row[0] == "18" and float(row[1]) == pytest.approx(17 / traj.fps, abs=1e-6)  # Frame# is 1-based
    m = int(np.flatnonzero(traj.valid[0])[0])
    x, y, z = traj.positions[0, m] / 1e-3  # the writer divides by the unit
    assert [float(v) for v in row[2 + 3 * m: 5 + 3 * m]] == [x, z, -y]  # OpenSim y-up
    gap = int(np.flatnonzero(~traj.valid[0])[0]) if (~traj.valid[0]).any() else None
    if gap is not None:
        assert row[2 + 3 * gap: 5 + 3 * gap] == ["", "", ""]


def test_y_up_rotation_is_a_proper_rotation_and_exact_inverse():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(50, 3))
    r = z_up_to_y_up(p)
    np.testing.assert_array_equal(r[:, 1], p[:, 2])  # up stays up
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), np.linalg.norm(p, axis=1))
    np.testing.assert_allclose(np.cross(r[0], r[1]), z_up_to_y_up(np.cross(p[0], p[1])[None])[0], atol=1e-12)
    np.testing.assert_array_equal(y_up_to_z_up(r), p)


def test_trc_reader_takes_the_comma_separated_pyomeca_file():
    path = require_shared_data("trc") / "markers.trc"
    traj = read_trc(path)
    assert (traj.n_markers, traj.fps, traj.first_frame) == (51, 100.0, 0)
    assert traj.labels[:3] == ["ASISl", "ASISr", "PSISl"]
    assert traj.n_frames == 93  # the header says 652 but the file holds 93 rows
    first = path.read_text().splitlines()[6].split(",")
    np.testing.assert_array_equal(traj.positions[0, 0], np.array([float(v) for v in first[2:5]]) * 1e-3)


def test_trc_header_with_two_tabs_between_values_is_read_by_name(traj, tmp_path):
    """OpenSim's example files (Moco's markers_walk.trc) space the header's values with two tabs and pad them, where
    the names have one: the values pair with the names by order, not by column."""
    write_trc(traj, tmp_path / "a.trc", units="cm")
    lines = (tmp_path / "a.trc").read_text().splitlines()
    lines[2] = "\t\t".join(f"  {v}" for v in lines[2].split("\t"))
    (tmp_path / "b.trc").write_text("\n".join(lines) + "\n")
    back = read_trc(tmp_path / "b.trc")
    assert back.metadata["units"] == "cm"
    assert_same_samples(back, traj, rtol=5e-16)


@pytest.mark.parametrize("y_up", [False, True])
def test_csv_round_trip_and_motive_layout(traj, tmp_path, y_up):
    write_csv(traj, tmp_path / "a.csv", units="Meters", y_up=y_up)
    back = read_csv(tmp_path / "a.csv")  # up axis from the file's 'Up Axis' entry
    assert_same_samples(back, traj)
    lines = (tmp_path / "a.csv").read_text().splitlines()
    assert lines[0].startswith("Format Version,1.23,Take Name,a,")
    assert lines[1] == ""
    assert lines[2].split(",")[:3] == ["", "Type", "Marker"]
    assert lines[3].split(",")[2:5] == [traj.labels[0]] * 3
    assert lines[5].split(",")[2] == "Position"
    assert lines[6].split(",")[:5] == ["Frame", "Time (Seconds)", "X", "Y", "Z"]
    assert lines[7].split(",")[0] == "17"  # Motive frames are 0-based take frames
    write_csv(traj, tmp_path / "mm.csv")
    assert_same_samples(read_csv(tmp_path / "mm.csv"), traj, rtol=5e-16)


def test_csv_reader_assumes_motive_y_up_and_skips_rigid_body_columns(tmp_path):
    text = "\n".join([
        "Format Version,1.23,Take Name,t,Capture Frame Rate,100.000000,Export Frame Rate,100.000000,"
        "Length Units,Millimeters,Coordinate Space,Global",
        "",
        ",Type,Rigid Body,Rigid Body,Rigid Body,Marker,Marker,Marker",
        ",Name,RB,RB,RB,RB:M1,RB:M1,RB:M1",
        ",ID,1,1,1,2,2,2",
        ",,Position,Position,Position,Position,Position,Position",
        "Frame,Time (Seconds),X,Y,Z,X,Y,Z",
        "5,0.05,1,2,3,10,20,30",
        "6,0.06,1,2,3,,,",
    ])
    (tmp_path / "m.csv").write_text(text)
    traj = read_csv(tmp_path / "m.csv")
    assert traj.labels == ["RB:M1"] and traj.first_frame == 5 and traj.fps == 100.0
    np.testing.assert_allclose(traj.positions[0, 0], [0.010, -0.030, 0.020])  # Motive y-up -> z-up
    assert not traj.valid[1, 0]


# (frames, markers, first frame): a short take, one longer than the C3D header's 16-bit frame count, and one
# whose last frame number passes 65,535 (the header cannot hold its range either)
C3D_TAKES = {"short": (150, 9, 17), "70,000 frames": (70_000, 3, 4321), "ends after frame 65535": (10_000, 3, 60_000)}


@pytest.mark.parametrize("take", C3D_TAKES)
def test_c3d_round_trip_and_the_c3d_package_reads_the_same_values(take, tmp_path):
    n_frames, n_markers, first_frame = C3D_TAKES[take]
    traj = synthetic_trajectories(n_frames, n_markers, gap_fraction=0.15, seed=3, first_frame=first_frame)
    traj.camera_masks &= 0x7F  # C3D stores 7 camera bits
    traj.residuals = np.minimum(traj.residuals, 2.5)  # the step asserted below assumes residuals < 2.55 mm
    write_c3d(traj, tmp_path / "a.c3d")
    assert ezc3d.c3d(str(tmp_path / "a.c3d"))["data"]["points"].shape[2] == n_frames  # ezc3d reads every frame
    back = read_c3d(tmp_path / "a.c3d")
    assert_same_samples(back, traj, rtol=6e-8)  # float32 storage
    step = 0.005  # residuals here are < 2.55 mm: POINT:SCALE chosen as 0.01 mm, rounding error <= half a step
    assert np.nanmax(np.abs(back.residuals - traj.residuals)) <= step + 1e-7
    np.testing.assert_array_equal(back.camera_masks, np.where(traj.valid, traj.camera_masks, 0))
    with open(tmp_path / "a.c3d", "rb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no analog data"
        reader = c3d_package.Reader(f)
        assert reader.point_rate == traj.fps
        assert reader.first_frame == traj.first_frame + 1  # C3D frames are 1-based
        assert reader.frame_count == n_frames
        assert [label.strip() for label in reader.point_labels] == traj.labels
        numbers, frames = zip(*[(i, points) for i, points, _ in reader.read_frames()], strict=True)
    np.testing.assert_array_equal(numbers, np.arange(n_frames) + first_frame + 1)
    frames = np.array(frames)  # (F, M, 5) mm
    valid = traj.valid
    np.testing.assert_allclose(frames[valid][:, :3] / 1000.0, traj.positions[valid], rtol=2e-7)  # float32 twice
    np.testing.assert_array_equal(frames[~valid][:, 3], -1.0)  # invalid samples: residual -1
    assert np.abs(frames[valid][:, 3] - traj.residuals[valid]).max() <= step + 1e-6
    np.testing.assert_array_equal(frames[valid][:, 4], traj.camera_masks[valid])


def test_c3d_reader_follows_the_spec_for_files_written_by_the_c3d_package(tmp_path):
    writer = c3d_package.Writer(point_rate=100.0, point_scale=-0.01, point_units="mm")
    points = np.zeros((2, 5), dtype=np.float32)
    points[:, :3] = [[1, 2, 3], [4, 5, 6]]
    points[:, 3] = [0.12, 0.5]
    points[:, 4] = [5, 64]
    writer.add_frames([(points, np.zeros((0, 0), np.float32))] * 3)
    writer.set_point_labels(["a", "b"])
    with open(tmp_path / "w.c3d", "wb") as f, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "no analog data"
        writer.write(f)
    traj = read_c3d(tmp_path / "w.c3d")
    np.testing.assert_allclose(traj.residuals, [[0.12, 0.5]] * 3, atol=1e-6)
    np.testing.assert_array_equal(traj.camera_masks, [[5, 64]] * 3)
    np.testing.assert_allclose(traj.positions[1], [[0.001, 0.002, 0.003], [0.004, 0.005, 0.006]])


def test_mcap_round_trip_is_exact_including_residuals_masks_and_never_seen_markers(traj, tmp_path):
    traj.positions[:, 4] = np.nan  # a marker that is never present keeps its column
    traj.residuals[:, 4] = np.nan
    traj.camera_masks[:, 4] = 0
    write_mcap(traj, tmp_path / "a.mcap")
    back = read_mcap_trajectories(tmp_path / "a.mcap")
    assert_same_samples(back, traj)
    np.testing.assert_array_equal(back.residuals, traj.residuals)
    np.testing.assert_array_equal(back.camera_masks, traj.camera_masks)
    assert back.camera_names == traj.camera_names
    assert back.metadata["subject"] == "synthetic"


@pytest.mark.parametrize("name", ["walkingOptiTrack.c3d", "kinematics_basket_sprint.c3d",
                                  "kinematics_tennis_serve.c3d", "kinematics_tennis_serve_2players.c3d"])
def test_real_c3d_files_survive_every_format(name, tmp_path):
    source = read_c3d(require_shared_data("c3d") / name)
    assert source.n_frames > 500 and source.n_markers >= 12
    tolerance = {".mcap": 0.0, ".c3d": 6e-8, ".trc": 5e-16, ".csv": 5e-16}  # exact, float32, mm <-> m
    assert set(tolerance) == set(FORMATS)
    for suffix, rtol in tolerance.items():
        out = tmp_path / f"out{suffix}"
        write_trajectories(source, out)
        assert_same_samples(read_trajectories(out), source, rtol=rtol)


@pytest.mark.parametrize("suffix", sorted(FORMATS))
def test_a_take_without_markers_round_trips(tmp_path, suffix):
    empty = Trajectories([], 120.0, np.zeros((10, 0, 3)), first_frame=3)
    write_trajectories(empty, tmp_path / f"e{suffix}")
    back = read_trajectories(tmp_path / f"e{suffix}")
    assert (back.n_markers, back.n_frames, back.first_frame, back.fps) == (0, 10, 3, 120.0)
