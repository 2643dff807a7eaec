"""What the rendered front-end test scenes share: a frontal arc rig, image noise, writing a colour take.

The renderers live in :mod:`~mocap.frontends.render_head` and :mod:`~mocap.frontends.render_hand`.
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from mocap.atomic import atomic_output
from mocap.camera import Camera, Rig, save_rig
from mocap.errors import MocapError

__all__ = ["arc_rig", "head_rig", "hand_rig", "add_noise", "write_colour_take"]


def arc_rig(
    n: int = 6,
    radius: float = 1.5,
    target: tuple[float, float, float] = (0.0, 0.0, 1.6),
    spread_deg: float = 100.0,
    size: tuple[int, int] = (128, 96),
    f: float = 180.0,
    elevation_deg: float = 8.0,
    distortions: tuple[float, ...] = (-0.04, 0.01, 0.0, 0.0, 0.0),
) -> Rig:
    """``n`` cameras on a horizontal arc in front of a subject facing -y, all looking at ``target``.

    Camera ``i`` sits at azimuth ``-spread/2 + i * spread / (n - 1)`` around the -y axis, ``radius`` m from
    the target, raised by ``elevation_deg``. World frame z up, metres.
    """
    target_v = np.asarray(target, dtype=np.float64)
    azimuths = np.radians(np.linspace(-spread_deg / 2, spread_deg / 2, n)) if n > 1 else np.zeros(1)
    elev = np.radians(elevation_deg)
    cams = []
    for i, az in enumerate(azimuths):
        offset = radius * np.array([np.sin(az) * np.cos(elev), -np.cos(az) * np.cos(elev), np.sin(elev)])
        c = target_v + offset
        z = -offset / radius
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        K = np.array([[f, 0.0, size[0] / 2 - 0.5], [0.0, f, size[1] / 2 - 0.5], [0.0, 0.0, 1.0]])
        cams.append(Camera(f"cam{i + 1}", size, K, np.array(distortions), cv2.Rodrigues(R)[0].ravel(), -R @ c))
    return Rig(cams, {"made_by": "mocap.frontends.scenes.arc_rig", "target": target_v.tolist()})


def head_rig(n: int = 6) -> Rig:
    """The head scenes' rig: 128x96 cameras 1.5 m from a head at 1.6 m, spread over 100 degrees."""
    return arc_rig(n)


def hand_rig(n: int = 6) -> Rig:
    """The hand scenes' rig: 320x240 cameras 0.55 m from a hand at 1.2 m, spread over 50 degrees (roughly frontal)."""
    return arc_rig(n, radius=0.55, target=(0.0, 0.0, 1.2), spread_deg=50.0, size=(320, 240), f=300.0)


def add_noise(image: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float BGR in 0..255 plus Gaussian sensor noise -> (H, W, 3) uint8."""
    noisy = image + rng.normal(0.0, sigma, image.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def write_colour_take(folder: str | os.PathLike, rig: Rig, videos: np.ndarray, fps: float) -> Path:
    """Write a colour take: ``calibration.toml``, ``take.toml`` and one lossless FFV1 ``<name>.mkv`` per camera.

    Args:
        folder: the take folder (created if missing).
        rig: the calibration; camera ``c`` records ``videos[c]``.
        videos: (C, F, H, W, 3) uint8 BGR frames.
        fps: frame rate, Hz.

    Returns:
        The take folder.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    save_rig(rig, folder / "calibration.toml")
    (folder / "take.toml").write_text(f"fps = {float(fps)!r}\n", encoding="utf-8")
    for cam, frames in zip(rig.cameras, videos, strict=True):
        h, w = frames.shape[1:3]
        with atomic_output(folder / f"{cam.name}.mkv") as tmp:
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"FFV1"), fps, (w, h))
            if not writer.isOpened():
                raise MocapError(f"{tmp}: OpenCV cannot write FFV1 video here; install an FFmpeg-enabled OpenCV")
            for frame in frames:
                writer.write(frame)
            writer.release()
    return folder
