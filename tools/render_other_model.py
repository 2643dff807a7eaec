"""Render a take whose marker images follow another image model than ``mocap synth``'s, to check the engine on
pictures its own renderer did not draw (the independent re-measurement uses a different renderer).

Everything but the picture of a marker comes from ``mocap synth`` (motion, cameras, occlusion, dropouts,
ghosts, truth); each blob is drawn with ``--model``:

* ``hard``: a disc with a hard edge and no optical blur, each pixel the disc's area fraction inside it
  (8 x 8 samples per pixel), as a supersampling renderer draws it;
* ``gauss``: a Gaussian spot of std max(0.7, radius / 1.5) px and the disc's height;
* ``bloom``: the blurred disc plus a halo of 6 % of its height, std 3 px (lens flare around bright markers);
* ``shot``: the blurred disc with photon noise, variance noise^2 + signal / 4 (a 4 e-/grey-level sensor).

The truth's ``sigma_px`` (and so ``mocap evaluate``'s Cramér–Rao column) stays that of the default blurred
disc: compare RMSE in mm between models, not the ratio.

Usage:
    python tools/render_other_model.py --model hard OUT_DIR [any mocap synth option ...]
    mocap reconstruct OUT_DIR --c3d OUT.c3d && mocap evaluate OUT.c3d --truth OUT_DIR.truth.npz
"""

from __future__ import annotations

import argparse
import importlib
import sys

import numpy as np

from mocap.cli import main as mocap_main
from mocap.synth import render

_SIMULATE = importlib.import_module("mocap.synth.simulate")  # (mocap.synth.simulate is also a function's name)

MODELS = ("hard", "gauss", "bloom", "shot")
_SAMPLES = (np.arange(8) + 0.5) / 8 - 0.5  # sub-pixel sample offsets of the hard disc, px
_HALO = (0.06, 3.0)  # bloom: height fraction and std (px) of the halo


class OtherSensor(render.Sensor):
    """:class:`mocap.synth.render.Sensor` drawing its blobs with another model (class attribute ``model``)."""

    model = "hard"

    def _reach(self, radius: np.ndarray) -> float:
        return {"hard": 1.0, "gauss": 2.0 * float(radius.max()), "bloom": 4 * _HALO[1],
                "shot": 4 * self.sigma}[self.model]

    def _signal(self, x: np.ndarray, y: np.ndarray, uv: np.ndarray, rho: np.ndarray, radius: np.ndarray,
                amplitude: np.ndarray) -> np.ndarray:
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
        if self.model == "bloom":
            signal += amplitude * _HALO[0] * np.exp(-rho * rho / (2 * _HALO[1] ** 2))
        return signal

    def _noise_std(self, signal: np.ndarray) -> float | np.ndarray:
        if self.model == "shot":
            return np.sqrt(self.noise**2 + np.maximum(signal, 0.0) / 4.0)
        return self.noise


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=MODELS, required=True, help="how a marker's blob is drawn")
    args, synth_args = parser.parse_known_args()
    OtherSensor.model = args.model
    _SIMULATE.Sensor = OtherSensor  # plan_take builds its sensor from this name
    return mocap_main(["synth", *synth_args])


if __name__ == "__main__":
    sys.exit(main())
