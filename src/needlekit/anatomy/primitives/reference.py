"""Slow references for the superquadric (scipy minimisation from many starts) and the
'radial' distance estimate, kept to show why it must not be used for safety."""

from __future__ import annotations

import math

import numpy as np

from needlekit._validation import as_points, as_poses, unbatch
from needlekit.anatomy.primitives._base import (
    _exponents3,
    _positive3,
)
from needlekit.anatomy.primitives.superquadric import _sq_grad, _sq_value, _superquadric_args
from needlekit.errors import InvalidInputError

__all__ = ["radial_distance_approximation", "superquadric_distance_reference"]


def _sq_radial_scale(p, a, e, iterations: int = 80):
    """lambda > 0 with G(lambda p) = 0 for rows p != 0 (bisection on log lambda)."""
    terms = (np.abs(p) / a) ** e
    with np.errstate(divide="ignore"):
        logs = np.log(terms)  # -inf for zero coordinates
        mu_i = np.where(terms > 0.0, -logs / e, np.inf)
    hi = mu_i.min(axis=1)  # any single term reaches 1 there, so the sum is >= 1
    lo = hi - math.log(3.0) / e.min()  # every term <= 1/3 there, so the sum is < 1
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        with np.errstate(over="ignore"):
            s = np.sum(np.exp(np.minimum(e * mid[:, None] + logs, 700.0)), axis=1)
        up = s < 1.0
        lo = np.where(up, mid, lo)
        hi = np.where(up, hi, mid)
    return np.exp(0.5 * (lo + hi))


def _kkt_polish(x, p, a, e, iterations: int = 30):
    """Newton on x - p + lam grad G(x) = 0, G(x) = 0 from x; None if it fails."""
    g = _sq_grad(x, a, e)
    lam = -float((x - p) @ g) / float(g @ g)
    z = np.concatenate([x, [lam]])
    for _ in range(iterations):
        xx, lam = z[:3], z[3]
        g = _sq_grad(xx, a, e)
        hess = (e * (e - 1.0) / a**2) * (np.abs(xx) / a) ** (e - 2.0)
        r = np.concatenate([xx - p + lam * g, [_sq_value(xx, a, e) - 1.0]])
        jac = np.zeros((4, 4))
        jac[:3, :3] = np.diag(1.0 + lam * hess)
        jac[:3, 3] = g
        jac[3, :3] = g
        try:
            step = np.linalg.solve(jac, -r)
        except np.linalg.LinAlgError:
            return None
        z = z + step
        if np.linalg.norm(step[:3]) <= 1e-14 * (1.0 + np.linalg.norm(z[:3])):
            break
    if not np.all(np.isfinite(z)):
        return None
    return z[:3]


def _sq_chart_samples(a, e, m: int) -> np.ndarray:
    """First-octant surface points: for each axis k, the graph x_k = phi(x_i, x_j) over an
    m x m grid of (x_i, x_j) (evenly spread on every part of the surface)."""
    out = []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        xi, xj = np.meshgrid(np.linspace(0.0, a[i], m), np.linspace(0.0, a[j], m))
        xi, xj = xi.ravel(), xj.ravel()
        s = (xi / a[i]) ** e[i] + (xj / a[j]) ** e[j]
        ok = s <= 1.0
        pts = np.zeros((int(ok.sum()), 3))
        pts[:, i], pts[:, j] = xi[ok], xj[ok]
        pts[:, k] = a[k] * (1.0 - s[ok]) ** (1.0 / e[k])
        out.append(pts)
    return np.concatenate(out)


