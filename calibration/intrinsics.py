"""Intrinsics of one camera from board images or a video: K, distortion, per-image errors.

Steps: read the images (a folder, a list of files or a video, sampled) -> find the board in
each (:meth:`calibration.boards.Board.detect`) -> if there are more views than needed, pick a
subset that covers the image and the range of board tilts -> ``cv2.calibrateCameraExtended``
-> drop views whose RMS reprojection error is far above the others (a blurred or misdetected
board) and solve again.
"""

from __future__ import annotations

import logging
import os
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calibration.boards import Board, BoardView
from mocap.camera import Camera
from mocap.errors import MocapError

__all__ = [
    "IMAGE_SUFFIXES",
    "IntrinsicsResult",
    "read_images",
    "find_views",
    "select_views",
    "calibrate_intrinsics",
]

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm")
VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov")
MIN_VIEWS = 4
CORNER_OUTLIER_FACTOR = 5.0  # a corner further than this many RMS errors from its projection is dropped
CORNER_OUTLIER_FLOOR_PX = 1.0
COVERAGE_GRID = (8, 6)


def _natural_key(path: Path) -> list[object]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def read_images(source: str | os.PathLike | Sequence[str | os.PathLike], every: int = 1
                ) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(name, grey image)`` from a folder of images, a list of image files, or a video.

    Args:
        source: a folder (its image files, natural order), a video file, or a list of image files.
        every: keep one frame in ``every`` (videos only).

    Raises:
        MocapError: missing or unreadable files, an empty folder, or images of different sizes.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if path.is_dir():
            files = sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES), key=_natural_key)
            if not files:
                raise MocapError(f"{path}: no images ({', '.join(IMAGE_SUFFIXES)}) in this folder")
        elif path.suffix.lower() in VIDEO_SUFFIXES:
            yield from _read_video(path, every)
            return
        else:
            files = [path]
    else:
        files = [Path(p) for p in source]
    first: tuple[Path, tuple[int, int]] | None = None
    for file in files:
        image = cv2.imread(str(file), cv2.IMREAD_GRAYSCALE)
        if image is None:
            what = "not found" if not file.exists() else "not an image OpenCV can read"
            raise MocapError(f"{file}: {what}; remove it from the list or convert it to PNG")
        size = (image.shape[1], image.shape[0])
        if first is None:
            first = (file, size)
        elif size != first[1]:
            raise MocapError(
                f"{file}: image size {size[0]}x{size[1]} differs from {first[0].name} ({first[1][0]}x{first[1][1]}); "
                "a folder must hold images of one camera at one resolution: move the others out"
            )
        yield file.name, image


def _read_video(path: Path, every: int) -> Iterator[tuple[str, np.ndarray]]:
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise MocapError(f"{path}: cannot open this video; check the file or export the frames as PNG")
    try:
        index = 0
        while True:
            ok, frame = capture.read()
            if not ok:
                break
            if index % every == 0:
                yield f"{path.name}#{index}", frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            index += 1
    finally:
        capture.release()
    if index == 0:
        raise MocapError(f"{path}: no frames could be decoded; check the file or export the frames as PNG")


def find_views(images: Iterator[tuple[str, np.ndarray]], board: Board, where: str = "images"
               ) -> tuple[list[BoardView], list[str], tuple[int, int]]:
    """Detect the board in every image.

    Returns:
        ``(views, names of images without the board, (width, height))``.

    Raises:
        MocapError: no images, or the board found in none of them.
    """
    views: list[BoardView] = []
    missed: list[str] = []
    size: tuple[int, int] | None = None
    for name, image in images:
        size = (image.shape[1], image.shape[0])
        view = board.detect(image, name)
        if view is None:
            missed.append(name)
        else:
            views.append(view)
    if size is None:
        raise MocapError(f"{where}: no images to calibrate from")
    if not views:
        raise MocapError(
            f"{where}: the board {board.describe()} was found in none of the {len(missed)} images; check the "
            "--board size (checkerboards count INNER corners, cols x rows) and that the board is sharp and whole"
        )
    if missed:
        log.warning("%s: no board in %d of %d images: %s", where, len(missed), len(missed) + len(views),
                    ", ".join(missed[:10]) + (" ..." if len(missed) > 10 else ""))
    return views, missed, size


