"""Primitives with closed-form exact signed distances: sphere, capsule, cylinder, box,
half-space."""

from __future__ import annotations

import math

import numpy as np

from needlekit._validation import as_positive
from needlekit.anatomy.primitives._base import (
    MIN_AXIS_LENGTH_MM,
    _fmt,
    _positive3,
    _Primitive,
    _safe_unit,
    _unit_perpendicular,
    _vector3,
)
from needlekit.errors import InvalidInputError

__all__ = ["Box", "Capsule", "Cylinder", "HalfSpace", "Sphere"]

# ----------------------------------------------------------------------------------------
# closed forms


class Sphere(_Primitive):
    """Solid sphere ``|x - center| <= radius`` (local frame, mm).

    Parameters
    ----------
    center_mm : array_like, shape (3,)
        Centre in the local frame (mm).
    radius_mm : float
        Radius (mm), > 0.
    world_T_local : array_like, shape (4, 4), optional
        Pose of the local frame in the world (identity by default).

    Examples
    --------
    >>> s = Sphere([0.0, 0.0, 0.0], 10.0)
    >>> s.signed_distance([[15.0, 0.0, 0.0], [0.0, 0.0, 0.0]]).tolist()
    [5.0, -10.0]
    """

    def __init__(self, center_mm, radius_mm, world_T_local=None) -> None:
        self.center_mm = _vector3(center_mm, "center_mm")
        self.radius_mm = as_positive(radius_mm, "radius_mm")
        self._set_pose(world_T_local)

    def _local_eval(self, q):
        v = q - self.center_mm
        r = np.linalg.norm(v, axis=1)
        return r - self.radius_mm, _safe_unit(v, r, np.array([1.0, 0.0, 0.0]))

    def _local_distance(self, q):
        return np.linalg.norm(q - self.center_mm, axis=1) - self.radius_mm

    def _local_bounds(self):
        return np.stack([self.center_mm - self.radius_mm, self.center_mm + self.radius_mm])

    def __repr__(self) -> str:
        return (
            f"Sphere(center_mm={_fmt(self.center_mm)}, radius_mm={self.radius_mm:g}"
            f"{self._pose_repr()})"
        )


class Capsule(_Primitive):
    """Segment-swept sphere: points within ``radius_mm`` of the segment p0-p1 (local, mm).

    Parameters
    ----------
    p0_mm, p1_mm : array_like, shape (3,)
        Segment end points in the local frame (mm); equal end points give a sphere.
    radius_mm : float
        Radius (mm), > 0.
    world_T_local : array_like, shape (4, 4), optional
        Pose of the local frame in the world (identity by default).

    Examples
    --------
    >>> c = Capsule([0.0, 0.0, 0.0], [0.0, 0.0, 50.0], 2.0)
    >>> c.signed_distance([[5.0, 0.0, 25.0], [0.0, 0.0, 55.0]]).tolist()
    [3.0, 3.0]
    """

    def __init__(self, p0_mm, p1_mm, radius_mm, world_T_local=None) -> None:
        self.p0_mm = _vector3(p0_mm, "p0_mm")
        self.p1_mm = _vector3(p1_mm, "p1_mm")
        self.radius_mm = as_positive(radius_mm, "radius_mm")
        self._set_pose(world_T_local)
        self._axis = self.p1_mm - self.p0_mm
        self._len2 = float(self._axis @ self._axis)
        length = math.sqrt(self._len2)
        self._perp = _unit_perpendicular(self._axis / length if length > 0 else np.eye(3)[2])

    def _axis_offset(self, q):
        w = q - self.p0_mm
        if self._len2 > 0.0:
            s = np.clip((w @ self._axis) / self._len2, 0.0, 1.0)
            return w - s[:, None] * self._axis
        return w

    def _local_eval(self, q):
        v = self._axis_offset(q)
        r = np.linalg.norm(v, axis=1)
        return r - self.radius_mm, _safe_unit(v, r, self._perp)

    def _local_distance(self, q):
        return np.linalg.norm(self._axis_offset(q), axis=1) - self.radius_mm

    def _local_bounds(self):
        lo = np.minimum(self.p0_mm, self.p1_mm) - self.radius_mm
        hi = np.maximum(self.p0_mm, self.p1_mm) + self.radius_mm
        return np.stack([lo, hi])

    def __repr__(self) -> str:
        return (
            f"Capsule(p0_mm={_fmt(self.p0_mm)}, p1_mm={_fmt(self.p1_mm)}, "
            f"radius_mm={self.radius_mm:g}{self._pose_repr()})"
        )


