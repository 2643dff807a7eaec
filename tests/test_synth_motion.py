"""Motion for synthetic takes: real C3D and TRC files (units, up axis, gaps), the marching body, capsule occlusion."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import MocapError
from mocap.export.c3d import read_c3d, write_c3d
from mocap.export.csv import write_csv
from mocap.export.trc import read_trc, write_trc
from mocap.synth.body import MARKERS, marching_body, marching_motion
from mocap.synth.motion import DUPLICATE_M, FOOT_LABEL, UP_AXES, detect_up_axis, load_motion, motion_from_file
from mocap.synth.occlusion import Capsules, capsules_from_markers, occluded, segment_distance
from mocap.trajectories import Trajectories
from tests.conftest import require_shared_data

C3D_FILES = ["kinematics_tennis_serve.c3d", "kinematics_tennis_serve_2players.c3d", "walkingOptiTrack.c3d",
             "kinematics_basket_sprint.c3d"]


@pytest.mark.parametrize("name", C3D_FILES)
def test_real_c3d_loads_upright_centred_with_gaps_kept(name):
    path = require_shared_data("c3d") / name
    raw = read_c3d(path)
    labels, fps, positions = load_motion(path)
    assert fps == raw.fps
    assert positions.shape == (raw.n_frames, len(labels), 3)
    seen = raw.valid.any(axis=0)
    assert labels == [label for label, s in zip(raw.labels, seen, strict=True) if s]
    missing = np.isnan(positions[..., 0])
    assert missing[~raw.valid[:, seen]].all()  # gaps stay gaps ...
    dropped = missing & raw.valid[:, seen]  # ... and a sample is dropped only where it lies on another marker
    assert dropped.sum() <= 2  # (the tennis files' LWRA on LWRB for a frame: the recording's labelling)
    for f, k in zip(*np.nonzero(dropped), strict=True):
        others = np.delete(raw.positions[f, seen], k, axis=0)
        assert np.nanmin(np.linalg.norm(others - raw.positions[f, seen][k], axis=1)) < DUPLICATE_M
    z = positions[..., 2]
    assert np.nanpercentile(z, 1) > -0.05  # on or above the floor
    assert np.nanpercentile(z, 99) < 2.3
    # each file is z-up already (the shared README says y-up for tennis; the data say z): z is kept as is
    np.testing.assert_allclose(z[~missing], raw.positions[:, seen, 2][~missing], atol=1e-12)
    mid = (np.nanpercentile(positions[..., :2].reshape(-1, 2), 0.5, axis=0)
           + np.nanpercentile(positions[..., :2].reshape(-1, 2), 99.5, axis=0)) / 2
    np.testing.assert_allclose(mid, 0.0, atol=1e-9)


def test_tennis_player_stands_upright():
    labels, _, positions = load_motion(require_shared_data("c3d") / "kinematics_tennis_serve.c3d")
    head = positions[:, labels.index("Derrick:LFHD"), 2]
    ankle = positions[:, labels.index("Derrick:LANK"), 2]
    assert np.median(head - ankle) > 1.2


@pytest.mark.parametrize("up", sorted(UP_AXES))
def test_up_axis_is_detected_for_every_orientation(up):
    motion = motion_from_file(require_shared_data("c3d") / "kinematics_tennis_serve_2players.c3d")
    in_file_axes = motion.positions @ UP_AXES[up]  # inverse rotation: z-up -> a file with `up` up
    assert detect_up_axis(in_file_axes - [0.3, -0.2, 0.9], motion.labels) == up  # origin off the floor too
    body = marching_motion(240, seed=4)
    assert detect_up_axis(body.positions @ UP_AXES[up], body.labels) == up


def test_a_point_that_copies_another_in_every_frame_is_filmed_once(tmp_path, caplog):
    """Two labels of one point (markers.trc's STER and STERr) would be two truth markers in one blob: the copy is
    dropped; a point 12 mm from another, or with it in some frames only, is not (it loses those samples)."""
    labels, fps, markers = marching_body(100, fps=100, n_markers=12, seed=5)
    near = markers[:, 3] + [0.012, 0.0, 0.0]
    partly = markers[:, 4].copy()
    partly[30:] += [0.0, 0.03, 0.0]
    points = np.concatenate([markers, markers[:, [2]], near[:, None], partly[:, None]], axis=1)
    points[:20, 12] = np.nan  # (a gap in the copy: it still copies where it is seen)
    write_c3d(Trajectories(labels + ["copy2", "near3", "partly4"], fps, points), tmp_path / "copies.c3d")
    with caplog.at_level("INFO"):
        motion = motion_from_file(tmp_path / "copies.c3d", up="z")
    assert motion.labels == labels + ["near3", "partly4"] and motion.info["points_dropped_copies"] == 1
    assert motion.info["samples_dropped_duplicates"] == 30
    assert "copy2" in caplog.text


def _axes(markers: np.ndarray, length_m: float) -> np.ndarray:
    """(F, 4, 3) a segment's origin (the mean of three markers (F, 3, 3)) and a point ``length_m`` along each of its
    three axes (Gram-Schmidt on the markers' directions), as Plug-in Gait writes its bones."""
    origin = markers.mean(axis=1)
    x = markers[:, 0] - origin
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = markers[:, 1] - origin
    y -= (y * x).sum(axis=1, keepdims=True) * x
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    z = np.cross(x, y)
    return np.stack([origin, origin + length_m * x, origin + length_m * y, origin + length_m * z], axis=1)


def test_segment_axes_a_model_wrote_are_not_filmed(tmp_path, caplog):
    """Plug-in Gait writes each segment as four points, PELO (origin), PELA, PELL and PELP, 0.14 m along three
    perpendicular axes: not markers. Four markers named so that stand otherwise (THIO, THIA, THIL, THIP: not
    perpendicular) are markers."""
    labels, fps, markers = marching_body(120, fps=100, n_markers=12, seed=6)
    pelvis = _axes(markers[:, [0, 1, 2]], 0.139)
    pelvis[30:40] = np.nan  # (a gap: the axes hold wherever they are seen)
    thigh = markers[:, [3, 4, 5, 6]] + [0.0, 0.0, 0.01]
    names = ["PELO", "PELA", "PELL", "PELP", "THIO", "THIA", "THIL", "THIP"]
    points = np.concatenate([markers, pelvis, thigh], axis=1)
    write_c3d(Trajectories(labels + names, fps, points), tmp_path / "pig.c3d")
    with caplog.at_level("INFO"):
        motion = motion_from_file(tmp_path / "pig.c3d", up="z")
    assert motion.labels == labels + names[4:]
    assert motion.info["points_dropped_segment_axes"] == 4 and "segments' axes" in caplog.text


def test_joint_centres_halfway_between_two_markers_are_not_filmed(tmp_path, caplog):
    """OpenSim's test_walking.c3d holds RKJC, RAJC ... halfway between the condyles or the malleoli (to 1e-4 mm): a
    model's points, filmed they sat 7 px from both markers in every image. A marker near a midpoint that wobbles by
    a millimetre or two (skin) is filmed."""
    labels, fps, markers = marching_body(150, fps=100, n_markers=12, seed=7)
    centre = (markers[:, 2] + markers[:, 5]) / 2
    centre[:15] = np.nan
    rng = np.random.default_rng(7)
    skin = (markers[:, 3] + markers[:, 8]) / 2 + rng.normal(0.0, 0.001, (150, 3))
    write_c3d(Trajectories(labels + ["RKJC", "SKIN"], fps, np.concatenate([markers, centre[:, None], skin[:, None]],
                                                                         axis=1)), tmp_path / "jc.c3d")
    with caplog.at_level("INFO"):
        motion = motion_from_file(tmp_path / "jc.c3d", up="z")
    assert motion.labels == labels + ["SKIN"] and motion.info["points_dropped_joint_centres"] == 1
    assert "RKJC" in caplog.text


def test_a_second_reconstruction_of_a_marker_is_not_filmed_where_it_lies_on_the_marker(tmp_path, caplog):
    """A point on another marker (within 10 mm) in a few of its frames loses those samples (a label on another
    marker for a frame: the tennis serve's LWRA on LWRB); one on it in half its frames or more is not filmed at all
    (a Vicon file's unlabelled *20, 2-7 mm from RASI for 740 of its 796 frames, wandering off elsewhere: its other
    samples are a reconstruction's artefacts too). Two markers 12 mm apart are both filmed."""
    labels, fps, markers = marching_body(120, fps=100, n_markers=12, seed=8)
    glimpse = markers[:, 5] + [0.0, 0.0, 0.03]
    glimpse[40:50] = markers[40:50, 4] + [0.004, 0.0, 0.003]  # (on marker 4 for 10 frames: those dropped)
    shadow = markers[:, 4] + [0.004, 0.0, 0.003]
    shadow[:30] = np.nan
    shadow[100:] = markers[100:, 4] + [0.0, 0.05, 0.0]  # (off the marker for 20 of 90 frames: dropped too)
    neighbour = markers[:, 6] + [0.012, 0.0, 0.0]
    points = np.concatenate([markers, glimpse[:, None], shadow[:, None], neighbour[:, None]], axis=1)
    write_c3d(Trajectories(labels + ["G12", "*20", "N13"], fps, points), tmp_path / "twice.c3d")
    with caplog.at_level("INFO"):
        motion = motion_from_file(tmp_path / "twice.c3d", up="z")
    assert motion.labels == labels + ["G12", "N13"]
    assert motion.info["points_dropped_duplicates"] == 1 and motion.info["samples_dropped_duplicates"] == 10
    seen = np.isfinite(motion.positions[..., 0])
    assert not seen[40:50, 12].any() and seen[:40, 12].all() and seen[50:, 12].all()
    assert seen[:, 4].all() and seen[:, 13].all()
    assert "*20" in caplog.text and "G12 (10)" in caplog.text


def test_a_label_on_another_marker_for_a_frame_loses_that_sample_not_the_marker_s_own(tmp_path):
    """The tennis serve's LWRA is on LWRB's marker at frame 400: the sample off its own path is dropped, though LWRB
    is the point seen less."""
    labels, fps, markers = marching_body(120, fps=100, n_markers=12, seed=9)
    points = markers.copy()
    points[60, 7] = markers[60, 8] + [0.001, 0.0, 0.0]
    points[10:20, 8] = np.nan
    write_c3d(Trajectories(labels, fps, points), tmp_path / "hop.c3d")
    motion = motion_from_file(tmp_path / "hop.c3d", up="z")
    seen = np.isfinite(motion.positions[..., 0])
    assert motion.info["samples_dropped_duplicates"] == 1 and not seen[60, 7] and seen[60, 8]


def test_a_treadmill_walker_whose_feet_move_more_than_the_head_stands_upright():
    """On a treadmill the belt moves the foot in stance while the head stays put: the floor-at-rest cue says the
    feet are up (unlabelled markers), the labels (head, shoulders, feet) say otherwise, for every file axis."""
    body = marching_motion(240, seed=4)
    feet = [i for i, label in enumerate(body.labels) if FOOT_LABEL.match(label)]
    assert len(feet) >= 4
    treadmill = body.positions.copy()
    t = np.arange(240) / body.fps
    treadmill[:, feet, 0] += (0.6 * (t % 1.0))[:, None]  # the belt pulls the feet back at 0.6 m/s
    assert detect_up_axis(treadmill) == "-z"  # (no labels: the moving end is taken for the top)
    for up in ("z", "-y", "x"):
        assert detect_up_axis(treadmill @ UP_AXES[up], body.labels) == up


def test_y_up_millimetre_file_with_gaps_round_trips(tmp_path):
    labels, fps, z_up = marching_body(200, fps=100, n_markers=30, seed=2)
    z_up = z_up + [1.5, -2.0, 0.0]
    z_up[50:60, 3] = np.nan
    y_up = z_up @ UP_AXES["y"]  # the same motion as a y-up recording
    write_c3d(Trajectories(labels, fps, y_up), tmp_path / "yup.c3d")  # stored in mm
    got_labels, got_fps, got = load_motion(tmp_path / "yup.c3d")
    assert got_labels == labels and got_fps == fps
    assert np.isnan(got[50:60, 3]).all() and np.isfinite(np.delete(got, 3, axis=1)).all()
    offset = np.nanmean(got - z_up, axis=(0, 1))
    np.testing.assert_allclose(got - offset, z_up, atol=1e-4)  # float32 mm storage
    assert offset[2] == pytest.approx(0.0, abs=1e-6)  # the floor was already at z = 0
    forced = motion_from_file(tmp_path / "yup.c3d", up="y")
    assert forced.info["up_axis"] == "y" and forced.info["up_axis_from"] == "--up"


def test_points_a_c3d_names_as_model_outputs_are_not_filmed(tmp_path, caplog):
    """A Vicon Nexus C3D stores joint angles and forces as points (degrees and newtons read as millimetres) and
    lists them in POINT:ANGLES, POINT:FORCES, ... (and any group POINT:TYPE_GROUPS names): only the markers are
    filmed."""
    ezc3d = pytest.importorskip("ezc3d")
    labels, fps, markers = marching_body(120, fps=100, n_markers=12, seed=4)
    extra = ["LHipAngles", "LGroundReactionForce", "PELO"]
    points = np.concatenate([markers * 1000.0, np.tile([[[16.0, -1.0, 3.0]]], (120, 3, 1))], axis=1)  # (F, M, 3) mm
    c3d = ezc3d.c3d()
    c3d["parameters"]["POINT"]["RATE"]["value"] = [fps]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = labels + extra
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d.add_parameter("POINT", "ANGLES", ["LHipAngles"])
    c3d.add_parameter("POINT", "FORCES", ["LGroundReactionForce"])
    c3d.add_parameter("POINT", "TYPE_GROUPS", ["ANGLES", "ANGLE", "FORCES", "FORCE", "BONES", "BONE"])
    c3d.add_parameter("POINT", "BONES", ["PELO"])
    data = np.ones((4, points.shape[1], points.shape[0]))
    data[:3] = np.transpose(points, (2, 1, 0))
    c3d["data"]["points"] = data
    c3d.write(str(tmp_path / "nexus.c3d"))
    assert read_c3d(tmp_path / "nexus.c3d").metadata["not_markers"] == extra
    with caplog.at_level("INFO"):
        motion = motion_from_file(tmp_path / "nexus.c3d", up="z")
    assert motion.labels == labels and motion.positions.shape == (120, 12, 3)
    assert motion.info["points_dropped_not_markers"] == 3 and "model outputs" in caplog.text


@pytest.mark.parametrize(("suffix", "writer"), [(".trc", write_trc), (".csv", write_csv)])
def test_trc_and_csv_motion_gives_the_same_motion_as_c3d(tmp_path, suffix, writer):
    labels, fps, z_up = marching_body(120, fps=100, n_markers=30, seed=5)
    z_up[30:40, 2] = np.nan
    traj = Trajectories(labels, fps, z_up @ UP_AXES["y"])  # a y-up recording, as OpenSim and Motive write
    write_c3d(traj, tmp_path / "m.c3d")
    writer(traj, tmp_path / f"m{suffix}")  # (y_up False: the axes are written as they are)
    ref = motion_from_file(tmp_path / "m.c3d")
    got = motion_from_file(tmp_path / f"m{suffix}")
    assert got.labels == ref.labels and got.fps == ref.fps and got.info["up_axis"] == ref.info["up_axis"]
    np.testing.assert_allclose(got.positions, ref.positions, atol=2e-4, equal_nan=True)  # text vs float32 mm


def test_real_trc_file_loads_and_an_unsure_up_axis_is_reported(caplog):
    """An upper-body marker set reaching forward spans more along x than along z: the guess is reported as one."""
    path = require_shared_data("trc") / "markers.trc"
    raw = read_trc(path)
    with caplog.at_level("WARNING", logger="mocap.synth.motion"):
        motion_from_file(path)
    assert "the up axis is a guess" in caplog.text
    motion = motion_from_file(path, up="z")
    assert motion.labels == [label for label in raw.labels if label != "STERr"]  # (STER's copy in the file)
    assert motion.fps == 100.0 and motion.n_frames == raw.n_frames
    sternum, hip = (motion.positions[:, motion.labels.index(n), 2] for n in ("STER", "ASISl"))
    assert np.median(sternum - hip) > 0.3  # the sternum 40 cm above the pelvis


def test_bad_motion_files_raise_user_errors(tmp_path):
    with pytest.raises(MocapError, match="not found"):
        load_motion(tmp_path / "missing.c3d")
    (tmp_path / "junk.c3d").write_bytes(b"not a c3d at all" * 20)
    with pytest.raises(MocapError, match="junk.c3d"):
        load_motion(tmp_path / "junk.c3d")
    write_c3d(Trajectories(["a", "b"], 100.0, np.full((10, 2, 3), np.nan)), tmp_path / "empty.c3d")
    with pytest.raises(MocapError, match="missing"):
        load_motion(tmp_path / "empty.c3d")
    write_c3d(Trajectories(["a"], 100.0, np.ones((10, 1, 3))), tmp_path / "one.c3d")
    with pytest.raises(MocapError, match="--up"):
        motion_from_file(tmp_path / "one.c3d", up="sideways")


def test_marching_body_is_a_marching_rigid_skeleton():
    labels, fps, p = marching_body(240, fps=120, n_markers=40, seed=0)
    assert fps == 120 and p.shape == (240, 40, 3) and len(set(labels)) == 40
    assert np.isfinite(p).all()
    z = {name: p[:, labels.index(name), 2] for name in ("LFHD", "LKNE", "RKNE", "LANK", "LTOE")}
    assert 1.4 < np.median(z["LFHD"]) < 1.8 and np.median(z["LTOE"]) < 0.15
    assert np.ptp(z["LKNE"]) > 0.12 and np.ptp(z["RKNE"]) > 0.12  # knees rise in turn
    assert np.corrcoef(z["LKNE"], z["RKNE"])[0, 1] < 0  # ... alternately
    assert np.ptp(p[..., :2].reshape(-1, 2), axis=0).max() < 1.5  # in place
    shin = np.linalg.norm(p[:, labels.index("LTIB")] - p[:, labels.index("LANK")], axis=1)
    assert np.ptp(shin) < 1e-9  # markers on one segment move rigidly
    np.testing.assert_array_equal(marching_body(240, seed=0)[2], p)
    assert not np.allclose(marching_body(240, seed=1)[2], p)
    assert marching_body(5, n_markers=len(MARKERS))[2].shape[1] == len(MARKERS)
    for bad in (0, len(MARKERS) + 1):
        with pytest.raises(MocapError, match="--markers"):
            marching_body(5, n_markers=bad)


def test_body_markers_sit_on_the_skin_of_their_segment():
    motion = marching_motion(60, n_markers=len(MARKERS), seed=1, marker_mm=14.0)
    caps = motion.capsules
    for m, (_, segment, t, _) in enumerate(MARKERS):
        k = caps.names.index(segment)
        axis = caps.b[:, k] - caps.a[:, k]
        rel = motion.positions[:, m] - caps.a[:, k]
        along = np.einsum("ij,ij->i", rel, axis) / np.einsum("ij,ij->i", axis, axis)
        perp = np.linalg.norm(rel - along[:, None] * axis, axis=1)
        np.testing.assert_allclose(along, t, atol=1e-9)
        np.testing.assert_allclose(perp, caps.radius[k] + 0.007, atol=1e-9)


def test_segment_distance_matches_dense_sampling():
    rng = np.random.default_rng(5)
    p0, p1, q0, q1 = (rng.normal(0, 1, (120, 3)) for _ in range(4))
    q1[:20] = q0[:20]  # degenerate: a point
    p1[20:30] = p0[20:30] + 1e-3 * (q1[20:30] - q0[20:30])  # nearly parallel, tiny
    s = np.linspace(0, 1, 201)
    a = p0[:, None] + s[None, :, None] * (p1 - p0)[:, None]
    b = q0[:, None] + s[None, :, None] * (q1 - q0)[:, None]
    brute = np.linalg.norm(a[:, :, None] - b[:, None, :], axis=-1).min(axis=(1, 2))
    got = segment_distance(p0, p1, q0, q1)
    assert (got <= brute + 1e-12).all()
    np.testing.assert_allclose(got, brute, atol=1e-2)


def test_a_capsule_hides_what_is_behind_it_but_not_markers_on_its_near_side():
    # A vertical torso at the origin, radius 0.15 m; camera 4 m away on +x.
    caps = Capsules(np.array([[[0.0, 0, 0.8]]]), np.array([[[0.0, 0, 1.4]]]), np.array([0.15]), ["torso"])
    camera = np.array([4.0, 0.0, 1.1])
    points = np.array([[[0.157, 0, 1.1],     # chest marker facing the camera
                        [-0.157, 0, 1.1],    # back marker: hidden by its own body
                        [-0.5, 0.0, 1.1],    # behind the body
                        [-0.5, 0.5, 1.1],    # behind, but off to the side
                        [0.0, 0.05, 1.1]]])  # inside the capsule (approximation error): never hidden by it
    np.testing.assert_array_equal(occluded(camera, points, caps)[0], [False, True, True, False, False])
    gap = points.copy()
    caps_nan = Capsules(np.full((1, 1, 3), np.nan), np.full((1, 1, 3), np.nan), np.array([0.15]), ["gone"])
    assert not occluded(camera, gap, caps_nan).any()


def test_marker_capsules_for_recorded_motion():
    motion = motion_from_file(require_shared_data("c3d") / "kinematics_tennis_serve_2players.c3d")
    caps = capsules_from_markers(motion.labels, motion.positions[:50])
    assert "Derrick torso" in caps.names and "Viktor torso" in caps.names
    assert len(caps) > 40 and np.isfinite(caps.a).all()
    k = caps.names.index("Derrick torso")
    assert 0.08 <= caps.radius[k] <= 0.16
    assert (caps.b[:, k, 2] > caps.a[:, k, 2] + 0.2).all()  # upright torso axis
    walking = motion_from_file(require_shared_data("c3d") / "walkingOptiTrack.c3d")
    legs = capsules_from_markers(walking.labels, walking.positions[:50])
    assert not any("torso" in n for n in legs.names)  # leg clusters only: no torso to invent


def test_resampling_keeps_samples_and_gaps():
    motion = marching_motion(101, fps=50, n_markers=10, seed=3)
    motion.positions[40:43, 2] = np.nan
    fast = motion.resampled(100.0)
    assert fast.fps == 100 and fast.n_frames == 201
    np.testing.assert_allclose(fast.positions[::2], motion.positions, atol=1e-12)  # shared instants unchanged
    mid = (motion.positions[10] + motion.positions[11]) / 2
    np.testing.assert_allclose(fast.positions[21], mid, atol=1e-12)
    assert np.isnan(fast.positions[79:86, 2]).all()  # source gap 40-42 -> 80-84, plus the half-steps around it
    assert np.isfinite(fast.positions[78, 2]).all() and np.isfinite(fast.positions[86, 2]).all()
    assert fast.capsules.a.shape[0] == 201
    part = fast.window(50, 20)
    assert part.n_frames == 20 and part.capsules.a.shape[0] == 20 and part.info["first_source_frame"] == 50
    with pytest.raises(MocapError, match="--start"):
        fast.window(500)
