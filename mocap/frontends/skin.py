"""Skin segmentation shared by the head and hand trackers, and the grey-scale check that guards it."""

from __future__ import annotations

import cv2
import numpy as np

from mocap.errors import MocapError

__all__ = ["skin_mask", "is_grey", "as_bgr"]

# Fixed YCrCb box of skin tones (Chai & Ngan 1999 widened a little for shading); Y excludes deep shadow.
_LOW = (40, 135, 80)
_HIGH = (250, 178, 130)


def as_bgr(frame: np.ndarray) -> np.ndarray:
    """Accept (H, W) grey or (H, W, 3) BGR uint8; return (H, W, 3) uint8 BGR."""
    frame = np.asarray(frame)
    if frame.dtype != np.uint8:
        raise MocapError(f"frames must be 8-bit images, got dtype {frame.dtype}")
    if frame.ndim == 2:
        return cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR)
    if frame.ndim == 3 and frame.shape[2] == 3:
        return frame
    raise MocapError(f"frames must be (H, W) grey or (H, W, 3) colour images, got shape {frame.shape}")


def is_grey(frame: np.ndarray) -> bool:
    """True for a (H, W) frame or a 3-channel frame whose channels are (nearly) equal."""
    frame = np.asarray(frame)
    if frame.ndim == 2:
        return True
    sub = frame[::4, ::4].astype(np.int16)
    return bool(np.abs(sub[..., 0] - sub[..., 1]).max() <= 2 and np.abs(sub[..., 1] - sub[..., 2]).max() <= 2)


def skin_mask(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 BGR -> (H, W) uint8 mask (255 = skin), fixed YCrCb thresholds, opened 3x3."""
    ycrcb = cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb)
    mask = cv2.inRange(ycrcb, _LOW, _HIGH)
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
