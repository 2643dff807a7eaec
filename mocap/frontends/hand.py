"""Deformable-hand tracker for one camera (paper 000): posture, fingertips by finger, palm centre.

Per frame: skin mask -> (not tracking) recognise and initialise, or (tracking) CAMShift hand box, one arc
particle filter per extended finger, K-means check of strong particles, palm centre, state check.

* Recognition: :mod:`~mocap.frontends.postures` on the largest skin contour; MAP under posture transition
  probabilities ``p(C_t | C_t-1)`` (set by hand: ``stay`` on the diagonal).
* Fingertips: along the contour with a window ``a..b`` of +-L points, ``ratio = dist(p, ab) / |ab|``; local
  maxima above eps (1.0) whose chord midpoint is skin are fingertips (valleys between fingers fail that
  test). The finger base is found by moving a and b outwards while the ratio test holds. L scales with
  the palm's inscribed radius (distance transform), so the test works at any hand size.
* Initialisation starts tracking only when the number of fingertips matches the recognised posture;
  fingertips are labelled by their angle around the palm centre (right hand, palm to the camera: thumb
  first).
* Fingertip filter: state ``(x, y, r, theta)``: arc centre, radius, pointing direction (the paper's
  diameter angle alpha is ambiguous about which side the half circle bulges to; theta is not). Second-order
  dynamics ``s(k+1) = s(k) + damping (s(k) - s(k-1)) + w``, plus the CAMShift box's shift (the whole hand
  moves the fingers). Likelihood: rays from the centre every beta degrees over the half circle; on each, the
  first point q where the grey gradient crosses a threshold (interpolated between samples); ``p(z|x) =
  exp(-delta mean_n |t(q_n) - r|)`` (the paper's sum, with delta per ray).
* Strong particles (p > strong) of all fingers are clustered with K-means (k = fingers, initial labels =
  own finger); a strong particle in another finger's cluster is suspicious: weight x0.2. Then systematic
  resampling.
* Palm: a circle of ``palm_factor`` x the mean fingertip radius, centred where it holds the most skin
  within a neighbourhood of the hand centroid.
* State check: a finger's mean particle confidence below ``fail_confidence`` -> that finger's filter is
  dropped and the hand re-recognised; the contour's fingertip count differing from the tracked count for
  ``check_frames`` frames (a finger came out; stands in for the paper's band scan around the centroid) ->
  re-recognise. Re-initialisation happens when a recognition's fingertips fit its posture; until then the
  fingers still tracked keep being followed (the paper restarts everything; this keeps fingers that did
  not change through a posture change).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.ndimage import maximum_filter1d

from mocap.errors import MocapError
from mocap.frontends.particles import normalise, systematic_resample
from mocap.frontends.postures import FINGERS, POSTURES, PostureModel, fourier_features, transition_matrix
from mocap.frontends.skin import is_grey, skin_mask

__all__ = ["HandConfig", "Fingertips", "HandEstimate", "HandTracker", "hand_contour", "find_fingertips",
           "label_fingers", "posture_features", "track_hand"]


@dataclass(frozen=True)
class HandConfig:
    """Hand-tracker settings (pixels, radians, frames).

    Attributes:
        particles: particles per fingertip filter.
        ray_step_deg: beta, the angle between rays of the arc likelihood.
        ray_samples: samples along each ray (from 0.3 r to ``ray_reach`` r).
        ray_reach: length of the rays in arc radii (a ray that meets no edge costs ``ray_reach - 1`` radii).
        delta: confidence fall-off per pixel of mean arc misfit.
        edge_threshold: Sobel gradient magnitude (3x3, grey levels) that counts as an edge.
        strong: confidence above which a particle is strong.
        suspicious_factor: weight factor of suspicious particles.
        fail_confidence: mean particle confidence below which a finger is lost.
        ratio_threshold: eps of the fingertip curvature test.
        window_factor: contour half-window L as a multiple of the palm's inscribed radius.
        min_hand_area: smallest skin blob taken for a hand, px^2.
        noise_pos, noise_radius, noise_angle: process-noise std of x/y (px), r (px), theta (rad).
        damping: weight of the previous step in the second-order dynamics.
        palm_factor: palm-circle radius as a multiple of the mean fingertip radius.
        camshift_iterations: CAMShift's iteration limit (the paper's 10).
        stay: posture transition probability of staying in the same posture.
        check_frames: frames the contour's fingertip count must disagree before re-recognition.
    """

    particles: int = 40
    ray_step_deg: float = 15.0
    ray_samples: int = 20
    ray_reach: float = 4.0
    delta: float = 1.0
    edge_threshold: float = 150.0
    strong: float = 0.3
    suspicious_factor: float = 0.2
    fail_confidence: float = 0.03
    ratio_threshold: float = 1.0
    window_factor: float = 0.7
    min_hand_area: float = 300.0
    noise_pos: float = 1.5
    noise_radius: float = 0.3
    noise_angle: float = 0.08
    damping: float = 0.5
    palm_factor: float = 3.5
    camshift_iterations: int = 10
    stay: float = 0.75
    check_frames: int = 2


@dataclass
class Fingertips:
    """Fingertips found on one contour (K of them).

    Attributes:
        centre: (K, 2) arc centres, px.
        radius: (K,) arc radii, px.
        direction: (K,) pointing directions (angle of base -> tip), rad.
        base: (K, 2, 2) the two contour points where each finger meets the hand, px.
    """

    centre: np.ndarray
    radius: np.ndarray
    direction: np.ndarray
    base: np.ndarray

    def __len__(self) -> int:
        return len(self.radius)


@dataclass
class HandEstimate:
    """The tracker's output for one frame.

    Attributes:
        posture: recognised posture letter, "" when no hand is recognised.
        tips: (5, 2) fingertip centres by finger (:data:`FINGERS` order), px; NaN when not tracked.
        radius: (5,) fingertip radii, px; NaN when not tracked.
        confidence: (5,) mean particle confidence of each tracked finger (NaN otherwise).
        palm: (2,) palm centre, px; NaN without a hand.
        tracking: the fingertip filters are running.
        box: the CAMShift hand box ``(x, y, w, h)``, px, while tracking.
    """

    posture: str
    tips: np.ndarray
    radius: np.ndarray
    confidence: np.ndarray
    palm: np.ndarray
    tracking: bool = False
    box: tuple[int, int, int, int] | None = field(default=None)


def hand_contour(mask: np.ndarray, min_area: float) -> np.ndarray | None:
    """(H, W) uint8 skin mask -> (N, 2) float outer contour of the largest blob, clockwise on screen, or None."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    areas = [cv2.contourArea(c) for c in contours]
    best = int(np.argmax(areas))
    if areas[best] < min_area:
        return None
    c = contours[best].reshape(-1, 2).astype(np.float64)
    if cv2.contourArea(contours[best], oriented=True) < 0:
        c = c[::-1]
    return c


