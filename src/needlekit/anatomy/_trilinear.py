"""Trilinear interpolation of voxel grids: numba kernels and the plain numpy reference
they are tested against (:func:`trilinear_reference`). See :mod:`needlekit.anatomy.voxel`
for the error bound of the interpolant.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["FEW_POINTS", "PARALLEL_MIN_POINTS", "trilinear_few", "trilinear_reference"]

#: Batches smaller than this use the serial kernel: starting numba's threads costs ~10 us.
PARALLEL_MIN_POINTS: int = 4096
#: Batches of at most this many points run the kernels' own Python source
#: (:func:`trilinear_few`): the same arithmetic, without loading numba for the one-point
#: questions a problem asks when it is built (a process's first numba call costs ~0.25 s).
FEW_POINTS: int = 8


# ----------------------------------------------------------------------------------------
# trilinear lookup: numba kernels and the numpy reference


@numba.njit(cache=True, inline="always")
def _lookup(values, inv, h0, h1, h2, x, y, z, want_grad):  # pragma: no cover - compiled
    """Value (and world gradient) at one world point; see the module notes."""
    ni, nj, nk = values.shape
    u = inv[0, 0] * x + inv[0, 1] * y + inv[0, 2] * z + inv[0, 3]
    v = inv[1, 0] * x + inv[1, 1] * y + inv[1, 2] * z + inv[1, 3]
    w = inv[2, 0] * x + inv[2, 1] * y + inv[2, 2] * z + inv[2, 3]
    uc = min(max(u, 0.0), ni - 1.0)
    vc = min(max(v, 0.0), nj - 1.0)
    wc = min(max(w, 0.0), nk - 1.0)
    i = min(math.floor(uc), ni - 2)
    j = min(math.floor(vc), nj - 2)
    k = min(math.floor(wc), nk - 2)
    fu = uc - i
    fv = vc - j
    fw = wc - k
    c000 = np.float64(values[i, j, k])
    c001 = np.float64(values[i, j, k + 1])
    c010 = np.float64(values[i, j + 1, k])
    c011 = np.float64(values[i, j + 1, k + 1])
    c100 = np.float64(values[i + 1, j, k])
    c101 = np.float64(values[i + 1, j, k + 1])
    c110 = np.float64(values[i + 1, j + 1, k])
    c111 = np.float64(values[i + 1, j + 1, k + 1])
    c00 = c000 + (c001 - c000) * fw
    c01 = c010 + (c011 - c010) * fw
    c10 = c100 + (c101 - c100) * fw
    c11 = c110 + (c111 - c110) * fw
    c0 = c00 + (c01 - c00) * fv
    c1 = c10 + (c11 - c10) * fv
    val = c0 + (c1 - c0) * fu
    du = (u - uc) * h0
    dv = (v - vc) * h1
    dw = (w - wc) * h2
    ext2 = du * du + dv * dv + dw * dw
    gu = 0.0
    gv = 0.0
    gw = 0.0
    if want_grad:
        gu = c1 - c0
        gv = (1.0 - fu) * (c01 - c00) + fu * (c11 - c10)
        d0 = (1.0 - fv) * (c001 - c000) + fv * (c011 - c010)
        d1 = (1.0 - fv) * (c101 - c100) + fv * (c111 - c110)
        gw = (1.0 - fu) * d0 + fu * d1
    if ext2 > 0.0:
        pos = max(val, 0.0)
        val = math.sqrt(ext2 + pos * pos)
        if want_grad:
            # d/dx sqrt(|x - p|^2 + I(p)^2): (x - p) + I(p) * (tangential grad of I)
            gu = 0.0 if u != uc else pos * gu
            gv = 0.0 if v != vc else pos * gv
            gw = 0.0 if w != wc else pos * gw
            gu = (gu + (u - uc) * h0 * h0) / val
            gv = (gv + (v - vc) * h1 * h1) / val
            gw = (gw + (w - wc) * h2 * h2) / val
    # index-space gradient -> world: g_world = inv[:3, :3]^T g_index
    gx = inv[0, 0] * gu + inv[1, 0] * gv + inv[2, 0] * gw
    gy = inv[0, 1] * gu + inv[1, 1] * gv + inv[2, 1] * gw
    gz = inv[0, 2] * gu + inv[1, 2] * gv + inv[2, 2] * gw
    return val, gx, gy, gz


@numba.njit(cache=True, inline="always")
def _spacings(inv):  # pragma: no cover - compiled
    # rows of inv[:3, :3] = diag(1/h) R^T have norms 1/h_i for orthogonal axes
    h0 = 1.0 / math.sqrt(inv[0, 0] ** 2 + inv[0, 1] ** 2 + inv[0, 2] ** 2)
    h1 = 1.0 / math.sqrt(inv[1, 0] ** 2 + inv[1, 1] ** 2 + inv[1, 2] ** 2)
    h2 = 1.0 / math.sqrt(inv[2, 0] ** 2 + inv[2, 1] ** 2 + inv[2, 2] ** 2)
    return h0, h1, h2


def trilinear_few(values, inv_affine, points, *, gradient: bool = False):
    """The kernels' lookup for a few points, run as Python (its ``py_func``): the same
    operations in the same order, so the same values bit for bit.

    Parameters
    ----------
    values : ndarray, shape (i, j, k)
    inv_affine : ndarray, shape (4, 4)
    points : ndarray, shape (n, 3)
    gradient : bool

    Returns
    -------
    out : ndarray, shape (n,)
    grad : ndarray, shape (n, 3)
        Only with ``gradient``.
    """
    look = _lookup.py_func
    h0, h1, h2 = _spacings.py_func(inv_affine)
    out = np.empty(points.shape[0])
    grad = np.empty((points.shape[0], 3))
    for q in range(points.shape[0]):
        x, y, z = float(points[q, 0]), float(points[q, 1]), float(points[q, 2])
        val, gx, gy, gz = look(values, inv_affine, h0, h1, h2, x, y, z, gradient)
        out[q] = val
        grad[q] = (gx, gy, gz)
    return (out, grad) if gradient else out


@numba.njit(cache=True, parallel=True)
def _trilinear(values, inv_affine, points, out):  # pragma: no cover - compiled
    """Field values at world points (parallel). values (i, j, k) float32, inv_affine
    (4, 4) world->voxel, points (n, 3) float64, out (n,) float64."""
    h0, h1, h2 = _spacings(inv_affine)
    for q in numba.prange(points.shape[0]):
        out[q] = _lookup(
            values, inv_affine, h0, h1, h2, points[q, 0], points[q, 1], points[q, 2], False
        )[0]


@numba.njit(cache=True)
def _trilinear_serial(values, inv_affine, points, out):  # pragma: no cover - compiled
    """:func:`_trilinear` on one thread (small batches)."""
    h0, h1, h2 = _spacings(inv_affine)
    for q in range(points.shape[0]):
        out[q] = _lookup(
            values, inv_affine, h0, h1, h2, points[q, 0], points[q, 1], points[q, 2], False
        )[0]


@numba.njit(cache=True, parallel=True)
def _trilinear_gradient(values, inv_affine, points, out, grad):  # pragma: no cover
    """Values and world gradients (n, 3) of the interpolated field (parallel)."""
    h0, h1, h2 = _spacings(inv_affine)
    for q in numba.prange(points.shape[0]):
        val, gx, gy, gz = _lookup(
            values, inv_affine, h0, h1, h2, points[q, 0], points[q, 1], points[q, 2], True
        )
        out[q] = val
        grad[q, 0] = gx
        grad[q, 1] = gy
        grad[q, 2] = gz


@numba.njit(cache=True)
def _trilinear_gradient_serial(values, inv_affine, points, out, grad):  # pragma: no cover
    """:func:`_trilinear_gradient` on one thread (small batches)."""
    h0, h1, h2 = _spacings(inv_affine)
    for q in range(points.shape[0]):
        val, gx, gy, gz = _lookup(
            values, inv_affine, h0, h1, h2, points[q, 0], points[q, 1], points[q, 2], True
        )
        out[q] = val
        grad[q, 0] = gx
        grad[q, 1] = gy
        grad[q, 2] = gz


def trilinear_reference(values, inv_affine, points, *, gradient: bool = False):
    """Plain numpy reference of the trilinear kernels (same outside-grid rule).

    Parameters
    ----------
    values : ndarray, shape (i, j, k)
        Signed distances (mm) at voxel centres.
    inv_affine : ndarray, shape (4, 4)
        World (RAS, mm) -> voxel index affine, orthogonal axes.
    points : ndarray, shape (n, 3)
        World points (RAS, mm).
    gradient : bool
        Also return the world gradient.

    Returns
    -------
    values : ndarray, shape (n,)
        Interpolated signed distances (mm).
    grad : ndarray, shape (n, 3)
        Only when ``gradient``: d value / d point (world frame).

    Examples
    --------
    >>> vals = np.arange(8, dtype=np.float32).reshape(2, 2, 2)
    >>> trilinear_reference(vals, np.eye(4), np.array([[0.5, 0.5, 0.5]])).tolist()
    [3.5]
    """
    vals = np.asarray(values, dtype=np.float64)
    inv = np.asarray(inv_affine, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    shape = np.array(vals.shape)
    h = 1.0 / np.linalg.norm(inv[:3, :3], axis=1)
    u = p @ inv[:3, :3].T + inv[:3, 3]
    uc = np.clip(u, 0.0, shape - 1.0)
    base = np.minimum(np.floor(uc).astype(np.int64), shape - 2)
    f = uc - base
    val = np.zeros(len(p))
    g_idx = np.zeros((len(p), 3))
    for corner in np.ndindex(2, 2, 2):
        c = np.array(corner)
        wts = np.where(c, f, 1.0 - f)  # (n, 3) per-axis weights
        v = vals[base[:, 0] + c[0], base[:, 1] + c[1], base[:, 2] + c[2]]
        val += wts.prod(axis=1) * v
        for axis in range(3):
            others = [a for a in range(3) if a != axis]
            sign = 1.0 if c[axis] else -1.0
            g_idx[:, axis] += sign * wts[:, others].prod(axis=1) * v
    off = (u - uc) * h
    ext = np.linalg.norm(off, axis=1)
    outside = ext > 0
    pos = np.maximum(val, 0.0)
    out = np.where(outside, np.sqrt(ext**2 + pos**2), val)
    if not gradient:
        return out
    clamped = u != uc
    g_out = (np.where(clamped, 0.0, pos[:, None] * g_idx) + off * h) / np.where(outside, out, 1.0)[
        :, None
    ]
    g = np.where(outside[:, None], g_out, g_idx) @ inv[:3, :3]
    return out, g
