"""Checks on array arguments, shared by every public function.

Each helper converts its argument to a float64 array of the promised shape or raises
:class:`~needlekit.errors.InvalidInputError` naming the argument. Batch-first: functions
accept one item or a batch; the helpers return the batch and whether the input was a
single item, so results can be returned in the caller's shape.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from needlekit._numbers import Bounds, magnitude
from needlekit.constants import ROTATION_ORTHONORMAL_TOL
from needlekit.errors import InvalidInputError

__all__ = [
    "as_batch",
    "check_array",
    "as_points",
    "as_poses",
    "as_positive",
    "as_rotations",
    "as_scalar",
    "unbatch",
]


def _as_float_array(value: Any, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(name, f"expected numbers, got {type(value).__name__}") from exc
    return arr


def _check_finite(arr: np.ndarray, name: str) -> None:
    if not np.all(np.isfinite(arr)):
        bad = "NaN" if np.any(np.isnan(arr)) else "infinity"
        raise InvalidInputError(name, f"must be finite, got {bad}")


def as_batch(value: Any, name: str, item_shape: tuple[int, ...]) -> tuple[np.ndarray, bool]:
    """Return ``value`` as a float64 batch of shape ``(n, *item_shape)``.

    Parameters
    ----------
    value : array_like
        One item of shape ``item_shape`` or a batch ``(n, *item_shape)``.
    name : str
        Argument name used in error messages.
    item_shape : tuple of int
        Shape of one item.

    Returns
    -------
    batch : ndarray, shape (n, *item_shape), float64
    single : bool
        True when ``value`` was one item (then ``n == 1``).
    """
    arr = _as_float_array(value, name)
    k = len(item_shape)
    if arr.shape == item_shape:
        single = True
        arr = arr[None]
    elif arr.ndim == k + 1 and arr.shape[1:] == item_shape:
        single = False
    else:
        want = "x".join(str(d) for d in item_shape)
        raise InvalidInputError(
            name, f"expected shape ({want}) or (n, {want.replace('x', ', ')}), got {arr.shape}"
        )
    _check_finite(arr, name)
    return np.ascontiguousarray(arr), single


def as_points(value: Any, name: str) -> tuple[np.ndarray, bool]:
    """Return points as ``(n, 3)`` float64 (see :func:`as_batch`).

    Parameters
    ----------
    value : array_like, shape (3,) or (n, 3)
        Point(s) (mm).
    name : str
        Argument name used in error messages.

    Returns
    -------
    points : ndarray, shape (n, 3), float64
    single : bool
        True when ``value`` was one point.
    """
    return as_batch(value, name, (3,))


def as_rotations(value: Any, name: str) -> tuple[np.ndarray, bool]:
    """Return rotation matrices as ``(n, 3, 3)``, checking they are proper rotations.

    Parameters
    ----------
    value : array_like, shape (3, 3) or (n, 3, 3)
    name : str
        Argument name used in error messages.

    Returns
    -------
    rotations : ndarray, shape (n, 3, 3), float64
    single : bool
        True when ``value`` was one matrix.
    """
    rot, single = as_batch(value, name, (3, 3))
    _check_rotation(rot, name)
    return rot, single


#: Batches at least this large are checked by the numba kernel (numpy's einsum is about 10x
#: slower on large batches); smaller ones by numpy, so that reading a pose file or checking
#: a few poses does not load numba.
_KERNEL_MIN_BATCH = 64


def _rotation_errors(rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per matrix: max |R^T R - I| and |det R - 1| (the same sums as the kernel)."""
    if rot.shape[0] >= _KERNEL_MIN_BATCH:
        from needlekit._validation_kernels import rotation_errors

        return rotation_errors(rot)
    gram = np.einsum("kai,kaj->kij", rot, rot) - np.eye(3)
    ortho = np.abs(gram).max(axis=(1, 2)) if len(rot) else np.zeros(0)
    r = rot
    d = (
        r[:, 0, 0] * (r[:, 1, 1] * r[:, 2, 2] - r[:, 1, 2] * r[:, 2, 1])
        - r[:, 0, 1] * (r[:, 1, 0] * r[:, 2, 2] - r[:, 1, 2] * r[:, 2, 0])
        + r[:, 0, 2] * (r[:, 1, 0] * r[:, 2, 1] - r[:, 1, 1] * r[:, 2, 0])
    )
    return ortho, np.abs(d - 1.0)