def _ratio(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of p from line ab over |ab|, for (..., 2) arrays."""
    ab = b - a
    ap = p - a
    cross = np.abs(ab[..., 0] * ap[..., 1] - ab[..., 1] * ap[..., 0])
    return cross / np.maximum((ab * ab).sum(axis=-1), 1e-9)


def find_fingertips(contour: np.ndarray, mask: np.ndarray, palm_radius: float, config: HandConfig) -> Fingertips:
    """Curvature-ratio fingertip detection with finger bases (paper 000 sec. 2.2).

    Args:
        contour: (N, 2) closed contour, px.
        mask: (H, W) uint8 skin mask (the convexity test reads it).
        palm_radius: the palm's inscribed radius, px (sets the window L).
        config: settings.

    Returns:
        The fingertips, in contour order.
    """
    n = len(contour)
    half = max(int(round(config.window_factor * palm_radius)), 3)
    empty = Fingertips(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.zeros((0, 2, 2)))
    if n < 4 * half:
        return empty
    idx = np.arange(n)
    a, b = contour[(idx - half) % n], contour[(idx + half) % n]
    ratio = _ratio(contour, a, b)
    peak = (ratio >= config.ratio_threshold) & (ratio >= maximum_filter1d(ratio, 2 * half + 1, mode="wrap"))
    h, w = mask.shape
    mid = np.rint((a + b) / 2).astype(np.intp)
    inside = (mid[:, 0] >= 0) & (mid[:, 0] < w) & (mid[:, 1] >= 0) & (mid[:, 1] < h)
    convex = np.zeros(n, bool)
    convex[inside] = mask[mid[inside, 1], mid[inside, 0]] > 0
    border = (contour[:, 0] < 2) | (contour[:, 0] > w - 3) | (contour[:, 1] < 2) | (contour[:, 1] > h - 3)
    kept: list[int] = []
    for i in np.flatnonzero(peak & convex & ~border):
        if not kept or min(abs(i - kept[-1]), n - abs(i - kept[-1])) > half:
            kept.append(int(i))
    if len(kept) > 1 and n - (kept[-1] - kept[0]) <= half:
        kept.pop()
    if not kept:
        return empty
    tips = np.array(kept)
    step = max(half // 3, 1)
    ext = np.arange(0, 3 * half, step)  # (M,) outward moves of a and b
    ia = (tips[:, None] - half - ext) % n
    ib = (tips[:, None] + half + ext) % n
    holds = _ratio(contour[tips][:, None], contour[ia], contour[ib]) >= config.ratio_threshold  # (K, M)
    last = np.where(holds.all(axis=1), holds.shape[1] - 1, np.argmin(holds, axis=1) - 1).clip(0)
    rows = np.arange(len(tips))
    base = np.stack([contour[ia[rows, last]], contour[ib[rows, last]]], axis=1)
    radius = np.hypot(*(b[tips] - a[tips]).T) / 2
    axis = contour[tips] - base.mean(axis=1)
    direction = np.arctan2(axis[:, 1], axis[:, 0])
    centre = contour[tips] - radius[:, None] * np.stack([np.cos(direction), np.sin(direction)], axis=1)
    return Fingertips(centre, radius, direction, base)


def label_fingers(tips: Fingertips, palm: np.ndarray, posture: str) -> np.ndarray | None:
    """Finger indices (into :data:`FINGERS`) of the tips, or None when their number does not fit the posture.

    Tips are ordered by angle around the palm centre, measured from the mean finger direction, thumb side
    (image right for a right palm facing the camera) first.
    """
    fingers = [FINGERS.index(f) for f in POSTURES[posture]]
    if len(tips) != len(fingers):
        return None
    if not fingers:
        return np.zeros(0, dtype=int)
    d = tips.centre - palm
    up = d.mean(axis=0)
    up /= max(np.linalg.norm(up), 1e-9)
    angle = np.arctan2(up[0] * d[:, 1] - up[1] * d[:, 0], d @ up)
    order = np.argsort(-angle)
    labels = np.empty(len(fingers), dtype=int)
    labels[order] = fingers
    return labels


def _disc(n: int) -> np.ndarray:
    """(S, 2) sample offsets on an n x n grid inside the unit disc."""
    g = (np.arange(n) + 0.5) / n * 2 - 1
    u, v = np.meshgrid(g, g)
    keep = u * u + v * v <= 1
    return np.stack([u[keep], v[keep]], axis=1)


class HandTracker:
    """Track one hand in one camera's video, one :meth:`update` per (H, W, 3) BGR frame.

    Args:
        model: the posture classifier (default: the shipped model).
        config: settings.
        rng: the random generator (seed it for reproducible runs).
    """

    def __init__(self, model: PostureModel | None = None, config: HandConfig | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.model = model or PostureModel.load()
        self.config = config or HandConfig()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        cfg = self.config
        self._transition = transition_matrix(self.model.classes, cfg.stay)
        n_rays = int(180 // cfg.ray_step_deg)
        self._ray_offsets = np.radians(-90.0 + cfg.ray_step_deg * (np.arange(n_rays) + 0.5))
        self._ray_t = np.linspace(0.3, cfg.ray_reach, cfg.ray_samples)
        self._palm_disc = _disc(9)
        self.posture = ""
        self.fingers = np.zeros(0, dtype=int)
        self.particles = np.zeros((0, cfg.particles, 4))
        self.previous = self.particles.copy()
        self.window: tuple[int, int, int, int] | None = None
        self.tip_radius = np.nan
        self._disagree = 0
        self._pending = False  # the last recognition's fingertips did not fit its posture: try again
        self._checked_colour = False
        self._estimate = np.zeros((0, 4))
        self._conf = np.zeros(0)

    @property
    def tracking(self) -> bool:
        return self.window is not None

    # ---------------------------------------------------------- recognition
    def _palm_radius(self, mask: np.ndarray) -> float:
        """The hand's inscribed radius, px (largest distance from non-skin)."""
        return float(cv2.distanceTransform(mask, cv2.DIST_L2, 3).max())

    def _recognise(self, mask: np.ndarray) -> tuple[str, Fingertips | None, np.ndarray | None]:
        """MAP posture of the largest skin blob, its fingertips and their finger labels (None if they do not fit)."""
        contour = hand_contour(mask, self.config.min_hand_area)
        if contour is None:
            return "", None, None
        prior = None
        if self.posture:
            prior = self._transition[self.model.classes.index(self.posture)]
        posture, _ = self.model.classify(fourier_features(contour, self.model.harmonics), prior)
        tips = find_fingertips(contour, mask, self._palm_radius(mask), self.config)
        m = cv2.moments(mask, binaryImage=True)
        centroid = np.array([m["m10"], m["m01"]]) / max(m["m00"], 1.0)
        return posture, tips, label_fingers(tips, centroid, posture)

    def _start(self, mask: np.ndarray, posture: str, tips: Fingertips, labels: np.ndarray) -> None:
        """Start tracking: CAMShift window on the hand blob, one particle cloud per labelled fingertip."""
        cfg = self.config
        contour = hand_contour(mask, cfg.min_hand_area)
        x, y, w, h = cv2.boundingRect(contour.astype(np.int32))
        self.window = (x, y, w, h)
        self.posture = posture
        order = np.argsort(labels)
        self.fingers = labels[order]
        init = np.column_stack([tips.centre[order], tips.radius[order], tips.direction[order]])
        if len(init):
            self.tip_radius = float(init[:, 2].mean())
        noise = np.array([cfg.noise_pos, cfg.noise_pos, cfg.noise_radius, cfg.noise_angle])
        self.particles = init[:, None, :] + self.rng.standard_normal((len(init), cfg.particles, 4)) * noise
        self.previous = self.particles.copy()
        self._radius0 = init[:, 2].copy()
        self._disagree = 0

    def _stop(self) -> None:
        self.window = None
        self.fingers = np.zeros(0, dtype=int)
        self.particles = np.zeros((0, self.config.particles, 4))
        self.previous = self.particles.copy()

    # ------------------------------------------------------------- tracking
    def _confidence(self, grad: np.ndarray, states: np.ndarray) -> np.ndarray:
        """(..., 4) arc states -> (...) likelihoods ``exp(-delta mean |t(q) - r|)`` on the gradient image.

        ``t(q)`` is where the first gradient peak above the threshold lies on each ray (parabolic sub-sample
        fit): the peak, not the crossing, so that the edge is not found early by half the edge's width.
        """
        cfg = self.config
        h, w = grad.shape
        x, y, r, th = (states[..., i, None, None] for i in range(4))
        phi = th + self._ray_offsets[:, None]  # (..., N, 1)
        t = r * self._ray_t  # (..., 1, T)
        xi = np.rint(x + np.cos(phi) * t).astype(np.intp).clip(0, w - 1)
        yi = np.rint(y + np.sin(phi) * t).astype(np.intp).clip(0, h - 1)
        g = grad[yi, xi]  # (..., N, T)
        above = g >= cfg.edge_threshold
        found = above.any(axis=-1)
        # The edge is the gradient peak that starts at the first threshold crossing: step on while g rises.
        j = np.argmax(above, axis=-1)
        last = g.shape[-1] - 1
        for _ in range(3):
            here = np.take_along_axis(g, j[..., None], -1)[..., 0]
            ahead = np.take_along_axis(g, np.minimum(j + 1, last)[..., None], -1)[..., 0]
            j = np.where(ahead > here, np.minimum(j + 1, last), j)
        jc = j.clip(1, last - 1)[..., None]
        g0, g1, g2 = (np.take_along_axis(g, jc + d, -1)[..., 0] for d in (-1, 0, 1))
        curv = g0 - 2 * g1 + g2
        offset = np.where(curv < 0, np.clip(0.5 * (g0 - g2) / np.where(curv < 0, curv, -1.0), -0.5, 0.5), 0.0)
        step = r[..., 0] * (self._ray_t[1] - self._ray_t[0])
        tq = r[..., 0] * self._ray_t[0] + (jc[..., 0] + offset) * step
        tq = np.where(found, tq, r[..., 0] * self._ray_t[-1])
        misfit = np.abs(tq - r[..., 0]).mean(axis=-1)
        return np.exp(-cfg.delta * misfit)

    def _suspicious(self, states: np.ndarray, conf: np.ndarray) -> np.ndarray:
        """(F, P) factors: ``suspicious_factor`` for strong particles K-means puts in another finger's cluster."""
        cfg = self.config
        factor = np.ones(conf.shape)
        strong = conf > cfg.strong
        present = np.flatnonzero(strong.any(axis=1))
        if len(present) < 2:
            return factor
        owner = np.broadcast_to(np.arange(conf.shape[0])[:, None], conf.shape)[strong]
        remap = np.full(conf.shape[0], -1)
        remap[present] = np.arange(len(present))
        labels = remap[owner].astype(np.int32).reshape(-1, 1)
        data = states[strong][:, :2].astype(np.float32)
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_MAX_ITER, 30, 0.1)
        _, clusters, _ = cv2.kmeans(data, len(present), labels, crit, 1, cv2.KMEANS_USE_INITIAL_LABELS)
        factor[strong] = np.where(clusters.ravel() == labels.ravel(), 1.0, cfg.suspicious_factor)
        return factor

    def _track(self, frame: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """One filter step for every tracked finger; returns (F,) mean confidences."""
        cfg = self.config
        crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, cfg.camshift_iterations, 1.0)
        old = self.window
        _, window = cv2.CamShift(mask, old, crit)
        if window[2] * window[3] < cfg.min_hand_area / 4:
            self._stop()
            return np.zeros(0)
        self.window = tuple(int(v) for v in window)
        shift = np.array([window[0] + window[2] / 2 - old[0] - old[2] / 2,
                          window[1] + window[3] / 2 - old[1] - old[3] / 2])
        if not len(self.fingers):
            return np.zeros(0)
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
        grad = cv2.magnitude(cv2.Sobel(grey, cv2.CV_32F, 1, 0), cv2.Sobel(grey, cv2.CV_32F, 0, 1))
        noise = np.array([cfg.noise_pos, cfg.noise_pos, cfg.noise_radius, cfg.noise_angle])
        states = (self.particles + cfg.damping * (self.particles - self.previous)
                  + self.rng.standard_normal(self.particles.shape) * noise)
        states[..., :2] += shift
        states[..., 2] = np.clip(states[..., 2], 0.7 * self._radius0[:, None], 1.4 * self._radius0[:, None])
        conf = self._confidence(grad, states)
        weights = conf * self._suspicious(states, conf)
        self._estimate = np.empty((len(self.fingers), 4))
        ancestors = np.empty(states.shape[:2], dtype=np.intp)
        for f in range(len(self.fingers)):
            w = normalise(weights[f])
            self._estimate[f, :3] = w @ states[f, :, :3]
            self._estimate[f, 3] = np.arctan2(w @ np.sin(states[f, :, 3]), w @ np.cos(states[f, :, 3]))
            ancestors[f] = systematic_resample(w, self.rng)
        rows = np.arange(len(self.fingers))[:, None]
        # each survivor's own previous state, moved with the hand so the velocity is the finger's own
        self.previous = self.particles[rows, ancestors] + np.array([shift[0], shift[1], 0.0, 0.0])
        self.particles = states[rows, ancestors]
        self.tip_radius = float(self._estimate[:, 2].mean())
        return conf.mean(axis=1)

    def _palm(self, mask: np.ndarray) -> np.ndarray:
        """(2,) palm centre: the most-skin circle of ``palm_factor`` tip radii near the hand centroid, px.

        Among circles that are equally full of skin (a fist, a wide palm) the one deepest inside the hand
        (largest distance to non-skin) wins; the paper leaves such ties open.
        """
        h, w = mask.shape
        x, y, bw, bh = self.window if self.window is not None else (0, 0, w, h)
        roi = mask[y:y + bh, x:x + bw]
        m = cv2.moments(roi, binaryImage=True)
        if m["m00"] <= 0:
            return np.full(2, np.nan)
        centroid = np.array([x + m["m10"] / m["m00"], y + m["m01"] / m["m00"]])
        radius = self.config.palm_factor * (self.tip_radius if np.isfinite(self.tip_radius) else 4.0)
        g = np.linspace(-0.5, 0.5, 7) * radius
        cand = centroid + np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
        pts = np.rint(cand[:, None, :] + radius * self._palm_disc).astype(np.intp)
        ok = (pts[..., 0] >= 0) & (pts[..., 0] < w) & (pts[..., 1] >= 0) & (pts[..., 1] < h)
        skin = mask[pts[..., 1].clip(0, h - 1), pts[..., 0].clip(0, w - 1)] > 0
        ci = np.rint(cand).astype(np.intp)
        inside = (ci[:, 0] >= x) & (ci[:, 0] < x + bw) & (ci[:, 1] >= y) & (ci[:, 1] < y + bh)
        depth = cv2.distanceTransform(roi, cv2.DIST_L2, 3)
        deep = np.where(inside, depth[(ci[:, 1] - y).clip(0, bh - 1), (ci[:, 0] - x).clip(0, bw - 1)], 0.0)
        return cand[int(np.argmax((skin & ok).mean(axis=1) + 1e-3 * deep))]

    # ----------------------------------------------------------------- step
    def update(self, frame: np.ndarray) -> HandEstimate:
        """Process one (H, W, 3) uint8 BGR frame.

        Raises:
            MocapError: the frame is grey-scale (skin segmentation needs colour).
        """
        frame = np.asarray(frame)
        if not self._checked_colour:
            if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3 or is_grey(frame):
                raise MocapError("the hand tracker needs 8-bit colour video (it finds the hand by skin colour); "
                                 "this video is grey-scale or not 3-channel")
            self._checked_colour = True
        mask = skin_mask(frame)
        recognise = not self.tracking
        if self.tracking:
            conf = self._track(frame, mask)
            failed = conf < self.config.fail_confidence
            if failed.any():  # drop the lost fingers, keep following the others until re-initialised
                keep = ~failed
                self.fingers, self.particles, self.previous = (
                    self.fingers[keep], self.particles[keep], self.previous[keep])
                self._radius0, self._estimate, conf = self._radius0[keep], self._estimate[keep], conf[keep]
            self._conf = conf
            recognise = not self.tracking or failed.any() or self._count_disagrees(mask) or self._pending
        if recognise:
            posture, tips, labels = self._recognise(mask)
            self.posture = posture
            self._pending = labels is None
            if labels is not None:
                self._start(mask, posture, tips, labels)
                self._estimate = np.column_stack([tips.centre, tips.radius, tips.direction])[np.argsort(labels)]
                self._conf = np.ones(len(labels))
            elif not posture:
                self._stop()
        return self._output(mask)

    def _count_disagrees(self, mask: np.ndarray) -> bool:
        """True when the contour has shown another number of fingertips than tracked for ``check_frames`` frames."""
        contour = hand_contour(mask, self.config.min_hand_area)
        if contour is None:
            return True
        count = len(find_fingertips(contour, mask, self._palm_radius(mask), self.config))
        self._disagree = self._disagree + 1 if count != len(self.fingers) else 0
        return self._disagree >= self.config.check_frames

    def _output(self, mask: np.ndarray) -> HandEstimate:
        tips = np.full((5, 2), np.nan)
        radius = np.full(5, np.nan)
        confidence = np.full(5, np.nan)
        if self.tracking and len(self.fingers):
            tips[self.fingers] = self._estimate[:, :2]
            radius[self.fingers] = self._estimate[:, 2]
            confidence[self.fingers] = self._conf
        palm = self._palm(mask) if self.posture else np.full(2, np.nan)
        return HandEstimate(self.posture, tips, radius, confidence, palm, self.tracking, self.window)


