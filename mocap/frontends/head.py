"""Particle-filter head tracker with adaptive colour + shape fusion (paper 003).

State per particle: ``(x, y, vx, vy, a)`` - ellipse centre (px), velocity (px/frame) and half-width ``a``
(px); the half-height is ``aspect * a`` with the aspect ratio of the initial box. Dynamics
``x(k) = A x(k-1) + w``: damped constant velocity, Gaussian noise.

* Colour cue: 8x8x8 BGR histogram of the ellipse, each pixel weighted by ``k(r) = 1 - r^2`` (r the
  normalised elliptic radius); Bhattacharyya coefficient ``rho`` against the first-frame template,
  ``d = sqrt(1 - rho)``, ``w_c = exp(-d^2 / 2 sigma_c^2)``.
* Shape cue: for each of ``n_outline`` points on the upright ellipse, the largest Sobel gradient magnitude
  among Canny edge pixels on a short normal segment; the mean over the outline, divided by that of the
  initial box, is ``G``; ``w_g = exp(-(1 - G)^2 / 2 sigma_g^2)``.
* Democratic integration: ``w = w_c^k_c * w_g^k_g`` (log-linear pooling: a particle needs the support of
  both cues, so a cue that is drawn to a distractor the other cue rejects cannot drag the estimate; the
  paper's sum ``k_c w_c + k_g w_g`` averages the two modes instead). Per frame each cue's reliability
  ``q`` is measured at the fused estimate (see :meth:`HeadTracker._adapt`);
  ``k <- k + (dt / tau) (q_normalised - k)``, renormalised, and kept above ``min_weight`` so a cue that
  failed can come back. Then systematic resampling. ``k = (1, 0)`` / ``(0, 1)`` are the single-cue modes.

Both cues are evaluated for all particles at once: kernel and outline sample offsets are precomputed, the
histograms are one ``np.bincount`` over every particle's samples.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import StrEnum

import cv2
import numpy as np

from mocap.errors import MocapError
from mocap.frontends.particles import normalise, predict_linear, systematic_resample, weighted_mean
from mocap.frontends.skin import as_bgr, skin_mask

__all__ = ["CueMode", "HeadConfig", "HeadTracker", "HeadEstimate", "detect_head_box", "track_head"]

_BINS = 8
_NBINS = _BINS**3


class CueMode(StrEnum):
    """Which cues weight the particles."""

    FUSED = "fused"
    COLOUR = "colour"
    SHAPE = "shape"


@dataclass(frozen=True)
class HeadConfig:
    """Head-tracker settings (pixels and frames unless stated).

    Attributes:
        particles: number of particles.
        mode: fused, colour-only or shape-only.
        damping: velocity damping factor per frame (the A matrix).
        noise_pos: position noise std, px.
        noise_vel: velocity noise std, px/frame.
        noise_size: half-width noise std, px.
        sigma_colour: std of the Bhattacharyya distance in the colour likelihood.
        sigma_shape: std of ``1 - G`` in the shape likelihood.
        kernel_grid: samples per axis of the square grid the colour kernel is sampled on.
        n_outline: outline points of the shape cue.
        normal_half_length: half-length of the normal search segment, as a fraction of the half-width.
        canny: Canny hysteresis thresholds on the grey image.
        rate: adaptation rate ``dt / tau`` of the cue weights per frame.
        min_weight: lower bound of each cue weight.
        probe_shift: reliability probes sit this many half-axes from the fused estimate.
    """

    particles: int = 200
    mode: CueMode = CueMode.FUSED
    damping: float = 0.7
    noise_pos: float = 3.0
    noise_vel: float = 1.5
    noise_size: float = 0.25
    sigma_colour: float = 0.2
    sigma_shape: float = 0.2
    kernel_grid: int = 13
    n_outline: int = 24
    normal_half_length: float = 0.3
    canny: tuple[float, float] = (40.0, 100.0)
    rate: float = 0.25
    min_weight: float = 0.05
    probe_shift: float = 0.6


@dataclass
class HeadEstimate:
    """The tracker's output for one frame.

    Attributes:
        centre: (2,) head-ellipse centre, px.
        axes: (2,) half-width, half-height, px.
        cue_weights: (2,) colour and shape weights ``(k_c, k_g)`` used for this frame.
        similarity: Bhattacharyya coefficient of the estimate's histogram with the template, 0..1.
    """

    centre: np.ndarray
    axes: np.ndarray
    cue_weights: np.ndarray
    similarity: float


def detect_head_box(image: np.ndarray) -> tuple[float, float, float, float] | None:
    """A head box ``(x, y, w, h)`` px from the largest skin blob (the face), grown upward for the hair.

    Returns None when the frame holds no skin blob of at least 12 pixels.
    """
    mask = skin_mask(image)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    if count < 2:
        return None
    best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h, area = stats[best]
    if area < 12:
        return None
    h_face = min(h, 1.3 * w)  # the neck below the face is skin too: keep a face-shaped top
    return float(x - 0.1 * w), float(y - 0.35 * h_face), float(1.2 * w), float(1.35 * h_face)


def _unit_kernel(grid: int) -> tuple[np.ndarray, np.ndarray]:
    """Sample offsets in the unit disc, (S, 2), and their kernel weights ``1 - r^2``, (S,)."""
    g = (np.arange(grid) + 0.5) / grid * 2.0 - 1.0
    u, v = np.meshgrid(g, g)
    r2 = u * u + v * v
    keep = r2 < 1.0
    return np.stack([u[keep], v[keep]], axis=1), 1.0 - r2[keep]


class HeadTracker:
    """Track one head through a video, one :meth:`update` per frame.

    Args:
        first_frame: (H, W, 3) uint8 BGR frame the box refers to (grey frames work: the colour histogram then
            degenerates to an intensity histogram).
        box: ``(x, y, w, h)`` head box, px.
        config: settings.
        rng: the random generator (seed it for reproducible runs).
    """

    def __init__(self, first_frame: np.ndarray, box: tuple[float, float, float, float],
                 config: HeadConfig | None = None, rng: np.random.Generator | None = None) -> None:
        self.config = config or HeadConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        x, y, w, h = (float(v) for v in box)
        if not (w > 2 and h > 2):
            raise MocapError(f"head box {box}: width and height must be more than 2 px")
        frame = as_bgr(first_frame)
        self.shape = frame.shape[:2]
        self.aspect = h / w
        cfg = self.config
        self._kernel_uv, self._kernel_w = _unit_kernel(cfg.kernel_grid)
        psi = np.linspace(0.0, 2 * np.pi, cfg.n_outline, endpoint=False)
        self._cos, self._sin = np.cos(psi), np.sin(psi)
        self._t = np.linspace(-1.0, 1.0, 7)
        ring = np.linspace(0.0, 2 * np.pi, 8, endpoint=False)
        self._ring = cfg.probe_shift * np.stack([np.cos(ring), np.sin(ring)], axis=1)
        self.A = np.eye(5)
        self.A[0, 2] = self.A[1, 3] = 1.0
        self.A[2, 2] = self.A[3, 3] = cfg.damping
        self.noise = np.array([cfg.noise_pos, cfg.noise_pos, cfg.noise_vel, cfg.noise_vel, cfg.noise_size])
        init = np.array([x + w / 2, y + h / 2, 0.0, 0.0, w / 2])
        self.particles = init + self.rng.standard_normal((cfg.particles, 5)) * self.noise
        self.particles[0] = init
        bins, edges = self._features(frame)
        self.template = self._histograms(bins, init[None])[0]
        self._g_ref = max(float(self._outline_gradient(edges, init[None])[0]), 1e-6)
        self.cue_weights = {CueMode.FUSED: np.array([0.5, 0.5]), CueMode.COLOUR: np.array([1.0, 0.0]),
                            CueMode.SHAPE: np.array([0.0, 1.0])}[cfg.mode]
        self.estimate = init

    # --------------------------------------------------------------- features
    def _features(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-frame images: (H, W) histogram-bin index, (H, W) float32 gradient magnitude on Canny edges."""
        q = (frame >> 5).astype(np.int32)
        bins = (q[..., 0] * _BINS + q[..., 1]) * _BINS + q[..., 2]
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        edges = cv2.Canny(grey, *self.config.canny, L2gradient=True)
        gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0)
        gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1)
        return bins, np.where(edges > 0, cv2.magnitude(gx, gy), 0.0).astype(np.float32)

    def _sample(self, image: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values of ``image`` at rounded (x, y) (any equal shapes) and a mask of the samples inside it."""
        h, w = self.shape
        xi = np.rint(x).astype(np.intp)
        yi = np.rint(y).astype(np.intp)
        inside = (xi >= 0) & (xi < w) & (yi >= 0) & (yi < h)
        return image[yi.clip(0, h - 1), xi.clip(0, w - 1)], inside

    def _histograms(self, bins: np.ndarray, states: np.ndarray) -> np.ndarray:
        """(N, 5) states -> (N, 512) kernel-weighted, normalised colour histograms."""
        a = states[:, 4:5]
        x = states[:, 0:1] + a * self._kernel_uv[:, 0]
        y = states[:, 1:2] + a * self.aspect * self._kernel_uv[:, 1]
        values, inside = self._sample(bins, x, y)
        n = len(states)
        index = (np.arange(n)[:, None] * _NBINS + values).ravel()
        weights = (inside * self._kernel_w).ravel()
        hist = np.bincount(index, weights=weights, minlength=n * _NBINS).reshape(n, _NBINS)
        return hist / np.maximum(hist.sum(axis=1, keepdims=True), 1e-12)

    def _outline_gradient(self, edges: np.ndarray, states: np.ndarray) -> np.ndarray:
        """(N, 5) states -> (N,) mean over the outline of the largest edge gradient along each normal."""
        a = states[:, 4:5]
        b = a * self.aspect
        px = states[:, 0:1] + a * self._cos
        py = states[:, 1:2] + b * self._sin
        nx, ny = b * self._cos, a * self._sin  # normal of the ellipse at angle psi, up to scale
        norm = np.hypot(nx, ny)
        step = (self.config.normal_half_length * a / norm)[..., None] * self._t  # (N, P, T)
        values, inside = self._sample(edges, px[..., None] + nx[..., None] * step, py[..., None] + ny[..., None] * step)
        return (values * inside).max(axis=2).mean(axis=1)

    def likelihoods(self, features: tuple[np.ndarray, np.ndarray], states: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Colour and shape likelihoods of (N, 5) states -> ``w_c``, ``w_g``, ``rho`` (N,).

        ``features`` is what :meth:`_features` returns for the frame.
        """
        bins, edges = features
        cfg = self.config
        rho = np.sqrt(self._histograms(bins, states)) @ np.sqrt(self.template)
        d2 = np.clip(1.0 - rho, 0.0, None)
        w_c = np.exp(-d2 / (2 * cfg.sigma_colour**2))
        g = np.minimum(self._outline_gradient(edges, states) / self._g_ref, 1.0)
        w_g = np.exp(-((1.0 - g) ** 2) / (2 * cfg.sigma_shape**2))
        return w_c, w_g, rho

    # ----------------------------------------------------------------- update
    def update(self, frame: np.ndarray) -> HeadEstimate:
        """Predict, weight, estimate, adapt the cue weights and resample for one (H, W, 3) frame."""
        frame = as_bgr(frame)
        if frame.shape[:2] != self.shape:
            raise MocapError(f"frame size {frame.shape[1]}x{frame.shape[0]} differs from the first frame's "
                             f"{self.shape[1]}x{self.shape[0]}; all frames of one video must have one size")
        cfg = self.config
        states = predict_linear(self.particles, self.A, self.noise, self.rng)
        states[:, 4] = np.clip(states[:, 4], 2.0, max(self.shape))
        features = self._features(frame)
        l_c, l_g, rho = self.likelihoods(features, states)
        k = self.cue_weights
        log_w = k[0] * np.log(l_c) + k[1] * np.log(l_g)
        w = normalise(np.exp(log_w - log_w.max()))
        fused = weighted_mean(states, w)
        if cfg.mode is CueMode.FUSED:
            self.cue_weights = self._adapt(k, features, fused)

        self.particles = states[systematic_resample(w, self.rng)]
        self.estimate = fused
        return HeadEstimate(fused[:2].copy(), np.array([fused[4], fused[4] * self.aspect]), k, float(w @ rho))

    def _adapt(self, k: np.ndarray, features: tuple[np.ndarray, np.ndarray], fused: np.ndarray) -> np.ndarray:
        """Democratic integration: move the (2,) cue weights towards the cues' normalised reliabilities.

        Reliability of a cue = how much better it rates the fused estimate than 8 probe states around it
        (``probe_shift`` half-axes away): ``q = max(0, L(x_hat) - mean L(probes))``. A cue that is flat there
        (shape in front of stripes), or that prefers a neighbouring place (colour on the neck when the head
        turns away; colour after a lighting change), loses weight. Triesch & von der Malsburg (2001) compare
        with the particles' mean instead; the particles crowd round the estimate, so that contrast is weak.
        The paper's ``q = exp(-alpha D)`` (D: distance of the cue's own estimate from the fused one) has a fixed
        point at equal weights under the paper's sum fusion (``D_c / D_g = k_g / k_c``).
        """
        cfg = self.config
        probes = np.repeat(fused[None], 1 + len(self._ring), axis=0)
        probes[1:, :2] += self._ring * fused[4] * np.array([1.0, self.aspect])
        at_c, at_g, _ = self.likelihoods(features, probes)
        q = np.maximum([at_c[0] - at_c[1:].mean(), at_g[0] - at_g[1:].mean()], 0.0)
        if q.sum() <= 0:
            return k
        k = k + cfg.rate * (q / q.sum() - k)
        k = np.maximum(k / k.sum(), cfg.min_weight)
        return k / k.sum()


def track_head(frames: Iterable[np.ndarray], box: tuple[float, float, float, float] | None = None,
               config: HeadConfig | None = None, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Track a head through a whole video.

    Args:
        frames: (H, W, 3) uint8 BGR (or (H, W) grey) frames, any iterable (streamed).
        box: ``(x, y, w, h)`` in the first frame, px; None finds it with :func:`detect_head_box` in the first
            frame holding skin (frames before it get NaN).
        config: settings.
        seed: random seed.

    Returns:
        ``centre`` (F, 2) px, ``axes`` (F, 2) px, ``cue_weights`` (F, 2); NaN before initialisation.

    Raises:
        MocapError: no box given and no skin-coloured blob in any frame (e.g. grey-scale video).
    """
    rows: list[np.ndarray] = []
    tracker: HeadTracker | None = None
    for frame in frames:
        if tracker is None:
            start = box if box is not None else detect_head_box(as_bgr(frame))
            if start is not None:
                tracker = HeadTracker(frame, start, config, np.random.default_rng(seed))
        if tracker is None:
            rows.append(np.full(6, np.nan))
            continue
        est = tracker.update(frame)
        rows.append(np.concatenate([est.centre, est.axes, est.cue_weights]))
    if tracker is None and rows:
        raise MocapError("no skin-coloured region in any frame, so the head cannot be found automatically; "
                         "give its box in the first frame (--box x,y,w,h)")
    out = np.array(rows).reshape(-1, 6)
    return out[:, 0:2], out[:, 2:4], out[:, 4:6]