def _tilt_bin(view: BoardView, board: Board) -> int:
    """Coarse board orientation (3 x 3 bins of the board normal's two tilt angles), from a rough K."""
    w, h = view.size
    f = float(max(w, h))
    K = np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]])
    H, _ = cv2.findHomography(board.object_points()[view.ids, :2], view.xy)
    if H is None:
        return 4
    B = np.linalg.inv(K) @ H
    r1 = B[:, 0] / np.linalg.norm(B[:, 0])
    r2 = B[:, 1] / np.linalg.norm(B[:, 1])
    n = np.cross(r1, r2)
    n = n if n[2] < 0 else -n  # facing the camera
    tx = np.degrees(np.arctan2(n[0], -n[2]))
    ty = np.degrees(np.arctan2(n[1], -n[2]))
    return int(np.digitize(tx, [-15, 15]) * 3 + np.digitize(ty, [-15, 15]))


def select_views(views: list[BoardView], board: Board, max_views: int = 40) -> list[BoardView]:
    """Choose at most ``max_views`` views that together cover the image and the board tilts.

    Greedy: repeatedly take the view adding the most new image cells (an 8 x 6 grid) plus new
    tilt bins (weighted 4 cells each); when nothing new is left, fill up in even steps.
    """
    if len(views) <= max_views:
        return list(views)
    gx, gy = COVERAGE_GRID
    cells = np.zeros((len(views), gx * gy), dtype=bool)
    for i, v in enumerate(views):
        cx = np.clip((v.xy[:, 0] / v.size[0] * gx).astype(int), 0, gx - 1)
        cy = np.clip((v.xy[:, 1] / v.size[1] * gy).astype(int), 0, gy - 1)
        cells[i, cy * gx + cx] = True
    tilts = np.zeros((len(views), 9), dtype=bool)
    tilts[np.arange(len(views)), [_tilt_bin(v, board) for v in views]] = True
    chosen: list[int] = []
    have_cells = np.zeros(gx * gy, dtype=bool)
    have_tilts = np.zeros(9, dtype=bool)
    while len(chosen) < max_views:
        gain = (cells & ~have_cells).sum(axis=1) + 4 * (tilts & ~have_tilts).sum(axis=1)
        gain[chosen] = -1
        best = int(np.argmax(gain))
        if gain[best] <= 0:
            break
        chosen.append(best)
        have_cells |= cells[best]
        have_tilts |= tilts[best]
    rest = [i for i in range(len(views)) if i not in chosen]
    take = max_views - len(chosen)
    if take > 0 and rest:
        chosen += [rest[int(k)] for k in np.linspace(0, len(rest) - 1, min(take, len(rest)))]
    return [views[i] for i in sorted(set(chosen))]


@dataclass
class IntrinsicsResult:
    """One camera's intrinsics and how well they fit.

    Attributes:
        matrix: (3, 3) K, pixels.
        distortions: (5,) OpenCV ``k1, k2, p1, p2, k3``.
        size: (width, height), pixels.
        rms_px: overall RMS reprojection error of the kept views, pixels.
        view_errors: image name -> RMS reprojection error of that view, pixels (kept views).
        rejected: image name -> RMS error of views dropped as outliers.
        no_board: images in which the board was not found.
        std_focal_px: standard deviation of fx estimated by OpenCV, pixels.
        rvecs, tvecs: (V, 3) board poses of the kept views (board -> camera), in ``view_errors`` order.
    """

    matrix: np.ndarray
    distortions: np.ndarray
    size: tuple[int, int]
    rms_px: float
    view_errors: dict[str, float]
    rejected: dict[str, float] = field(default_factory=dict)
    no_board: list[str] = field(default_factory=list)
    std_focal_px: float = float("nan")
    rvecs: np.ndarray | None = None
    tvecs: np.ndarray | None = None

    def camera(self, name: str) -> Camera:
        """A :class:`mocap.camera.Camera` with these intrinsics and an identity pose (pose unknown)."""
        return Camera(name, self.size, self.matrix, self.distortions, np.zeros(3), np.zeros(3))