def posture_features(images: list[np.ndarray], harmonics: int, min_area: float = HandConfig.min_hand_area
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Fourier features of the largest skin blob of each (H, W, 3) BGR image.

    Returns:
        (N, 2h - 1) features (NaN rows where no hand was found) and (N,) bool found.
    """
    out = np.full((len(images), 2 * harmonics - 1), np.nan)
    for i, img in enumerate(images):
        contour = hand_contour(skin_mask(img), min_area)
        if contour is not None:
            out[i] = fourier_features(contour, harmonics)
    return out, np.isfinite(out).all(axis=1)


def track_hand(frames: Iterable[np.ndarray], model: PostureModel | None = None, config: HandConfig | None = None,
               seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Track a hand through a video of (H, W, 3) uint8 BGR frames (any iterable; streamed).

    Returns:
        ``tips`` (F, 5, 2) px by finger (NaN when not tracked), ``palm`` (F, 2) px, ``posture`` (F,) letters.
    """
    tracker = HandTracker(model, config, np.random.default_rng(seed))
    tips, palm, posture = [], [], []
    for frame in frames:
        est = tracker.update(frame)
        tips.append(est.tips)
        palm.append(est.palm)
        posture.append(est.posture)
    return np.array(tips).reshape(-1, 5, 2), np.array(palm).reshape(-1, 2), np.array(posture, dtype=str)
