"""The skin of the liver phantom: an elliptic cylinder with its parametric surface
S(u, v) and exact signed distance."""

from __future__ import annotations

import numpy as np

from needlekit.anatomy.fields import DistanceField

# ----------------------------------------------------------------------------------------
# the skin: an elliptic cylinder with its parametric surface S(u, v)


def _ellipse_root(r0, z0, z1, g, iterations: int = 160):
    """Eberly's bisection for the root ``s`` of ``(r0 z0 / (s + r0))^2 + (z1 / (s + 1))^2
    = 1`` (vectorised; 160 halvings reach double precision from any start bracket)."""
    n0 = r0 * z0
    s0 = z1 - 1.0
    s1 = np.where(g < 0.0, 0.0, np.hypot(n0, z1) - 1.0)
    s = 0.5 * (s0 + s1)
    for _ in range(iterations):
        s = 0.5 * (s0 + s1)
        val = (n0 / (s + r0)) ** 2 + (z1 / (s + 1.0)) ** 2 - 1.0
        s0 = np.where(val > 0.0, s, s0)
        s1 = np.where(val < 0.0, s, s1)
    return s


def ellipse_signed_distance(x, y, a: float, b: float) -> np.ndarray:
    """Signed distance of planar points to the ellipse ``(x/a)^2 + (y/b)^2 = 1``.

    D. Eberly, "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid"
    (Geometric Tools, 2013), vectorised; negative inside.

    Parameters
    ----------
    x, y : ndarray, shape (n,)
        Coordinates in the ellipse's frame (mm).
    a, b : float
        Semi-axes along x and y (mm), > 0.

    Returns
    -------
    ndarray, shape (n,)
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    swap = b > a
    e0, e1 = (b, a) if swap else (a, b)
    y0, y1 = (np.abs(y), np.abs(x)) if swap else (np.abs(x), np.abs(y))
    x0 = np.empty_like(y0)
    x1 = np.empty_like(y1)
    # generic: both coordinates positive
    gen = (y0 > 0.0) & (y1 > 0.0)
    if np.any(gen):
        z0 = y0[gen] / e0
        z1 = y1[gen] / e1
        g = z0 * z0 + z1 * z1 - 1.0
        r0 = (e0 / e1) ** 2
        s = _ellipse_root(r0, z0, z1, g)
        x0[gen] = r0 * y0[gen] / (s + r0)
        x1[gen] = y1[gen] / (s + 1.0)
    on_minor = (y0 == 0.0) & (y1 > 0.0)
    x0[on_minor], x1[on_minor] = 0.0, e1
    on_major = y1 == 0.0
    if np.any(on_major):
        numer = e0 * y0[on_major]
        denom = e0 * e0 - e1 * e1
        inner = numer < denom
        xde = np.where(inner, numer / denom if denom > 0 else 0.0, 1.0)
        x0[on_major] = np.where(inner, e0 * xde, e0)
        x1[on_major] = np.where(inner, e1 * np.sqrt(np.maximum(1.0 - xde * xde, 0.0)), 0.0)
    dist = np.hypot(x0 - y0, x1 - y1)
    inside = (y0 / e0) ** 2 + (y1 / e1) ** 2 < 1.0
    return np.where(inside, -dist, dist)


class EllipticCylinderSkin(DistanceField):
    """Body surface as an elliptic cylinder along z, with the parametric skin
    ``S(u, v) = (cx + a cos u, cy + b sin u, v)`` of Liu et al. (2016).

    ``u`` (rad) runs around the body from +x (patient's right) toward +y (anterior);
    ``v`` is the height z (mm). The field is the exact signed distance to the infinite
    cylinder (negative inside the body).

    Parameters
    ----------
    center_xy_mm : array_like, shape (2,)
        Axis position ``(cx, cy)`` (mm).
    semi_axes_mm : array_like, shape (2,)
        ``(a, b)``: half width (x) and half depth (y) (mm).
    u_range_rad, v_range_mm : array_like, shape (2,)
        Parameter domain of the skin patch available for entry.

    Examples
    --------
    >>> skin = EllipticCylinderSkin([0, 0], [150, 110], [0.0, 1.5], [-50, 50])
    >>> skin.skin_point(0.0, 10.0).tolist(), float(skin.signed_distance([160.0, 0, 0]))
    ([150.0, 0.0, 10.0], 10.0)
    """

    error_bound_mm = 1e-9

    def __init__(self, center_xy_mm, semi_axes_mm, u_range_rad, v_range_mm) -> None:
        self.center_xy_mm = np.asarray(center_xy_mm, dtype=np.float64).copy()
        self.semi_axes_mm = np.asarray(semi_axes_mm, dtype=np.float64).copy()
        self.u_range_rad = np.asarray(u_range_rad, dtype=np.float64).copy()
        self.v_range_mm = np.asarray(v_range_mm, dtype=np.float64).copy()

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return ellipse_signed_distance(
            points[:, 0] - self.center_xy_mm[0],
            points[:, 1] - self.center_xy_mm[1],
            *self.semi_axes_mm,
        )

    def bounds(self) -> np.ndarray:
        """Box of the body (infinite along z), shape (2, 3) (mm)."""
        c, ab = self.center_xy_mm, self.semi_axes_mm
        return np.array(
            [[c[0] - ab[0], c[1] - ab[1], -np.inf], [c[0] + ab[0], c[1] + ab[1], np.inf]]
        )

    def skin_point(self, u, v) -> np.ndarray:
        """Points ``S(u, v)`` of the skin.

        Parameters
        ----------
        u : float or array_like, shape (n,)
            Angle around the body (rad).
        v : float or array_like, shape (n,)
            Height z (mm).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            World points (RAS, mm).
        """
        u_, v_ = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        out = np.stack(
            [
                self.center_xy_mm[0] + self.semi_axes_mm[0] * np.cos(u_),
                self.center_xy_mm[1] + self.semi_axes_mm[1] * np.sin(u_),
                v_,
            ],
            axis=-1,
        )
        return out

    def skin_normal(self, u, v) -> np.ndarray:
        """Outward unit normals of the skin at ``S(u, v)``.

        Parameters
        ----------
        u, v : float or array_like, shape (n,)

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Unit vectors (world frame).
        """
        u_, _ = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        n = np.stack(
            [np.cos(u_) / self.semi_axes_mm[0], np.sin(u_) / self.semi_axes_mm[1], 0.0 * u_],
            axis=-1,
        )
        return n / np.linalg.norm(n, axis=-1, keepdims=True)
