"""Render a take whose marker images follow another image model than ``mocap synth``'s, to check the engine on
pictures its own renderer did not draw (the independent re-measurement uses a different renderer).

Everything but the picture of a marker comes from ``mocap synth`` (motion, cameras, occlusion, dropouts,
ghosts, truth); each blob is drawn with ``--model``:

* ``hard``: a disc with a hard edge and no optical blur, each pixel the disc's area fraction inside it
  (8 x 8 samples per pixel), as a supersampling renderer draws it;
* ``gauss``: a Gaussian spot of std max(0.7, radius / 1.5) px and the disc's height;
* ``bloom``: the blurred disc plus a halo of 6 % of its height, std 3 px (lens flare around bright markers);
* ``shot``: the blurred disc with photon noise, variance noise^2 + signal / 4 (a 4 e-/grey-level sensor);
* ``cut``: the blurred disc, partly hidden where the marker goes behind something or comes out: in a camera's
  frames next to one where the marker is not drawn by it but by another camera (occluded, dropped, out of the
  image; not where the recording has no sample or every camera lost it), the disc beyond a
  straight edge is not drawn, the edge through the disc's centre in the frame next to the hidden one and half a
  radius out in the frame before that, at a random angle (seeded by take seed, frame and camera). The blob's
  centroid then lies up to 0.42 radius off the marker's centre, which the truth keeps (a real renderer's limbs
  cut markers this way; ``mocap synth`` hides a marker whole).

``--light-power P`` (any model) rescales each blob's height so that its light (height x area) falls as
1 / distance^P instead of ``mocap synth``'s 4 (a retroreflector lit from beside the lens): 2 draws every marker at
one height (flux with its area, as saturated blobs give it); blobs of 2 px radius keep their height.

The truth's ``sigma_px`` (and so ``mocap evaluate``'s Cramér–Rao column) stays that of the default blurred
disc: compare RMSE in mm between models, not the ratio.

Usage:
    python tools/render_other_model.py --model hard [--light-power P] OUT_DIR [any mocap synth option ...]
    mocap reconstruct OUT_DIR --c3d OUT.c3d && mocap evaluate OUT.c3d --truth OUT_DIR.truth.npz
"""

from __future__ import annotations

import argparse
import importlib
import sys

import numpy as np
from scipy.special import erfc

from mocap.cli import main as mocap_main
from mocap.synth import render

_SIMULATE = importlib.import_module("mocap.synth.simulate")  # (mocap.synth.simulate is also a function's name)
_WRITER = importlib.import_module("mocap.synth.writer")

MODELS = ("hard", "gauss", "bloom", "shot", "cut")
_SAMPLES = (np.arange(8) + 0.5) / 8 - 0.5  # sub-pixel sample offsets of the hard disc, px
_HALO = (0.06, 3.0)  # bloom: height fraction and std (px) of the halo
_LIGHT_RADIUS_PX = 2.0  # --light-power: blobs of this radius keep their height
_CUT_EDGES = (0.0, 0.5)  # cut: the edge's distance from the centre, radii, one and two frames from a hidden frame


class OtherSensor(render.Sensor):
    """:class:`mocap.synth.render.Sensor` drawing its blobs with another model (class attribute ``model``)."""

    model = "hard"
    light_power = 4.0  # the blobs' light falls as 1 / distance^light_power

    def _reach(self, radius: np.ndarray) -> float:
        return {"hard": 1.0, "gauss": 2.0 * float(radius.max()), "bloom": 4 * _HALO[1],
                "shot": 4 * self.sigma, "cut": super()._reach(radius)}[self.model]

    def _signal(self, x: np.ndarray, y: np.ndarray, uv: np.ndarray, rho: np.ndarray, radius: np.ndarray,
                amplitude: np.ndarray) -> np.ndarray:
        if self.light_power != 4.0:  # (synth's height falls as 1 / distance^2 and the radius as 1 / depth)
            amplitude = amplitude * (radius / _LIGHT_RADIUS_PX) ** (self.light_power - 4.0)
        if self.model == "hard":
            dx, dy = x - uv[:, 0, None, None], y - uv[:, 1, None, None]
            inside = np.zeros(rho.shape)
            for sx in _SAMPLES:
                for sy in _SAMPLES:
                    inside += np.hypot(dx + sx, dy + sy) <= radius
            return amplitude * inside / len(_SAMPLES) ** 2
        if self.model == "gauss":
            spread = np.maximum(0.7, radius / 1.5)
            return amplitude * np.exp(-rho * rho / (2 * spread * spread))
        signal = super()._signal(x, y, uv, rho, radius, amplitude)
        if self.model == "cut" and _CUT[0] is not None:
            normal, edge = _cut_per_blob(len(uv))  # (the part beyond the edge, along the normal, is hidden)
            n = normal[:, :, None, None]
            along = (x - uv[:, 0, None, None]) * n[:, 0] + (y - uv[:, 1, None, None]) * n[:, 1]
            signal = signal * 0.5 * erfc((along - edge[:, None, None]) / (np.sqrt(2.0) * self.sigma))
        if self.model == "bloom":
            signal += amplitude * _HALO[0] * np.exp(-rho * rho / (2 * _HALO[1] ** 2))
        return signal

    def _noise_std(self, signal: np.ndarray) -> float | np.ndarray:
        if self.model == "shot":
            return np.sqrt(self.noise**2 + np.maximum(signal, 0.0) / 4.0)
        return self.noise


