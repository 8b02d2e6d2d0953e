"""Atomic file output: a file is either written whole or left as it was."""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["atomic_write", "write_json", "write_text"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: str | os.PathLike, write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it over
    ``path``. On any error the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    path : path-like
        Destination; its directory is created if missing.
    write : callable
        Writes the whole content to the path it is given.

    Returns
    -------
    Path
        The destination.
    """
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=".tmp", dir=dest.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        # mkstemp creates 0600 files; give the result the mode a plain open() would.
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return dest


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write text atomically (UTF-8).

    Parameters
    ----------
    path : path-like
    text : str

    Returns
    -------
    Path
    """
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def write_json(path: str | os.PathLike, data: Any) -> Path:
    """Write JSON atomically (UTF-8, indented, trailing newline).

    Parameters
    ----------
    path : path-like
    data : object
        JSON-serialisable; NaN and infinity are refused (``ValueError``) before anything is
        written.

    Returns
    -------
    Path
    """
    text = json.dumps(data, indent=2, allow_nan=False, ensure_ascii=False) + "\n"
    return write_text(path, text)
