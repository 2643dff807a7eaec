"""What each camera sees, without drawing a pixel: projections, occlusion, dropouts, ghosts, truth.

:func:`plan_take` decides everything random up front (seeded), so that :func:`render_frame` only
draws, and :func:`simulate` gives the :class:`~mocap.truth.Truth` alone (e.g. for centroid-level
tests, at a fraction of the cost of rendering).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocap.camera import Rig, rig_to_toml
from mocap.errors import MocapError
from mocap.synth.motion import Motion, as_motion
from mocap.synth.occlusion import occluded
from mocap.synth.render import Sensor
from mocap.synth.settings import SynthSettings
from mocap.truth import Truth

__all__ = ["TakePlan", "plan_take", "simulate", "render_frame", "REFERENCE_DISTANCE_M"]

REFERENCE_DISTANCE_M = 4.0  # distance at which a marker's peak is ``brightness`` above background
_GHOST_MEAN_FRAMES = 15.0  # mean on and off durations of a flickering ghost


@dataclass(eq=False)
class TakePlan:
    """Everything needed to draw a take, decided up front.

    Attributes:
        rig: the cameras.
        sensor: the imaging model.
        truth: the ground truth (uv, visible, sigma_px, settings ...).
        drawn: (F, C, M) bool: the marker's blob is drawn (its centre is in the image, it is in front,
            unoccluded and not dropped); ``truth.visible`` also needs the whole blob inside the image.
        radius_px: (F, C, M) disc radius, px (NaN where not in front).
        amplitude: (F, C, M) disc height, grey levels.
        ghost_uv: (C, G, 2) ghost centres, px.
        ghost_radius: (C, G) ghost radii, px.
        ghost_amplitude: (C, G) ghost heights, grey levels.
        ghost_on: (F, C, G) bool: the ghost shows in that frame.
        seed_sequence: where the per-camera noise streams come from.
        exposure_frames: shutter time as a fraction of the frame interval (markers smear over it).
    """

    rig: Rig
    sensor: Sensor
    truth: Truth
    drawn: np.ndarray
    radius_px: np.ndarray
    amplitude: np.ndarray
    ghost_uv: np.ndarray
    ghost_radius: np.ndarray
    ghost_amplitude: np.ndarray
    ghost_on: np.ndarray
    seed_sequence: np.random.SeedSequence
    exposure_frames: float = 0.0

    def noise_streams(self) -> list[np.random.Generator]:
        """One fresh noise generator per camera (the same every call)."""
        return [np.random.default_rng(s) for s in self.seed_sequence.spawn(len(self.rig))]


def _markov_mask(rng: np.random.Generator, shape: tuple[int, ...], n_frames: int, rate: float,
                 mean_frames: float) -> np.ndarray:
    """(F, *shape) bool two-state Markov chains: True a fraction ``rate`` of the time, in runs of mean ``mean_frames``.

    Starts in the stationary distribution; P(True -> False) = 1 / mean_frames.
    """
    out = np.zeros((n_frames,) + shape, dtype=bool)
    if rate <= 0 or n_frames == 0:
        return out
    p_end = 1.0 / mean_frames
    p_start = min(1.0, rate * p_end / (1.0 - rate))
    state = rng.random(shape) < rate
    for f in range(n_frames):
        out[f] = state
        u = rng.random(shape)
        state = np.where(state, u >= p_end, u < p_start)
    return out


def plan_take(rig: Rig, motion: Motion | tuple[list[str], float, np.ndarray], settings: SynthSettings
              ) -> TakePlan:
    """Project the motion into every camera and decide occlusion, dropouts and ghosts (seeded).

    Args:
        rig: the cameras.
        motion: the marker motion (z up, m) and its body capsules, or ``(labels, fps, positions)``.
        settings: rendering settings.

    Returns:
        The plan; ``plan.truth.settings`` holds every setting, the motion's facts, the ghost
        positions and ``calibration_toml`` (the exact calibration text).
    """
    motion = as_motion(motion)
    F, M = motion.positions.shape[:2]
    C = len(rig)
    seeds = np.random.SeedSequence(settings.seed).spawn(4)  # (the first three as before the gaps' fourth)
    dropout_rng, ghost_rng, hidden_rng = (np.random.default_rng(s) for s in (*seeds[:2], seeds[3]))
    sensor = Sensor(settings.background, settings.noise, settings.blur_px)
    marker_r = settings.marker_mm / 2000.0
    pts = motion.positions.reshape(-1, 3)
    valid = np.isfinite(motion.positions).all(axis=2)
    body = motion.body() if settings.occlusion else None

    uv = np.full((F, C, M, 2), np.nan)
    radius = np.full((F, C, M), np.nan)
    amplitude = np.full((F, C, M), np.nan)
    drawable = np.zeros((F, C, M), dtype=bool)
    inside = np.zeros((F, C, M), dtype=bool)
    for c, cam in enumerate(rig):
        depth = cam.world_to_camera(pts)[:, 2].reshape(F, M)
        with np.errstate(invalid="ignore"):
            front = valid & (depth > 2 * marker_r)
            proj = cam.project(pts).reshape(F, M, 2)
            centre_in = front & cam.in_image(proj.reshape(-1, 2)).reshape(F, M)
            r = np.where(front, 0.5 * (cam.matrix[0, 0] + cam.matrix[1, 1]) * marker_r / depth, np.nan)
            dist = np.linalg.norm(motion.positions - cam.center, axis=2)
        uv[:, c] = np.where(centre_in[..., None], proj, np.nan)
        radius[:, c] = r
        amplitude[:, c] = np.where(front, settings.brightness * (REFERENCE_DISTANCE_M / dist) ** 2, np.nan)
        hidden = occluded(cam.center, motion.positions, body) if body is not None else np.zeros((F, M), bool)
        drawable[:, c] = centre_in & ~hidden
        w, h = cam.size
        with np.errstate(invalid="ignore"):
            edge = r + 1.0
            inside[:, c] = centre_in & ((proj[..., 0] - edge >= -0.5) & (proj[..., 0] + edge <= w - 0.5)
                             & (proj[..., 1] - edge >= -0.5) & (proj[..., 1] + edge <= h - 0.5))
    dropped = _markov_mask(dropout_rng, (C, M), F, settings.dropout_rate, settings.dropout_frames)
    hidden_everywhere = _markov_mask(hidden_rng, (M,), F, settings.hidden_rate, settings.hidden_frames)  # (F, M)
    dropped |= hidden_everywhere[:, None, :]
    drawn = drawable & ~dropped
    visible = drawn & inside

    sigma = np.full((F, C, M), np.nan)
    if visible.any():
        sigma[visible] = sensor.centroid_sigma(uv[visible], radius[visible], amplitude[visible])

    G = settings.ghosts
    sizes = np.array([cam.size for cam in rig], dtype=np.float64)  # (C, 2)
    ghost_uv = 10 + ghost_rng.random((C, G, 2)) * (sizes[:, None, :] - 21)
    ghost_radius = ghost_rng.uniform(0.8, 2.5, (C, G))
    ghost_amplitude = ghost_rng.uniform(80, 250, (C, G))
    blinking = np.arange(G) < round(G * settings.ghost_blink)
    flicker = _markov_mask(ghost_rng, (C, G), F, 0.5, _GHOST_MEAN_FRAMES)
    ghost_on = np.where(blinking[None, None, :], ~flicker, True)

    in_view = np.isfinite(uv[..., 0])
    record = settings.to_dict()
    record.update({
        "motion": motion.info,
        "fps": motion.fps,
        "frames": F,
        "sensor_sigma_px": sensor.sigma,
        "reference_distance_m": REFERENCE_DISTANCE_M,
        "ghosts_uv": ghost_uv.round(3).tolist(),
        "ghosts_blinking": int(blinking.sum()),
        "occlusion_capsules": body.names if body is not None else [],
        "dropped_fraction": float(dropped.mean()) if dropped.size else 0.0,
        "hidden_fraction": float(hidden_everywhere.mean()) if hidden_everywhere.size else 0.0,
        "occluded_fraction": float((in_view & ~drawable).sum() / max(1, in_view.sum())),
        "rig": rig.metadata,
        "calibration_toml": rig_to_toml(rig),
    })
    truth = Truth(list(motion.labels), motion.fps, motion.positions.copy(), rig.names, uv, visible, sigma, record)
    exposure = settings.exposure_ms * 1e-3 * motion.fps
    if exposure >= 1.0:
        raise MocapError(f"--exposure {settings.exposure_ms:g} ms is not shorter than a frame at {motion.fps:g} Hz")
    return TakePlan(rig, sensor, truth, drawn, radius, amplitude, ghost_uv, ghost_radius, ghost_amplitude,
                    ghost_on, seeds[2], exposure)


def simulate(rig: Rig, motion: Motion | tuple[list[str], float, np.ndarray], settings: SynthSettings | None = None
             ) -> Truth:
    """The ground truth of a take (uv, visible, sigma_px) without rendering any image."""
    return plan_take(rig, motion, settings or SynthSettings()).truth


def render_frame(plan: TakePlan, frame: int, camera: int, rng: np.random.Generator) -> np.ndarray:
    """(H, W) uint8 image of one camera at one frame: background noise, markers and ghosts."""
    cam = plan.rig[camera]
    w, h = cam.size
    image = plan.sensor.background_frame((h, w), rng)
    sel = plan.drawn[frame, camera]
    on = plan.ghost_on[frame, camera]
    if plan.exposure_frames > 0 and sel.any():
        uv, radius, amplitude = _smeared(plan, frame, camera, sel)
    else:
        uv, radius, amplitude = (a[frame, camera, sel] for a in (plan.truth.uv, plan.radius_px, plan.amplitude))
    uv = np.concatenate([uv, plan.ghost_uv[camera, on]])
    radius = np.concatenate([radius, plan.ghost_radius[camera, on]])
    amplitude = np.concatenate([amplitude, plan.ghost_amplitude[camera, on]])
    plan.sensor.draw(image, uv, radius, amplitude, rng)
    return image


def _smeared(plan: TakePlan, frame: int, camera: int, sel: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The markers ``sel`` (M,) of one camera-frame as sub-discs spread over the exposure: (S*n, 2) centres,
    px, (S*n,) radii and heights (each 1/S of the marker's), S enough for sub-discs <= 0.25 px apart.

    The image velocity is the central difference of the projected centres (one-sided at the ends of the
    take or of a visible stretch); the smear is centred on the frame's position."""
    centres = plan.truth.uv[:, camera]  # (F, M, 2), a view
    here = centres[frame, sel]
    before = centres[frame - 1, sel] if frame > 0 else here
    after = centres[frame + 1, sel] if frame + 1 < len(centres) else here
    before = np.where(np.isfinite(before), before, here)
    after = np.where(np.isfinite(after), after, here)
    span = 0.5 * (after - before) * plan.exposure_frames  # (n, 2) smear over the exposure, px
    steps = int(min(64, max(1, np.ceil(np.nanmax(np.linalg.norm(span, axis=1), initial=0.0) / 0.25) + 1)))
    offsets = np.linspace(-0.5, 0.5, steps) if steps > 1 else np.zeros(1)
    uv = (here[None] + offsets[:, None, None] * span[None]).reshape(-1, 2)
    radius = np.tile(plan.radius_px[frame, camera, sel], steps)
    amplitude = np.tile(plan.amplitude[frame, camera, sel] / steps, steps)
    return uv, radius, amplitude
