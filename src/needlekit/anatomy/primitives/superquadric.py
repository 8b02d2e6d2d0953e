"""Superquadrics (Liu et al. 2016, Eq. 4) with the true Euclidean distance: projection
onto the surface in a numba kernel."""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit._validation import as_points, as_positive, unbatch
from needlekit.anatomy.primitives._base import (
    _CURVATURE_FLOOR,
    _EPS,
    _GRID_DIVISIONS,
    _INNER_MAX_ITER,
    _LINE_SEARCH_HALVINGS,
    _REFINE_MAX_ITER,
    _REFINE_STEP_TOL_REL,
    _ROOT_MAX_ITER,
    SUPERQUADRIC_ERROR_BOUND_MM,
    SUPERQUADRIC_MAX_EXPONENT,
    _exponents3,
    _fmt,
    _positive3,
    _Primitive,
    _snap,
)
from needlekit.anatomy.primitives.closed_forms import Capsule
from needlekit.errors import InvalidInputError

__all__ = ["Superquadric", "superquadric_distance"]

# ----------------------------------------------------------------------------------------
# superquadric  G(x) = sum_i (|x_i| / a_i)^{e_i} - 1,  e_i in [2, 32]
#
# The body is convex and symmetric in each coordinate plane, so the closest point lies in
# the point's octant; work with y = |p| and x >= 0. Per coordinate
#   T_i(x) = (x/a)^e,  g_i(x) = T_i'(x) = (e/a)(x/a)^(e-1),  g_i'(x) = (e(e-1)/a^2)(x/a)^(e-2).
#
# Outside (G(y) > 0): the closest point is x(t) with x_i + t g_i(x_i) = y_i, t > 0. For
# each t this has one root x_i in [0, y_i] (the left side is convex and increasing), and
# G(x(t)) decreases from G(y) > 0 to -1: a bracketed monotone 1-D root, nested around
# monotone 1-D roots. Any such critical point is the global minimum (its tangent plane
# separates the convex body from y).
#
# Inside (G(y) < 0): the same equations have folds (the global minimum may sit on the
# decreasing branch of some coordinate), so project by descent instead: a Newton method
# on the surface, written in the graph chart x_k = phi(x_i, x_j) of the coordinate k with
# the largest normal component (slopes |dphi| <= 1), with a modified Hessian, a
# negative-curvature direction at saddles and a backtracking line search on |x - y|^2,
# from seven starting points: the three axis projections (moving y along one axis onto
# the surface) and the four best of a 45-point simplex grid on the surface. Every iterate
# is a true surface point, so the reported depth is never shallower than the truth.


@numba.njit(cache=True, error_model="numpy", inline="always")
def _pow(r, p):  # pragma: no cover - compiled
    """r ** p for r >= 0: by repeated squaring where p is a whole number up to 32 (the
    exponents of vessels and needle heads: 2, 8), a few roundings instead of a call to
    the library's pow (about half the time of the outside projection)."""
    n = int(p)
    if n == p and 0 <= n <= 32:
        out = 1.0
        while n:
            if n & 1:
                out *= r
            r *= r
            n >>= 1
        return out
    return r**p


@numba.njit(cache=True, error_model="numpy", inline="always")
def _sq_t(x, a, e):  # pragma: no cover - compiled
    return _pow(x / a, e)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _sq_g(x, a, e):  # pragma: no cover - compiled
    return (e / a) * _pow(x / a, e - 1.0)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _sq_gp(x, a, e):  # pragma: no cover - compiled
    return (e * (e - 1.0) / (a * a)) * _pow(x / a, e - 2.0)


