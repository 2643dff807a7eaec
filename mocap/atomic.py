"""Atomic output: a file is either its old self or complete, never half-written."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

from mocap.errors import MocapError


def _checked(path: str | os.PathLike) -> Path:
    """``path``, if it names a file in an existing, writable folder; else a clear error."""
    path = Path(path)
    if path.is_dir():
        raise MocapError(f"{path}: is a folder; give a file name for the output")
    if not path.parent.exists():
        raise MocapError(f"{path}: output folder {path.parent} does not exist; create it first")
    if not os.access(path.parent, os.W_OK):
        raise MocapError(f"{path}: output folder {path.parent} is not writable")
    return path


def _temporary_beside(path: Path, suffix: str) -> Path:
    """A new empty file in ``path``'s folder. Creating it is the real test of the folder: access() says yes to root
    everywhere, and knows nothing of read-only or special file systems."""
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=suffix)
    except OSError as err:
        raise MocapError(f"{path}: cannot create files in {path.parent} ({err.strerror}); choose another "
                         "output folder") from None
    os.close(fd)
    return Path(tmp)


def check_output_path(path: str | os.PathLike) -> Path:
    """Fail early, with a clear message, if ``path`` cannot be written."""
    path = _checked(path)
    _temporary_beside(path, ".probe").unlink()
    return path


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and an existing ``path`` is untouched.
    The temporary name keeps the final suffix, for libraries that choose by extension.
    """
    path = _checked(path)
    tmp_path = _temporary_beside(path, f".tmp{path.suffix}")
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    except OSError as err:  # (disk full, file system gone read-only, a read-only file in the way)
        raise MocapError(f"{path}: could not be written ({err.strerror or err}); free some space or choose "
                         "another output path (the file, if it existed, is unchanged)") from err
    finally:
        tmp_path.unlink(missing_ok=True)


def atomic_write_bytes(path: str | os.PathLike, payload: bytes) -> None:
    """Write ``payload`` to ``path`` atomically (temp file in the same folder + rename)."""
    with atomic_output(path) as tmp:
        tmp.write_bytes(payload)
