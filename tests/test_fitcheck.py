"""The calibration-fit check tells a matching calibration from a wrong one."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.fitcheck import FitMonitor, FitReport, check_calibration_fit
from tests.conftest import ring_rig


def _frames(rig: Rig, n_frames: int = 10, n_markers: int = 30, seed: int = 0) -> list[list[Detections]]:
    rng = np.random.default_rng(seed)
    frames = []
    for _ in range(n_frames):
        X = rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.9], size=(n_markers, 3))
        frames.append([Detections(cam.project(X) + rng.normal(0, 0.1, (n_markers, 2))) for cam in rig])
    return frames


def test_matching_calibration_has_full_support():
    rig = ring_rig()
    report = check_calibration_fit(rig, _frames(rig))
    assert np.all(report.support > 0.95)
    assert report.poor_cameras(rig) == []


def test_swapped_cameras_are_named():
    rig = ring_rig()
    frames = _frames(rig, n_markers=40)
    cams = list(rig.cameras)
    swapped = [c.with_pose(o.rotation, o.translation) for c, o in zip(cams, [cams[0], cams[3], cams[2], cams[1],
                                                                              cams[4], cams[5]], strict=True)]
    report = check_calibration_fit(Rig(swapped), frames)
    assert sorted(report.poor_cameras(rig)) == ["cam2", "cam4"]
    assert report.support[[0, 2, 4, 5]].min() > 0.9


def test_empty_frames_give_nan_support():
    rig = ring_rig(3)
    report = check_calibration_fit(rig, [[Detections.empty()] * 3])
    assert np.isnan(report.support).all() and report.poor_cameras(rig) == []


def test_sparse_rig_is_judged_against_its_own_level():
    """Four cameras, each marker seen by 40 % of them: only ~1/3 of the blobs can have three-camera support
    even with the right calibration (the old fixed 50 % limit warned about every camera); a swapped pair still
    falls to chance and is named."""
    rig = ring_rig(4)
    rng = np.random.default_rng(3)
    frames = []
    for _ in range(10):
        X = rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.9], size=(40, 3))
        seen = rng.random((4, 40)) < 0.4
        frames.append([Detections(cam.project(X[seen[c]]) + rng.normal(0, 0.1, (seen[c].sum(), 2)))
                       for c, cam in enumerate(rig)])
    report = check_calibration_fit(rig, frames)
    assert (report.support < 0.5).all() and report.poor_cameras(rig) == []
    cams = list(rig.cameras)
    swapped = [c.with_pose(o.rotation, o.translation) for c, o in zip(cams, [cams[1], cams[0], cams[2], cams[3]],
                                                                      strict=True)]
    assert report.support.min() > 3 * check_calibration_fit(Rig(swapped), frames).support.max()
    assert len(check_calibration_fit(Rig(swapped), frames).poor_cameras(rig)) >= 2


def test_three_cameras_are_judged_against_chance():
    """Three cameras, each marker seen by two of them most of the time: only a few percent of the blobs can
    have three-camera support even with the right calibration, but chance (the blobs mirrored) gives none;
    another session's calibration (other poses, same names) is named on every camera."""
    rig = ring_rig(3)
    rng = np.random.default_rng(4)
    frames = []
    for _ in range(10):
        X = rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.9], size=(40, 3))
        hidden = rng.integers(0, 3, 40)  # each marker hidden from one camera ...
        hidden[rng.random(40) < 0.05] = -1  # ... but a few are seen by all three
        frames.append([Detections(cam.project(X[hidden != c]) + rng.normal(0, 0.1, ((hidden != c).sum(), 2)))
                       for c, cam in enumerate(rig)])
    report = check_calibration_fit(rig, frames)
    assert (report.support < 0.1).all() and report.poor_cameras(rig) == []  # a fixed 10 % limit: all named
    assert (report.chance < report.support / 3).all()
    other = Rig([c.with_pose(o.rotation, o.translation) for c, o in zip(rig.cameras, ring_rig(3, radius=5.0).cameras,
                                                                          strict=True)])
    assert sorted(check_calibration_fit(other, frames).poor_cameras(rig)) == ["cam1", "cam2", "cam3"]


def test_cameras_that_see_only_reflections_are_not_judged():
    """Along a walkway, the cameras far from the subject see only a few fixed reflections: too little to
    judge (they used to be named); a swapped pair among the cameras that see the subject still is."""
    rig = ring_rig(8)
    rng = np.random.default_rng(3)
    frames = _frames(rig, n_markers=30, seed=3)
    reflections = [rng.uniform(0, 700, (3, 2)) for _ in rig]
    for dets in frames:
        for c in (5, 6, 7):  # the subject is out of these cameras' view
            dets[c] = Detections(reflections[c] + rng.normal(0, 0.1, (3, 2)))
    assert check_calibration_fit(rig, frames).poor_cameras(rig) == []
    swapped = _swapped(rig, [0, 3, 2, 1, 4, 5, 6, 7])
    assert sorted(check_calibration_fit(swapped, frames).poor_cameras(rig)) == ["cam2", "cam4"]