@numba.njit(cache=True, error_model="numpy")
def _sq_inner(y, a, e, t):  # pragma: no cover - compiled
    """Root x in [0, y] of x + t g(x) = y (t >= 0) and dx/dt."""
    if y == 0.0:
        return 0.0, 0.0
    if t == 0.0:
        return y, -_sq_g(y, a, e)
    if e == 2.0:
        den = 1.0 + 2.0 * t / (a * a)
        x = y / den
        return x, -(2.0 * x / (a * a)) / den
    # both y and the root of t g(x) = y bound the root from above; Newton from above on a
    # convex increasing function descends monotonically onto the root
    x = y
    rho = a * (y * a / (t * e)) ** (1.0 / (e - 1.0))
    if 0.0 < rho < y:
        x = rho
    for _ in range(_INNER_MAX_ITER):
        h = x + t * _sq_g(x, a, e) - y
        step = h / (1.0 + t * _sq_gp(x, a, e))
        if not step > 0.0:
            break
        x_new = x - step
        if x_new <= 0.0:
            x_new = 0.5 * x
        if x - x_new <= 2.0 * _EPS * x:
            x = x_new
            break
        x = x_new
    return x, -_sq_g(x, a, e) / (1.0 + t * _sq_gp(x, a, e))


@numba.njit(cache=True, error_model="numpy")
def _sq_outside(y, a, e, out):  # pragma: no cover - compiled
    """Closest surface point to y >= 0 with G(y) > 0, written to out.

    Safeguarded Newton on psi(tau) = log sum_i T_i(x_i(e^tau)), decreasing, root psi = 0:
    far from the surface every term is close to a power of t, so psi is nearly linear in
    tau = log t and Newton takes a few steps; the bracket [tau_lo, tau_hi] and bisection
    (or, before a lower end is known, steps down by a factor e^2) keep it safe.
    """
    t_hi = 0.0
    grad2 = 0.0
    big_g = -1.0
    for i in range(3):
        t_hi = max(t_hi, 3.0 * y[i] * a[i] / e[i])  # psi(t_hi) < 0 (see the module notes)
        gi = _sq_g(y[i], a[i], e[i])
        grad2 += gi * gi
        big_g += _sq_t(y[i], a[i], e[i])
    tau_hi = math.log(t_hi)
    tau_lo = -np.inf
    t = big_g / grad2  # first-order estimate: algebraic distance / |grad|^2
    if not (0.0 < t < t_hi):
        t = 0.5 * t_hi
    tau = math.log(t)
    dx_old = np.inf
    dx = np.inf
    for _ in range(_ROOT_MAX_ITER):
        t = math.exp(tau)
        s = 0.0
        ds = 0.0
        for i in range(3):
            xi, dxi = _sq_inner(y[i], a[i], e[i], t)
            s += _sq_t(xi, a[i], e[i])
            ds += _sq_g(xi, a[i], e[i]) * dxi
        f = math.log(s)
        if f > 0.0:
            tau_lo = tau
        elif f < 0.0:
            tau_hi = tau
        else:
            break
        df = t * ds / s
        newton = tau - f / df
        if abs(newton - tau) <= 4.0 * _EPS * max(1.0, abs(tau)):  # converged
            if tau_lo <= newton <= tau_hi:
                tau = newton
            break
        if (
            not (math.isfinite(f) and df < 0.0)
            or not (tau_lo < newton < tau_hi)
            or abs(2.0 * f) > abs(dx_old * df)
        ):
            dx_old = dx
            if tau_lo == -np.inf:
                tau_new = tau_hi - 2.0
            else:
                tau_new = 0.5 * (tau_lo + tau_hi)
            dx = tau - tau_new
        else:
            dx_old = dx
            dx = tau - newton
            tau_new = newton
        if tau_new == tau or tau_new == tau_lo or tau_new == tau_hi:
            tau = tau_new
            break
        tau = tau_new
    t = math.exp(tau)
    for i in range(3):
        out[i] = _sq_inner(y[i], a[i], e[i], t)[0]


