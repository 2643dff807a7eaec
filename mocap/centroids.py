"""Per-camera 2D centroid files: what real mocap cameras send instead of images.

Two interchangeable formats (documented in docs/take-format.md), one file per camera named
``<camera>.centroids.csv`` or ``<camera>.centroids.npz``:

- CSV: optional first line ``# frames = N``; a header naming the columns; one row per blob,
  rows sorted by frame. Required columns ``frame,x,y`` (distorted pixels); optional ``area``,
  ``roundness``, ``cov_xx``, ``cov_xy``, ``cov_yy`` (px^2), ``merged`` (0/1), ``flux`` (grey levels),
  ``cut`` (0/1: :class:`mocap.detections.Detections`). A frame with no rows had no blobs. Read in chunks, so a long take
  never sits in memory whole.
- NPZ: arrays ``frame`` (N,) int, ``xy`` (N, 2) float and optionally ``area`` (N,), ``roundness`` (N,),
  ``cov`` (N, 2, 2), ``merged`` (N,) bool, ``flux`` (N,), ``cut`` (N,) bool and a scalar ``n_frames``. Loaded
  whole.

Rows with NaN or infinite values are dropped with a warning; a negative or fractional frame
number, a missing column or unsorted frames are errors naming the file and the fix.
"""

from __future__ import annotations

import itertools
import logging
import os
import re
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from mocap.atomic import atomic_output
from mocap.detections import Detections
from mocap.errors import MocapError

__all__ = ["CENTROID_SUFFIXES", "CentroidFile", "open_centroids", "write_centroids"]

log = logging.getLogger(__name__)

CENTROID_SUFFIXES = (".centroids.csv", ".centroids.npz")
COLUMNS = ("frame", "x", "y", "area", "roundness", "cov_xx", "cov_xy", "cov_yy", "merged", "flux", "cut")
REQUIRED = ("frame", "x", "y")
_CHUNK_ROWS = 65536
_FRAMES_RE = re.compile(r"^#\s*frames\s*=\s*(\d+)\s*$")


def _rows_to_detections(rows: np.ndarray, cols: dict[str, int]) -> Detections:
    """(N, K) float rows in the file's column order -> Detections (defaults for absent columns)."""
    def col(name: str) -> np.ndarray | None:
        return rows[:, cols[name]] if name in cols else None

    cov = None
    if all(c in cols for c in ("cov_xx", "cov_xy", "cov_yy")):
        cov = np.empty((len(rows), 2, 2))
        cov[:, 0, 0] = col("cov_xx")
        cov[:, 0, 1] = cov[:, 1, 0] = col("cov_xy")
        cov[:, 1, 1] = col("cov_yy")
    merged, cut = col("merged"), col("cut")
    return Detections(rows[:, [cols["x"], cols["y"]]], col("area"), col("roundness"), cov,
                      None if merged is None else merged != 0, col("flux"), None if cut is None else cut != 0)