def _cut_edges(plan, frame: int, camera: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``cut``: for the markers drawn in one camera-frame, (n, 2) unit normals of their edges and (n,) the edges'
    distances from the centres, px (inf: whole disc)."""
    drawn = plan.drawn[:, camera]  # (F, M)
    sel = drawn[frame]
    F = len(drawn)
    edge = np.full(int(sel.sum()), np.inf)
    if _DRAWN_SOMEWHERE[0] is None or _DRAWN_SOMEWHERE[0][0] is not plan:
        _DRAWN_SOMEWHERE[0] = (plan, plan.drawn.any(axis=1))
    anywhere = _DRAWN_SOMEWHERE[0][1]  # (F, M) drawn by some camera: hidden from this one by something in its way
    for reach, fraction in zip((2, 1), _CUT_EDGES[::-1], strict=True):  # (the nearer hidden frame wins)
        near = np.zeros(drawn.shape[1], dtype=bool)
        for step in (-reach, reach):
            if 0 <= frame + step < F:
                near |= ~drawn[frame + step] & anywhere[frame + step]
        edge = np.where(near[sel], fraction * plan.radius_px[frame, camera, sel], edge)
    angle = np.random.default_rng([seed, frame, camera]).uniform(0.0, 2.0 * np.pi, drawn.shape[1])[sel]
    return np.stack([np.cos(angle), np.sin(angle)], axis=1), edge


def _cut_per_blob(blobs: int) -> tuple[np.ndarray, np.ndarray]:
    """The edges of the camera-frame being drawn (``_CUT``) for its ``blobs`` blobs: the markers' (n of them, or n
    sub-discs per exposure step when smeared, step by step), then the ghosts' (whole)."""
    normal, edge, ghosts = _CUT[0]
    steps = (blobs - ghosts) // len(edge) if len(edge) else 0
    return (np.concatenate([np.tile(normal, (steps, 1)), np.ones((ghosts, 2))]),
            np.concatenate([np.tile(edge, steps), np.full(ghosts, np.inf)]))


def _render_cut_frame(plan, frame: int, camera: int, rng: np.random.Generator) -> np.ndarray:
    """``render_frame`` with the blobs of markers next to a hidden frame cut (``cut`` model)."""
    _CUT[0] = (*_cut_edges(plan, frame, camera, _CUT_SEED[0]), int(plan.ghost_on[frame, camera].sum()))
    try:
        return _RENDER_FRAME(plan, frame, camera, rng)
    finally:
        _CUT[0] = None


_RENDER_FRAME = _SIMULATE.render_frame
_CUT_SEED = [0]  # the take's seed
_CUT: list = [None]  # (normals (n, 2), edges (n,) px, ghosts) of the camera-frame being drawn
_DRAWN_SOMEWHERE: list = [None]  # (plan, (F, M) bool: drawn by some camera), computed once per take


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=MODELS, required=True, help="how a marker's blob is drawn")
    parser.add_argument("--light-power", type=float, default=4.0,
                        help="the blobs' light falls as 1 / distance^P (default 4, as mocap synth draws it)")
    args, synth_args = parser.parse_known_args()
    OtherSensor.model = args.model
    OtherSensor.light_power = args.light_power
    _SIMULATE.Sensor = OtherSensor  # plan_take builds its sensor from this name
    if args.model == "cut":
        seed = argparse.ArgumentParser(add_help=False)
        seed.add_argument("--seed", type=int, default=0)
        _CUT_SEED[0] = seed.parse_known_args(synth_args)[0].seed
        _WRITER.render_frame = _render_cut_frame  # the writer renders each camera-frame through this name
    return mocap_main(["synth", *synth_args])


if __name__ == "__main__":
    sys.exit(main())
