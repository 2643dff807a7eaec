"""Rendered hands with ground truth for the hand tracker (paper 000's six postures).

A right hand is a palm (rounded rectangle), a wrist stub and five fingers made of capsules (line segments
with a radius), posed in 3D in a hand frame: ``u`` across the palm towards the thumb, ``v`` along the
fingers, ``n`` out of the palm. A finger is extended (straight, spread about ``n``) or curled (bent
towards the palm side over the palm). Each camera of a rig draws the projected capsules anti-aliased
(every capsule is skin, so drawing order does not matter for the silhouette; curled fingers are drawn a
little darker so a fist has inner edges) over a non-skin background, then adds sensor noise.

The fingertip point is the centre of the last capsule's end sphere - the centre of the arc the tracker fits.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from mocap.camera import Camera, Rig
from mocap.frontends.postures import FINGERS, POSTURES
from mocap.frontends.scenes import add_noise

__all__ = ["HandPose", "HandFrameTruth", "HandClip", "render_hand", "hand_clip",
           "random_hand_pose", "posture_samples"]

SKIN = np.array([112.0, 146.0, 205.0])
_BASE_UV = np.array([[0.036, -0.026], [0.027, 0.045], [0.009, 0.047], [-0.009, 0.045], [-0.027, 0.040]])
_LENGTH = np.array([0.060, 0.075, 0.083, 0.077, 0.062])
_RADIUS = np.array([0.0095, 0.0085, 0.0088, 0.0083, 0.0074])
_SPREAD = np.radians([48.0, 9.0, 0.0, -9.0, -18.0])  # about n, from v towards +u
_PHALANX = np.array([0.45, 0.30, 0.25])
_CURLED = np.radians([80.0, 100.0, 70.0])
_THUMB_CURLED = np.radians([25.0, 30.0, 20.0])
_PALM = (0.042, 0.047)
_WRIST = (np.array([0.0, -0.047]), np.array([0.0, -0.11]), 0.027)


@dataclass
class HandPose:
    """A hand in the world.

    Attributes:
        position: (3,) palm centre, metres.
        rotation: (3, 3) hand frame -> world; columns are u, v, n.
        extension: (5,) per finger, 1 extended .. 0 curled.
        spread: factor on the fingers' spread angles.
        bend: (5,) extra flexion of an extended finger, rad.
        scale: hand size factor.
    """

    position: np.ndarray
    rotation: np.ndarray
    extension: np.ndarray
    spread: float = 1.0
    bend: np.ndarray = field(default_factory=lambda: np.zeros(5))
    scale: float = 1.0


def _finger_chain(i: int, pose: HandPose) -> np.ndarray:
    """(4, 3) joint points of finger ``i`` in the hand frame, metres (base .. tip centre)."""
    s = pose.scale
    base = np.array([*_BASE_UV[i] * s, 0.0])
    ang = _SPREAD[i] * pose.spread
    along = np.array([np.sin(ang), np.cos(ang), 0.0])  # direction in the palm plane
    flex = (1.0 - pose.extension[i]) * _CURLED + pose.bend[i] * _PHALANX / _PHALANX.sum() * 3
    if i == 0:  # the thumb folds across the palm instead of curling into it
        flex = (1.0 - pose.extension[0]) * _THUMB_CURLED + pose.bend[0] * _PHALANX / _PHALANX.sum() * 3
        across = np.array([-np.cos(ang), np.sin(ang), 0.0])
        fold = (1.0 - pose.extension[0]) * 1.9
        along = np.cos(fold) * along + np.sin(fold) * across
    points = [base]
    total = 0.0
    for length, theta in zip(_LENGTH[i] * s * _PHALANX, flex, strict=True):
        total += theta
        step = np.cos(total) * along + np.sin(total) * np.array([0.0, 0.0, 1.0])
        points.append(points[-1] + length * step)
    return np.array(points)


@dataclass
class HandFrameTruth:
    """Ground truth of one rendered view.

    Attributes:
        tips: (5, 2) fingertip centres, distorted px; NaN for fingers that are not extended.
        tips_world: (5, 3) fingertip centres, metres; NaN for fingers that are not extended.
        palm: (2,) palm centre, px.
        tip_radius: (5,) fingertip radius, px.
    """

    tips: np.ndarray
    tips_world: np.ndarray
    palm: np.ndarray
    tip_radius: np.ndarray


def _background(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float non-skin background: dark blue-grey cloth with soft blotches."""
    w, h = size
    noise = cv2.resize(rng.normal(0.0, 1.0, (h // 16 + 2, w // 16 + 2)), (w, h), interpolation=cv2.INTER_CUBIC)
    base = np.array([95.0, 80.0, 60.0])
    return base * (1.0 + 0.12 * noise[..., None])


def render_hand(cam: Camera, pose: HandPose, background: np.ndarray, rng: np.random.Generator,
                noise: float = 3.0) -> tuple[np.ndarray, HandFrameTruth]:
    """Render one view of a hand.

    Returns:
        (H, W, 3) uint8 BGR image and the view's ground truth.
    """
    w, h = cam.size
    shift = 4
    one = 1 << shift
    to_world = lambda p: pose.position + p @ pose.rotation.T  # noqa: E731  (N, 3) hand -> world
    depth_f = cam.matrix[0, 0] / cam.world_to_camera(pose.position[None])[0, 2]  # px per metre at the hand
    layers = [np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)]  # 0: skin, 1: shadowed skin

    def capsule(layer: np.ndarray, a: np.ndarray, b: np.ndarray, radius_m: float) -> None:
        uv = cam.project(to_world(np.stack([a, b])))
        if not np.isfinite(uv).all():
            return
        p = [tuple(int(v) for v in np.rint(q * one)) for q in uv]
        r = max(int(round(radius_m * pose.scale * depth_f * one)), one)
        cv2.line(layer, p[0], p[1], 1.0, thickness=max(2 * r // one, 1), lineType=cv2.LINE_AA, shift=shift)
        for q in p:
            cv2.circle(layer, q, r, 1.0, thickness=-1, lineType=cv2.LINE_AA, shift=shift)

    t = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    c, s = np.cos(t), np.sin(t)
    palm = np.stack([_PALM[0] * pose.scale * np.sign(c) * np.abs(c) ** 0.5,
                     _PALM[1] * pose.scale * np.sign(s) * np.abs(s) ** 0.5, np.zeros_like(t)], axis=1)
    palm_uv = cam.project(to_world(palm))
    if np.isfinite(palm_uv).all():
        cv2.fillPoly(layers[0], [np.rint(palm_uv * one).astype(np.int32)], 1.0, cv2.LINE_AA, shift)
    wa, wb, wr = _WRIST
    capsule(layers[0], np.array([*wa * pose.scale, 0.0]), np.array([*wb * pose.scale, 0.0]), wr)
    tips_world = np.full((5, 3), np.nan)
    for i in range(5):
        chain = _finger_chain(i, pose)
        layer = layers[0] if pose.extension[i] >= 0.5 else layers[1]
        for a, b in zip(chain[:-1], chain[1:], strict=True):
            capsule(layer, a, b, _RADIUS[i])
        if pose.extension[i] >= 0.999:
            tips_world[i] = to_world(chain[-1][None])[0]
    skin = np.clip(layers[0], 0.0, 1.0)[..., None]
    shadow = np.clip(layers[1], 0.0, 1.0)[..., None] * (1.0 - skin)
    yy, xx = np.mgrid[0:h, 0:w]
    centre = cam.project(pose.position[None])[0]
    light = 1.0 - 0.15 * np.clip(np.hypot(xx - centre[0], yy - centre[1]) / (0.15 * depth_f), 0.0, 1.0)
    colour = SKIN * light[..., None]
    img = background * (1.0 - skin - shadow) + colour * skin + 0.8 * colour * shadow
    truth = HandFrameTruth(cam.project(tips_world), tips_world, centre, _RADIUS * pose.scale * depth_f)
    return add_noise(img, noise, rng), truth


def _rotation(roll: float, yaw: float, pitch: float) -> np.ndarray:
    """(3, 3) hand -> world: palm facing -y (towards an arc rig), fingers up, then roll/yaw/pitch, rad."""
    base = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # columns u=+x, v=+z, n=-y
    rn = cv2.Rodrigues(np.array([0.0, -roll, 0.0]))[0]  # about the palm normal
    rz = cv2.Rodrigues(np.array([0.0, 0.0, yaw]))[0]
    rx = cv2.Rodrigues(np.array([pitch, 0.0, 0.0]))[0]
    return rz @ rx @ rn @ base


def random_hand_pose(posture: str, rng: np.random.Generator, centre: np.ndarray) -> HandPose:
    """A roughly frontal hand in ``posture`` near ``centre``: random roll (+-30 deg), yaw/pitch (+-12 deg),
    finger spread (x0.85..1.3), bends of the extended fingers (0..12 deg) and size (x0.9..1.1)."""
    ext = np.array([1.0 if f in POSTURES[posture] else 0.0 for f in FINGERS])
    rot = _rotation(*np.radians(rng.uniform([-30, -12, -12], [30, 12, 12])))
    bend = rng.uniform(0.0, np.radians(12.0), 5) * ext
    return HandPose(centre + rng.uniform(-0.03, 0.03, 3), rot, ext, rng.uniform(0.85, 1.3), bend,
                    rng.uniform(0.9, 1.1))


def posture_samples(rig: Rig, per_class: int, seed: int) -> tuple[list[np.ndarray], list[str]]:
    """Labelled single-view hand images for training / testing the posture classifier.

    Each sample: a random posture pose (:func:`random_hand_pose`) seen by a random camera of ``rig``.

    Returns:
        images ((H, W, 3) uint8 BGR) and their posture letters, classes interleaved.
    """
    rng = np.random.default_rng(seed)
    target = _rig_target(rig)
    backgrounds = [_background(c.size, rng) for c in rig.cameras]
    images, labels = [], []
    for _ in range(per_class):
        for posture in POSTURES:
            c = int(rng.integers(len(rig)))
            img, _ = render_hand(rig[c], random_hand_pose(posture, rng, target), backgrounds[c], rng)
            images.append(img)
            labels.append(posture)
    return images, labels


def _rig_target(rig: Rig) -> np.ndarray:
    """(3,) the point the rig's cameras look at: ``metadata["target"]``, else where their optical axes meet."""
    if "target" in rig.metadata:
        return np.asarray(rig.metadata["target"], dtype=np.float64)
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for cam in rig:
        d = cam.R[2]
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ cam.center
    return np.linalg.solve(A, b)


@dataclass
class HandClip:
    """A hand changing posture while moving, seen by every camera of a rig.

    Attributes:
        videos: (C, F, H, W, 3) uint8 BGR.
        tips: (C, F, 5, 2) fingertip centres, distorted px; NaN where the finger is not fully extended.
        tips_world: (F, 5, 3) fingertip centres, metres; NaN where the finger is not fully extended.
        tip_radius: (C, F, 5) fingertip radii, px.
        palm: (C, F, 2) palm centre, distorted px; NaN while the hand is removed.
        posture: (F,) posture letter, "" during a transition.
        fps: frame rate, Hz.
    """

    videos: np.ndarray
    tips: np.ndarray
    tips_world: np.ndarray
    tip_radius: np.ndarray
    palm: np.ndarray
    posture: np.ndarray
    fps: float = 30.0


def hand_clip(rig: Rig, sequence: str = "FBCEDA", hold: int = 30, transition: int = 6, seed: int = 0,
              blank: tuple[int, int] | None = None, fps: float = 30.0) -> HandClip:
    """Render a hand going through the postures in ``sequence`` while it moves and rolls.

    Each posture is held ``hold`` frames; fingers bend or straighten over ``transition`` frames in between.
    ``blank = (start, stop)`` removes the hand from those frames (a forced loss: the hand leaves the view).
    """
    rng = np.random.default_rng(seed)
    target = _rig_target(rig)
    ext_of = {p: np.array([1.0 if f in POSTURES[p] else 0.0 for f in FINGERS]) for p in POSTURES}
    exts, labels = [], []
    for i, p in enumerate(sequence):
        if i:
            prev = ext_of[sequence[i - 1]]
            for k in range(1, transition + 1):
                exts.append(prev + (ext_of[p] - prev) * k / (transition + 1))
                labels.append("")
        exts += [ext_of[p]] * hold
        labels += [p] * hold
    n = len(exts)
    t = np.arange(n) / fps
    backgrounds = [_background(c.size, rng) for c in rig.cameras]
    videos = np.empty((len(rig), n, rig[0].size[1], rig[0].size[0], 3), np.uint8)
    tips = np.full((len(rig), n, 5, 2), np.nan)
    radius = np.full((len(rig), n, 5), np.nan)
    palm = np.full((len(rig), n, 2), np.nan)
    tips_world = np.full((n, 5, 3), np.nan)
    for k in range(n):
        offset = np.array([0.04 * np.sin(2 * np.pi * t[k] / 4.0), 0.02 * np.sin(2 * np.pi * t[k] / 3.0),
                           0.03 * np.sin(2 * np.pi * t[k] / 2.5)])
        rot = _rotation(np.radians(20.0) * np.sin(2 * np.pi * t[k] / 5.0), np.radians(10.0) * np.sin(t[k]), 0.0)
        pose = HandPose(target + offset, rot, exts[k])
        for c, cam in enumerate(rig.cameras):
            if blank is not None and blank[0] <= k < blank[1]:
                videos[c, k] = add_noise(backgrounds[c], 3.0, rng)
                continue
            videos[c, k], truth = render_hand(cam, pose, backgrounds[c], rng)
            tips[c, k], radius[c, k], palm[c, k] = truth.tips, truth.tip_radius, truth.palm
            tips_world[k] = truth.tips_world
    return HandClip(videos, tips, tips_world, radius, palm, np.array(labels), fps)
