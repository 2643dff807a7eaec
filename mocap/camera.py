"""Camera and rig model; ``calibration.toml`` reading and writing.

Conventions (anipose / Pose2Sim, see DESIGN.md):

* ``rotation`` is a Rodrigues vector and ``translation`` a vector in metres, both
  mapping world to camera: ``X_cam = R @ X_world + t`` (a 3x3 rotation matrix is read too, and written
  back as a vector).
* ``matrix`` is the 3x3 intrinsic matrix K in pixels, ``distortions`` the OpenCV
  coefficients ``(k1, k2, p1, p2[, k3])`` (or ``(k1, k2, k3, k4)`` when ``fisheye``).
* ``size`` is ``(width, height)`` in pixels.
* The world frame is z-up, in metres.

Pixel coordinates are *distorted* (as seen in the image) unless a name says
``ideal``: ideal pixels are where a distortion-free pinhole camera with the same K
would see the point. Epipolar geometry and triangulation work in ideal pixels.
"""

from __future__ import annotations

import functools
import math
import os
import tomllib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import tomli_w

from mocap import kernels
from mocap.atomic import atomic_write_bytes
from mocap.errors import MocapError

__all__ = ["Camera", "Lenses", "Rig", "load_rig", "parse_rig", "save_rig", "rig_to_toml"]