def _swapped(rig: Rig, order: list[int]) -> Rig:
    """The rig with camera k given the pose of camera ``order[k]`` (names swapped between recordings)."""
    cams = list(rig.cameras)
    return Rig([c.with_pose(cams[o].rotation, cams[o].translation) for c, o in zip(cams, order, strict=True)])


def _feed(monitor: FitMonitor, frames: list[list[Detections]]):
    """Offer ``frames`` one a frame; the monitor's decision (report, names), or its decision at the end."""
    for k, dets in enumerate(frames):
        verdict = monitor.offer(k, dets)
        if verdict is not None:
            return verdict
    return monitor.finish()


def _lonely_then_shared(rig: Rig, lonely: tuple[int, ...], n_frames: int = 60) -> list[list[Detections]]:
    """The first 20 frames: cameras ``lonely`` see markers that no other camera sees (a walkway camera away from
    the subject); then every camera sees the shared markers."""
    rng = np.random.default_rng(7)
    frames = _frames(rig, n_frames=n_frames, n_markers=30, seed=7)
    for dets in frames[:20]:
        for c in lonely:
            X = rng.uniform([-0.8, -0.8, 0.1], [0.8, 0.8, 1.9], size=(30, 3))
            dets[c] = Detections(rig[c].project(X) + rng.normal(0, 0.1, (30, 2)))
    return frames


def test_cameras_that_share_no_marker_in_the_first_frames_are_judged_on_later_ones():
    """One window of frames cannot judge a camera whose markers no second camera sees (no support, no chance
    either): it used to be named. It is named only if later windows (10 frames each, 10 apart) find it poor too."""
    rig = ring_rig()
    frames = _lonely_then_shared(rig, (4, 5))
    assert sorted(check_calibration_fit(rig, frames[:10]).poor_cameras(rig)) == ["cam5", "cam6"]  # the old check
    report, names = _feed(FitMonitor(rig, frames=10, spacing=10), frames)
    assert names == [] and sorted(report.poor_cameras(rig)) == ["cam5", "cam6"]
    swapped = _swapped(rig, [0, 3, 2, 1, 4, 5])
    _, names = _feed(FitMonitor(swapped, frames=10, spacing=10), frames)
    assert names == ["cam2", "cam4"]


def test_a_short_take_is_judged_on_what_it_has():
    rig = ring_rig()
    swapped = _swapped(rig, [0, 3, 2, 1, 4, 5])
    _, names = _feed(FitMonitor(swapped, frames=10, spacing=10), _frames(rig, n_frames=6, n_markers=40))
    assert names == ["cam2", "cam4"]
    assert _feed(FitMonitor(rig, frames=10, spacing=10), []) is None


def _turned(cam, degrees: float):
    """``cam`` turned about its own vertical image axis by ``degrees`` (its centre kept)."""
    R = Rotation.from_euler("y", degrees, degrees=True).as_matrix() @ cam.R
    return cam.with_pose(Rotation.from_matrix(R).as_rotvec(), -R @ cam.center)


def test_a_camera_whose_view_holds_none_of_the_subject_is_not_judged():
    """The whole sprint's window after its gap (cam10): the walkway's far camera sees 1-2 reflections a frame while
    the subject, a few markers, is out of its view for seconds; by blob count it was judged, found poor in every
    window and named. The markers the other cameras agree on fall outside its view, so it is not judged; a camera
    bumped by 3 degrees, whose view still holds them, is named."""
    rig = ring_rig(6)
    rng = np.random.default_rng(11)
    cams = list(rig.cameras)
    cams[5] = _turned(cams[5], 180.0)  # (looks away from the volume)
    away = Rig(cams)
    frames = _frames(away, n_markers=8, seed=11)
    for dets in frames:
        dets[5] = Detections(rng.uniform(0, 700, (6, 2)))  # reflections
    report = check_calibration_fit(away, frames)
    assert report.in_view[5] == 0.0 and report.in_view[:5].min() == 1.0
    assert report.poor_cameras(away) == []
    assert report.blobs[5] >= 0.25 * report.blobs.max()  # (judged by the blob count alone, it was named:)
    assert FitReport(report.support, report.chance, report.blobs, report.tolerance_px).poor_cameras(away) == ["cam6"]
    frames = _frames(rig, n_markers=8, seed=11)
    bumped = Rig(list(rig.cameras[:5]) + [_turned(rig[5], 3.0)])
    assert check_calibration_fit(bumped, frames).poor_cameras(rig) == ["cam6"]
