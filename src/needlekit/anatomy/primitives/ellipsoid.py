"""The ellipsoid with its exact Euclidean distance (Eberly's reduction to a 1-D root):
a numba kernel and the plain-Python reference it is tested against."""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit._validation import as_points, unbatch
from needlekit.anatomy.primitives._base import (
    _EPS,
    _ROOT_MAX_ITER,
    _SNAP_REL,
    ELLIPSOID_ERROR_BOUND_MM,
    _fmt,
    _positive3,
    _Primitive,
    _snap,
)

__all__ = ["Ellipsoid", "ellipsoid_distance", "ellipsoid_distance_reference"]

# ----------------------------------------------------------------------------------------
# ellipsoid: Eberly's 1-D root, in the shifted variable u = s + 1 (relative precision near
# the coordinate planes). Axes sorted a0 >= a1 >= a2, point in the first octant.
#
#   F(u) = (n0 / (u + c0))^2 + (n1 / (u + c1))^2 + (z2 / u)^2 - 1,
#   z_i = y_i / a_i, r_i = (a_i / a2)^2, c_i = r_i - 1 >= 0, n_i = r_i z_i,
#
# is convex and decreasing on u > 0 with one root in [z2, 1] (inside) or [z2, |n|]
# (outside); the closest point is x_i = r_i y_i / (u + c_i).


def _eberly_bracket(n0, n1, z2, g):
    hi = 1.0 if g < 0.0 else math.sqrt(n0 * n0 + n1 * n1 + z2 * z2)
    return z2, hi


@numba.njit(cache=True, error_model="numpy")
def _eberly_root_nb(n0, c0, n1, c1, z2, g):  # pragma: no cover - compiled
    lo = z2
    hi = 1.0 if g < 0.0 else math.sqrt(n0 * n0 + n1 * n1 + z2 * z2)
    u = 0.5 * (lo + hi)
    dx_old = hi - lo
    dx = dx_old
    for _ in range(_ROOT_MAX_ITER):
        a0 = n0 / (u + c0)
        a1 = n1 / (u + c1)
        a2 = z2 / u
        f = a0 * a0 + a1 * a1 + a2 * a2 - 1.0
        df = -2.0 * (a0 * a0 / (u + c0) + a1 * a1 / (u + c1) + a2 * a2 / u)
        if f > 0.0:
            lo = u
        elif f < 0.0:
            hi = u
        else:
            return u
        newton = u - f / df
        if abs(newton - u) <= 4.0 * _EPS * u:  # converged: Newton's step is at rounding
            return newton if lo <= newton <= hi else u
        if not (lo < newton < hi) or abs(2.0 * f) > abs(dx_old * df):
            # bisect; geometrically while the bracket spans orders of magnitude (tiny z2)
            dx_old = dx
            u_new = math.sqrt(lo) * math.sqrt(hi) if hi > 4.0 * lo else 0.5 * (lo + hi)
            dx = u - u_new
        else:
            dx_old = dx
            dx = u - newton
            u_new = newton
        if abs(u_new - u) <= 4.0 * _EPS * u_new or u_new == lo or u_new == hi:
            return u_new
        u = u_new
    return u


@numba.njit(cache=True, error_model="numpy")
def _ellipse_closest_nb(a0, a1, y0, y1):  # pragma: no cover - compiled
    """Closest point of the ellipse (a0 >= a1) to (y0, y1) >= 0."""
    if y1 > 0.0:
        if y0 > 0.0:
            z0 = y0 / a0
            z1 = y1 / a1
            g = z0 * z0 + z1 * z1 - 1.0
            if g == 0.0:
                return y0, y1
            r0 = (a0 / a1) ** 2
            u = _eberly_root_nb(r0 * z0, r0 - 1.0, 0.0, 0.0, z1, g)
            return r0 * y0 / (u + r0 - 1.0), y1 / u
        return 0.0, a1
    denom = a0 * a0 - a1 * a1
    numer = a0 * y0
    if numer < denom:
        xa = numer / denom
        return a0 * xa, a1 * math.sqrt(max(1.0 - xa * xa, 0.0))
    return a0, 0.0