@numba.njit(cache=True, error_model="numpy")
def _sq_refine(y, a, e, x, tol):  # pragma: no cover - compiled
    """Descend |x - y|^2 over the surface from the surface point x >= 0 (in place)."""
    f = (x[0] - y[0]) ** 2 + (x[1] - y[1]) ** 2 + (x[2] - y[2]) ** 2
    gv = np.empty(3)
    for _ in range(_REFINE_MAX_ITER):
        for m in range(3):
            gv[m] = _sq_g(x[m], a[m], e[m])
        k = 0
        if gv[1] > gv[k]:
            k = 1
        if gv[2] > gv[k]:
            k = 2
        i = (k + 1) % 3
        j = (k + 2) % 3
        gk = gv[k]
        if not gk > 0.0:
            break
        pi = -gv[i] / gk
        pj = -gv[j] / gk
        gpk = _sq_gp(x[k], a[k], e[k])
        pii = -(_sq_gp(x[i], a[i], e[i]) + gpk * pi * pi) / gk
        pjj = -(_sq_gp(x[j], a[j], e[j]) + gpk * pj * pj) / gk
        pij = -gpk * pi * pj / gk
        rk = x[k] - y[k]
        gi = x[i] - y[i] + rk * pi
        gj = x[j] - y[j] + rk * pj
        h_ii = 1.0 + pi * pi + rk * pii
        h_jj = 1.0 + pj * pj + rk * pjj
        h_ij = pi * pj + rk * pij
        mid = 0.5 * (h_ii + h_jj)
        rad = math.sqrt(0.25 * (h_ii - h_jj) ** 2 + h_ij * h_ij)
        lmin = mid - rad
        floor = _CURVATURE_FLOOR * max(mid + rad, 1.0)
        target = max(floor, -lmin)
        shift = target - lmin if lmin < target else 0.0
        m_ii = h_ii + shift
        m_jj = h_jj + shift
        det = m_ii * m_jj - h_ij * h_ij
        di = -(m_jj * gi - h_ij * gj) / det
        dj = -(m_ii * gj - h_ij * gi) / det
        if lmin < -floor:  # saddle or worse: also move along the negative curvature
            if h_ij != 0.0:
                vi = h_ij
                vj = lmin - h_ii
            elif h_ii <= h_jj:
                vi = 1.0
                vj = 0.0
            else:
                vi = 0.0
                vj = 1.0
            vn = math.sqrt(vi * vi + vj * vj)
            sgn = -1.0 if gi * vi + gj * vj > 0.0 else 1.0
            length = 0.5 * math.sqrt(f)
            di += sgn * length * vi / vn
            dj += sgn * length * vj / vn
        alpha = 1.0
        accepted = False
        ni = nj = nk = 0.0
        f_new = f
        for _ls in range(_LINE_SEARCH_HALVINGS):
            ni = abs(x[i] + alpha * di)
            nj = abs(x[j] + alpha * dj)
            s = _sq_t(ni, a[i], e[i]) + _sq_t(nj, a[j], e[j])
            if s <= 1.0:
                nk = a[k] * (1.0 - s) ** (1.0 / e[k])
                f_new = (ni - y[i]) ** 2 + (nj - y[j]) ** 2 + (nk - y[k]) ** 2
                if f_new < f:
                    accepted = True
                    break
            alpha *= 0.5
        if not accepted:
            break
        step = math.sqrt((ni - x[i]) ** 2 + (nj - x[j]) ** 2 + (nk - x[k]) ** 2)
        x[i] = ni
        x[j] = nj
        x[k] = nk
        f = f_new
        if step <= tol:
            break
    return f


