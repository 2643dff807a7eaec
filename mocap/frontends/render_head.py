"""Rendered head videos with ground truth for the head tracker (paper 003's test conditions).

A head is an ellipse (skin face, dark hair) on a skin neck and a shirt, in front of an office wall with
strongly striped blinds, a bookshelf and a wall clock. It can turn away (yaw: hair replaces the face), tilt
(rotated ellipse), be swept over by a raised hand (skin palm and fingers, dark sleeve), and the light can
change (a global gain). Frames are rendered at 2x and area-averaged (anti-aliased), then get
Gaussian sensor noise. Colours are BGR, as OpenCV reads video.

Two scenes: :func:`head_clip`, one 128x96 camera with labelled segments (easy, turn, occluder, tilt,
stripes), and :func:`head_take`, a head moving in 3D seen by every camera of a rig.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.camera import Rig
from mocap.frontends.scenes import add_noise

__all__ = ["HeadPose", "HeadClip", "HeadTake", "render_head", "head_clip", "head_take", "HEAD_SEGMENTS"]

SKIN = np.array([118.0, 150.0, 212.0])
NECK = np.array([100.0, 130.0, 190.0])
HAIR = np.array([28.0, 34.0, 46.0])
SHIRT = np.array([150.0, 85.0, 45.0])
WALL = np.array([168.0, 176.0, 172.0])
HAND = np.array([112.0, 146.0, 206.0])  # a hand in front of the face: skin-coloured, its own strong edges
SLEEVE = np.array([30.0, 36.0, 48.0])  # dark sweater
STRIPE_DARK = np.array([40.0, 50.0, 60.0])
STRIPE_LIGHT = np.array([215.0, 220.0, 215.0])  # light-wood blinds: close to skin
SHELF_BACK = np.array([40.0, 52.0, 66.0])
SHELF_WOOD = np.array([60.0, 95.0, 135.0])
BOOKS = np.array([[40.0, 40.0, 150.0], [140.0, 90.0, 40.0], [60.0, 130.0, 60.0], [200.0, 205.0, 210.0],
                  [50.0, 60.0, 70.0], [70.0, 160.0, 200.0], [120.0, 60.0, 110.0]])
CLOCK_RIM = np.array([35.0, 35.0, 40.0])
CLOCK_FACE = np.array([235.0, 238.0, 240.0])
HEAD_SEGMENTS = ("easy", "turn", "occluder", "tilt", "stripes")
_SS = 2  # supersampling factor
# head_clip's room and hard conditions (fractions of the image width W / height H unless stated).
_SHELF_FROM = 0.86  # bookshelf from x = 0.86 W to the right edge
_CLOCK = (0.40, 0.12, 0.06)  # wall clock centre (x / W, y / H) and radius / W
_TURN_STEP = 0.1  # turn: sideways step towards the bookshelf
_HAND = 1.0  # occluder: palm half-width / head half-width
_DIM = 0.35  # tilt: the room light dims by up to 35 %
_CLOUD = 0.3  # stripes: the daylight through the window drops by up to 30 % (first 30 % of the segment)


@dataclass
class HeadPose:
    """Image-plane head parameters for one frame (pixels, radians).

    Attributes:
        centre: (2,) head-ellipse centre, px.
        axes: (2,) half-width and half-height of the head ellipse, px.
        tilt: in-plane rotation, rad (positive: clockwise on screen).
        yaw: 0 facing the camera, pi facing away, rad.
        neck_x: x of the neck and body, px; None: under the head centre.
    """

    centre: np.ndarray
    axes: np.ndarray
    tilt: float = 0.0
    yaw: float = 0.0
    neck_x: float | None = None


def _background(size: tuple[int, int], stripes_until: float, rng: np.random.Generator,
                shelf_from: float | None = None, clock: tuple[float, float, float] | None = None) -> np.ndarray:
    """(H*ss, W*ss, 3) float office wall: soft shading, a striped panel (blinds) left of ``stripes_until`` px,
    optionally a bookshelf right of ``shelf_from`` px and a round wall clock ``(cx, cy, radius)`` px."""
    w, h = size[0] * _SS, size[1] * _SS
    yy, xx = np.mgrid[0:h, 0:w] / _SS
    phase = rng.uniform(0, 2 * np.pi, 2)
    shade = 1.0 + 0.06 * np.sin(xx / 23.0 + phase[0]) * np.cos(yy / 17.0 + phase[1])
    img = WALL * shade[..., None]
    stripe = (np.floor(xx / 3.0) % 2 == 0)[..., None]
    panel = (xx < stripes_until)[..., None]
    img = np.where(panel, np.where(stripe, STRIPE_DARK, STRIPE_LIGHT), img)
    if shelf_from is not None:
        _draw_shelf(img, shelf_from, size, rng)
    if clock is not None:
        r = np.hypot(xx - clock[0], yy - clock[1]) / clock[2]
        img[r <= 1.0] = CLOCK_RIM
        img[r <= 0.85] = CLOCK_FACE
        for angle, length in ((rng.uniform(0, 2 * np.pi), 0.7), (rng.uniform(0, 2 * np.pi), 0.5)):
            along = (xx - clock[0]) * np.sin(angle) - (yy - clock[1]) * np.cos(angle)
            across = (xx - clock[0]) * np.cos(angle) + (yy - clock[1]) * np.sin(angle)
            img[(along >= 0) & (along <= length * clock[2]) & (np.abs(across) <= 0.6)] = CLOCK_RIM
    return img


def _draw_shelf(img: np.ndarray, x0: float, size: tuple[int, int], rng: np.random.Generator) -> None:
    """Paint a bookshelf into the supersampled ``img`` from ``x0`` px to the right edge: wooden boards every
    ~30 % of the height, between them books of random width, height and colour."""
    w, h = size
    board = 0.3 * h
    img[:, int(x0 * _SS):] = SHELF_BACK
    for top in np.arange(0.0, h, board):
        x = x0 + 1.0
        while x < w:
            bw = rng.uniform(1.5, 4.5)
            bh = board * rng.uniform(0.55, 0.9)
            colour = BOOKS[rng.integers(len(BOOKS))] * rng.uniform(0.8, 1.15)
            y1 = int((top + board - 2.0) * _SS)
            img[max(int(y1 - bh * _SS), 0):y1, int(x * _SS):int((x + bw) * _SS)] = colour
            x += bw + rng.uniform(0.0, 0.8)
        img[int((top + board - 2.0) * _SS):int((top + board) * _SS), int(x0 * _SS):] = SHELF_WOOD


def _hand_mask(xx: np.ndarray, yy: np.ndarray, hand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks of a raised open hand ``(cx, cy, s)`` (palm centre px, palm half-width px): skin (palm, four
    fingers, thumb) and sleeve (the forearm, down to the bottom of the image)."""
    cx, cy, s = hand
    dx, dy = (xx - cx) / s, (yy - cy) / s
    skin = (dx / 1.0) ** 2 + (dy / 1.15) ** 2 <= 1.0
    for base_x, angle, length in ((-0.7, -0.25, 1.5), (-0.25, -0.08, 1.8), (0.2, 0.06, 1.9), (0.62, 0.22, 1.6),
                                  (1.0, 0.9, 1.2)):  # four fingers and the thumb (image right)
        ux, uy = np.sin(angle), -np.cos(angle)
        px, py = dx - base_x, dy + (0.5 if abs(base_x) < 1 else -0.1)
        along = np.clip(px * ux + py * uy, 0.0, length)
        skin |= (px - along * ux) ** 2 + (py - along * uy) ** 2 <= 0.2**2
    sleeve = (dy > 0.9) & (np.abs(dx - 0.25 * (dy - 0.9)) <= 0.95)
    return skin, sleeve & ~skin