# OpenCV's iterative undistortion: up to 30 steps, until a step moves less than 1e-10 (normalised units).
_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-10)


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def _rodrigues_to_matrix(rvec: np.ndarray) -> np.ndarray:
    """(3,) Rodrigues vector -> (3, 3) rotation matrix."""
    return cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    Attributes:
        name: camera name; also the stem of its recording in a take.
        size: (width, height) in pixels.
        matrix: (3, 3) intrinsic matrix K, pixels.
        distortions: (4,) or (5,) OpenCV distortion coefficients.
        rotation: (3,) Rodrigues vector, world -> camera.
        translation: (3,) world -> camera translation, metres.
        fisheye: use OpenCV's fisheye model instead of the standard one.
    """

    name: str
    size: tuple[int, int]
    matrix: np.ndarray
    distortions: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray
    fisheye: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "size", (int(self.size[0]), int(self.size[1])))
        for attr, shape in (("matrix", (3, 3)), ("rotation", (3,)), ("translation", (3,))):
            value = np.asarray(getattr(self, attr), dtype=np.float64)
            if value.shape != shape:
                raise ValueError(f"camera {self.name!r}: {attr} must have shape {shape}, got {value.shape}")
            value.setflags(write=False)
            object.__setattr__(self, attr, value)
        dist = np.asarray(self.distortions, dtype=np.float64).ravel()
        if dist.size not in (4, 5, 8):
            raise ValueError(f"camera {self.name!r}: distortions must have 4, 5 or 8 values, got {dist.size}")
        dist.setflags(write=False)
        object.__setattr__(self, "distortions", dist)

    # ----------------------------------------------------------------- poses
    @functools.cached_property
    def R(self) -> np.ndarray:
        """(3, 3) world -> camera rotation matrix (read-only)."""
        return _read_only(_rodrigues_to_matrix(self.rotation))

    @functools.cached_property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates, metres: ``-R^T t`` (read-only)."""
        return _read_only(-self.R.T @ self.translation)

    @functools.cached_property
    def projection_matrix(self) -> np.ndarray:
        """(3, 4) ideal-pixel projection matrix ``K [R | t]`` (read-only)."""
        return _read_only(self.matrix @ np.hstack([self.R, self.translation[:, None]]))

    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points, metres -> (N, 3) camera-frame points, metres."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return points @ self.R.T + self.translation

    def camera_to_world(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) camera-frame points, metres -> (N, 3) world points, metres."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return (points - self.translation) @ self.R

    # ------------------------------------------------------------ projection
    def project(self, points: np.ndarray) -> np.ndarray:
        """Project world points to distorted pixel coordinates.

        Args:
            points: (N, 3) world points, metres.

        Returns:
            (N, 2) pixel coordinates (x right, y down). Points behind the camera
            (depth <= 0) or beyond the lens model's :attr:`fold_radius` come back as NaN.
        """
        xc = self.world_to_camera(points)
        z = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = xc[:, 0] / z
            y = xc[:, 1] / z
        if self.fisheye:
            pts = np.stack([x, y], axis=1)
            xd = _fisheye_distort(pts, self.distortions)
        else:
            xd = _standard_distort(x, y, self.distortions)
        K = self.matrix
        u = K[0, 0] * xd[:, 0] + K[0, 1] * xd[:, 1] + K[0, 2]
        v = K[1, 1] * xd[:, 1] + K[1, 2]
        uv = np.stack([u, v], axis=1)
        uv[~(z > 0) | ~(np.hypot(x, y) < self.fold_radius)] = np.nan
        return uv

    @functools.cached_property
    def fold_radius(self) -> float:
        """Normalised radius (tangent of the angle off the optical axis) up to which the lens model maps rays one to
        one onto the image (inf: everywhere). Beyond it the distortion polynomial turns back, or its radial factor
        turns negative, and would draw points from far outside the field of view inside the image (a walkway
        camera with k1 = 0.038, k2 = -0.009 put a marker 75 degrees off its axis 350 px from the image's left
        edge); :meth:`project` returns NaN there."""
        return _fold_radius(self.distortions, self.fisheye)

    def ideal_to_distorted(self, uv_ideal: np.ndarray) -> np.ndarray:
        """(N, 2) ideal pixels -> (N, 2) distorted pixels (applies the lens model)."""
        uv_ideal = np.asarray(uv_ideal, dtype=np.float64).reshape(-1, 2)
        rays = np.column_stack([uv_ideal, np.ones(len(uv_ideal))]) @ np.linalg.inv(self.matrix).T
        return self.project(self.camera_to_world(rays))

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """Remove lens distortion.

        Args:
            uv: (N, 2) distorted pixel coordinates.

        Returns:
            (N, 2) ideal pixel coordinates (same K, no distortion). NaN rows stay NaN.
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if np.isfinite(uv).all():  # the usual case: no copy in and out of a NaN-filled array
            return self._undistort_finite(uv)
        ok = np.isfinite(uv).all(axis=1)
        out = np.full_like(uv, np.nan)
        if ok.any():
            out[ok] = self._undistort_finite(uv[ok])
        return out

    @functools.cached_property
    def _distorted(self) -> bool:
        """The lens model is not the identity (some distortion coefficient is non-zero)."""
        return bool(self.distortions.any())

    @functools.cached_property
    def _lens(self) -> Lenses:
        """This camera's lens for the compiled undistortion."""
        return Lenses([self])

    def _undistort_finite(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) finite distorted pixels -> (N, 2) ideal pixels."""
        if len(uv) == 0 or not (self.fisheye or self._distorted):
            return uv.copy()
        if kernels.HAVE_NUMBA and not self.fisheye:
            return self._lens.undistort([uv])
        src = uv.reshape(-1, 1, 2)
        if self.fisheye:
            und = cv2.fisheye.undistortPoints(src, self.matrix, self.distortions[:4], P=self.matrix)
        else:
            und = cv2.undistortPoints(src, self.matrix, self.distortions, None, None, self.matrix, _UNDISTORT_CRITERIA)
        return und.reshape(-1, 2)

    def projection_jacobian(self, points: np.ndarray, step: float = 1e-6) -> np.ndarray:
        """Jacobian of :meth:`project` with respect to the world point.

        Central differences of the full (distorted) model; accurate to ~1e-6 relative.

        Args:
            points: (N, 3) world points, metres.
            step: finite-difference step, metres.

        Returns:
            (N, 2, 3) d(pixel)/d(world), pixels per metre.
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        jac = np.empty((len(points), 2, 3))
        for axis in range(3):
            delta = np.zeros(3)
            delta[axis] = step
            jac[:, :, axis] = (self.project(points + delta) - self.project(points - delta)) / (2 * step)
        return jac

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N, 2) pixels -> (N,) bool: inside the image, ``margin`` pixels from the border."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        w, h = self.size
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= margin - 0.5)
                & (uv[:, 0] <= w - 0.5 - margin)
                & (uv[:, 1] >= margin - 0.5)
                & (uv[:, 1] <= h - 0.5 - margin)
            )

    def with_pose(self, rotation: np.ndarray, translation: np.ndarray) -> Camera:
        """A copy of this camera at another pose."""
        return Camera(self.name, self.size, self.matrix, self.distortions, rotation, translation, self.fisheye)

    # ---------------------------------------------------------------- toml
    def to_table(self) -> dict[str, Any]:
        """This camera as a ``calibration.toml`` table (plain Python types)."""
        return {
            "name": self.name,
            "size": [int(self.size[0]), int(self.size[1])],
            "matrix": self.matrix.tolist(),
            "distortions": self.distortions.tolist(),
            "rotation": self.rotation.tolist(),
            "translation": self.translation.tolist(),
            "fisheye": bool(self.fisheye),
        }


