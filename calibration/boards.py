"""Calibration boards: what they look like and where their corners are in an image.

A board's corners have ids ``0..N-1`` and known positions on the board plane (z = 0, metres,
x along the rows to the right, y down the columns, as in OpenCV). A detection returns the
corners it found, sub-pixel, with their ids, so that partial ChArUco views are usable.

Two kinds:

* ``checker``: a plain checkerboard of ``cols x rows`` *inner* corners (OpenCV's pattern size),
  found with ``cv2.findChessboardCornersSB`` (the sector-based detector) and polished with
  ``cv2.cornerSubPix`` (together ~0.03 px on synthetic boards, against ~0.2 px for SB alone).
  It must be seen whole. Its pattern is symmetric under a half turn, so the corner order is
  made canonical (the first corner is the one nearer the image's top-left): two cameras
  looking at the board from similar directions then number the corners alike.
* ``charuco``: a ChArUco board of ``cols x rows`` *squares* (``cv2.aruco.CharucoDetector``,
  OpenCV >= 4.7 API; its own corner refinement: ``cornerSubPix`` on top was worse, pulled by
  the marker edges); partial views are fine because every corner is identified.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from mocap.errors import MocapError

__all__ = ["Board", "BoardView", "parse_board"]

_CHECKER_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE


@dataclass(frozen=True)
class Board:
    """A planar calibration target.

    Attributes:
        kind: ``"checker"`` or ``"charuco"``.
        cols: inner corners per row (checker) or squares per row (charuco).
        rows: inner corners per column (checker) or squares per column (charuco).
        square: side of one square, metres.
        marker: ArUco marker side, metres (charuco only).
        dictionary: OpenCV predefined ArUco dictionary name (charuco only).
    """

    kind: str
    cols: int
    rows: int
    square: float
    marker: float = 0.0
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        if self.kind not in ("checker", "charuco"):
            raise MocapError(f"board kind must be 'checker' or 'charuco', got {self.kind!r}")
        if self.cols < 2 or self.rows < 2 or self.square <= 0:
            raise MocapError(f"board {self.describe()}: needs at least 2x2 corners and a positive square size")
        if self.kind == "charuco":
            if not 0 < self.marker < self.square:
                raise MocapError(f"board {self.describe()}: the marker side must be between 0 and the square side")
            if not hasattr(cv2.aruco, self.dictionary):
                raise MocapError(f"board {self.describe()}: unknown ArUco dictionary {self.dictionary!r}")

    def describe(self) -> str:
        """The board as the command line spells it (see :func:`parse_board`)."""
        if self.kind == "checker":
            return f"checker:{self.cols}x{self.rows}:{self.square:g}"
        return f"charuco:{self.cols}x{self.rows}:{self.square:g}:{self.marker:g}:{self.dictionary}"

    @property
    def n_corners(self) -> int:
        return self.cols * self.rows if self.kind == "checker" else (self.cols - 1) * (self.rows - 1)

    def object_points(self) -> np.ndarray:
        """(N, 3) corner positions on the board, metres, indexed by corner id."""
        if self.kind == "charuco":
            return np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
        grid = np.mgrid[0 : self.cols, 0 : self.rows].T.reshape(-1, 2) * self.square
        return np.column_stack([grid, np.zeros(len(grid))])

    def cv_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV ChArUco board (charuco only)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square, self.marker, dictionary)

    def detect(self, image: np.ndarray, name: str = "") -> BoardView | None:
        """Find the board's corners in a grey image.

        Args:
            image: (H, W) uint8 grey image (3-channel images are converted).
            name: the image's name, kept in the view.

        Returns:
            The view, or None when the board is not there (or fewer than 6 ChArUco corners).
        """
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        if self.kind == "checker":
            found, corners = cv2.findChessboardCornersSB(grey, (self.cols, self.rows), flags=_CHECKER_FLAGS)
            if not found:
                return None
            xy = _refine(grey, corners.reshape(-1, 2))
            if xy[0].sum() > xy[-1].sum():  # canonical within one image; stereo re-checks pairs
                xy = xy[::-1].copy()
            return BoardView(name, xy, np.arange(len(xy)), grey.shape[::-1])
        corners, ids, _, _ = cv2.aruco.CharucoDetector(self.cv_board()).detectBoard(grey)
        if ids is None or len(ids) < 6:
            return None
        return BoardView(name, corners.reshape(-1, 2).astype(np.float64), ids.ravel().astype(np.intp),
                         grey.shape[::-1])


def _refine(grey: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Polish (N, 2) board corners with ``cv2.cornerSubPix`` (gradient orthogonality).

    The checkerboard detector alone errs by up to a few tenths of a pixel on sharp, tilted boards; the
    refinement window is a quarter of the smallest corner spacing (2..11 px half-size).
    """
    spacing = cKDTree(xy).query(xy, k=2)[0][:, 1].min()
    half = int(np.clip(spacing / 4, 2, 11))
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    refined = cv2.cornerSubPix(grey, xy.astype(np.float32).reshape(-1, 1, 2), (half, half), (-1, -1), criteria)
    return refined.reshape(-1, 2).astype(np.float64)


@dataclass
class BoardView:
    """The corners of one board found in one image.

    Attributes:
        name: the image (file name, or ``video.mp4#frame``).
        xy: (N, 2) corner positions, distorted pixels.
        ids: (N,) corner ids (rows of :meth:`Board.object_points`).
        size: (width, height) of the image, pixels.
    """

    name: str
    xy: np.ndarray
    ids: np.ndarray
    size: tuple[int, int]


def parse_board(text: str) -> Board:
    """Parse ``checker:COLSxROWS:SQUARE`` or ``charuco:COLSxROWS:SQUARE:MARKER[:DICT]`` (sizes in metres).

    Example: ``checker:9x6:0.025`` (9 x 6 inner corners, 25 mm squares),
    ``charuco:7x5:0.04:0.03:DICT_5X5_100`` (7 x 5 squares).
    """
    parts = text.strip().split(":")
    usage = ("write the board as checker:COLSxROWS:SQUARE_M (inner corners) or "
             "charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT] (squares)")
    try:
        kind = parts[0].lower()
        cols, rows = (int(v) for v in parts[1].lower().split("x"))
        square = float(parts[2])
        if kind == "checker" and len(parts) == 3:
            return Board("checker", cols, rows, square)
        if kind == "charuco" and len(parts) in (4, 5):
            return Board("charuco", cols, rows, square, float(parts[3]), *parts[4:])
    except (IndexError, ValueError):
        pass
    raise MocapError(f"--board {text!r}: {usage}")