class Cylinder(_Primitive):
    """Finite solid cylinder with flat caps, axis p0-p1 (local frame, mm).

    The distance is exact everywhere, including around the rim where a cap meets the side.

    Parameters
    ----------
    p0_mm, p1_mm : array_like, shape (3,)
        Centres of the two caps in the local frame (mm); at least
        :data:`MIN_AXIS_LENGTH_MM` apart.
    radius_mm : float
        Radius (mm), > 0.
    world_T_local : array_like, shape (4, 4), optional
        Pose of the local frame in the world (identity by default).

    Examples
    --------
    >>> c = Cylinder([0.0, 0.0, 0.0], [0.0, 0.0, 10.0], 3.0)
    >>> c.signed_distance([[7.0, 0.0, 13.0], [0.0, 0.0, 5.0]]).tolist()
    [5.0, -3.0]
    """

    def __init__(self, p0_mm, p1_mm, radius_mm, world_T_local=None) -> None:
        self.p0_mm = _vector3(p0_mm, "p0_mm")
        self.p1_mm = _vector3(p1_mm, "p1_mm")
        self.radius_mm = as_positive(radius_mm, "radius_mm")
        axis = self.p1_mm - self.p0_mm
        length = float(np.linalg.norm(axis))
        if not length >= MIN_AXIS_LENGTH_MM:
            raise InvalidInputError(
                "p1_mm", f"must differ from p0_mm by at least {MIN_AXIS_LENGTH_MM:g} mm"
            )
        self._set_pose(world_T_local)
        self._u = axis / length
        self._half = 0.5 * length
        self._mid = 0.5 * (self.p0_mm + self.p1_mm)
        self._perp = _unit_perpendicular(self._u)

    def _local_eval(self, q):
        w = q - self._mid
        a = w @ self._u
        radial = w - a[:, None] * self._u
        r = np.linalg.norm(radial, axis=1)
        e_r = _safe_unit(radial, r, self._perp)
        e_a = np.where(a >= 0.0, 1.0, -1.0)[:, None] * self._u
        qx = r - self.radius_mm
        qy = np.abs(a) - self._half
        ox, oy = np.maximum(qx, 0.0), np.maximum(qy, 0.0)
        outside = np.hypot(ox, oy)
        sd = np.minimum(np.maximum(qx, qy), 0.0) + outside
        # normal: rim region mixes the two, else the side or the cap that is nearest
        side = qx >= qy
        normal = np.where(side[:, None], e_r, e_a)
        rim = (qx > 0.0) & (qy > 0.0)
        if np.any(rim):
            normal[rim] = (ox[rim, None] * e_r[rim] + oy[rim, None] * e_a[rim]) / outside[rim, None]
        return sd, normal

    def _local_bounds(self):
        ext = self.radius_mm * np.sqrt(np.maximum(1.0 - self._u**2, 0.0))
        lo = np.minimum(self.p0_mm, self.p1_mm) - ext
        hi = np.maximum(self.p0_mm, self.p1_mm) + ext
        return np.stack([lo, hi])

    def __repr__(self) -> str:
        return (
            f"Cylinder(p0_mm={_fmt(self.p0_mm)}, p1_mm={_fmt(self.p1_mm)}, "
            f"radius_mm={self.radius_mm:g}{self._pose_repr()})"
        )