def _standard_radial(r2: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """The standard model's radial factor at squared normalised radii ``r2`` (N,)."""
    d = np.zeros(8)
    d[: dist.size] = dist
    k1, k2, _, _, k3, k4, k5, k6 = d
    return (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))


def _standard_distort(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's standard (Brown-Conrady) model on normalised coordinates; (N,) x, y -> (N, 2)."""
    p1, p2 = dist[2], dist[3]
    r2 = x * x + y * y
    radial = _standard_radial(r2, dist)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=1)


def _fisheye_angle(r: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """The fisheye model's distorted angle theta_d at normalised radii ``r`` (N,)."""
    k = np.zeros(4)
    k[: min(4, dist.size)] = dist[:4]
    theta = np.arctan(r)
    t2 = theta * theta
    return theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))


def _fisheye_distort(xy: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """OpenCV's fisheye (equidistant) model on normalised coordinates; (N, 2) -> (N, 2)."""
    r = np.hypot(xy[:, 0], xy[:, 1])
    theta_d = _fisheye_angle(r, dist)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(r > 1e-12, theta_d / r, 1.0)
    return xy * scale[:, None]


_FOLD_RADII = np.linspace(0.0, 20.0, 20001)  # normalised radii searched for a fold (up to 87 degrees off axis)


def _fold_radius(dist: np.ndarray, fisheye: bool) -> float:
    """The smallest normalised radius where the radial part of the lens model stops increasing (or the standard
    model's radial factor stops being positive); inf if it never does up to 87 degrees off axis."""
    r = _FOLD_RADII
    if fisheye:
        bad = np.diff(_fisheye_angle(r, dist)) <= 0
    else:
        radial = _standard_radial(r * r, dist)
        bad = (np.diff(r * radial) <= 0) | (radial[1:] <= 0)
    first = np.flatnonzero(bad)
    return float(r[first[0]]) if first.size else math.inf


# --------------------------------------------------------------------- rig
class Lenses:
    """The lenses of several cameras as arrays, to undistort the blobs of all of them in one call (the compiled
    kernel :func:`mocap.kernels.undistort_points`, OpenCV's steps; per camera with OpenCV without numba or with a
    fisheye lens)."""

    def __init__(self, cameras: list[Camera]) -> None:
        self._cameras = list(cameras)
        self._matrices = np.stack([c.matrix for c in self._cameras]) if self._cameras else np.zeros((0, 3, 3))
        self._coefficients = np.zeros((len(self._cameras), 8))
        for row, cam in zip(self._coefficients, self._cameras, strict=True):
            row[: cam.distortions.size] = cam.distortions
        self._distorted = np.array([c._distorted for c in self._cameras], dtype=bool)
        self._standard = not any(c.fisheye for c in self._cameras)

    @property
    def compiled(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, float] | None:
        """The lens arguments of :func:`mocap.kernels.undistort_points` (matrices (C, 3, 3), coefficients (C, 8),
        distorted (C,), step count, tolerance px), or None where the kernel does not serve (numba off, a fisheye)."""
        if not (kernels.HAVE_NUMBA and self._standard):
            return None
        return self._matrices, self._coefficients, self._distorted, _UNDISTORT_CRITERIA[1], _UNDISTORT_CRITERIA[2]

    def undistort(self, uv: list[np.ndarray]) -> np.ndarray:
        """(sum N_c, 2) ideal px of the (N_c, 2) distorted px ``uv`` of each camera, one after another."""
        lenses = self.compiled
        if lenses is None:
            return np.concatenate([cam.undistort(p) for cam, p in zip(self._cameras, uv, strict=True)])
        points = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in uv])
        camera = np.repeat(np.arange(len(uv)), [len(p) for p in uv])
        return kernels.undistort_points(points, camera, *lenses)


