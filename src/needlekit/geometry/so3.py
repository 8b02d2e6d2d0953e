"""Rotations: the hat map, and the exponential and logarithm of SO(3).

Pure functions over arrays, batch-first: a single vector ``(3,)`` or matrix ``(3, 3)``
gives a single result, a batch ``(n, 3)`` / ``(n, 3, 3)`` gives a batch.
"""

from __future__ import annotations

import math

import numpy as np

from needlekit._validation import as_batch, as_rotations, unbatch
from needlekit.constants import SMALL_ANGLE_RAD

__all__ = [
    "angle_between",
    "cross3",
    "hat",
    "hat_unchecked",
    "rot_x",
    "rot_y",
    "rot_z",
    "so3_exp",
    "so3_exp_unchecked",
    "so3_log",
    "so3_log_unchecked",
    "vee",
]


def _hat_batch(w: np.ndarray) -> np.ndarray:
    out = np.zeros((w.shape[0], 3, 3))
    out[:, 0, 1] = -w[:, 2]
    out[:, 0, 2] = w[:, 1]
    out[:, 1, 0] = w[:, 2]
    out[:, 1, 2] = -w[:, 0]
    out[:, 2, 0] = -w[:, 1]
    out[:, 2, 1] = w[:, 0]
    return out


def hat(omega):
    """Skew-symmetric matrix of a 3-vector, so that ``hat(a) @ b == cross(a, b)``.

    Parameters
    ----------
    omega : array_like, shape (3,) or (n, 3)

    Returns
    -------
    ndarray, shape (3, 3) or (n, 3, 3)

    Examples
    --------
    >>> hat([1.0, 2.0, 3.0]) @ [4.0, 5.0, 6.0]
    array([-3.,  6., -3.])
    """
    w, single = as_batch(omega, "omega", (3,))
    return unbatch(_hat_batch(w), single)


def vee(matrix):
    """Inverse of :func:`hat`: the 3-vector of the skew part of a 3x3 matrix.

    Parameters
    ----------
    matrix : array_like, shape (3, 3) or (n, 3, 3)

    Returns
    -------
    ndarray, shape (3,) or (n, 3)
        ``(M[2,1] - M[1,2], M[0,2] - M[2,0], M[1,0] - M[0,1]) / 2``.
    """
    m, single = as_batch(matrix, "matrix", (3, 3))
    out = 0.5 * np.stack(
        [m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], axis=1
    )
    return unbatch(out, single)


