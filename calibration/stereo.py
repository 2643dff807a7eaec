"""A two-camera rig from stereo board images (left/right pairs taken at the same instants).

Each camera's intrinsics come from its own views (:func:`calibration.intrinsics.calibrate_intrinsics`);
``cv2.stereoCalibrate`` then refines everything jointly from the pairs in which both cameras
saw the board (the corner ids say which corners match). The left camera defines the world
frame. The fundamental matrix is reported twice: from the calibrated rig, and estimated
directly from the matched (undistorted) corners (:func:`calibration.fundamental.estimate_fundamental`).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calibration.boards import Board, BoardView
from calibration.fundamental import EpipolarStats, FundamentalFit, epipolar_stats, estimate_fundamental
from calibration.intrinsics import IntrinsicsResult, calibrate_intrinsics
from mocap.camera import Camera, Rig
from mocap.errors import MocapError
from mocap.geometry import fundamental_from_cameras

__all__ = ["StereoResult", "read_image_list", "calibrate_stereo"]


@dataclass
class StereoResult:
    """A calibrated stereo pair.

    Attributes:
        rig: the two cameras; camera 1 at the origin.
        rms_px: joint RMS reprojection error of ``cv2.stereoCalibrate``, pixels.
        intrinsics: the per-camera calibrations used as the starting point.
        pairs: names of the image pairs used.
        corners: ((N, 2), (N, 2)) matched corners, ideal pixels, over all pairs.
        rig_stats: epipolar distances of ``corners`` under the rig's F.
        fit: F estimated from ``corners`` directly.
    """

    rig: Rig
    rms_px: float
    intrinsics: tuple[IntrinsicsResult, IntrinsicsResult]
    pairs: list[tuple[str, str]]
    corners: tuple[np.ndarray, np.ndarray]
    rig_stats: EpipolarStats
    fit: FundamentalFit


def read_image_list(path: str | os.PathLike) -> list[tuple[Path, Path]]:
    """Left/right file pairs from an OpenCV ``<imagelist>`` XML/YAML file (as in OpenCV's stereo_calib.xml).

    Raises:
        MocapError: unreadable file, no ``imagelist``, or an odd number of names.
    """
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise MocapError(f"{path}: cannot read the image list ({exc}); expected OpenCV's <imagelist> XML") from None
    node = root.find("imagelist")
    names = (node.text or "").split() if node is not None else []
    names = [n.strip('"') for n in names]
    if not names or len(names) % 2:
        raise MocapError(f"{path}: <imagelist> must hold an even number of file names (left, right, left, ...)")
    return [(path.parent / names[k], path.parent / names[k + 1]) for k in range(0, len(names), 2)]


def _matched(view1: BoardView, view2: BoardView, board: Board) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corner ids both views found, and their pixels in each.

    A checkerboard's numbering is ambiguous under a half turn: camera 2's is reversed when its
    first-to-last corner direction opposes camera 1's (both cameras see the board from similar
    directions in a stereo pair).
    """
    xy2 = view2.xy
    if board.kind == "checker" and np.dot(view1.xy[-1] - view1.xy[0], xy2[-1] - xy2[0]) < 0:
        xy2 = xy2[::-1]
    ids, i1, i2 = np.intersect1d(view1.ids, view2.ids, return_indices=True)
    return ids, view1.xy[i1], xy2[i2]


def calibrate_stereo(views1: list[BoardView | None], views2: list[BoardView | None], board: Board,
                     size: tuple[int, int], names: tuple[str, str] = ("cam1", "cam2"),
                     fix_intrinsics: bool = False) -> StereoResult:
    """Calibrate a stereo pair from pair-wise board views.

    Args:
        views1, views2: the board view of each pair in camera 1 and camera 2 (None where not found).
        board: the board.
        size: (width, height) of both cameras' images.
        names: the cameras' names.
        fix_intrinsics: keep each camera's own intrinsics; else refine them jointly.

    Raises:
        MocapError: fewer than 4 pairs in which both cameras found the board.
    """
    intr = tuple(
        calibrate_intrinsics([v for v in views if v is not None], board, size, where=f"camera {name}")
        for views, name in ((views1, names[0]), (views2, names[1]))
    )
    obj = board.object_points().astype(np.float32)
    obj_pts, pts1, pts2, pairs = [], [], [], []
    for v1, v2 in zip(views1, views2, strict=True):
        if v1 is None or v2 is None:
            continue
        ids, a, b = _matched(v1, v2, board)
        if len(ids) < 6:
            continue
        obj_pts.append(obj[ids])
        pts1.append(a.astype(np.float32))
        pts2.append(b.astype(np.float32))
        pairs.append((v1.name, v2.name))
    if len(pairs) < 4:
        raise MocapError(f"stereo: the board was found in both images of only {len(pairs)} pair(s); "
                         "at least 4 are needed")
    flags = cv2.CALIB_FIX_INTRINSIC if fix_intrinsics else cv2.CALIB_USE_INTRINSIC_GUESS
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-10)
    rms, K1, d1, K2, d2, R, T, _, _ = cv2.stereoCalibrate(
        obj_pts, pts1, pts2, intr[0].matrix.copy(), intr[0].distortions.copy(), intr[1].matrix.copy(),
        intr[1].distortions.copy(), size, flags=flags, criteria=criteria,
    )
    cam1 = Camera(names[0], size, K1, d1.ravel()[:5], np.zeros(3), np.zeros(3))
    cam2 = Camera(names[1], size, K2, d2.ravel()[:5], cv2.Rodrigues(R)[0].ravel(), T.ravel() * 1.0)
    rig = Rig([cam1, cam2], {"made_by": "mocap calibrate stereo", "board": board.describe(),
                             "pairs": len(pairs), "rms_px": float(rms)})
    x1 = cam1.undistort(np.concatenate(pts1).astype(np.float64))
    x2 = cam2.undistort(np.concatenate(pts2).astype(np.float64))
    F = fundamental_from_cameras(cam1, cam2)
    fit = estimate_fundamental(x1, x2, where=f"stereo {names[0]}-{names[1]}")
    return StereoResult(rig, float(rms), intr, pairs, (x1, x2), epipolar_stats(F, x1, x2), fit)