def _calibrate(views: list[BoardView], board: Board, size: tuple[int, int], flags: int
               ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    obj = board.object_points().astype(np.float32)
    object_points = [obj[v.ids] for v in views]
    image_points = [v.xy.astype(np.float32).reshape(-1, 1, 2) for v in views]
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-9)
    rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
        object_points, image_points, size, None, None, flags=flags, criteria=criteria
    )
    return (rms, K, dist.ravel()[:5], np.asarray(rvecs).reshape(-1, 3), np.asarray(tvecs).reshape(-1, 3),
            std_in.ravel(), per_view.ravel())


def calibrate_intrinsics(
    views: list[BoardView],
    board: Board,
    size: tuple[int, int],
    *,
    max_views: int = 40,
    reject_factor: float = 3.0,
    reject_floor_px: float = 0.5,
    flags: int = 0,
    where: str = "images",
) -> IntrinsicsResult:
    """Calibrate one camera from its board views.

    A view is rejected when its RMS error exceeds ``max(reject_factor * median, reject_floor_px)``;
    the solve is repeated (at most three rounds) until no view is rejected.

    Args:
        views: board views of one camera (all the same image size).
        board: the board.
        size: (width, height) of the images.
        max_views: views used at most (chosen by :func:`select_views`).
        reject_factor, reject_floor_px: the outlier rule above.
        flags: extra ``cv2.CALIB_*`` flags (e.g. ``CALIB_FIX_K3``).
        where: what to name in error messages.

    Raises:
        MocapError: fewer than 4 usable views.
    """
    used = select_views(views, board, max_views)
    if len(used) < MIN_VIEWS:
        raise MocapError(
            f"{where}: the board was found in only {len(used)} image(s); at least {MIN_VIEWS} views at different "
            "angles are needed (about 15-30 recommended, covering the whole image)"
        )
    rejected: dict[str, float] = {}
    dropped_corners = 0
    for _ in range(3):
        rms, K, dist, rvecs, tvecs, std_in, per_view = _calibrate(used, board, size, flags)
        # Single misdetected corners first (a corner pulled by a nearby edge), then whole views.
        corner_limit = max(CORNER_OUTLIER_FACTOR * rms, CORNER_OUTLIER_FLOOR_PX)
        trimmed = []
        for v, rvec, tvec in zip(used, rvecs, tvecs, strict=True):
            proj = cv2.projectPoints(board.object_points()[v.ids], rvec, tvec, K, dist)[0].reshape(-1, 2)
            good = np.linalg.norm(proj - v.xy, axis=1) <= corner_limit
            trimmed.append(v if good.all() else BoardView(v.name, v.xy[good], v.ids[good], v.size))
            dropped_corners += int((~good).sum())
        limit = max(reject_factor * float(np.median(per_view)), reject_floor_px)
        bad = per_view > limit
        changed = any(t is not v for t, v in zip(trimmed, used, strict=True))
        if len(used) - bad.sum() < MIN_VIEWS:
            break
        rejected.update({v.name: float(e) for v, e, b in zip(used, per_view, bad, strict=True) if b})
        used = [t for t, b in zip(trimmed, bad, strict=True) if not b and len(t.ids) >= 6]
        if not bad.any() and not changed:
            break
    if dropped_corners:
        log.info("%s: %d misdetected corner(s) dropped", where, dropped_corners)
    if rejected:
        log.warning("%s: %d view(s) rejected for a high reprojection error: %s", where, len(rejected),
                    ", ".join(f"{k} ({v:.2f} px)" for k, v in rejected.items()))
    return IntrinsicsResult(
        matrix=K,
        distortions=dist,
        size=size,
        rms_px=float(rms),
        view_errors={v.name: float(e) for v, e in zip(used, per_view, strict=True)},
        rejected=rejected,
        std_focal_px=float(std_in[0]),
        rvecs=rvecs,
        tvecs=tvecs,
    )