def render_head(background: np.ndarray, pose: HeadPose, hand: np.ndarray | None, rng: np.random.Generator,
                noise: float = 3.0, gain: float = 1.0) -> np.ndarray:
    """Render one frame.

    Args:
        background: (H*2, W*2, 3) float supersampled background (from the scene).
        pose: the head.
        hand: (3,) a raised hand in front of the head ``(cx, cy, palm half-width)`` px, or None.
        rng: noise generator.
        noise: sensor-noise standard deviation, grey levels.
        gain: exposure: every colour is multiplied by it (lighting or camera exposure change).

    Returns:
        (H, W, 3) uint8 BGR frame.
    """
    img = background.copy()
    hs, ws = img.shape[:2]
    yy, xx = (np.mgrid[0:hs, 0:ws] + 0.5) / _SS - 0.5
    cx, cy = pose.centre
    a, b = pose.axes
    dx, dy = xx - cx, yy - cy
    # Shirt and neck (they do not tilt with the head).
    bx = xx - (cx if pose.neck_x is None else pose.neck_x)
    shirt = (dy > 1.45 * b) & (np.abs(bx) < 1.3 * a + 0.8 * (dy - 1.45 * b))
    img[shirt] = SHIRT
    neck = (dy > 0.3 * b) & (dy <= 1.6 * b) & (np.abs(bx) < 0.5 * a)
    img[neck] = NECK
    # Head, in its own rotated frame (u right, v down, unit = half-axes).
    c, s = np.cos(pose.tilt), np.sin(pose.tilt)
    u = (dx * c + dy * s) / a
    v = (-dx * s + dy * c) / b
    r2 = u * u + v * v
    head = r2 <= 1.0
    facing = max(np.cos(pose.yaw), 0.0)
    u0 = 0.85 * np.sin(pose.yaw)
    face_w = 0.8 * facing + 1e-3
    face = head & (((u - u0) / face_w) ** 2 + ((v - 0.18) / 0.8) ** 2 <= 1.0)
    light = 0.8 + 0.2 * np.sqrt(np.clip(1.0 - r2, 0.0, 1.0))
    img[head] = HAIR * (0.9 + 0.2 * light[head, None])
    img[face] = SKIN * light[face, None]
    if facing > 0.3:  # eyes
        for side in (-1.0, 1.0):
            eye = ((u - u0 - side * 0.35 * face_w) / 0.12) ** 2 + ((v - 0.05) / 0.09) ** 2 <= 1.0
            img[face & eye] = HAIR
    if hand is not None:
        skin, sleeve = _hand_mask(xx, yy, hand)
        img[sleeve] = SLEEVE
        img[skin] = HAND
    small = cv2.resize(img * gain, (ws // _SS, hs // _SS), interpolation=cv2.INTER_AREA)
    return add_noise(small, noise, rng)


@dataclass
class HeadClip:
    """A single-camera head video with ground truth.

    Attributes:
        frames: (F, H, W, 3) uint8 BGR.
        centre: (F, 2) true head centre, px.
        axes: (F, 2) true half-axes, px.
        segments: name -> (start, stop) frame range, in :data:`HEAD_SEGMENTS` order.
        fps: frame rate, Hz.
    """

    frames: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    segments: dict[str, tuple[int, int]]
    fps: float = 30.0

    @property
    def head_size(self) -> np.ndarray:
        """(F,) head size, px: the geometric mean of the full ellipse width and height."""
        return 2.0 * np.sqrt(self.axes[:, 0] * self.axes[:, 1])


def _smooth(t: np.ndarray) -> np.ndarray:
    """Smoothstep 0..1 of t in 0..1 (zero slope at both ends)."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


def head_clip(segment_frames: int = 60, seed: int = 0, size: tuple[int, int] = (128, 96)) -> HeadClip:
    """Paper 003's test video, scripted: 128x96, 30 fps, five labelled segments of ``segment_frames`` each.

    The room: a wall with window blinds (vertical stripes) on the left, a bookshelf on the right and a round
    wall clock.

    * ``easy``: the head sways in front of the plain wall.
    * ``turn``: the head turns away (only hair visible for the middle fifth) and back, while stepping
      sideways in front of the bookshelf.
    * ``occluder``: a raised hand sweeps across the face and out of the picture.
    * ``tilt``: the head shakes, tilting +-40 degrees about the neck, below the wall clock, while the room
      light dims by up to 35 % and comes back.
    * ``stripes``: the head moves in front of the blinds and back; on the way the daylight drops by up to
      30 % for a moment (a cloud).

    Each segment is meant to be tracked on its own, starting from the true box at its first frame.
    """
    rng = np.random.default_rng(seed)
    n = segment_frames
    w, h = size
    stripes_until = 0.36 * w
    home = np.array([0.66 * w, 0.40 * h])
    axes = np.array([0.085 * w, 0.145 * h])
    shelf_from = _SHELF_FROM * w
    clock = (_CLOCK[0] * w, _CLOCK[1] * h, _CLOCK[2] * w)
    background = _background(size, stripes_until, rng, shelf_from, clock)
    poses: list[HeadPose] = []
    hands: list[np.ndarray | None] = []
    gains: list[float] = []
    t = np.arange(n) / n
    for name in HEAD_SEGMENTS:
        sway = np.stack([6 * np.sin(2 * np.pi * t + 0.5), 2.5 * np.sin(4 * np.pi * t)], axis=1)
        for k in range(n):
            centre = home + sway[k]
            tilt = yaw = 0.0
            hand = None
            neck_x = None
            gain = 1.0
            if name == "turn":
                yaw = np.pi * (_smooth(t[k] / 0.4) - _smooth((t[k] - 0.6) / 0.4))
                centre = centre + np.array([_TURN_STEP * w * np.sin(np.pi * t[k]), 0.0])
            elif name == "occluder":
                p = (t[k] - 0.2) / 0.6
                if 0.0 <= p <= 1.0:
                    x = centre[0] - 3.5 * axes[0] + p * 9.0 * axes[0]
                    hand = np.array([x, centre[1] + 0.3 * axes[1], _HAND * axes[0]])
            elif name == "tilt":  # about the neck, 1.3 half-heights below the head centre
                tilt = np.radians(40.0) * np.sin(2 * np.pi * 2 * t[k])
                neck_x = centre[0]
                centre = centre + 1.3 * axes[1] * np.array([np.sin(tilt), 1.0 - np.cos(tilt)])
                gain = 1.0 - _DIM * np.sin(np.pi * t[k]) ** 2
            elif name == "stripes":
                across = np.sin(np.pi * t[k])
                centre = centre + np.array([-(home[0] - 0.5 * stripes_until) * across, 0.0])
                gain = 1.0 - _CLOUD * np.sin(np.pi * np.clip(t[k] / 0.3, 0.0, 1.0)) ** 2
            poses.append(HeadPose(centre, axes.copy(), tilt, yaw, neck_x))
            hands.append(hand)
            gains.append(gain)
    frames = np.stack([render_head(background, p, hd, rng, gain=g)
                       for p, hd, g in zip(poses, hands, gains, strict=True)])
    segments = {name: (i * n, (i + 1) * n) for i, name in enumerate(HEAD_SEGMENTS)}
    return HeadClip(frames, np.stack([p.centre for p in poses]), np.stack([p.axes for p in poses]), segments)


@dataclass
class HeadTake:
    """A head moving in 3D, rendered by every camera of a rig.

    Attributes:
        videos: (C, F, H, W, 3) uint8 BGR.
        position: (F, 3) true head centre, metres (world, z up).
        centre: (C, F, 2) true head centre in each image, distorted px.
        axes: (C, F, 2) true half-axes in each image, px.
        fps: frame rate, Hz.
    """

    videos: np.ndarray
    position: np.ndarray
    centre: np.ndarray
    axes: np.ndarray
    fps: float = 30.0


def head_take(rig: Rig, frames: int = 90, seed: int = 0, head_radii: tuple[float, float] = (0.08, 0.11),
              fps: float = 30.0, stripes: float = 0.25) -> HeadTake:
    """A head (facing -y, towards an :func:`~mocap.frontends.scenes.arc_rig`) walking a slow loop in 3D.

    Each camera renders the head as an ellipse at the projection of the head centre, half-axes scaled by
    focal length over depth, yaw = the angle between the face direction and the camera, and the
    head turning +-40 degrees on the way. A striped panel covers the left ``stripes`` fraction of each image.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / fps
    position = np.stack([0.12 * np.sin(2 * np.pi * t / 3.0), 0.08 * np.sin(2 * np.pi * t / 2.0),
                         1.6 + 0.03 * np.sin(2 * np.pi * t / 1.5)], axis=1)
    heading = np.radians(40.0) * np.sin(2 * np.pi * t / 3.0)  # face direction, rad from -y about z
    face_dir = np.stack([np.sin(heading), -np.cos(heading), np.zeros(frames)], axis=1)
    videos, centres, axes_all = [], [], []
    for cam in rig.cameras:
        background = _background(cam.size, stripes * cam.size[0], rng)
        uv = cam.project(position)
        depth = cam.world_to_camera(position)[:, 2]
        f = cam.matrix[0, 0]
        axes = np.stack([head_radii[0] * f / depth, head_radii[1] * f / depth], axis=1)
        to_cam = cam.center - position
        to_cam /= np.linalg.norm(to_cam, axis=1, keepdims=True)
        yaw = np.arccos(np.clip((to_cam * face_dir).sum(axis=1), -1.0, 1.0))
        side = np.sign(np.cross(face_dir, to_cam)[:, 2])
        frames_c = [render_head(background, HeadPose(uv[k], axes[k], 0.0, float(side[k] * yaw[k])), None, rng)
                    for k in range(frames)]
        videos.append(np.stack(frames_c))
        centres.append(uv)
        axes_all.append(axes)
    return HeadTake(np.stack(videos), position, np.stack(centres), np.stack(axes_all), fps)