@numba.njit(cache=True, error_model="numpy")
def _sq_inside(y, a, e, out, tol):  # pragma: no cover - compiled
    """Closest surface point to y >= 0 with G(y) < 0, written to out; returns distance^2."""
    best = np.inf
    cand = np.empty(3)
    # the axis projections: y moved along one axis onto the surface
    for j in range(3):
        s = 0.0
        for i in range(3):
            if i != j:
                s += _sq_t(y[i], a[i], e[i])
        for i in range(3):
            cand[i] = y[i]
        cand[j] = a[j] * max(1.0 - s, 0.0) ** (1.0 / e[j])
        f = _sq_refine(y, a, e, cand, tol)
        if f < best:
            best = f
            out[:] = cand
    # the best few points of a simplex grid on the surface
    n_keep = 4
    keep_f = np.full(n_keep, np.inf)
    keep_x = np.zeros((n_keep, 3))
    nd = _GRID_DIVISIONS
    for i0 in range(nd + 1):
        for i1 in range(nd + 1 - i0):
            u0 = i0 / nd
            u1 = i1 / nd
            u2 = max(1.0 - u0 - u1, 0.0)
            cand[0] = a[0] * u0 ** (1.0 / e[0])
            cand[1] = a[1] * u1 ** (1.0 / e[1])
            cand[2] = a[2] * u2 ** (1.0 / e[2])
            f = (cand[0] - y[0]) ** 2 + (cand[1] - y[1]) ** 2 + (cand[2] - y[2]) ** 2
            if f < keep_f[n_keep - 1]:
                m = n_keep - 1
                while m > 0 and keep_f[m - 1] > f:
                    keep_f[m] = keep_f[m - 1]
                    keep_x[m] = keep_x[m - 1]
                    m -= 1
                keep_f[m] = f
                keep_x[m] = cand
    for m in range(n_keep):
        cand[:] = keep_x[m]
        f = _sq_refine(y, a, e, cand, tol)
        if f < best:
            best = f
            out[:] = cand
    return best


@numba.njit(cache=True, error_model="numpy")
def _superquadric_kernel(points, a, e, sd, closest):  # pragma: no cover - compiled
    y = np.empty(3)
    x = np.empty(3)
    scale = max(a[0], max(a[1], a[2]))
    for k in range(points.shape[0]):
        big_g = -1.0
        for i in range(3):
            y[i] = _snap(abs(points[k, i]), a[i])
            big_g += _sq_t(y[i], a[i], e[i])
        if big_g > 0.0:
            _sq_outside(y, a, e, x)
        elif big_g < 0.0:
            norm_y = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
            _sq_inside(y, a, e, x, _REFINE_STEP_TOL_REL * max(scale, norm_y))
        else:
            x[:] = y
        dist = math.sqrt((x[0] - y[0]) ** 2 + (x[1] - y[1]) ** 2 + (x[2] - y[2]) ** 2)
        sd[k] = -dist if big_g < 0.0 else dist
        for i in range(3):
            closest[k, i] = math.copysign(x[i], points[k, i])


def _superquadric_args(points, semi_axes_mm, exponents):
    p, single = as_points(points, "points")
    return p, single, _positive3(semi_axes_mm, "semi_axes_mm"), _exponents3(exponents, "exponents")


def superquadric_distance(points, semi_axes_mm, exponents):
    """Exact signed distance to ``sum_i |x_i / a_i|^{e_i} = 1`` (numba kernel).

    Outside points: a bracketed monotone 1-D root of the Lagrange conditions (exact to
    rounding). Inside points: the best of seven projected-Newton descents over the
    surface (see the module notes); the answer is always a true surface point.

    Parameters
    ----------
    points : array_like, shape (3,) or (n, 3)
        Points in the superquadric's local frame (mm).
    semi_axes_mm : array_like, shape (3,)
        Semi-axes ``a`` along local x, y, z (mm), each > 0.
    exponents : array_like, shape (3,)
        Exponents ``e`` in [2, :data:`SUPERQUADRIC_MAX_EXPONENT`] (2 is an ellipsoid;
        large values approach a box).

    Returns
    -------
    signed_distance : ndarray, shape () or (n,)
        Euclidean distance to the surface (mm), negative inside; within
        :data:`SUPERQUADRIC_ERROR_BOUND_MM`.
    closest : ndarray, shape (3,) or (n, 3)
        A closest surface point (local frame, mm).

    Examples
    --------
    >>> sd, x = superquadric_distance([[0.0, 0.0, 7.0]], [50.0, 5.0, 5.0], [8.0, 2.0, 2.0])
    >>> round(float(sd[0]), 9), x[0].round(9).tolist()
    (2.0, [0.0, 0.0, 5.0])
    """
    p, single, a, e = _superquadric_args(points, semi_axes_mm, exponents)
    sd = np.empty(p.shape[0])
    closest = np.empty_like(p)
    _superquadric_kernel(p, a, e, sd, closest)
    return unbatch(sd, single), unbatch(closest, single)


