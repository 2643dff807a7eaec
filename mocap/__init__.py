"""Marker-based optical motion capture: images or 2D centroids in, labelled 3D trajectories out.

The Python API's entry point is :func:`mocap.reconstruct` (see :mod:`mocap.pipeline`).
"""

from typing import Any

__version__ = "0.1.0"
__all__ = ["reconstruct", "__version__"]


def __getattr__(name: str) -> Any:
    # Lazy, so that `import mocap` stays light and the CLI starts fast.
    if name == "reconstruct":
        from mocap.pipeline import reconstruct

        return reconstruct
    raise AttributeError(f"module 'mocap' has no attribute {name!r}")
