"""Rigid motions: homogeneous poses, and the exponential and logarithm of SE(3).

A twist is the 6-vector ``xi = (v, omega)`` (linear part first, see
:mod:`needlekit.conventions`) and ``hat6(xi)`` its 4x4 matrix. For a body twist held
constant for unit time, ``g(1) = g(0) @ se3_exp(xi)``.
"""

from __future__ import annotations

import numpy as np

from needlekit._validation import as_batch, as_poses, unbatch
from needlekit.constants import SMALL_ANGLE_RAD
from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import _exp_coefficients, _hat_batch, _so3_exp_batch, _so3_log_batch

__all__ = [
    "adjoint",
    "hat6",
    "make_pose",
    "pose_from_direction",
    "pose_inverse",
    "se3_exp",
    "se3_log",
    "transform_points",
    "vee6",
]


def hat6(twist):
    """4x4 matrix of a twist ``(v, omega)``.

    Parameters
    ----------
    twist : array_like, shape (6,) or (n, 6)

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
        ``[[hat(omega), v], [0, 0]]``.
    """
    xi, single = as_batch(twist, "twist", (6,))
    out = np.zeros((xi.shape[0], 4, 4))
    out[:, :3, :3] = _hat_batch(xi[:, 3:])
    out[:, :3, 3] = xi[:, :3]
    return unbatch(out, single)


