"""Unit dual quaternions as 8-vectors ``[r0, r1, r2, r3, d0, d1, d2, d3]`` (numba kernels).

A rigid transform with rotation quaternion ``r`` (scalar first) and translation ``t`` (mm)
is ``x = r + eps * (1/2) t r``. Products compose like 4x4 matrices
(``dq_mul(world_x_a, a_x_b) = world_x_b``). These are the few operations the controller's
hot path needs; ``dqrobotics`` is their test oracle.

Examples
--------
>>> import numpy as np
>>> x = dq_from_matrix(np.array([[0., -1, 0, 5], [1, 0, 0, 0], [0, 0, 1, 2], [0, 0, 0, 1]]))
>>> np.round(dq_translation(x), 12).tolist()
[5.0, 0.0, 2.0]
>>> bool(np.allclose(dq_to_matrix(dq_mul(x, dq_conj(x))), np.eye(4)))
True
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = [
    "dq_conj",
    "dq_from_matrix",
    "dq_mul",
    "dq_to_matrix",
    "dq_translation",
    "quat_mul",
    "quat_rotate",
]


@nb.njit(cache=True, inline="always")
def _qmul(a0, a1, a2, a3, b0, b1, b2, b3):
    return (
        a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3,
        a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2,
        a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1,
        a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0,
    )


@nb.njit(cache=True)
def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of quaternions (scalar first).

    Parameters
    ----------
    a, b : ndarray, shape (4,)

    Returns
    -------
    ndarray, shape (4,)
    """
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = _qmul(a[0], a[1], a[2], a[3], b[0], b[1], b[2], b[3])
    return out


@nb.njit(cache=True)
def quat_rotate(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate a 3-vector by a unit quaternion: ``r v r*``.

    Parameters
    ----------
    r : ndarray, shape (4,)
    v : ndarray, shape (3,)

    Returns
    -------
    ndarray, shape (3,)
    """
    p = _qmul(r[0], r[1], r[2], r[3], 0.0, v[0], v[1], v[2])
    q = _qmul(p[0], p[1], p[2], p[3], r[0], -r[1], -r[2], -r[3])
    out = np.empty(3)
    out[0], out[1], out[2] = q[1], q[2], q[3]
    return out


@nb.njit(cache=True)
def dq_mul(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Dual-quaternion product ``x y`` (composition of rigid transforms).

    Parameters
    ----------
    x, y : ndarray, shape (8,)

    Returns
    -------
    ndarray, shape (8,)
    """
    out = np.empty(8)
    p = _qmul(x[0], x[1], x[2], x[3], y[0], y[1], y[2], y[3])
    d1 = _qmul(x[0], x[1], x[2], x[3], y[4], y[5], y[6], y[7])
    d2 = _qmul(x[4], x[5], x[6], x[7], y[0], y[1], y[2], y[3])
    for i in range(4):
        out[i] = p[i]
        out[4 + i] = d1[i] + d2[i]
    return out


@nb.njit(cache=True)
def dq_conj(x: np.ndarray) -> np.ndarray:
    """Conjugate ``r* + eps d*`` (the inverse of a unit dual quaternion).

    Parameters
    ----------
    x : ndarray, shape (8,)

    Returns
    -------
    ndarray, shape (8,)
    """
    out = x.copy()
    for i in (1, 2, 3, 5, 6, 7):
        out[i] = -x[i]
    return out


@nb.njit(cache=True)
def dq_translation(x: np.ndarray) -> np.ndarray:
    """Translation ``t = 2 d r*`` (mm).

    Parameters
    ----------
    x : ndarray, shape (8,)

    Returns
    -------
    ndarray, shape (3,)
    """
    t = _qmul(x[4], x[5], x[6], x[7], x[0], -x[1], -x[2], -x[3])
    out = np.empty(3)
    out[0], out[1], out[2] = 2.0 * t[1], 2.0 * t[2], 2.0 * t[3]
    return out


@nb.njit(cache=True)
def _dq_to_matrix(x):
    w, a, b, c = x[0], x[1], x[2], x[3]
    g = np.eye(4)
    g[0, 0] = 1.0 - 2.0 * (b * b + c * c)
    g[0, 1] = 2.0 * (a * b - w * c)
    g[0, 2] = 2.0 * (a * c + w * b)
    g[1, 0] = 2.0 * (a * b + w * c)
    g[1, 1] = 1.0 - 2.0 * (a * a + c * c)
    g[1, 2] = 2.0 * (b * c - w * a)
    g[2, 0] = 2.0 * (a * c - w * b)
    g[2, 1] = 2.0 * (b * c + w * a)
    g[2, 2] = 1.0 - 2.0 * (a * a + b * b)
    t = dq_translation(x)
    g[0, 3], g[1, 3], g[2, 3] = t[0], t[1], t[2]
    return g


def dq_to_matrix(x) -> np.ndarray:
    """4x4 homogeneous transform of a unit dual quaternion.

    Parameters
    ----------
    x : array_like, shape (8,)

    Returns
    -------
    ndarray, shape (4, 4)
    """
    return _dq_to_matrix(np.ascontiguousarray(x, dtype=float))


@nb.njit(cache=True)
def _dq_from_matrix(g):
    # rotation matrix -> quaternion by Shepperd's method (the largest of the four
    # candidate denominators keeps it accurate everywhere)
    m00, m11, m22 = g[0, 0], g[1, 1], g[2, 2]
    tr = m00 + m11 + m22
    r = np.empty(4)
    if tr >= m00 and tr >= m11 and tr >= m22:
        s = 2.0 * np.sqrt(1.0 + tr)
        r[0] = 0.25 * s
        r[1] = (g[2, 1] - g[1, 2]) / s
        r[2] = (g[0, 2] - g[2, 0]) / s
        r[3] = (g[1, 0] - g[0, 1]) / s
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * np.sqrt(1.0 + m00 - m11 - m22)
        r[0] = (g[2, 1] - g[1, 2]) / s
        r[1] = 0.25 * s
        r[2] = (g[0, 1] + g[1, 0]) / s
        r[3] = (g[0, 2] + g[2, 0]) / s
    elif m11 >= m22:
        s = 2.0 * np.sqrt(1.0 + m11 - m00 - m22)
        r[0] = (g[0, 2] - g[2, 0]) / s
        r[1] = (g[0, 1] + g[1, 0]) / s
        r[2] = 0.25 * s
        r[3] = (g[1, 2] + g[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + m22 - m00 - m11)
        r[0] = (g[1, 0] - g[0, 1]) / s
        r[1] = (g[0, 2] + g[2, 0]) / s
        r[2] = (g[1, 2] + g[2, 1]) / s
        r[3] = 0.25 * s
    r /= np.sqrt(r[0] ** 2 + r[1] ** 2 + r[2] ** 2 + r[3] ** 2)
    if r[0] < 0.0:
        r = -r
    t = np.array([0.0, g[0, 3], g[1, 3], g[2, 3]])
    d = 0.5 * quat_mul(t, r)
    out = np.empty(8)
    out[:4] = r
    out[4:] = d
    return out


def dq_from_matrix(g) -> np.ndarray:
    """Unit dual quaternion of a 4x4 homogeneous transform (``r0 >= 0``).

    Parameters
    ----------
    g : array_like, shape (4, 4)

    Returns
    -------
    ndarray, shape (8,)
    """
    return _dq_from_matrix(np.ascontiguousarray(g, dtype=float))
