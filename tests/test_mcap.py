"""The live MCAP logger: Foxglove topics and schemas, capture-time stamps, bit-exact centroids, crash safety."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from helpers_export import synthetic_detections, synthetic_trajectories
from mcap.reader import make_reader
from scipy.spatial.transform import Rotation

from mocap.camera import parse_rig, rig_to_toml
from mocap.errors import MocapError
from mocap.export import foxglove as fx
from mocap.export.common import identity_colors
from mocap.export.mcap import CENTROID_LAYOUT, McapLogger, _detections, read_mcap_take, read_mcap_trajectories

CLASSES = {cls.DESCRIPTOR.full_name: cls for cls in
           (FrameTransform, CameraCalibration, ImageAnnotations, PointCloud, SceneUpdate)}
FRAMES, MARKERS, FIRST = 40, 8, 100


@pytest.fixture
def take(rig):
    """A logged take: (path, trajectories, detections per frame)."""
    traj = synthetic_trajectories(FRAMES, MARKERS, seed=5, first_frame=FIRST)
    rng = np.random.default_rng(6)
    dets = [synthetic_detections(rig, np.nan_to_num(traj.positions[f], nan=1.0), rng) for f in range(FRAMES)]
    dets[3][2] = dets[3][2].subset(np.zeros(len(dets[3][2]), dtype=bool))  # a camera that saw nothing
    return traj, dets


def log_take(path, rig, traj, dets, stop=None):
    with McapLogger(path, rig, traj.fps, rig_to_toml(rig), {"take": "synthetic", "operator": "é"},
                    chunk_size=32 * 1024) as logger:
        for f in range(FRAMES if stop is None else stop):
            ids = np.flatnonzero(traj.valid[f])
            logger.log_frame(FIRST + f, dets[f], ids, traj.positions[f, ids], traj.residuals[f, ids],
                             traj.camera_masks[f, ids])
    return path


def test_topics_schemas_counts_and_capture_times(tmp_path, rig, take):
    traj, dets = take
    path = log_take(tmp_path / "run.mcap", rig, traj, dets)
    per_frame = [f"/{n}/{w}" for n in rig.names for w in ("centroids", "detections")] + ["/markers", "/markers/cloud"]
    static = ["/tf"] + [f"/{n}/calibration" for n in rig.names]
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        assert topics == {**{t: "foxglove.PointCloud" for t in per_frame if t.endswith(("centroids", "cloud"))},
                          **{t: "foxglove.ImageAnnotations" for t in per_frame if t.endswith("detections")},
                          "/markers": "foxglove.SceneUpdate", "/tf": "foxglove.FrameTransform",
                          **{t: "foxglove.CameraCalibration" for t in static[1:]}}
        counts = {summary.channels[cid].topic: n for cid, n in summary.statistics.channel_message_counts.items()}
        assert counts == {**{t: FRAMES for t in per_frame}, "/tf": len(rig), **{t: 1 for t in static[1:]}}
        assert summary.statistics.message_count == FRAMES * len(per_frame) + 2 * len(rig)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            decoded = CLASSES[schema.name].FromString(message.data)  # every message decodes
            assert decoded.SerializeToString() and message.publish_time == message.log_time
            if channel.topic in static:
                assert message.log_time == 0
            else:  # capture time of the frame, never wall-clock
                assert message.log_time == round(message.sequence * 1e9 / traj.fps)
                assert FIRST <= message.sequence < FIRST + FRAMES
                stamps = [e.timestamp for e in [*decoded.deletions, *decoded.entities]] \
                    if isinstance(decoded, SceneUpdate) else [decoded.timestamp]
                assert all(s.seconds * 10**9 + s.nanos == message.log_time for s in stamps)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert metadata["take"] == {"take": "synthetic", "operator": "é"}
        assert json.loads(metadata["mocap.log"]["cameras"]) == rig.names
        attachments = {a.name: a for a in reader.iter_attachments()}
        rig_back = parse_rig(attachments["calibration.toml"].data.decode())
        assert rig_back.names == rig.names


def test_camera_messages_match_the_rig(tmp_path, rig, take):
    traj, dets = take
    path = log_take(tmp_path / "run.mcap", rig, traj, dets)
    with open(path, "rb") as f:
        msgs = [(c.topic, CLASSES[s.name].FromString(m.data)) for s, c, m in
                make_reader(f).iter_messages(topics=["/tf"] + [f"/{n}/calibration" for n in rig.names])]
    transforms = {m.child_frame_id: m for t, m in msgs if t == "/tf"}
    for cam in rig:
        tf = transforms[cam.name]
        assert tf.parent_frame_id == "world"
        np.testing.assert_allclose([tf.translation.x, tf.translation.y, tf.translation.z], cam.center, atol=1e-12)
        q = [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w]
        # the transform maps camera (OpenCV optical) coordinates to world coordinates
        X_cam = np.array([[0.1, -0.2, 3.0]])
        np.testing.assert_allclose(Rotation.from_quat(q).apply(X_cam) + cam.center, cam.camera_to_world(X_cam),
                                   atol=1e-12)
        calib = next(m for t, m in msgs if t == f"/{cam.name}/calibration")
        assert (calib.width, calib.height, calib.frame_id) == (*cam.size, cam.name)
        assert calib.distortion_model == "plumb_bob"
        np.testing.assert_array_equal(np.reshape(calib.K, (3, 3)), cam.matrix)
        np.testing.assert_array_equal(calib.D, cam.distortions)


def test_frame_messages_carry_the_logged_values(tmp_path, rig, take):
    traj, dets = take
    path = log_take(tmp_path / "run.mcap", rig, traj, dets)
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            f_idx = message.sequence - FIRST
            msg = CLASSES[schema.name].FromString(message.data)
            ids = np.flatnonzero(traj.valid[f_idx]) if f_idx >= 0 else None
            if channel.topic == "/markers":
                assert [d.type for d in msg.deletions] == [1]  # delete all, then this frame's spheres
                assert [e.id.strip() for e in msg.entities] == [f"M{i + 1:03d}" for i in ids]
                for e, i in zip(msg.entities, ids, strict=True):
                    p = e.spheres[0].pose.position
                    np.testing.assert_array_equal([p.x, p.y, p.z], traj.positions[f_idx, i])
                    meta = {kv.key: kv.value.strip() for kv in e.metadata}
                    assert float(meta["residual_mm"]) == pytest.approx(traj.residuals[f_idx, i], abs=0.005)
                    assert int(meta["cameras"]) == bin(int(traj.camera_masks[f_idx, i])).count("1")
                    assert e.frame_id == "world" and e.spheres[0].pose.orientation.w == 1.0
            elif channel.topic.endswith("/detections"):
                c = rig.names.index(channel.topic.split("/")[1])
                points = np.array([[p.x, p.y] for p in msg.points[0].points]).reshape(-1, 2)
                np.testing.assert_array_equal(points, dets[f_idx][c].xy)
                seen = ids[(traj.camera_masks[f_idx, ids] >> c) & 1 == 1]
                assert [t.text.strip() for t in msg.texts] == [f"M{i + 1:03d}" for i in seen]
                uv = rig[c].project(traj.positions[f_idx, seen]).reshape(-1, 2)
                text_xy = np.array([[t.position.x, t.position.y] for t in msg.texts]).reshape(-1, 2)
                np.testing.assert_allclose(text_xy - uv, np.tile([8.0, -8.0], (len(seen), 1)), atol=1e-9)


def test_hand_packed_scene_update_equals_the_protobuf_class_construction():
    rng = np.random.default_rng(2)
    pos = rng.normal(size=(3, 3))
    colors = identity_colors(np.array([0, 5, 9]))
    packed = SceneUpdate.FromString(fx.scene_update(
        12_345_678_901, fx.padded_strings(["a", "bb", "ccc"]), pos, colors,
        fx.padded_strings(["1.00", "22.50", "3.25"], "right"), fx.padded_strings(["2", "3", "4"], "right")))
    expected = SceneUpdate()
    d = expected.deletions.add(type=1)
    d.timestamp.FromNanoseconds(12_345_678_901)
    for label, p, c, r, n in zip(["a  ", "bb ", "ccc"], pos, colors, [" 1.00", "22.50", " 3.25"], "234",
                                 strict=True):
        e = SceneEntity(frame_id="world", id=label)
        e.timestamp.FromNanoseconds(12_345_678_901)
        e.metadata.add(key="residual_mm", value=r)
        e.metadata.add(key="cameras", value=n)
        s = e.spheres.add()
        s.pose.position.x, s.pose.position.y, s.pose.position.z = p
        s.pose.orientation.w = 1.0
        s.size.x = s.size.y = s.size.z = 0.014
        s.color.r, s.color.g, s.color.b, s.color.a = c
        expected.entities.append(e)
    assert packed == expected


def test_centroids_come_back_bit_exact_and_trajectories_exact(tmp_path, rig, take):
    traj, dets = take
    path = log_take(tmp_path / "run.mcap", rig, traj, dets)
    log = read_mcap_take(path)
    assert (log.fps, log.first_frame, log.n_frames, log.truncated) == (traj.fps, FIRST, FIRST + FRAMES, False)
    assert log.camera_names == rig.names
    seen = []
    for frame, frame_dets in log.centroids(FIRST + 5, FIRST + 30):
        seen.append(frame)
        for got, want in zip(frame_dets, dets[frame - FIRST], strict=True):
            for name in ("xy", "area", "roundness", "cov", "merged", "flux", "cut"):
                assert np.array_equal(getattr(got, name), getattr(want, name)), name
            assert got.merged.dtype == bool and got.cut.dtype == bool
    assert seen == list(range(FIRST + 5, FIRST + 30))
    back = read_mcap_trajectories(path)
    np.testing.assert_array_equal(back.positions, traj.positions)
    np.testing.assert_array_equal(back.residuals, traj.residuals)
    np.testing.assert_array_equal(back.camera_masks, traj.camera_masks)
    assert back.first_frame == FIRST and back.labels == [f"M{i + 1:03d}" for i in range(MARKERS)]


def test_a_log_written_before_the_blobs_light_was_logged_reads_it_as_unknown():
    """Logs of earlier versions have no ``flux`` field in their centroid clouds: their blobs read back whole, with
    the light NaN (the tracker then judges partly hidden markers by their blobs' size)."""
    old = np.zeros(3, dtype=[(name, "<f8") for name, _ in CENTROID_LAYOUT if name != "flux"])
    old["x"], old["area"], old["merged"] = [1.0, 2.0, 3.0], [10.0, 11.0, 12.0], [0.0, 1.0, 0.0]
    det = _detections(old)
    np.testing.assert_array_equal(det.xy[:, 0], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(det.merged, [False, True, False])
    assert np.isnan(det.flux).all()


def test_a_log_written_before_blobs_were_flagged_cut_reads_none_as_cut():
    """Logs of earlier versions have no ``cut`` field: no blob reads back as measured partly hidden."""
    old = np.zeros(3, dtype=[(name, "<f8") for name, _ in CENTROID_LAYOUT if name != "cut"])
    old["x"], old["merged"], old["flux"] = [1.0, 2.0, 3.0], [0.0, 1.0, 0.0], [90.0, 80.0, 70.0]
    det = _detections(old)
    np.testing.assert_array_equal(det.cut, [False, False, False])
    np.testing.assert_array_equal(det.flux, [90.0, 80.0, 70.0])


def test_a_failed_run_never_replaces_an_existing_log(tmp_path, rig, take):
    traj, dets = take
    path = tmp_path / "run.mcap"
    path.write_bytes(b"the previous run's log")
    with pytest.raises(RuntimeError, match="tracker crashed"):
        with McapLogger(path, rig, traj.fps, rig_to_toml(rig), {}) as logger:
            for f in range(10):
                logger.log_frame(FIRST + f, dets[f], np.zeros(0), np.zeros((0, 3)), np.zeros(0), np.zeros(0))
            raise RuntimeError("tracker crashed")
    assert path.read_bytes() == b"the previous run's log"
    partial = read_mcap_take(tmp_path / "run.mcap.partial")  # finished and readable up to the failure
    assert partial.n_frames == FIRST + 10 and not partial.truncated


def test_a_killed_run_leaves_a_partial_log_readable_up_to_its_last_chunk(tmp_path, rig, take, caplog):
    traj, dets = take
    path = log_take(tmp_path / "run.mcap", rig, traj, dets)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])  # no summary, the last chunk cut through
    with caplog.at_level(logging.WARNING):
        log = read_mcap_take(cut)
        frames = [(f, d) for f, d in log.centroids()]
    assert log.truncated and "ends early" in caplog.text
    assert 0 < len(frames) < FRAMES
    for f, frame_dets in frames:
        assert all(np.array_equal(a.xy, b.xy) for a, b in zip(frame_dets, dets[f - FIRST], strict=True))
    partial = read_mcap_trajectories(cut)
    full = read_mcap_trajectories(path)
    n = partial.n_frames
    assert 0 < n < FRAMES and partial.first_frame == FIRST
    columns = [full.labels.index(label) for label in partial.labels]
    np.testing.assert_array_equal(partial.positions, full.positions[:n, columns])


@pytest.mark.parametrize("payload", [b"", b"\x89MCAP0\r\n", b"not an mcap file at all" * 10])
def test_unreadable_logs_raise_a_clear_error(tmp_path, payload):
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(payload)
    with pytest.raises(MocapError, match="bad.mcap: not a readable MCAP log"):
        read_mcap_trajectories(bad)
    with pytest.raises(MocapError, match="bad.mcap"):
        read_mcap_take(bad)


def test_logger_checks_its_output_folder_and_a_trajectory_log_cannot_be_rerun(tmp_path, rig):
    with pytest.raises(MocapError, match="does not exist"):
        McapLogger(tmp_path / "missing" / "run.mcap", rig, 120.0, rig_to_toml(rig), {})
    with McapLogger(tmp_path / "t.mcap", None, 120.0) as logger:
        logger.log_frame(0, [], np.array([0]), np.zeros((1, 3)), np.zeros(1), np.zeros(1, np.uint32))
    with pytest.raises(MocapError, match="no 'calibration.toml' attachment"):
        read_mcap_take(tmp_path / "t.mcap")