def vee6(matrix):
    """Inverse of :func:`hat6`: the twist ``(v, omega)`` of a 4x4 se(3) matrix.

    Parameters
    ----------
    matrix : array_like, shape (4, 4) or (n, 4, 4)

    Returns
    -------
    ndarray, shape (6,) or (n, 6)
    """
    m, single = as_batch(matrix, "matrix", (4, 4))
    w = 0.5 * np.stack(
        [m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1
    )
    return unbatch(np.concatenate([m[:, :3, 3], w], axis=1), single)


def _se3_exp_batch(xi: np.ndarray) -> np.ndarray:
    v, w = xi[:, :3], xi[:, 3:]
    theta = np.linalg.norm(w, axis=1)
    _, b, c = _exp_coefficients(theta)
    k = _hat_batch(w)
    k2 = k @ k
    left_jac = np.eye(3) + b[:, None, None] * k + c[:, None, None] * k2
    out = np.zeros((xi.shape[0], 4, 4))
    out[:, :3, :3] = _so3_exp_batch(w)
    out[:, :3, 3] = np.einsum("nij,nj->ni", left_jac, v)
    out[:, 3, 3] = 1.0
    return out


def se3_exp(twist):
    """Pose ``exp(hat6(twist))`` in closed form.

    Parameters
    ----------
    twist : array_like, shape (6,) or (n, 6)
        Twists ``(v, omega)``: v in mm, omega in rad (i.e. a velocity times a duration).

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)

    Examples
    --------
    A unit-length insertion of a needle with curvature 0.01 /mm:

    >>> import numpy as np
    >>> g = se3_exp([0.0, 0.0, 10.0, 0.1, 0.0, 0.0])
    >>> np.round(g[:3, 3], 6)
    array([ 0.      , -0.499583,  9.983342])
    """
    xi, single = as_batch(twist, "twist", (6,))
    return unbatch(_se3_exp_batch(xi), single)


def _se3_log_batch(g: np.ndarray) -> np.ndarray:
    w = _so3_log_batch(g[:, :3, :3])
    theta = np.linalg.norm(w, axis=1)
    k = _hat_batch(w)
    small = theta < SMALL_ANGLE_RAD
    t = np.where(small, 1.0, theta)
    # V^-1 = I - K/2 + d K^2 with d = (1 - theta sin(theta) / (2 (1 - cos(theta)))) / theta^2
    half = 0.5 * t
    d = np.where(
        small,
        1.0 / 12.0 + theta**2 / 720.0,
        (1.0 - half / np.tan(half)) / (t * t),
    )
    v_inv = np.eye(3) - 0.5 * k + d[:, None, None] * (k @ k)
    v = np.einsum("nij,nj->ni", v_inv, g[:, :3, 3])
    return np.concatenate([v, w], axis=1)


def se3_log(pose):
    """Twist ``xi`` with ``se3_exp(xi) == pose``, rotation angle in [0, pi].

    Parameters
    ----------
    pose : array_like, shape (4, 4) or (n, 4, 4)

    Returns
    -------
    ndarray, shape (6,) or (n, 6)
        ``(v, omega)``, v in mm and omega in rad.
    """
    g, single = as_poses(pose, "pose")
    return unbatch(_se3_log_batch(g), single)


def make_pose(rotation=None, translation=None):
    """Build homogeneous poses from rotations and translations.

    Parameters
    ----------
    rotation : array_like, shape (3, 3) or (n, 3, 3), optional
        Proper rotation matrices (default identity).
    translation : array_like, shape (3,) or (n, 3), optional
        Translations in mm (default zero). Shapes broadcast over the batch axis.

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
    """
    r = np.eye(3) if rotation is None else np.asarray(rotation, dtype=np.float64)
    p = np.zeros(3) if translation is None else np.asarray(translation, dtype=np.float64)
    batch = np.broadcast_shapes(r.shape[:-2], p.shape[:-1])
    out = np.zeros((*batch, 4, 4))
    out[..., :3, :3] = r
    out[..., :3, 3] = p
    out[..., 3, 3] = 1.0
    _, _ = as_poses(out, "pose")  # validates rotation and finiteness
    return out


def pose_inverse(pose):
    """Inverse of rigid poses: ``a_T_b`` to ``b_T_a``.

    Parameters
    ----------
    pose : array_like, shape (4, 4) or (n, 4, 4)

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
        ``[[R^T, -R^T p], [0, 1]]``.
    """
    g, single = as_poses(pose, "pose")
    out = np.zeros_like(g)
    rt = np.transpose(g[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", rt, g[:, :3, 3])
    out[:, 3, 3] = 1.0
    return unbatch(out, single)


def pose_from_direction(point, direction) -> np.ndarray:
    """A pose at ``point`` whose z axis is ``direction`` (the rotation about z arbitrary but
    fixed).

    Parameters
    ----------
    point : array_like, shape (3,)
    direction : array_like, shape (3,)

    Returns
    -------
    ndarray, shape (4, 4)
    """
    z = np.asarray(direction, dtype=float)
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    g = np.eye(4)
    g[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    g[:3, 3] = point
    return g


def adjoint(pose):
    """6x6 adjoint of a pose for twists ordered ``(v, omega)``.

    ``Ad(g) @ xi_body`` is the same motion expressed as a spatial twist:
    ``hat6(Ad(g) xi) = g hat6(xi) g^-1``.

    Parameters
    ----------
    pose : array_like, shape (4, 4) or (n, 4, 4)

    Returns
    -------
    ndarray, shape (6, 6) or (n, 6, 6)
        ``[[R, hat(p) R], [0, R]]``.
    """
    g, single = as_poses(pose, "pose")
    r = g[:, :3, :3]
    out = np.zeros((g.shape[0], 6, 6))
    out[:, :3, :3] = r
    out[:, 3:, 3:] = r
    out[:, :3, 3:] = _hat_batch(g[:, :3, 3]) @ r
    return unbatch(out, single)


def transform_points(pose, points):
    """Apply one pose to points.

    Parameters
    ----------
    pose : array_like, shape (4, 4)
        ``a_T_b``: maps coordinates in frame b to frame a.
    points : array_like, shape (3,) or (n, 3)
        Points in frame b (mm).

    Returns
    -------
    ndarray, shape (3,) or (n, 3)
        The points in frame a (mm).
    """
    g, single_pose = as_poses(pose, "pose")
    if not single_pose:
        raise InvalidInputError("pose", f"expected one 4x4 pose, got a batch of {g.shape[0]}")
    p, single = as_batch(points, "points", (3,))
    out = p @ g[0, :3, :3].T + g[0, :3, 3]
    return unbatch(out, single)