@numba.njit(cache=True, error_model="numpy")
def _ellipsoid_closest_nb(a0, a1, a2, y0, y1, y2):  # pragma: no cover - compiled
    """Closest point of the ellipsoid (a0 >= a1 >= a2) to (y0, y1, y2) >= 0."""
    if y2 > 0.0:
        if y1 > 0.0:
            if y0 > 0.0:
                z0 = y0 / a0
                z1 = y1 / a1
                z2 = y2 / a2
                g = z0 * z0 + z1 * z1 + z2 * z2 - 1.0
                if g == 0.0:
                    return y0, y1, y2
                r0 = (a0 / a2) ** 2
                r1 = (a1 / a2) ** 2
                u = _eberly_root_nb(r0 * z0, r0 - 1.0, r1 * z1, r1 - 1.0, z2, g)
                return r0 * y0 / (u + r0 - 1.0), r1 * y1 / (u + r1 - 1.0), y2 / u
            x1, x2 = _ellipse_closest_nb(a1, a2, y1, y2)
            return 0.0, x1, x2
        if y0 > 0.0:
            x0, x2 = _ellipse_closest_nb(a0, a2, y0, y2)
            return x0, 0.0, x2
        return 0.0, 0.0, a2
    d0 = a0 * a0 - a2 * a2
    d1 = a1 * a1 - a2 * a2
    n0 = a0 * y0
    n1 = a1 * y1
    if n0 < d0 and n1 < d1:
        xa0 = n0 / d0
        xa1 = n1 / d1
        disc = 1.0 - xa0 * xa0 - xa1 * xa1
        if disc > 0.0:
            return a0 * xa0, a1 * xa1, a2 * math.sqrt(disc)
    x0, x1 = _ellipse_closest_nb(a0, a1, y0, y1)
    return x0, x1, 0.0


@numba.njit(cache=True, error_model="numpy")
def _ellipsoid_kernel(points, axes, perm, sd, closest):  # pragma: no cover - compiled
    a0 = axes[perm[0]]
    a1 = axes[perm[1]]
    a2 = axes[perm[2]]
    for k in range(points.shape[0]):
        y0 = _snap(abs(points[k, perm[0]]), a0)
        y1 = _snap(abs(points[k, perm[1]]), a1)
        y2 = _snap(abs(points[k, perm[2]]), a2)
        x0, x1, x2 = _ellipsoid_closest_nb(a0, a1, a2, y0, y1, y2)
        closest[k, perm[0]] = math.copysign(x0, points[k, perm[0]])
        closest[k, perm[1]] = math.copysign(x1, points[k, perm[1]])
        closest[k, perm[2]] = math.copysign(x2, points[k, perm[2]])
        dist = math.sqrt((x0 - y0) ** 2 + (x1 - y1) ** 2 + (x2 - y2) ** 2)
        g = (y0 / a0) ** 2 + (y1 / a1) ** 2 + (y2 / a2) ** 2 - 1.0
        sd[k] = -dist if g < 0.0 else dist


def _ellipsoid_args(points, semi_axes_mm):
    p, single = as_points(points, "points")
    axes = _positive3(semi_axes_mm, "semi_axes_mm")
    perm = np.argsort(-axes, kind="stable").astype(np.int64)
    return p, single, axes, perm


