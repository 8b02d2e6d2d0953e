"""Poses and points in plain text files (the Med-RAD ``start*.txt`` / ``target.txt`` form)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit._numbers import ANY_MM
from needlekit._validation import as_poses, check_array
from needlekit.errors import InvalidInputError
from needlekit.io.files import atomic_write

__all__ = ["read_point_txt", "read_pose_txt", "write_pose_txt"]


#: Largest pose or point file read (bytes): a 4x4 pose is a few hundred bytes; a larger
#: file is not one (and is not read whole to find out).
MAX_TEXT_BYTES: int = 64 * 1024


def _load(path: str | os.PathLike) -> np.ndarray:
    """The numbers of a small text file, whitespace-separated, ``#`` comments and blank
    lines skipped. An error names the line and the item that is not a number, never what
    the file holds there (it may be any file the user pointed at by mistake)."""
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(str(p), "file not found")
    try:
        with open(p, "rb") as fh:
            raw = fh.read(MAX_TEXT_BYTES + 1)
    except OSError as exc:
        raise InvalidInputError(str(p), f"cannot read the file ({exc.strerror or exc})") from None
    if len(raw) > MAX_TEXT_BYTES:
        raise InvalidInputError(
            str(p), f"larger than {MAX_TEXT_BYTES // 1024} KiB: not a pose or point file"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise InvalidInputError(str(p), "not a text file of numbers") from None
    values: list[float] = []
    for line_no, line in enumerate(text.splitlines(), start=1):
        items = line.split("#", 1)[0].split()
        for col, item in enumerate(items, start=1):
            try:
                values.append(float(item))
            except ValueError:
                raise InvalidInputError(
                    str(p),
                    f"line {line_no}, item {col} is not a number (pose and point files hold "
                    "whitespace-separated numbers)",
                ) from None
    return np.array(values, dtype=np.float64)


def read_pose_txt(path: str | os.PathLike) -> np.ndarray:
    """Read a 4x4 homogeneous pose (RAS mm, rows on lines) from a text file.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    ndarray, shape (4, 4)

    Raises
    ------
    InvalidInputError
        Missing file, not 16 numbers, NaN, or not a rigid transform; the message names the
        file.
    """
    arr = _load(path)
    if arr.size != 16:
        raise InvalidInputError(str(path), f"expected a 4x4 matrix (16 numbers), got {arr.size}")
    check_array(arr.reshape(4, 4), str(path), ANY_MM)
    pose, _ = as_poses(arr.reshape(4, 4), str(path))
    return pose[0]


def read_point_txt(path: str | os.PathLike) -> np.ndarray:
    """Read one 3D point (RAS mm) from a text file of three numbers.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    ndarray, shape (3,)
    """
    arr = _load(path).reshape(-1)
    if arr.size != 3:
        raise InvalidInputError(str(path), f"expected 3 numbers (x y z), got {arr.size}")
    check_array(arr.reshape(3), str(path), ANY_MM)
    return arr


def write_pose_txt(path: str | os.PathLike, pose) -> Path:
    """Write a 4x4 pose as text, the form :func:`read_pose_txt` reads (atomically).

    Parameters
    ----------
    path : path-like
    pose : array_like, shape (4, 4)

    Returns
    -------
    Path
    """
    g, single = as_poses(pose, "pose")
    if not single:
        raise InvalidInputError("pose", "expected one 4x4 pose")
    return atomic_write(path, lambda p: np.savetxt(p, g[0], fmt="%.18e"))
