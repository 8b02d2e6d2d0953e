"""The skin of the liver phantom: an elliptic cylinder with its parametric surface
S(u, v) and exact signed distance."""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit.anatomy.fields import DistanceField

# ----------------------------------------------------------------------------------------
# the skin: an elliptic cylinder with its parametric surface S(u, v)


@numba.njit(cache=True, error_model="numpy")
def _ellipse_root_kernel(r0, z0, z1, g, iterations, out):  # pragma: no cover - compiled
    for k in range(z0.shape[0]):
        n0 = r0 * z0[k]
        lo = z1[k] - 1.0  # F(lo) >= 0
        hi = 0.0 if g[k] < 0.0 else math.hypot(n0, z1[k]) - 1.0  # F(hi) <= 0
        # F(s) = (n0 / (s + r0))^2 + (z1 / (s + 1))^2 - 1 is convex and decreasing for
        # s > -1, so Newton's steps from lo stay below the root and rise to it; a step
        # that fails to rise (rounding) ends the search, a bisection step keeps the
        # bracket when one would leave it
        s = lo
        for _ in range(iterations):
            a = n0 / (s + r0)
            b = z1[k] / (s + 1.0)
            f = a * a + b * b - 1.0
            if f <= 0.0:
                hi = s
                break
            lo = s
            df = -2.0 * (a * a / (s + r0) + b * b / (s + 1.0))
            nxt = s - f / df
            if not nxt < hi:
                nxt = 0.5 * (s + hi)
            if not nxt > s:
                break
            s = nxt
        out[k] = s


def _ellipse_root(r0, z0, z1, g, iterations: int = 160):
    """The root ``s`` of ``(r0 z0 / (s + r0))^2 + (z1 / (s + 1))^2 = 1`` on Eberly's
    bracket, by Newton's method from its left end (a numba loop per point; the function
    is convex and decreasing there, so the steps rise monotonically to the root, to
    rounding)."""
    out = np.empty(len(z0))
    _ellipse_root_kernel(
        float(r0),
        np.ascontiguousarray(z0, dtype=np.float64),
        np.ascontiguousarray(z1, dtype=np.float64),
        np.ascontiguousarray(g, dtype=np.float64),
        int(iterations),
        out,
    )
    return out


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

    def content_key(self) -> tuple:
        """A key of the field's contents: equal for two skins only when their axes, semi-axes
        and entry patches are equal, bit for bit.

        Returns
        -------
        tuple
            Hashable: the four parameters' bytes.
        """
        parts = (self.center_xy_mm, self.semi_axes_mm, self.u_range_rad, self.v_range_mm)
        return ("EllipticCylinderSkin", *(np.asarray(p, dtype=np.float64).tobytes() for p in parts))

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return ellipse_signed_distance(
            points[:, 0] - self.center_xy_mm[0],
            points[:, 1] - self.center_xy_mm[1],
            *self.semi_axes_mm,
        )

    def bounds(self) -> np.ndarray:
        """Box of the body (infinite along z), shape (2, 3) (mm).

        Returns
        -------
        ndarray, shape (2, 3)
            Lower and upper corner (mm, world frame).
        """
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
