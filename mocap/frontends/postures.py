"""Hand-posture recognition: contour Fourier descriptors and a Gaussian Bayes classifier (paper 000, sec. 2.1).

Feature of a closed contour resampled to ``samples`` points by arc length, ``z = x + i y``, ``FD = fft(z)``:
``log(|FD_k| / |FD_1|)`` for ``k = 2..h`` and ``k = -1..-h`` - invariant to translation (FD_0 dropped),
rotation and start point (moduli), and scale (ratio). The paper lists only ``k = 2..n``; the negative
frequencies carry half of the shape, so they are kept. The logarithm makes the ratios closer to Gaussian.

The classifier keeps one mean and covariance per class (covariances shrunk towards their diagonal so that
a few hundred samples suffice) and decides by maximum posterior, which is the minimum-risk decision under
0-1 loss. The model is stored as JSON (never pickle).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.atomic import atomic_write_bytes
from mocap.errors import MocapError

__all__ = ["FINGERS", "POSTURES", "fourier_features", "PostureModel", "DEFAULT_MODEL_PATH", "transition_matrix"]

DEFAULT_MODEL_PATH = Path(__file__).with_name("postures.json")
_FORMAT = "mocap-posture-model"
FINGERS = ("thumb", "index", "middle", "ring", "little")
#: Extended fingers of each posture (paper 000): A fist, B index, C index+middle, D middle+ring+little,
#: E four fingers without the thumb, F open hand.
POSTURES: dict[str, tuple[str, ...]] = {
    "A": (),
    "B": ("index",),
    "C": ("index", "middle"),
    "D": ("middle", "ring", "little"),
    "E": ("index", "middle", "ring", "little"),
    "F": FINGERS,
}


def fourier_features(contour: np.ndarray, harmonics: int = 10, samples: int = 128) -> np.ndarray:
    """Translation-, rotation- and scale-invariant shape feature of a closed contour.

    Args:
        contour: (N, 2) contour points in order, px (N >= 8).
        harmonics: h; the feature has ``2h - 1`` values.
        samples: points the contour is resampled to (uniform arc length).

    Returns:
        (2h - 1,) ``log(|FD_k| / |FD_1|)`` for k = 2..h, -1..-h.
    """
    pts = np.asarray(contour, dtype=np.float64).reshape(-1, 2)
    closed = np.vstack([pts, pts[:1]])
    seg = np.hypot(*np.diff(closed, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    t = np.linspace(0.0, s[-1], samples, endpoint=False)
    z = np.interp(t, s, closed[:, 0]) + 1j * np.interp(t, s, closed[:, 1])
    fd = np.abs(np.fft.fft(z))
    k = np.concatenate([np.arange(2, harmonics + 1), -np.arange(1, harmonics + 1)])
    return np.log(np.maximum(fd[k], 1e-12) / max(fd[1], 1e-12))


def transition_matrix(classes: tuple[str, ...], stay: float) -> np.ndarray:
    """(K, K) posture transition probabilities ``p(C_t = j | C_t-1 = i)``: ``stay`` on the diagonal, rest even."""
    k = len(classes)
    m = np.full((k, k), (1.0 - stay) / (k - 1))
    np.fill_diagonal(m, stay)
    return m


@dataclass
class PostureModel:
    """Gaussian Bayes posture classifier.

    Attributes:
        classes: (K,) posture names.
        means: (K, D) class means of :func:`fourier_features`.
        covariances: (K, D, D) class covariances.
        harmonics: the ``harmonics`` the features were computed with.
    """

    classes: tuple[str, ...]
    means: np.ndarray
    covariances: np.ndarray
    harmonics: int

    def __post_init__(self) -> None:
        self.means = np.asarray(self.means, dtype=np.float64)
        self.covariances = np.asarray(self.covariances, dtype=np.float64)
        k, d = self.means.shape
        if len(self.classes) != k or self.covariances.shape != (k, d, d) or d != 2 * self.harmonics - 1:
            raise ValueError("posture model arrays do not fit together")
        self._inv = np.linalg.inv(self.covariances)
        self._logdet = np.linalg.slogdet(self.covariances)[1]

    @classmethod
    def fit(cls, features: np.ndarray, labels: list[str], harmonics: int, shrink: float = 0.2) -> PostureModel:
        """Learn class means and covariances from (N, D) features and their N labels.

        ``shrink`` blends each covariance with its diagonal: ``(1 - shrink) S + shrink diag(S)``.
        """
        features = np.asarray(features, dtype=np.float64)
        labels_arr = np.asarray(labels)
        classes = tuple(sorted(set(labels)))
        means, covs = [], []
        for c in classes:
            x = features[labels_arr == c]
            if len(x) < 2:
                raise ValueError(f"posture {c!r} needs at least 2 training samples, got {len(x)}")
            s = np.cov(x, rowvar=False)
            covs.append((1.0 - shrink) * s + shrink * np.diag(np.diag(s)) + 1e-6 * np.eye(len(s)))
            means.append(x.mean(axis=0))
        return cls(classes, np.array(means), np.array(covs), harmonics)

    def log_likelihoods(self, features: np.ndarray) -> np.ndarray:
        """(N, D) or (D,) features -> (N, K) or (K,) Gaussian log densities ``log p(X | C)``."""
        x = np.asarray(features, dtype=np.float64)
        diff = x[..., None, :] - self.means  # (..., K, D)
        maha = np.einsum("...kd,kde,...ke->...k", diff, self._inv, diff)
        return -0.5 * (maha + self._logdet + self.means.shape[1] * np.log(2 * np.pi))

    def classify(self, features: np.ndarray, prior: np.ndarray | None = None) -> tuple[str, np.ndarray]:
        """MAP posture of one (D,) feature under an optional (K,) prior -> (name, (K,) posterior)."""
        log_post = self.log_likelihoods(features)
        if prior is not None:
            log_post = log_post + np.log(np.maximum(prior, 1e-300))
        post = np.exp(log_post - log_post.max())
        post /= post.sum()
        return self.classes[int(np.argmax(post))], post

    def save(self, path: str | os.PathLike) -> None:
        """Write the model as JSON, atomically."""
        doc = {"format": _FORMAT, "version": 1, "harmonics": self.harmonics, "classes": list(self.classes),
               "means": self.means.tolist(), "covariances": self.covariances.tolist()}
        atomic_write_bytes(Path(path), json.dumps(doc).encode("utf-8"))

    @classmethod
    def load(cls, path: str | os.PathLike = DEFAULT_MODEL_PATH) -> PostureModel:
        """Read a model written by :meth:`save`."""
        path = Path(path)
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            if doc.get("format") != _FORMAT:
                raise ValueError(f"format is {doc.get('format')!r}, expected {_FORMAT!r}")
            return cls(tuple(doc["classes"]), doc["means"], doc["covariances"], int(doc["harmonics"]))
        except FileNotFoundError:
            raise MocapError(f"{path}: posture model not found; train one with 'python tools/bench_frontends.py "
                             "train' or give --model") from None
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise MocapError(f"{path}: not a usable posture model ({exc}); retrain it") from None