class CentroidFile:
    """One camera's centroid file, opened and checked; :meth:`frames` streams it.

    Attributes:
        path: the file.
        n_frames: frames the file covers: its ``frames`` declaration, else the last frame + 1.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        name = self.path.name.lower()
        if name.endswith(".centroids.npz"):
            self._binary = True
            self._arrays = self._load_npz()
            self._declared = self._arrays.pop("n_frames", None)
            frames = self._arrays["frame"]
            self._last = int(frames[-1]) if len(frames) else -1
        elif name.endswith(".centroids.csv"):
            self._binary = False
            self._declared, self._cols, self._data_line = self._read_header()
            self._last = self._last_csv_frame()
        else:
            raise MocapError(f"{self.path}: a centroid file must be named <camera>.centroids.csv or .centroids.npz")
        self.n_frames = self._last + 1 if self._declared is None else int(self._declared)
        if self._last >= self.n_frames:
            raise MocapError(f"{self.path}: declares {self.n_frames} frames but has rows for frame {self._last}; "
                             "fix the 'frames' declaration or remove it")

    # ------------------------------------------------------------------ CSV
    def _read_header(self) -> tuple[int | None, dict[str, int], int]:
        declared = None
        try:
            with self.path.open(encoding="utf-8") as f:
                for line_no, line in enumerate(f, start=1):
                    text = line.strip()
                    match = _FRAMES_RE.match(text)
                    if match:
                        declared = int(match.group(1))
                    elif text and not text.startswith("#"):
                        return declared, self._parse_header(text), line_no
        except UnicodeDecodeError:
            raise MocapError(f"{self.path}: not a text file; a .centroids.csv must be UTF-8 CSV") from None
        except OSError as exc:
            raise MocapError(f"{self.path}: cannot read ({exc.strerror})") from None
        raise MocapError(f"{self.path}: empty file; it needs a header line '{','.join(COLUMNS[:5])}'")

    def _parse_header(self, text: str) -> dict[str, int]:
        names = [n.strip().lower() for n in text.split(",")]
        missing = [c for c in REQUIRED if c not in names]
        if missing:
            raise MocapError(f"{self.path}: header {text!r} lacks column(s) {missing}; the first line must name "
                             f"the columns, at least {','.join(REQUIRED)}")
        unknown = [n for n in names if n not in COLUMNS]
        if unknown:
            log.warning("%s: ignoring unknown column(s) %s (known: %s)", self.path, unknown, ", ".join(COLUMNS))
        return {n: i for i, n in enumerate(names) if n in COLUMNS}

    def _last_csv_frame(self) -> int:
        """Frame of the file's last data row (rows are sorted), -1 if there is none."""
        with self.path.open("rb") as f:
            size = f.seek(0, os.SEEK_END)
            block = 4096
            while True:
                f.seek(max(0, size - block))
                lines = f.read().decode("utf-8", errors="replace").splitlines()
                if block >= size:
                    break
                lines = lines[1:]  # the first line of the tail may be cut
                if any(ln.strip() and not ln.lstrip().startswith("#") for ln in lines):
                    break
                block *= 4
        data = [ln.strip() for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
        for line in reversed(data):
            if self._header_like(line):
                return -1
            fields = line.split(",")
            try:
                last = float(fields[self._cols["frame"]])
            except (ValueError, IndexError):
                raise MocapError(f"{self.path}: unreadable last row {line!r}; every row needs numbers separated "
                                 "by commas") from None
            if np.isfinite(last):  # (a NaN row is dropped, with a warning, while streaming)
                if last < 0:
                    raise MocapError(f"{self.path}: negative frame number {last:g}; frames count from 0")
                return int(last)
        return -1

    @staticmethod
    def _header_like(text: str) -> bool:
        return text.split(",")[0].strip().lower() in COLUMNS

    def _csv_chunks(self) -> Iterator[np.ndarray]:
        """(n, K) float row blocks in file order."""
        n_cols = max(self._cols.values()) + 1
        with self.path.open(encoding="utf-8") as f:
            first = self._data_line + 1
            lines = itertools.islice(f, self._data_line, None)
            while True:
                block = [ln for ln in itertools.islice(lines, _CHUNK_ROWS)]
                if not block:
                    return
                block_first, first = first, first + len(block)
                block = [ln for ln in block if ln.strip() and not ln.lstrip().startswith("#")]
                if not block:
                    continue
                try:
                    rows = np.loadtxt(block, delimiter=",", ndmin=2, dtype=np.float64, usecols=range(n_cols))
                except ValueError as exc:
                    raise MocapError(f"{self.path}: unreadable row between lines {block_first} and {first - 1} "
                                     f"({exc}); every row needs {n_cols} numbers separated by commas") from None
                yield rows

    # ------------------------------------------------------------------ NPZ
    def _load_npz(self) -> dict[str, np.ndarray]:
        try:
            with np.load(self.path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except (OSError, ValueError) as exc:
            raise MocapError(f"{self.path}: not a readable .npz file ({exc}); re-export the centroids") from None
        missing = [k for k in ("frame", "xy") if k not in data]
        if missing:
            raise MocapError(f"{self.path}: lacks array(s) {missing}; a .centroids.npz needs 'frame' (N,) "
                             "and 'xy' (N, 2)")
        n = len(data["frame"])
        shapes = {"frame": (n,), "xy": (n, 2), "area": (n,), "roundness": (n,), "cov": (n, 2, 2), "merged": (n,),
                  "flux": (n,), "cut": (n,), "n_frames": ()}
        for key, value in data.items():
            if key in shapes and value.shape != shapes[key]:
                raise MocapError(f"{self.path}: array '{key}' has shape {value.shape}, expected {shapes[key]}")
        out: dict[str, np.ndarray] = {}
        try:
            for key in shapes:
                if key in data:
                    out[key] = data[key].astype(bool if key in ("merged", "cut") else np.float64)
        except (TypeError, ValueError):
            raise MocapError(f"{self.path}: array '{key}' must be numeric") from None
        if "n_frames" in out:
            out["n_frames"] = int(out["n_frames"])
        rows = np.column_stack([out["frame"], out["xy"]] + [out[k].reshape(n, -1) for k in
                                                            ("area", "roundness", "cov", "flux")
                                                            if k in out])
        keep = self._check_rows(rows, first_line=None)
        out = {k: (v[keep] if k != "n_frames" else v) for k, v in out.items()}
        if "flux" in out:
            out["flux"] = self._light(out["flux"])
        order = np.argsort(out["frame"], kind="stable")
        return {k: (v[order] if k != "n_frames" else v) for k, v in out.items()}

    # ------------------------------------------------------------------ both
    def _light(self, flux: np.ndarray) -> np.ndarray:
        """Blobs' light (n,) with the values no blob can hold (zero or negative) read as not measured (NaN), with a
        warning: the tracker would take such a blob for its marker partly hidden."""
        bad = flux <= 0
        if not np.count_nonzero(bad):
            return flux
        log.warning("%s: %d blob(s) with zero or negative light (column 'flux'); read as not measured", self.path,
                    int(bad.sum()))
        return np.where(bad, np.nan, flux)

    def _check_rows(self, rows: np.ndarray, first_line: int | None) -> np.ndarray:
        """(N, K) rows with frame in column 0 -> (N,) bool rows to keep; raises on bad frame numbers."""
        finite = np.isfinite(rows).all(axis=1)
        if not finite.all():
            where = "" if first_line is None else f" (from line {first_line})"
            log.warning("%s: dropped %d row(s) with NaN or infinite values%s", self.path, int((~finite).sum()), where)
        frame = rows[finite, 0]
        if (frame < 0).any():
            raise MocapError(f"{self.path}: negative frame number {frame[frame < 0][0]:g}; frames count from 0")
        if (frame != np.round(frame)).any():
            bad = frame[frame != np.round(frame)][0]
            raise MocapError(f"{self.path}: frame number {bad:g} is not a whole number")
        return finite

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[Detections]:
        """One :class:`Detections` per frame in ``[start, stop)`` (empty where the file has no rows)."""
        stop = self.n_frames if stop is None else stop
        if self._binary:
            a = self._arrays
            bounds = np.searchsorted(a["frame"], np.arange(start, stop + 1))
            for lo, hi in itertools.pairwise(bounds):
                yield Detections(a["xy"][lo:hi], a["area"][lo:hi] if "area" in a else None,
                                 a["roundness"][lo:hi] if "roundness" in a else None,
                                 a["cov"][lo:hi] if "cov" in a else None,
                                 a["merged"][lo:hi] if "merged" in a else None,
                                 a["flux"][lo:hi] if "flux" in a else None,
                                 a["cut"][lo:hi] if "cut" in a else None)
            return
        yield from self._csv_frames(start, stop)

    def _csv_frames(self, start: int, stop: int) -> Iterator[Detections]:
        order = [self._cols["frame"]] + [i for n, i in self._cols.items() if n != "frame"]
        cols = {n: k for k, n in enumerate(["frame"] + [n for n in self._cols if n != "frame"])}
        pending = np.zeros((0, len(cols)))
        last_frame = -1.0
        chunks = self._csv_chunks()
        exhausted = False
        for k in range(start, stop):
            while not exhausted and (len(pending) == 0 or pending[-1, 0] <= k):
                rows = next(chunks, None)
                if rows is None:
                    exhausted = True
                    break
                rows = rows[:, order]
                rows = rows[self._check_rows(rows, None)]
                if "flux" in cols:
                    rows[:, cols["flux"]] = self._light(rows[:, cols["flux"]])
                frame = rows[:, 0]
                if len(frame) and (frame[0] < last_frame or (np.diff(frame) < 0).any()):
                    raise MocapError(f"{self.path}: rows are not sorted by frame; sort them by the 'frame' column")
                if len(frame):
                    last_frame = frame[-1]
                pending = np.concatenate([pending, rows])
            lo = np.searchsorted(pending[:, 0], k, side="left")
            hi = np.searchsorted(pending[:, 0], k, side="right")
            yield _rows_to_detections(pending[lo:hi], cols)
            pending = pending[hi:]


def open_centroids(path: str | os.PathLike) -> CentroidFile:
    """Open and check a ``<camera>.centroids.csv|.npz`` file (see the module docstring for the format)."""
    path = Path(path)
    if not path.is_file():
        raise MocapError(f"{path}: centroid file not found")
    return CentroidFile(path)


def write_centroids(path: str | os.PathLike, frames: Iterable[tuple[int, Detections]],
                    n_frames: int | None = None) -> int:
    """Write one camera's blobs to ``path`` (``.centroids.csv`` or ``.centroids.npz``), atomically.

    Args:
        path: output file; its suffix picks the format.
        frames: ``(frame_index, detections)`` in increasing frame order.
        n_frames: frames the recording has (stored, so trailing blob-less frames survive).

    Returns:
        The number of blobs written.
    """
    path = Path(path)
    name = path.name.lower()
    if not name.endswith(CENTROID_SUFFIXES):
        raise MocapError(f"{path}: centroid files must end in {' or '.join(CENTROID_SUFFIXES)}")
    blocks = []
    last = -1
    for frame_index, det in frames:
        if frame_index <= last:
            raise ValueError("frames must be given in increasing order")
        last = frame_index
        n = len(det)
        if n:
            blocks.append(np.column_stack([np.full(n, frame_index), det.xy, det.area, det.roundness,
                                           det.cov[:, 0, 0], det.cov[:, 0, 1], det.cov[:, 1, 1], det.merged,
                                           det.flux, det.cut]))
    rows = np.concatenate(blocks) if blocks else np.zeros((0, len(COLUMNS)))
    measured = np.isfinite(rows[:, 9]).all()  # (flux: written where every blob has it)
    cut = rows[:, 10].any()  # (the cut flag: where some blob has it)
    keep = [k for k in range(len(COLUMNS)) if (k != 9 or measured) and (k != 10 or cut)]
    columns = [COLUMNS[k] for k in keep]
    with atomic_output(path) as tmp:
        if name.endswith(".npz"):
            cov = np.stack([rows[:, 5], rows[:, 6], rows[:, 6], rows[:, 7]], axis=1).reshape(-1, 2, 2)
            extra = {} if n_frames is None else {"n_frames": np.int64(n_frames)}
            if measured:
                extra["flux"] = rows[:, 9]
            if cut:
                extra["cut"] = rows[:, 10].astype(bool)
            with tmp.open("wb") as f:
                np.savez_compressed(f, frame=rows[:, 0].astype(np.int64), xy=rows[:, 1:3], area=rows[:, 3],
                                    roundness=rows[:, 4], cov=cov, merged=rows[:, 8].astype(bool), **extra)
        else:
            with tmp.open("w", encoding="utf-8", newline="\n") as f:
                if n_frames is not None:
                    f.write(f"# frames = {int(n_frames)}\n")
                f.write(",".join(columns) + "\n")
                formats = ["%d", "%.6f", "%.6f", "%.3f", "%.5f", "%.6g", "%.6g", "%.6g", "%d", "%.6g", "%d"]
                np.savetxt(f, rows[:, keep], delimiter=",", fmt=[formats[k] for k in keep])
    return len(rows)