def _sq_value(x, a, e):
    """G(x) + 1 = sum |x_i / a_i|^{e_i} for rows of x."""
    return np.sum((np.abs(x) / a) ** e, axis=-1)


def _sq_grad(x, a, e):
    return np.sign(x) * (e / a) * (np.abs(x) / a) ** (e - 1.0)


class Superquadric(_Primitive):
    """Solid superquadric ``sum_i |x_i / a_i|^{e_i} <= 1`` centred at the local origin.

    The general implicit form of Liu et al. (2016), Eq. 4,
    ``F(x) = sum_i |x_i / s_i|^{e_i} - k``, is this shape with semi-axes
    ``a_i = s_i * k^(1 / e_i)`` (:meth:`from_liu`). The distance is the true Euclidean
    distance to the surface (:func:`superquadric_distance`), negative inside, within
    :data:`SUPERQUADRIC_ERROR_BOUND_MM`; inside, the reported depth is never shallower
    than the truth.

    Parameters
    ----------
    semi_axes_mm : array_like, shape (3,)
        Semi-axes ``a`` along the local x, y, z axes (mm), each > 0.
    exponents : array_like, shape (3,)
        Exponents ``e`` in [2, :data:`SUPERQUADRIC_MAX_EXPONENT`]: 2 gives an ellipse
        across that axis, larger values flatter ends (a cylinder-like needle head is
        ``(8, 2, 2)``).
    world_T_local : array_like, shape (4, 4), optional
        Pose of the centre and axes in the world (identity by default).

    Examples
    --------
    >>> head = Superquadric.from_liu()  # Eq. 4: the needle head, x along the needle
    >>> head.semi_axes_mm.round(3).tolist()
    [142.282, 3.162, 3.162]
    >>> round(float(head.signed_distance([0.0, 10.0, 0.0])), 6)
    6.837722
    """

    error_bound_mm = SUPERQUADRIC_ERROR_BOUND_MM

    def __init__(self, semi_axes_mm, exponents, world_T_local=None) -> None:
        self.semi_axes_mm = _positive3(semi_axes_mm, "semi_axes_mm")
        self.exponents = _exponents3(exponents, "exponents")
        self._set_pose(world_T_local)
        self._enclosing = None

    @property
    def max_depth_mm(self) -> float:
        """How deep any point lies inside (mm): at most the smallest semi-axis (the solid
        lies in the box of its semi-axes, so a ball inside it is no wider).

        Returns
        -------
        float
        """
        return float(np.min(self.semi_axes_mm))

    def _enclosing_capsule(self):
        """A capsule containing the shape: along its longest axis, as long, and as wide as
        the box of the other two semi-axes (every term of the sum is at most 1, so the
        shape lies in the box of its semi-axes)."""
        if self._enclosing is None:
            a = self.semi_axes_mm
            k = int(np.argmax(a))
            others = np.delete(a, k)
            axis = self._rot[:, k]
            self._enclosing = Capsule(
                self._trans - a[k] * axis, self._trans + a[k] * axis, float(np.hypot(*others))
            )
        return self._enclosing

    def capped_distance(self, points: np.ndarray, cap_mm: float) -> np.ndarray:
        """Exact below ``cap_mm``; beyond it, the distance to an enclosing capsule (a lower
        bound at least the cap), which spares the iterative solver far from the shape.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
        cap_mm : float

        Returns
        -------
        ndarray, shape (n,)
        """
        lower = self._enclosing_capsule()._signed_distance(points)
        near = lower < cap_mm
        if near.any():
            lower[near] = self._signed_distance(points[near])
        return lower

    @classmethod
    def from_liu(
        cls,
        scales_mm=(60.0, 0.1, 0.1),
        exponents=(8.0, 2.0, 2.0),
        level: float = 1000.0,
        world_T_local=None,
    ) -> Superquadric:
        """The superquadric ``sum_i |x_i / s_i|^{e_i} - level = 0`` of Liu et al. (2016).

        The defaults are Eq. 4, the needle head in its frame Sigma' (origin at the head's
        geometric centre, x along the needle): semi-axes
        ``(60 * 1000^(1/8), 0.1 * 1000^(1/2), 0.1 * 1000^(1/2))`` =
        ``(142.28, 3.162, 3.162)`` mm. Eq. 6's ``T_obs`` is the ``world_T_local``.

        Parameters
        ----------
        scales_mm : array_like, shape (3,)
            The divisors ``s_i`` (mm), each > 0.
        exponents : array_like, shape (3,)
            The exponents ``e_i`` in [2, :data:`SUPERQUADRIC_MAX_EXPONENT`].
        level : float
            The constant ``k`` > 0 on the right-hand side.
        world_T_local : array_like, shape (4, 4), optional
            Pose of the local frame in the world.

        Returns
        -------
        Superquadric
        """
        s = _positive3(scales_mm, "scales_mm")
        ex = _exponents3(exponents, "exponents")
        k = as_positive(level, "level")
        return cls(s * k ** (1.0 / ex), ex, world_T_local)

    @classmethod
    def from_barr(cls, a1, a2, a3, eps1, eps2, world_T_local=None) -> Superquadric:
        """Barr's superellipsoid ``((x/a1)^(2/eps2) + (y/a2)^(2/eps2))^(eps2/eps1) +
        (z/a3)^(2/eps1) = 1``, for the separable case ``eps1 == eps2`` only.

        With ``eps1 == eps2 = eps`` it is exponents ``2 / eps`` on every axis; ``eps`` in
        ``[2 / SUPERQUADRIC_MAX_EXPONENT, 1]`` keeps it convex. The general
        ``eps1 != eps2`` form is not separable and not supported (it raises).

        Parameters
        ----------
        a1, a2, a3 : float
            Semi-axes along local x, y, z (mm), each > 0.
        eps1, eps2 : float
            Barr's shape exponents (north-south and east-west), equal.
        world_T_local : array_like, shape (4, 4), optional
            Pose of the local frame in the world.

        Returns
        -------
        Superquadric
        """
        e1 = as_positive(eps1, "eps1")
        e2 = as_positive(eps2, "eps2")
        if abs(e1 - e2) > 1e-12 * max(e1, e2):
            raise InvalidInputError(
                "eps2", f"only eps1 == eps2 (separable) is supported, got {e1:g} and {e2:g}"
            )
        lo = 2.0 / SUPERQUADRIC_MAX_EXPONENT
        if not lo <= e1 <= 1.0:
            raise InvalidInputError("eps1", f"must lie in [{lo:g}, 1] (convex), got {e1:g}")
        return cls([a1, a2, a3], [2.0 / e1] * 3, world_T_local)

    def inside_outside(self, points) -> np.ndarray:
        """Barr's inside-outside function ``sum_i |x_i / a_i|^{e_i}``: < 1 inside.

        Not a distance (see :func:`radial_distance_approximation`).

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).

        Returns
        -------
        ndarray, shape () or (n,)
            Dimensionless; 1 on the surface.
        """
        p, single = as_points(points, "points")
        return unbatch(_sq_value(self._to_local(p), self.semi_axes_mm, self.exponents), single)

    def _local_eval(self, q):
        sd = np.empty(q.shape[0])
        x = np.empty_like(q)
        _superquadric_kernel(np.ascontiguousarray(q), self.semi_axes_mm, self.exponents, sd, x)
        grad = _sq_grad(x, self.semi_axes_mm, self.exponents)
        return sd, grad / np.linalg.norm(grad, axis=1, keepdims=True)

    def _local_distance(self, q):
        sd = np.empty(q.shape[0])
        x = np.empty_like(q)
        _superquadric_kernel(np.ascontiguousarray(q), self.semi_axes_mm, self.exponents, sd, x)
        return sd

    def _local_bounds(self):
        return np.stack([-self.semi_axes_mm, self.semi_axes_mm])

    def __repr__(self) -> str:
        return (
            f"Superquadric(semi_axes_mm={_fmt(self.semi_axes_mm)}, "
            f"exponents={_fmt(self.exponents)}{self._pose_repr()})"
        )