def superquadric_distance_reference(points, semi_axes_mm, exponents, *, n_starts: int = 6):
    """Slow reference of :func:`superquadric_distance`: scipy SLSQP from many starts.

    For each point, the ``n_starts`` surface points nearest to it among a grid spread
    over the whole surface (all eight octants) start SLSQP on ``min |x - p|^2`` subject to
    ``G(x) = 0``; each result is polished by Newton's method on the Lagrange conditions
    and pulled radially onto the surface; the nearest wins. For tests and benchmarks
    only (milliseconds per point).

    Parameters
    ----------
    points : array_like, shape (3,) or (n, 3)
        Points in the superquadric's local frame (mm).
    semi_axes_mm : array_like, shape (3,)
        Semi-axes along local x, y, z (mm), each > 0.
    exponents : array_like, shape (3,)
        Exponents in [2, :data:`SUPERQUADRIC_MAX_EXPONENT`].
    n_starts : int
        Starting points per query point, >= 1.

    Returns
    -------
    signed_distance : ndarray, shape () or (n,)
        Euclidean distance to the surface (mm), negative inside.
    closest : ndarray, shape (3,) or (n, 3)
        The closest surface point found (local frame, mm).

    Examples
    --------
    >>> sd, _ = superquadric_distance_reference([0.0, 9.0, 0.0], [50.0, 5.0, 5.0], [8, 2, 2])
    >>> round(float(sd), 9)
    4.0
    """
    from scipy.optimize import minimize

    p_all, single, a, e = _superquadric_args(points, semi_axes_mm, exponents)
    if int(n_starts) < 1:
        raise InvalidInputError("n_starts", f"must be >= 1, got {n_starts}")
    samples = _sq_chart_samples(a, e, 12)
    signs = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])
    samples = np.unique((signs[:, None, :] * samples[None]).reshape(-1, 3), axis=0)

    def objective(x, p):
        d = x - p
        return 0.5 * float(d @ d), d

    constraint = {
        "type": "eq",
        "fun": lambda x: np.array([_sq_value(x, a, e) - 1.0]),
        "jac": lambda x: _sq_grad(x, a, e)[None, :],
    }
    sd = np.empty(p_all.shape[0])
    closest = np.empty_like(p_all)
    for k, p in enumerate(p_all):
        value = _sq_value(p, a, e) - 1.0
        if value == 0.0:
            sd[k], closest[k] = 0.0, p
            continue
        order = np.argsort(np.sum((samples - p) ** 2, axis=1))[: int(n_starts)]
        best_d, best_x = np.inf, p
        for start in samples[order]:
            res = minimize(
                objective,
                start,
                args=(p,),
                jac=True,
                method="SLSQP",
                constraints=[constraint],
                options={"ftol": 1e-12, "maxiter": 200},
            )
            for x in (res.x, _kkt_polish(res.x, p, a, e)):
                if x is None or not np.all(np.isfinite(x)) or not np.any(x != 0.0):
                    continue
                x = x * _sq_radial_scale(x[None], a, e)[0]
                d = float(np.linalg.norm(x - p))
                if d < best_d:
                    best_d, best_x = d, x
        sd[k] = -best_d if value < 0.0 else best_d
        closest[k] = best_x
    return unbatch(sd, single), unbatch(closest, single)


# ----------------------------------------------------------------------------------------
# the radial estimate, kept to show why it must not be used as a safety distance


def radial_distance_approximation(
    points, semi_axes_mm, exponents=(2.0, 2.0, 2.0), world_T_local=None
):
    """The 'radial Euclidean distance' to a superquadric. NOT A SAFETY DISTANCE.

    The distance from ``p`` to the surface along the ray from the centre through ``p``,
    ``|p| (1 - lambda)`` with ``G(lambda p) = 0`` (for equal exponents ``e`` this is the
    common ``|p| (1 - F(p)^(-1/e))`` with ``F`` the inside-outside function; Jaklic,
    Leonardis & Solina 2000). It is only an upper bound on the true distance: beside an
    elongated shape it overestimates the clearance several times over (measured in the
    tests, 2 to 8 mm beside the side: median 10x, up to 20x for Liu's Eq. 4 needle head;
    median 3.7x, up to 4.7x for a 100 x 10 x 10 mm ellipsoid). Use :class:`Superquadric` or
    :class:`Ellipsoid` for anything that decides safety.

    Parameters
    ----------
    points : array_like, shape (3,) or (n, 3)
        World points (RAS, mm).
    semi_axes_mm : array_like, shape (3,)
        Semi-axes along local x, y, z (mm), each > 0.
    exponents : array_like, shape (3,)
        Exponents in [2, :data:`SUPERQUADRIC_MAX_EXPONENT`] (default: an ellipsoid).
    world_T_local : array_like, shape (4, 4), optional
        Pose of the shape in the world (identity by default).

    Returns
    -------
    ndarray, shape () or (n,)
        Radial distance (mm), positive outside, negative inside; ``-min(a)`` at the
        centre, where the ray is undefined.

    Examples
    --------
    5 mm beside Liu's Eq. 4 needle head the radial estimate claims 61 mm of clearance:

    >>> from needlekit.anatomy.primitives import Superquadric
    >>> head = Superquadric.from_liu()
    >>> p = [100.0, 8.0, 0.0]
    >>> round(float(radial_distance_approximation(p, head.semi_axes_mm, head.exponents)), 2)
    60.67
    >>> round(float(head.signed_distance(p)), 2)
    4.93
    """
    p, single = as_points(points, "points")
    a = _positive3(semi_axes_mm, "semi_axes_mm")
    e = _exponents3(exponents, "exponents")
    if world_T_local is not None:
        g, one = as_poses(world_T_local, "world_T_local")
        if not one:
            raise InvalidInputError("world_T_local", "expected one 4x4 pose")
        p = (p - g[0, :3, 3]) @ g[0, :3, :3]
    r = np.linalg.norm(p, axis=1)
    out = np.full(p.shape[0], -float(a.min()))
    nz = r > 0.0
    if np.any(nz):
        out[nz] = r[nz] * (1.0 - _sq_radial_scale(p[nz], a, e))
    return unbatch(out, single)
