"""Poses and points in plain text files (the Med-RAD ``start*.txt`` / ``target.txt`` form)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit._validation import as_poses
from needlekit.errors import InvalidInputError
from needlekit.io.files import atomic_write

__all__ = ["read_point_txt", "read_pose_txt", "write_pose_txt"]


def _load(path: str | os.PathLike) -> np.ndarray:
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(str(p), "file not found")
    try:
        return np.loadtxt(p, dtype=np.float64, ndmin=1)
    except ValueError as exc:
        raise InvalidInputError(str(p), f"expected whitespace-separated numbers ({exc})") from exc


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
    if not np.all(np.isfinite(arr)):
        raise InvalidInputError(str(path), "must be finite, got NaN or infinity")
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
