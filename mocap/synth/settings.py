"""Every knob of a synthetic take, with realistic defaults, in one record."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from mocap.errors import MocapError

__all__ = ["SynthSettings", "FORMATS"]

FORMATS = ("mkv", "png")


@dataclass(frozen=True)
class SynthSettings:
    """How a take is rendered (all image levels in 8-bit grey levels).

    Attributes:
        marker_mm: marker (ball) diameter, mm.
        background: background grey level.
        noise: standard deviation of the additive sensor noise, grey levels (before 8-bit rounding).
        brightness: peak level above background of a marker 4 m from the camera (the returned light
            falls off as 1/distance^2); discs saturate at 255.
        blur_px: standard deviation of the Gaussian optical blur (PSF), pixels.
        exposure_ms: shutter (strobe) time, ms: a moving marker smears along its image motion over it
            (0: instantaneous). The truth stays the mid-exposure position, the centre of the smear.
        ghosts: fixed bright reflections per camera (not markers; not in the truth).
        ghost_blink: fraction of the ghosts that flicker on and off.
        dropout_rate: long-run fraction of (camera, marker, frame) samples dropped at random.
        dropout_frames: mean length of one dropout, frames (dropouts are temporally correlated).
        hidden_rate: long-run fraction of (marker, frame) samples hidden from every camera at once: gaps in every
            view, as where a marker is behind the body or a limb for a while (0: none beyond the capsules').
        hidden_frames: mean length of one such gap, frames (real recordings: a median of a few frames, a long tail).
        occlusion: hide markers behind the body (capsule model).
        seed: seed of every random choice (rig jitter, noise, ghosts, dropouts, body).
        format: "mkv" (lossless FFV1 video per camera) or "png" (a folder of frames per camera).
    """

    marker_mm: float = 14.0
    background: float = 12.0
    noise: float = 2.0
    brightness: float = 300.0
    blur_px: float = 0.5
    exposure_ms: float = 0.0
    ghosts: int = 3
    ghost_blink: float = 0.5
    dropout_rate: float = 0.01
    dropout_frames: float = 6.0
    hidden_rate: float = 0.0
    hidden_frames: float = 20.0
    occlusion: bool = True
    seed: int = 0
    format: str = "mkv"

    def __post_init__(self) -> None:
        checks = (
            ("marker_mm", self.marker_mm > 0, "a positive diameter in mm"),
            ("background", 0 <= self.background < 255, "a grey level in [0, 255)"),
            ("noise", self.noise >= 0, ">= 0 grey levels"),
            ("brightness", self.brightness > 0, "> 0 grey levels"),
            ("blur_px", 0.3 <= self.blur_px <= 5, "in [0.3, 5] px (below 0.3 px the discs alias)"),
            ("exposure_ms", 0 <= self.exposure_ms <= 100, "in [0, 100] ms"),
            ("ghosts", self.ghosts >= 0, ">= 0"),
            ("ghost_blink", 0 <= self.ghost_blink <= 1, "a fraction in [0, 1]"),
            ("dropout_rate", 0 <= self.dropout_rate < 1, "a fraction in [0, 1)"),
            ("dropout_frames", self.dropout_frames >= 1, ">= 1 frame"),
            ("hidden_rate", 0 <= self.hidden_rate < 1, "a fraction in [0, 1)"),
            ("hidden_frames", self.hidden_frames >= 1, ">= 1 frame"),
            ("seed", self.seed >= 0, ">= 0"),
        )
        for name, ok, what in checks:
            if not ok:
                flag = "--" + name.removesuffix("_px").removesuffix("_ms").replace("_", "-")
                raise MocapError(f"synth setting {name} ({flag}) = {getattr(self, name)!r} must be {what}")
        if self.format not in FORMATS:
            raise MocapError(f"synth setting format (--format) = {self.format!r} must be one of {FORMATS}")

    def clean(self) -> SynthSettings:
        """The same settings with every artefact off: no noise, ghosts, dropouts or gaps (8-bit rounding stays)."""
        return dataclasses.replace(self, noise=0.0, ghosts=0, dropout_rate=0.0, hidden_rate=0.0)

    def replace(self, **changes: Any) -> SynthSettings:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)
