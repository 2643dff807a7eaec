"""Synthetic calibration-board images with known truth, through a camera's full lens model.

Each image is rendered by inverse mapping: every output pixel is sampled ``supersample`` x
``supersample`` times; each sample's viewing ray (the pixel undistorted by the camera's lens
model, :meth:`mocap.camera.Camera.undistort`) is intersected with the board plane through the
inverse of the board's homography ``H = K [r1 r2 t]`` (in normalised coordinates), and the board's
texture (a checkerboard, or OpenCV's ChArUco image) is read there with bilinear interpolation;
the samples are averaged (area anti-aliasing). Then a Gaussian optical blur, sensor noise and
8-bit rounding. The true corner positions are the board corners projected by
:meth:`mocap.camera.Camera.project`, so a calibration can be scored against the camera's K and
distortion exactly.

The board is a ``mocap``-side description (kind, size, square, marker, dictionary), so that the
engine does not depend on the calibration package; ``calibration.boards.Board`` reads the same.
"""

from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from mocap.camera import Camera, Rig, rig_to_toml
from mocap.synth.rig import ring_rig
from mocap.synth.settings import SynthSettings
from mocap.synth.writer import default_truth_path, staged_directory
from mocap.truth import Truth, save_truth

__all__ = ["BoardSpec", "DEFAULT_BOARD", "board_texture", "board_poses", "render_board", "render_board_take"]

_TEXTURE_PX = 48  # texture pixels per square
_BLACK, _WHITE, _AMBIENT = 25.0, 215.0, 70.0


@dataclass(frozen=True)
class BoardSpec:
    """A planar board (same fields as ``calibration.boards.Board``).

    Attributes:
        kind: ``"checker"`` (``cols x rows`` inner corners) or ``"charuco"`` (``cols x rows`` squares).
        cols, rows: see ``kind``.
        square: square side, m.
        marker: ArUco marker side, m (charuco).
        dictionary: OpenCV ArUco dictionary name (charuco).
    """

    kind: str = "checker"
    cols: int = 9
    rows: int = 6
    square: float = 0.06
    marker: float = 0.045
    dictionary: str = "DICT_5X5_100"

    def corners(self) -> np.ndarray:
        """(N, 3) inner-corner positions on the board (z = 0), m, in OpenCV's corner-id order."""
        if self.kind == "charuco":
            nx, ny = self.cols - 1, self.rows - 1
            grid = (np.mgrid[0:nx, 0:ny].T.reshape(-1, 2) + 1) * self.square
        else:
            grid = np.mgrid[0 : self.cols, 0 : self.rows].T.reshape(-1, 2) * self.square
        return np.column_stack([grid, np.zeros(len(grid))])

    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Board rectangle (white margin included), m: lower and upper (x, y) corners."""
        if self.kind == "charuco":
            return np.array([-0.5, -0.5]) * self.square, np.array([self.cols + 0.5, self.rows + 0.5]) * self.square
        return np.array([-1.5, -1.5]) * self.square, np.array([self.cols + 0.5, self.rows + 0.5]) * self.square


DEFAULT_BOARD = BoardSpec()


@functools.lru_cache(maxsize=4)
def board_texture(spec: BoardSpec) -> tuple[np.ndarray, np.ndarray]:
    """The board's printed pattern as a float image, and the board (x, y) (m) of texture pixel (0, 0)'s corner.

    Returns:
        ``(texture (h, w) float32 in [0, 1], origin (2,) m)``; texture pixel (i, j) covers board
        ``origin + ([j, i] .. [j + 1, i + 1]) * square / 48``.
    """
    lo, hi = spec.extent()
    size = np.round((hi - lo) / spec.square * _TEXTURE_PX).astype(int)
    if spec.kind == "charuco":
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
        board = cv2.aruco.CharucoBoard((spec.cols, spec.rows), spec.square, spec.marker, dictionary)
        margin = _TEXTURE_PX // 2
        img = board.generateImage((int(size[0]), int(size[1])), marginSize=margin)
        tex = img.astype(np.float32) / 255.0
    else:
        # Board position of each texture pixel's centre, in squares; inner corner (0, 0) is at 0.
        y, x = (np.indices((int(size[1]), int(size[0]))) + 0.5) / _TEXTURE_PX + (lo[::-1] / spec.square)[:, None, None]
        inside = (x >= -1) & (x < spec.cols) & (y >= -1) & (y < spec.rows)
        black = (np.floor(x) + np.floor(y)) % 2 == 0
        tex = np.where(inside & black, 0.0, 1.0).astype(np.float32)
    tex.setflags(write=False)
    return tex, lo


@functools.lru_cache(maxsize=8)
def _rays(camera: Camera, supersample: int) -> np.ndarray:
    """(H*s, W*s, 2) normalised undistorted coordinates of the camera's sub-pixel samples."""
    w, h = camera.size
    s = supersample
    xs = (np.arange(w * s) + 0.5) / s - 0.5
    ys = (np.arange(h * s) + 0.5) / s - 0.5
    grid = np.stack(np.meshgrid(xs, ys), axis=-1).reshape(-1, 2)
    ideal = camera.undistort(grid)
    Kinv = np.linalg.inv(camera.matrix)
    return (ideal @ Kinv[:2, :2].T + Kinv[:2, 2]).reshape(h * s, w * s, 2).astype(np.float32)


