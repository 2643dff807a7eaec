"""Hand tracker (paper 000): features, classifier, fingertips, tracking, recovery and bad input."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from mocap.errors import MocapError
from mocap.frontends.hand import (
    HandConfig,
    HandTracker,
    find_fingertips,
    hand_contour,
    label_fingers,
    posture_features,
    track_hand,
)
from mocap.frontends.postures import FINGERS, POSTURES, PostureModel, fourier_features
from mocap.frontends.render_hand import hand_clip, posture_samples, random_hand_pose, render_hand
from mocap.frontends.scenes import hand_rig
from mocap.frontends.skin import skin_mask

RIG1 = hand_rig(1)


def _tips_ok(tips: np.ndarray, truth: np.ndarray, tol: float = 5.0) -> np.ndarray:
    """(F,) frame is right: every finger with a truth tip is tracked within ``tol`` px."""
    visible = np.isfinite(truth).all(axis=-1)
    err = np.linalg.norm(tips - truth, axis=-1)
    return np.where(visible, err < tol, True).all(axis=-1)


def test_fourier_features_ignore_translation_rotation_scale_and_start():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    r = 40 + 8 * np.sin(3 * t) + 5 * np.cos(5 * t + 1)
    shape = np.stack([r * np.cos(t), r * np.sin(t)], axis=1)
    a = rng.uniform(0, 2 * np.pi)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    moved = np.roll(shape @ R.T * 1.7 + [120.0, -30.0], 77, axis=0)
    # Compared as magnitude ratios: the log of a tiny harmonic magnifies resampling differences.
    np.testing.assert_allclose(np.exp(fourier_features(moved, 10)), np.exp(fourier_features(shape, 10)), atol=2e-4)
    other = np.stack([(r + 6 * np.sin(2 * t)) * np.cos(t), r * np.sin(t)], axis=1)
    assert np.abs(fourier_features(other, 10) - fourier_features(shape, 10)).max() > 0.1


def test_gaussian_bayes_learns_classes_and_round_trips_through_json(tmp_path):
    rng = np.random.default_rng(1)
    means = rng.normal(0, 3, (3, 5))
    x = np.concatenate([rng.normal(m, 1.0, (200, 5)) for m in means])
    y = [c for c in "PQR" for _ in range(200)]
    model = PostureModel.fit(x, y, harmonics=3)
    np.testing.assert_allclose(model.means, means, atol=0.25)
    test = np.concatenate([rng.normal(m, 1.0, (100, 5)) for m in means])
    truth = np.repeat(list("PQR"), 100)
    pred = np.array([model.classify(v)[0] for v in test])
    assert (pred == truth).mean() > 0.9
    # MAP: posterior proportional to likelihood x prior.
    x = 0.6 * means[0] + 0.4 * means[1]
    prior = np.array([0.01, 0.9, 0.09])
    label, post = model.classify(x, prior)
    joint = np.exp(model.log_likelihoods(x) - model.log_likelihoods(x).max()) * prior
    np.testing.assert_allclose(post, joint / joint.sum(), rtol=1e-9)
    assert label == model.classes[int(np.argmax(joint))]
    path = tmp_path / "m.json"
    model.save(path)
    again = PostureModel.load(path)
    np.testing.assert_array_equal(again.covariances, model.covariances)
    assert again.classes == model.classes


def test_bad_model_files_are_user_errors(tmp_path):
    with pytest.raises(MocapError, match="not found"):
        PostureModel.load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "something-else"}))
    with pytest.raises(MocapError, match="retrain"):
        PostureModel.load(bad)
    bad.write_text("{not json")
    with pytest.raises(MocapError, match="retrain"):
        PostureModel.load(bad)


def test_shipped_model_recognises_held_out_rendered_postures():
    images, labels = posture_samples(hand_rig(), per_class=8, seed=1234)  # training used seed 1
    model = PostureModel.load()
    features, found = posture_features(images, model.harmonics)
    assert found.all()
    pred = np.array([model.classify(f)[0] for f in features])
    labels = np.array(labels)
    assert (pred == labels).mean() >= 0.9
    for c in POSTURES:
        assert (pred[labels == c] == c).mean() >= 0.75, c


@pytest.mark.parametrize("posture", ["B", "D", "F"])
def test_fingertips_and_their_fingers_on_a_rendered_hand(posture):
    rng = np.random.default_rng(5)
    pose = random_hand_pose(posture, rng, np.array(RIG1.metadata["target"]))
    bg = np.full((240, 320, 3), (95.0, 80.0, 60.0))
    image, truth = render_hand(RIG1[0], pose, bg, rng)
    mask = skin_mask(image)
    contour = hand_contour(mask, 300)
    palm_r = float(cv2.distanceTransform(mask, cv2.DIST_L2, 3).max())
    tips = find_fingertips(contour, mask, palm_r, HandConfig())
    m = cv2.moments(mask, binaryImage=True)
    labels = label_fingers(tips, np.array([m["m10"], m["m01"]]) / m["m00"], posture)
    assert labels is not None
    expected = [FINGERS.index(f) for f in POSTURES[posture]]
    assert sorted(labels.tolist()) == expected
    err = np.linalg.norm(tips.centre - truth.tips[labels], axis=1)
    assert (err < 3.0).all(), err
    # Bases lie between the tip and the palm: further from the tip than the arc radius.
    assert (np.linalg.norm(tips.base.mean(axis=1) - tips.centre, axis=1) > 2 * tips.radius).all()


@pytest.fixture(scope="module")
def clip():
    return hand_clip(RIG1, "FBCE", hold=18, transition=4, seed=3, blank=(30, 34))


def test_tracking_follows_fingertips_and_postures(clip):
    tips, palm, posture = track_hand(clip.videos[0], seed=0)
    ok = _tips_ok(tips, clip.tips[0])
    scored = np.isfinite(clip.tips[0]).all(axis=-1).any(axis=-1) | (clip.posture == "A")
    assert ok[scored].mean() >= 0.95
    stable = clip.posture != ""
    stable[30:34] = False  # the hand is out of view
    assert (posture[stable] == clip.posture[stable]).mean() >= 0.95
    palm_err = np.linalg.norm(palm[stable] - clip.palm[0][stable], axis=1)
    assert np.median(palm_err) < 6.0  # px; the palm is ~50 px tall here


def test_recovers_within_ten_frames_after_the_hand_leaves_and_returns(clip):
    tips, _, posture = track_hand(clip.videos[0], seed=1)
    assert (posture[30:34] == "").all() and np.isnan(tips[30:34]).all()  # no hand, no guesses
    ok = _tips_ok(tips, clip.tips[0])
    back = 34 + int(np.argmax(ok[34:] & np.isfinite(tips[34:]).any(axis=(1, 2))))
    assert back - 34 < 10
    assert ok[back:40].all()  # and stays right until the next posture change (frame 40)


def test_hand_sliding_out_of_the_image_is_handled(clip):
    frames = []
    for k, dx in enumerate(range(0, 320, 12)):
        frame = np.empty_like(clip.videos[0, k])
        frame[:] = (95, 80, 60)
        frame[:, : 320 - dx] = clip.videos[0, k, :, dx:]
        frames.append(frame)
    tips, palm, posture = track_hand(frames, seed=0)
    inside = np.isfinite(tips).all(axis=-1)
    assert ((tips[inside] >= 0) & (tips[inside] < [320, 240])).all()
    assert posture[-1] == "" and np.isnan(tips[-1]).all() and np.isnan(palm[-1]).all()


def test_grey_video_is_refused_with_a_clear_message(clip):
    grey = cv2.cvtColor(cv2.cvtColor(clip.videos[0, 0], cv2.COLOR_BGR2GRAY), cv2.COLOR_GRAY2BGR)
    with pytest.raises(MocapError, match="colour"):
        HandTracker().update(grey)
    with pytest.raises(MocapError, match="colour"):
        HandTracker().update(grey[..., 0])