def _exp_coefficients(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3, series near 0."""
    small = theta < SMALL_ANGLE_RAD
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    a = np.where(small, 1.0 - t2 / 6.0, np.sin(t) / t)
    b = np.where(small, 0.5 - t2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    c = np.where(small, 1.0 / 6.0 - t2 / 120.0, (t - np.sin(t)) / (t * t * t))
    return a, b, c


def _so3_exp_batch(w: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(w, axis=1)
    a, b, _ = _exp_coefficients(theta)
    k = _hat_batch(w)
    return np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)


def so3_exp(omega):
    """Rotation matrix ``exp(hat(omega))`` (Rodrigues' formula).

    Parameters
    ----------
    omega : array_like, shape (3,) or (n, 3)
        Rotation vectors (axis times angle, rad).

    Returns
    -------
    ndarray, shape (3, 3) or (n, 3, 3)

    Examples
    --------
    >>> import numpy as np
    >>> np.round(so3_exp([0.0, 0.0, np.pi / 2]), 12)
    array([[ 0., -1.,  0.],
           [ 1.,  0.,  0.],
           [ 0.,  0.,  1.]])
    """
    w, single = as_batch(omega, "omega", (3,))
    return unbatch(_so3_exp_batch(w), single)


# unchecked entry points for per-step loops (a simulation tick): one float64 3-vector in,
# nothing validated or broadcast; each gives what its checked twin gives for one vector


def hat_unchecked(w: np.ndarray) -> np.ndarray:
    """:func:`hat` of one float64 3-vector, without its checks.

    Parameters
    ----------
    w : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (3, 3)
    """
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def so3_exp_unchecked(w: np.ndarray) -> np.ndarray:
    """:func:`so3_exp` of one float64 3-vector, without its checks (a fifth of its time).

    Parameters
    ----------
    w : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (3, 3)
    """
    theta = math.sqrt(float(w @ w))
    if theta < SMALL_ANGLE_RAD:  # the series of _exp_coefficients
        a, b = 1.0 - theta * theta / 6.0, 0.5 - theta * theta / 24.0
    else:
        a, b = math.sin(theta) / theta, (1.0 - math.cos(theta)) / (theta * theta)
    k = hat_unchecked(w)
    return np.eye(3) + a * k + b * (k @ k)


def _so3_log_batch(r: np.ndarray) -> np.ndarray:
    cos_t = np.clip((np.trace(r, axis1=1, axis2=2) - 1.0) * 0.5, -1.0, 1.0)
    s = 0.5 * np.stack(
        [r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0], r[:, 1, 0] - r[:, 0, 1]], axis=1
    )  # sin(theta) * axis
    sin_t = np.linalg.norm(s, axis=1)
    theta = np.arctan2(sin_t, cos_t)
    out = np.empty_like(s)
    small = theta < SMALL_ANGLE_RAD
    out[small] = s[small] * (1.0 + theta[small, None] ** 2 / 6.0)
    # Away from 0 and pi the skew part gives the axis accurately.
    near_pi = (~small) & (cos_t < -0.5)
    regular = ~small & ~near_pi
    out[regular] = s[regular] * (theta[regular] / sin_t[regular])[:, None]
    if np.any(near_pi):
        # Near pi, sin(theta) loses the axis; read it from the symmetric part instead:
        # (R + R^T) / 2 = cos(theta) I + (1 - cos(theta)) a a^T.
        rp = r[near_pi]
        cp = cos_t[near_pi]
        sym = 0.5 * (rp + np.transpose(rp, (0, 2, 1))) - cp[:, None, None] * np.eye(3)
        aat = sym / (1.0 - cp)[:, None, None]
        idx = np.argmax(np.diagonal(aat, axis1=1, axis2=2), axis=1)
        rows = np.arange(rp.shape[0])
        axis = aat[rows, idx, :] / np.sqrt(aat[rows, idx, idx])[:, None]
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        # Choose the sign that agrees with the skew part (which is sin(theta) * axis).
        sign = np.where(np.einsum("ni,ni->n", axis, s[near_pi]) < 0.0, -1.0, 1.0)
        out[near_pi] = axis * (sign * theta[near_pi])[:, None]
    return out


def so3_log_unchecked(r: np.ndarray) -> np.ndarray:
    """:func:`so3_log` of one float64 rotation matrix, without its checks: the same
    operations one number at a time (the same bits; near pi, the batch's branch itself).
    A tenth of its time, for a filter that takes the log of every sample (the sample
    screened where it came in).

    Parameters
    ----------
    r : ndarray, shape (3, 3)

    Returns
    -------
    ndarray, shape (3,)
    """
    cos_t = min(max((r[0, 0] + r[1, 1] + r[2, 2] - 1.0) * 0.5, -1.0), 1.0)
    s0, s1, s2 = 0.5 * (r[2, 1] - r[1, 2]), 0.5 * (r[0, 2] - r[2, 0]), 0.5 * (r[1, 0] - r[0, 1])
    sin_t = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2)
    # numpy's arctan2, not math's: on AVX-512 machines numpy's SIMD loop rounds about one
    # result in ten differently from libm's (called on one number it runs the same loop)
    theta = float(np.arctan2(sin_t, cos_t))
    if theta < SMALL_ANGLE_RAD:
        f = 1.0 + theta * theta / 6.0
    elif cos_t < -0.5:  # near pi: the symmetric part's branch of the batch
        return _so3_log_batch(r.reshape(1, 3, 3))[0]
    else:
        f = theta / sin_t
    return np.array([s0 * f, s1 * f, s2 * f])


def so3_log(rotation):
    """Rotation vector of a rotation matrix, with angle in [0, pi].

    Parameters
    ----------
    rotation : array_like, shape (3, 3) or (n, 3, 3)
        Proper rotation matrices.

    Returns
    -------
    ndarray, shape (3,) or (n, 3)
        ``omega`` with ``so3_exp(omega) == rotation``; accurate near 0 and near pi.
    """
    r, single = as_rotations(rotation, "rotation")
    return unbatch(_so3_log_batch(r), single)


def _axis_rotation(angle, axis: int) -> np.ndarray:
    th, single = as_batch(np.asarray(angle, dtype=np.float64)[..., None], "angle", (1,))
    th = th[:, 0]
    c, s = np.cos(th), np.sin(th)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out = np.zeros((th.shape[0], 3, 3))
    out[:, axis, axis] = 1.0
    out[:, i, i] = c
    out[:, j, j] = c
    out[:, i, j] = -s
    out[:, j, i] = s
    return unbatch(out, single)


def rot_x(angle):
    """Rotation matrix about the x axis.

    Parameters
    ----------
    angle : float or array_like, shape (n,)
        Rotation angle (rad), right-handed.

    Returns
    -------
    ndarray, shape (3, 3) or (n, 3, 3)
    """
    return _axis_rotation(angle, 0)


def rot_y(angle):
    """Rotation matrix about the y axis.

    Parameters
    ----------
    angle : float or array_like, shape (n,)
        Rotation angle (rad), right-handed.

    Returns
    -------
    ndarray, shape (3, 3) or (n, 3, 3)
    """
    return _axis_rotation(angle, 1)


def rot_z(angle):
    """Rotation matrix about the z axis.

    Parameters
    ----------
    angle : float or array_like, shape (n,)
        Rotation angle (rad), right-handed.

    Returns
    -------
    ndarray, shape (3, 3) or (n, 3, 3)
    """
    return _axis_rotation(angle, 2)


def _cross_parts(a0, a1, a2, b0, b1, b2) -> tuple[float, float, float]:
    # np.cross's products and differences, in its order
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


def cross3(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``u x v`` of one pair of 3-vectors by scalar arithmetic, the same bits as
    ``np.cross`` (whose axis handling costs about 20 us on one pair).

    Parameters
    ----------
    u, v : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (3,)

    Examples
    --------
    >>> cross3(np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])).tolist()
    [0.0, 0.0, 1.0]
    """
    return np.array(_cross_parts(*u.tolist(), *v.tolist()))


def angle_between(u, v) -> np.ndarray:
    """The angle (rad) between directions ``u`` and ``v`` (any lengths), row by row:
    ``atan2(|u x v|, u . v)``, exact at 0 and pi where ``arccos`` of the normalised dot
    product loses half the digits (two unit vectors equal to 1e-13 in length give
    ``arccos`` 1e-6 rad, not 0).

    Parameters
    ----------
    u, v : array_like, shape (..., 3)
        Broadcast against each other.

    Returns
    -------
    ndarray
        Shape of the broadcast without the last axis (a 0-d array for two vectors).

    Examples
    --------
    >>> z = np.array([0.0, 0.0, 1.0])
    >>> float(angle_between(z * (1 - 3e-13), z))
    0.0
    >>> round(float(np.degrees(angle_between([1.0, 0.0, 0.0], [1.0, 1.0, 0.0]))), 12)
    45.0
    """
    a = np.asarray(u, dtype=np.float64)
    b = np.asarray(v, dtype=np.float64)
    if a.shape == (3,) and b.shape == (3,):
        # one pair (a control tick's angle): the same products and sums in the same order
        # as the batch line below, and numpy's own arctan2 (math's rounds differently on
        # AVX-512 machines), so the same bits, without np.cross's axis handling
        # (measured: 30x faster per call, a sixth of a multi trial's time before)
        a0, a1, a2 = a.tolist()
        b0, b1, b2 = b.tolist()
        x, y, z = _cross_parts(a0, a1, a2, b0, b1, b2)
        return np.arctan2(math.sqrt(x * x + y * y + z * z), a0 * b0 + a1 * b1 + a2 * b2)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