def render_board(camera: Camera, spec: BoardSpec, rvec: np.ndarray, tvec: np.ndarray, rng: np.random.Generator,
                 settings: SynthSettings | None = None, supersample: int = 3) -> np.ndarray:
    """(H, W) uint8 image of the board at pose ``(rvec, tvec)`` (board -> camera) seen by ``camera``."""
    settings = settings or SynthSettings()
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    Hinv = np.linalg.inv(np.column_stack([R[:, 0], R[:, 1], np.asarray(tvec, dtype=np.float64)]))
    rays = _rays(camera, supersample)
    q = rays @ Hinv[:, :2].T.astype(np.float32) + Hinv[:, 2].astype(np.float32)
    with np.errstate(divide="ignore", invalid="ignore"):
        bx, by = q[..., 0] / q[..., 2], q[..., 1] / q[..., 2]
    tex, origin = board_texture(spec)
    scale = _TEXTURE_PX / spec.square
    map_x = np.where(q[..., 2] > 0, (bx - origin[0]) * scale - 0.5, -1e6).astype(np.float32)
    map_y = np.where(q[..., 2] > 0, (by - origin[1]) * scale - 0.5, -1e6).astype(np.float32)
    board = cv2.remap(tex, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    level = np.where(board < 0, _AMBIENT, _BLACK + (_WHITE - _BLACK) * np.clip(board, 0, 1)).astype(np.float32)
    w, h = camera.size
    image = cv2.resize(level, (w, h), interpolation=cv2.INTER_AREA)
    image = cv2.GaussianBlur(image, (0, 0), settings.blur_px)
    image = image + settings.noise * rng.standard_normal(image.shape).astype(np.float32)
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)