@dataclass(eq=False)
class Rig:
    """A calibrated set of cameras sharing one world frame.

    Attributes:
        cameras: the cameras, in file order.
        metadata: the free-form ``[metadata]`` table.
        extra_tables: other top-level tables this reader does not interpret (for
            example pairwise fundamental matrices written by the calibration
            utility). They are kept and written back unchanged.
    """

    cameras: list[Camera]
    metadata: dict[str, Any] = field(default_factory=dict)
    extra_tables: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        names = [c.name for c in self.cameras]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise MocapError(f"calibration: camera name(s) {dupes} appear more than once; names must be unique")

    def __len__(self) -> int:
        return len(self.cameras)

    def __iter__(self) -> Iterator[Camera]:
        return iter(self.cameras)

    def __getitem__(self, index: int) -> Camera:
        return self.cameras[index]

    @property
    def names(self) -> list[str]:
        """Camera names in order."""
        return [c.name for c in self.cameras]

    def index(self, name: str) -> int:
        """Position of the camera called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise MocapError(f"no camera named {name!r} in the calibration (cameras: {self.names})") from None

    def project(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points, metres -> (C, N, 2) distorted pixels per camera."""
        return np.stack([c.project(points) for c in self.cameras])

    def projection_matrices(self) -> np.ndarray:
        """(C, 3, 4) ideal-pixel projection matrices."""
        return np.stack([c.projection_matrix for c in self.cameras])

    def centers(self) -> np.ndarray:
        """(C, 3) camera centres, metres."""
        return np.stack([c.center for c in self.cameras])


_CAMERA_FIELDS = ("name", "size", "matrix", "distortions", "rotation", "translation")


def _camera_from_table(key: str, table: dict[str, Any], source: str) -> Camera:
    where = f"{source}: table [{key}]"
    missing = [f for f in _CAMERA_FIELDS if f not in table]
    if missing:
        raise MocapError(f"{where} is missing field(s) {missing}; every camera table needs {list(_CAMERA_FIELDS)}")

    def array(field_name: str, shape: tuple[int, ...] | None = None, sizes: tuple[int, ...] = ()) -> np.ndarray:
        try:
            value = np.asarray(table[field_name], dtype=np.float64)
        except (TypeError, ValueError):
            raise MocapError(f"{where}: field '{field_name}' must be numbers, got {table[field_name]!r}") from None
        if shape is not None and value.shape != shape:
            raise MocapError(
                f"{where}: field '{field_name}' must have shape {list(shape)}, got {list(value.shape)}"
            )
        if sizes and (value.ndim != 1 or value.size not in sizes):
            raise MocapError(f"{where}: field '{field_name}' must hold {' or '.join(map(str, sizes))} numbers")
        if not np.isfinite(value).all():
            raise MocapError(f"{where}: field '{field_name}' contains NaN or infinity")
        return value

    size = array("size", (2,))
    if (size <= 0).any() or (size != np.round(size)).any():
        raise MocapError(f"{where}: field 'size' must be two positive whole numbers [width, height]")
    matrix = array("matrix", (3, 3))
    if matrix[0, 0] <= 0 or matrix[1, 1] <= 0:
        raise MocapError(f"{where}: field 'matrix' must have positive focal lengths fx, fy")
    fisheye = table.get("fisheye", False)
    if not isinstance(fisheye, bool):
        raise MocapError(f"{where}: field 'fisheye' must be true or false")
    name = table["name"]
    if not isinstance(name, str) or not name or any(ch in name for ch in "/\\"):
        raise MocapError(f"{where}: field 'name' must be a non-empty string without slashes")
    return Camera(
        name=name,
        size=(int(size[0]), int(size[1])),
        matrix=matrix,
        distortions=array("distortions", sizes=(4, 5, 8)),
        rotation=_rotation_vector(array("rotation"), where),
        translation=array("translation", (3,)),
        fisheye=fisheye,
    )