def ellipsoid_distance(points, semi_axes_mm):
    """Exact signed distance to the ellipsoid ``sum (x_i / a_i)^2 = 1`` (numba kernel).

    Eberly's method: by symmetry the closest point lies in the point's octant; with the
    semi-axes sorted, the Lagrange condition reduces to one convex decreasing function
    of one variable with a bracketed root, solved by safeguarded Newton (bisection when
    Newton leaves the bracket). Points on the coordinate planes, on the axes and at the
    centre, and equal semi-axes (spheroids, spheres), take the closed-form branches.

    Parameters
    ----------
    points : array_like, shape (3,) or (n, 3)
        Points in the ellipsoid's local frame (mm).
    semi_axes_mm : array_like, shape (3,)
        Semi-axes ``a`` along local x, y, z (mm), each > 0.

    Returns
    -------
    signed_distance : ndarray, shape () or (n,)
        Euclidean distance to the surface (mm), negative inside.
    closest : ndarray, shape (3,) or (n, 3)
        A closest surface point (local frame, mm); one of several on the medial axis.

    Examples
    --------
    >>> sd, x = ellipsoid_distance([[0.0, 0.0, 0.0], [0.0, 0.0, 20.0]], [100.0, 10.0, 5.0])
    >>> sd.tolist(), x[1].tolist()
    ([-5.0, 15.0], [0.0, 0.0, 5.0])
    """
    p, single, axes, perm = _ellipsoid_args(points, semi_axes_mm)
    sd = np.empty(p.shape[0])
    closest = np.empty_like(p)
    _ellipsoid_kernel(p, axes, perm, sd, closest)
    return unbatch(sd, single), unbatch(closest, single)


# plain-Python reference: the same reduction, with Eberly's pure bisection (run until the
# midpoint equals an end point) instead of safeguarded Newton.


def _eberly_root_py(n0, c0, n1, c1, z2, g):
    lo, hi = _eberly_bracket(n0, n1, z2, g)
    u = lo
    for _ in range(2200):
        u = 0.5 * (lo + hi)
        if u in (lo, hi):
            break
        f = (n0 / (u + c0)) ** 2 + (n1 / (u + c1)) ** 2 + (z2 / u) ** 2 - 1.0
        if f > 0.0:
            lo = u
        elif f < 0.0:
            hi = u
        else:
            break
    return u


def _ellipse_closest_py(a0, a1, y0, y1):
    if y1 > 0.0:
        if y0 > 0.0:
            z0, z1 = y0 / a0, y1 / a1
            g = z0 * z0 + z1 * z1 - 1.0
            if g == 0.0:
                return y0, y1
            r0 = (a0 / a1) ** 2
            u = _eberly_root_py(r0 * z0, r0 - 1.0, 0.0, 0.0, z1, g)
            return r0 * y0 / (u + r0 - 1.0), y1 / u
        return 0.0, a1
    denom, numer = a0 * a0 - a1 * a1, a0 * y0
    if numer < denom:
        xa = numer / denom
        return a0 * xa, a1 * math.sqrt(max(1.0 - xa * xa, 0.0))
    return a0, 0.0


def _ellipsoid_closest_py(a0, a1, a2, y0, y1, y2):
    if y2 > 0.0:
        if y1 > 0.0:
            if y0 > 0.0:
                z0, z1, z2 = y0 / a0, y1 / a1, y2 / a2
                g = z0 * z0 + z1 * z1 + z2 * z2 - 1.0
                if g == 0.0:
                    return y0, y1, y2
                r0, r1 = (a0 / a2) ** 2, (a1 / a2) ** 2
                u = _eberly_root_py(r0 * z0, r0 - 1.0, r1 * z1, r1 - 1.0, z2, g)
                return r0 * y0 / (u + r0 - 1.0), r1 * y1 / (u + r1 - 1.0), y2 / u
            x1, x2 = _ellipse_closest_py(a1, a2, y1, y2)
            return 0.0, x1, x2
        if y0 > 0.0:
            x0, x2 = _ellipse_closest_py(a0, a2, y0, y2)
            return x0, 0.0, x2
        return 0.0, 0.0, a2
    d0, d1 = a0 * a0 - a2 * a2, a1 * a1 - a2 * a2
    n0, n1 = a0 * y0, a1 * y1
    if n0 < d0 and n1 < d1:
        xa0, xa1 = n0 / d0, n1 / d1
        disc = 1.0 - xa0 * xa0 - xa1 * xa1
        if disc > 0.0:
            return a0 * xa0, a1 * xa1, a2 * math.sqrt(disc)
    x0, x1 = _ellipse_closest_py(a0, a1, y0, y1)
    return x0, x1, 0.0