def board_poses(camera: Camera, spec: BoardSpec, n_views: int, rng: np.random.Generator, max_tilt_deg: float = 45.0,
                fill: tuple[float, float] = (0.3, 0.6), margin_px: float = 12.0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Random board poses (board -> camera) spread over the image, the whole board inside it.

    The board's centre goes to a random image point, at a distance where it spans ``fill`` of the
    image width, tilted up to ``max_tilt_deg`` about both board axes and turned freely in plane.
    """
    corners = spec.corners()
    centre = corners.mean(axis=0)
    lo, hi = spec.extent()
    outline = np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]])
    width = hi[0] - lo[0]
    w, h = camera.size
    f = camera.matrix[0, 0]
    poses: list[tuple[np.ndarray, np.ndarray]] = []
    while len(poses) < n_views:
        tilt = np.deg2rad(rng.uniform(-max_tilt_deg, max_tilt_deg, 2))
        roll = rng.uniform(-np.pi / 6, np.pi / 6) + (np.pi if rng.random() < 0.5 else 0.0)
        R = cv2.Rodrigues(np.array([tilt[0], 0, 0]))[0] @ cv2.Rodrigues(np.array([0, tilt[1], 0]))[0] @ \
            cv2.Rodrigues(np.array([0, 0, roll]))[0]
        depth = f * width / (rng.uniform(*fill) * w)
        target = np.array([rng.uniform(0.2, 0.8) * w, rng.uniform(0.2, 0.8) * h])
        ray = np.linalg.solve(camera.matrix, np.array([target[0], target[1], 1.0]))
        t = ray * depth - R @ centre
        rvec = cv2.Rodrigues(R)[0].ravel()
        cam = camera.with_pose(rvec, t)
        uv = cam.project(outline)
        if np.isfinite(uv).all() and cam.in_image(uv, margin_px).all():
            poses.append((rvec, t))
    return poses


def render_board_take(out_dir: str | os.PathLike, rig: Rig | None = None, settings: SynthSettings | None = None,
                      n_frames: int = 20, truth_path: str | os.PathLike | None = None, progress: bool = True,
                      force: bool = False, spec: BoardSpec = DEFAULT_BOARD) -> Truth:
    """Render a board waved in front of each camera in turn: ``out_dir/<camera>/NNNNNN.png``.

    Camera c's views are frames ``c * n_frames ... (c + 1) * n_frames - 1`` of the session; each
    folder holds only its own camera's frames (named by session frame). ``out_dir/board.txt`` says
    which board it is (the ``--board`` argument of ``mocap calibrate intrinsics``).

    Truth (``truth_path``, default ``<out_dir>.truth.npz``): labels = corner ids, positions (F, N, 3)
    = the corners in the world, uv / visible = their true pixels in the camera that filmed each frame
    (NaN / False in the others), ``settings["calibration_toml"]`` = the true rig.

    Args:
        out_dir: folder to create.
        rig: the cameras (default: the six-camera ``ring_rig``).
        settings: noise and blur (``noise``, ``blur_px``, ``seed``).
        n_frames: views per camera.
        truth_path: where the truth goes.
        progress: show a progress bar.
        force: replace an existing non-empty ``out_dir``.
        spec: the board.
    """
    settings = settings or SynthSettings()
    rig = rig if rig is not None else ring_rig(seed=settings.seed)
    truth_path = Path(truth_path) if truth_path is not None else default_truth_path(out_dir)
    rng = np.random.default_rng(settings.seed)
    corners = spec.corners()
    C, V, N = len(rig), n_frames, len(corners)
    positions = np.full((C * V, N, 3), np.nan)
    uv = np.full((C * V, C, N, 2), np.nan)
    with staged_directory(out_dir, force) as folder:
        bar = tqdm(total=C * V, desc="rendering boards", unit="image", disable=None if progress else True)
        for c, cam in enumerate(rig):
            (folder / cam.name).mkdir()
            for v, (rvec, tvec) in enumerate(board_poses(cam, spec, V, rng)):
                frame = c * V + v
                on_cam = cam.with_pose(rvec, tvec)
                positions[frame] = cam.camera_to_world(on_cam.world_to_camera(corners))
                uv[frame, c] = on_cam.project(corners)
                image = render_board(cam, spec, rvec, tvec, rng, settings)
                cv2.imwrite(str(folder / cam.name / f"{frame:06d}.png"), image)
                bar.update(1)
        bar.close()
        describe = (f"checker:{spec.cols}x{spec.rows}:{spec.square:g}" if spec.kind == "checker" else
                    f"charuco:{spec.cols}x{spec.rows}:{spec.square:g}:{spec.marker:g}:{spec.dictionary}")
        (folder / "board.txt").write_text(describe + "\n", encoding="utf-8")
    truth = Truth([f"corner{k}" for k in range(N)], 1.0, positions, rig.names, uv, np.isfinite(uv[..., 0]),
                  np.full(uv.shape[:3], np.nan), {**settings.to_dict(), "board": describe,
                                                   "calibration_toml": rig_to_toml(rig)})
    save_truth(truth, truth_path)
    return truth