class Box(_Primitive):
    """Solid box ``|x_i| <= h_i`` centred at the local origin (mm).

    Parameters
    ----------
    half_extents_mm : array_like, shape (3,)
        Half side lengths along the local x, y, z axes (mm), each > 0.
    world_T_local : array_like, shape (4, 4), optional
        Pose of the box centre and axes in the world (identity by default).

    Examples
    --------
    >>> b = Box([1.0, 2.0, 3.0])
    >>> b.signed_distance([[4.0, 6.0, 3.0], [0.0, 0.0, 0.0]]).tolist()
    [5.0, -1.0]
    """

    def __init__(self, half_extents_mm, world_T_local=None) -> None:
        self.half_extents_mm = _positive3(half_extents_mm, "half_extents_mm")
        self._set_pose(world_T_local)

    def _local_eval(self, q):
        sgn = np.where(q >= 0.0, 1.0, -1.0)
        d = np.abs(q) - self.half_extents_mm
        out = np.maximum(d, 0.0)
        out_norm = np.linalg.norm(out, axis=1)
        dmax = d.max(axis=1)
        sd = out_norm + np.minimum(dmax, 0.0)
        normal = np.zeros_like(q)
        outside = out_norm > 0.0
        normal[outside] = out[outside] / out_norm[outside, None]
        inside = ~outside
        k = np.argmax(d[inside], axis=1)
        normal[np.flatnonzero(inside), k] = 1.0
        return sd, normal * sgn

    def _local_bounds(self):
        return np.stack([-self.half_extents_mm, self.half_extents_mm])

    def __repr__(self) -> str:
        return f"Box(half_extents_mm={_fmt(self.half_extents_mm)}{self._pose_repr()})"


class HalfSpace(_Primitive):
    """Solid half-space ``(x - point) . n <= 0``: inside is the side ``n`` points away from.

    Parameters
    ----------
    point_mm : array_like, shape (3,)
        A point on the boundary plane (local frame, mm).
    normal_mm : array_like, shape (3,)
        Outward normal (local frame; any non-zero length, normalised here).
    world_T_local : array_like, shape (4, 4), optional
        Pose of the local frame in the world (identity by default).

    Examples
    --------
    >>> h = HalfSpace([0.0, 0.0, 5.0], [0.0, 0.0, 2.0])
    >>> h.signed_distance([[1.0, 2.0, 8.0], [0.0, 0.0, 0.0]]).tolist()
    [3.0, -5.0]
    """

    def __init__(self, point_mm, normal_mm, world_T_local=None) -> None:
        self.point_mm = _vector3(point_mm, "point_mm")
        n = _vector3(normal_mm, "normal_mm")
        norm = float(np.linalg.norm(n))
        if not norm > 1e-12:
            raise InvalidInputError("normal_mm", f"must be a non-zero vector, got {n.tolist()}")
        self.unit_normal = n / norm
        self._set_pose(world_T_local)

    def _local_eval(self, q):
        sd = (q - self.point_mm) @ self.unit_normal
        return sd, np.broadcast_to(self.unit_normal, q.shape).copy()

    def _local_bounds(self):
        return self._axis_aligned_bounds(self.unit_normal, self.point_mm)

    @staticmethod
    def _axis_aligned_bounds(n: np.ndarray, point: np.ndarray) -> np.ndarray:
        b = np.array([[-np.inf] * 3, [np.inf] * 3])
        k = int(np.argmax(np.abs(n)))
        if abs(abs(n[k]) - 1.0) <= 1e-12:  # axis-aligned: one finite side
            b[1 if n[k] > 0 else 0, k] = point[k]
        return b

    def bounds(self) -> np.ndarray:
        """World bounds (mm): infinite, except on the axis a world-aligned normal follows.

        Returns
        -------
        ndarray, shape (2, 3)
        """
        n_world = self._rot @ self.unit_normal
        p_world = self._rot @ self.point_mm + self._trans
        return self._axis_aligned_bounds(n_world, p_world)

    def __repr__(self) -> str:
        return (
            f"HalfSpace(point_mm={_fmt(self.point_mm)}, normal={_fmt(self.unit_normal)}"
            f"{self._pose_repr()})"
        )