def _check_rotation(rot: np.ndarray, name: str) -> None:
    ortho_err, det_err = _rotation_errors(np.ascontiguousarray(rot))
    bad = np.flatnonzero(
        (ortho_err > ROTATION_ORTHONORMAL_TOL) | (det_err > ROTATION_ORTHONORMAL_TOL)
    )
    if bad.size:
        i = int(bad[0])
        raise InvalidInputError(
            name,
            f"rotation part of item {i} is not a proper rotation "
            f"(|R^T R - I| = {ortho_err[i]:.2e}, det = {np.linalg.det(rot[i]):.6f})",
        )


def as_poses(value: Any, name: str) -> tuple[np.ndarray, bool]:
    """Return homogeneous poses as ``(n, 4, 4)``, checking rotation and last row.

    Parameters
    ----------
    value : array_like, shape (4, 4) or (n, 4, 4)
        Pose(s), translation in mm.
    name : str
        Argument name used in error messages.

    Returns
    -------
    poses : ndarray, shape (n, 4, 4), float64
    single : bool
        True when ``value`` was one pose.
    """
    pose, single = as_batch(value, name, (4, 4))
    last = np.abs(pose[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
    if np.any(last > ROTATION_ORTHONORMAL_TOL):
        i = int(np.flatnonzero(last > ROTATION_ORTHONORMAL_TOL)[0])
        raise InvalidInputError(
            name, f"last row of item {i} must be [0, 0, 0, 1], got {pose[i, 3]}"
        )
    _check_rotation(pose[:, :3, :3], name)
    return pose, single


def as_scalar(value: Any, name: str) -> float:
    """Return a finite float, or raise naming ``name``.

    Parameters
    ----------
    value : float or 0-d array_like (shape ())
    name : str
        Argument name used in error messages.

    Returns
    -------
    float
    """
    arr = _as_float_array(value, name)
    if arr.ndim != 0:
        raise InvalidInputError(name, f"expected a single number, got shape {arr.shape}")
    _check_finite(arr, name)
    return float(arr)


def as_positive(value: Any, name: str, *, allow_inf: bool = False) -> float:
    """Return a float > 0 (optionally allowing +inf), or raise naming ``name``.

    Parameters
    ----------
    value : float or 0-d array_like (shape ())
    name : str
        Argument name used in error messages.
    allow_inf : bool
        Accept +inf.

    Returns
    -------
    float
    """
    arr = _as_float_array(value, name)
    if arr.ndim != 0:
        raise InvalidInputError(name, f"expected a single number, got shape {arr.shape}")
    v = float(arr)
    if np.isnan(v) or (np.isinf(v) and not (allow_inf and v > 0)):
        raise InvalidInputError(name, f"must be a finite number > 0, got {v}")
    if v <= 0.0:
        raise InvalidInputError(name, f"must be > 0, got {v}")
    return v


def unbatch(arr: np.ndarray, single: bool) -> np.ndarray:
    """Drop the batch axis again when the caller passed one item.

    Parameters
    ----------
    arr : ndarray, shape (n, ...)
    single : bool
        As the ``as_*`` function returned it.

    Returns
    -------
    ndarray
        ``arr[0]`` (shape ``(...)``) when ``single``, else ``arr``.
    """
    return arr[0] if single else arr


def check_array(values: Any, name: str, bounds: Bounds) -> None:
    """Every entry of an array (a pose, the points of a file) finite and within ``bounds``.

    Parameters
    ----------
    values : ndarray
        Any shape, real.
    name : str
        The file or field, shown first in the message.
    bounds : Bounds

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"<name>: entry [i, j]: expected <range>, got <value>"`` for the first entry out of
        range.
    """
    arr = np.asarray(values, dtype=np.float64)
    above = arr > bounds.low if bounds.low_open else arr >= bounds.low
    bad = ~(np.isfinite(arr) & above & (arr <= bounds.high))
    if bad.any():
        at = tuple(int(i) for i in np.argwhere(bad)[0])
        where = f"entry [{', '.join(map(str, at))}]: " if at else ""
        raise InvalidInputError(name, f"{where}expected {bounds}, got {magnitude(float(arr[at]))}")