def _rotation_vector(value: np.ndarray, where: str) -> np.ndarray:
    """A calibration's ``rotation``: the (3,) Rodrigues vector, or a (3, 3) rotation matrix (converted)."""
    if value.shape == (3,):
        return value
    if value.shape == (3, 3):
        if np.abs(value @ value.T - np.eye(3)).max() > 1e-6 or np.linalg.det(value) < 0:
            raise MocapError(f"{where}: field 'rotation' is a 3x3 matrix but not a rotation (orthonormal, det +1)")
        return cv2.Rodrigues(value)[0].ravel()
    raise MocapError(f"{where}: field 'rotation' must be a Rodrigues vector [rx, ry, rz] (or a 3x3 rotation matrix), "
                     f"got shape {list(value.shape)}")


def load_rig(path: str | os.PathLike) -> Rig:
    """Read a ``calibration.toml`` (see :func:`parse_rig` for what it holds).

    Raises:
        MocapError: missing or unreadable file, or any problem :func:`parse_rig` reports.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise MocapError(
            f"{path}: calibration file not found; run 'mocap calibrate' or copy one into the take"
        ) from None
    except UnicodeDecodeError:
        raise MocapError(f"{path}: not a text file; calibration.toml must be UTF-8 TOML") from None
    except OSError as exc:
        raise MocapError(f"{path}: cannot read the calibration file ({exc.strerror})") from None
    return parse_rig(text, str(path))


def parse_rig(text: str, where: str = "calibration") -> Rig:
    """Parse ``calibration.toml`` text.

    Camera tables are the top-level tables holding the camera fields (their keys are
    conventionally ``cam_1``, ``cam_2`` ...); ``[metadata]`` is kept as-is, and any other
    table is kept in :attr:`Rig.extra_tables` and otherwise ignored.

    Args:
        text: the TOML text.
        where: the file name (or other origin) to name in error messages.

    Raises:
        MocapError: TOML syntax error or a malformed camera table; the message names
            ``where``, the table and the field.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise MocapError(f"{where}: not valid TOML ({exc}); fix the syntax or re-export the calibration") from None
    cameras: list[Camera] = []
    metadata: dict[str, Any] = {}
    extra: dict[str, Any] = {}
    for key, value in data.items():
        if key == "metadata" and isinstance(value, dict):
            metadata = value
        elif isinstance(value, dict) and ("matrix" in value or key.startswith("cam")):
            cameras.append(_camera_from_table(key, value, where))
        else:
            extra[key] = value
    if not cameras:
        raise MocapError(f"{where}: no camera tables found; expected tables like [cam_1] with {list(_CAMERA_FIELDS)}")
    return Rig(cameras, metadata, extra)


def rig_to_toml(rig: Rig) -> str:
    """The ``calibration.toml`` text of a rig (cameras as ``cam_1``..., then metadata, then extras)."""
    doc: dict[str, Any] = {f"cam_{i + 1}": cam.to_table() for i, cam in enumerate(rig.cameras)}
    for key, value in rig.extra_tables.items():
        doc[key] = value
    doc["metadata"] = dict(rig.metadata)
    return tomli_w.dumps(_plain(doc))


def _plain(value: Any) -> Any:
    """Convert numpy scalars/arrays inside nested containers to plain Python for TOML."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def save_rig(rig: Rig, path: str | os.PathLike) -> None:
    """Write ``rig`` to ``path`` atomically (temp file + rename); exact float round trip."""
    atomic_write_bytes(Path(path), rig_to_toml(rig).encode("utf-8"))
