"""Delimited numeric tables (TRC, CSV): exact, fast formatting and parsing of float rows.

Floats are written with Python's shortest round-trip repr, so reading back gives the same
float64 bit for bit; missing values (NaN) are empty cells.
"""

from __future__ import annotations

import re
import warnings

import numpy as np

from mocap.errors import MocapError

__all__ = ["format_rows", "parse_rows"]

_EMPTY_CELL = {d: re.compile(rf"(?<![^{re.escape(d)}\n])(?![^{re.escape(d)}\n])") for d in ("\t", ",")}


def format_rows(frames: np.ndarray, times: np.ndarray, values: np.ndarray, delimiter: str) -> str:
    """Rows ``frame, time, v0, v1 ...`` joined by ``delimiter``, one per line, ending in a newline.

    Args:
        frames: (F,) integer frame numbers.
        times: (F,) seconds, written with 6 decimals.
        values: (F, K) float64; NaN or infinite values become empty cells.
    """
    values = np.where(np.isfinite(values), values, np.nan)
    fmt = delimiter.join(["%d", "%.6f"] + ["%r"] * values.shape[1])
    rows = [fmt % (f, t, *row) for f, t, row in zip(frames.tolist(), times.tolist(), values.tolist(), strict=True)]
    return ("\n".join(rows) + "\n").replace("nan", "") if rows else ""


def parse_rows(lines: list[str], delimiter: str, n_fields: int, where: str, first_line: int) -> np.ndarray:
    """Parse data lines into an (R, n_fields) float64 array; empty cells become NaN.

    Trailing empty cells beyond ``n_fields`` (padding some programs add) are ignored.

    Args:
        lines: the data lines, without line ends.
        where: file name for error messages.
        first_line: 1-based line number of ``lines[0]`` in the file, for error messages.

    Raises:
        MocapError: a row with another number of fields (ragged), or a cell that is not a number.
    """
    lines = list(lines)
    counts = np.fromiter((line.count(delimiter) for line in lines), dtype=np.int64, count=len(lines))
    for i in np.flatnonzero(counts != n_fields - 1).tolist():
        head = delimiter.join(lines[i].split(delimiter)[:n_fields])
        if counts[i] < n_fields - 1 or lines[i][len(head):].strip(delimiter + " "):
            raise MocapError(
                f"{where}: line {first_line + i} has {counts[i] + 1} fields, expected {n_fields} "
                f"(frame, time and 3 per marker); the file is ragged or truncated: re-export it or fix that row"
            )
        lines[i] = head
    if not lines:
        return np.zeros((0, n_fields))
    text = _EMPTY_CELL[delimiter].sub("nan", "\n".join(lines)).replace("\n", delimiter)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            flat = np.fromstring(text, dtype=np.float64, sep=delimiter)  # text mode is not deprecated
    except ValueError:
        flat = np.zeros(0)
    if flat.size != len(lines) * n_fields:
        _raise_bad_cell(lines, delimiter, where, first_line)
    return flat.reshape(len(lines), n_fields)


def _raise_bad_cell(lines: list[str], delimiter: str, where: str, first_line: int) -> None:
    for i, line in enumerate(lines):
        for j, cell in enumerate(line.split(delimiter)):
            try:
                float(cell) if cell.strip() else None
            except ValueError:
                raise MocapError(
                    f"{where}: line {first_line + i}, field {j + 1}: {cell.strip()!r} is not a number; "
                    f"fix or delete that row"
                ) from None
    raise MocapError(f"{where}: cannot read the data rows as numbers; the file may be damaged")