def ellipsoid_distance_reference(points, semi_axes_mm):
    """Plain-Python reference of :func:`ellipsoid_distance` (Eberly's pure bisection).

    Parameters
    ----------
    points : array_like, shape (3,) or (n, 3)
        Points in the ellipsoid's local frame (mm).
    semi_axes_mm : array_like, shape (3,)
        Semi-axes along local x, y, z (mm), each > 0.

    Returns
    -------
    signed_distance : ndarray, shape () or (n,)
        Euclidean distance to the surface (mm), negative inside.
    closest : ndarray, shape (3,) or (n, 3)
        A closest surface point (local frame, mm).

    Examples
    --------
    >>> sd, _ = ellipsoid_distance_reference([3.0, 0.0, 0.0], [1.0, 1.0, 1.0])
    >>> float(sd)
    2.0
    """
    p, single, axes, perm = _ellipsoid_args(points, semi_axes_mm)
    a = [float(axes[i]) for i in perm]
    sd = np.empty(p.shape[0])
    closest = np.empty_like(p)
    for k, row in enumerate(p):
        y = [abs(float(row[i])) for i in perm]
        y = [0.0 if yi < _SNAP_REL * ai else yi for yi, ai in zip(y, a, strict=True)]
        x = _ellipsoid_closest_py(*a, *y)
        for slot, i in enumerate(perm):
            closest[k, i] = math.copysign(x[slot], row[i])
        dist = math.sqrt(sum((xi - yi) ** 2 for xi, yi in zip(x, y, strict=True)))
        g = sum((yi / ai) ** 2 for yi, ai in zip(y, a, strict=True)) - 1.0
        sd[k] = -dist if g < 0.0 else dist
    return unbatch(sd, single), unbatch(closest, single)


class Ellipsoid(_Primitive):
    """Solid ellipsoid ``sum (x_i / a_i)^2 <= 1`` centred at the local origin (mm).

    Exact Euclidean distance (:func:`ellipsoid_distance`), not the radial or algebraic
    estimate. :attr:`error_bound_mm` is :data:`ELLIPSOID_ERROR_BOUND_MM`.

    Parameters
    ----------
    semi_axes_mm : array_like, shape (3,)
        Semi-axes along the local x, y, z axes (mm), each > 0 (equal ones allowed).
    world_T_local : array_like, shape (4, 4), optional
        Pose of the centre and axes in the world (identity by default).

    Examples
    --------
    >>> e = Ellipsoid([100.0, 10.0, 10.0])
    >>> e.signed_distance([[0.0, 15.0, 0.0], [110.0, 0.0, 0.0]]).tolist()
    [5.0, 10.0]
    """

    error_bound_mm = ELLIPSOID_ERROR_BOUND_MM

    def __init__(self, semi_axes_mm, world_T_local=None) -> None:
        self.semi_axes_mm = _positive3(semi_axes_mm, "semi_axes_mm")
        self._perm = np.argsort(-self.semi_axes_mm, kind="stable").astype(np.int64)
        self._set_pose(world_T_local)

    def _local_eval(self, q):
        sd = np.empty(q.shape[0])
        x = np.empty_like(q)
        _ellipsoid_kernel(np.ascontiguousarray(q), self.semi_axes_mm, self._perm, sd, x)
        grad = x / self.semi_axes_mm**2
        return sd, grad / np.linalg.norm(grad, axis=1, keepdims=True)

    def _local_bounds(self):
        return np.stack([-self.semi_axes_mm, self.semi_axes_mm])

    def __repr__(self) -> str:
        return f"Ellipsoid(semi_axes_mm={_fmt(self.semi_axes_mm)}{self._pose_repr()})"
