"""Shared parts of the analytic primitives: tolerances, argument checks and the pose
(one base class places every shape in the world)."""

from __future__ import annotations

from abc import abstractmethod

import numba
import numpy as np

from needlekit._validation import as_points, as_poses, unbatch
from needlekit.anatomy.fields import DistanceField
from needlekit.errors import InvalidInputError

# ----------------------------------------------------------------------------------------
# tolerances (each with the reason for its value)

#: Stated error (mm) of :class:`Ellipsoid`. The 1-D root is found to machine precision;
#: for shapes and points within 10^4 mm of the origin rounding stays below ~1e-11 mm, and
#: the tests hold the kernel to 1e-9 mm against a plain bisection and scipy.
ELLIPSOID_ERROR_BOUND_MM: float = 1e-9

#: Stated error (mm) of :class:`Superquadric`. Outside points: a bracketed monotone 1-D
#: root, exact to rounding. Inside points: the best of several projected-Newton descents
#: (always a true surface point, so never a shallower depth than the truth); the tests
#: hold both to 1e-6 mm against scipy with many starts, the accuracy the brief asks for.
SUPERQUADRIC_ERROR_BOUND_MM: float = 1e-6

#: Largest superquadric exponent accepted. At 32 the shape already fills its box to within
#: 3.4 % at the corners (use :class:`Box` beyond), and the curvature of the rounded edges
#: (~e^2 / a) would make the projection needlessly ill-conditioned; exponents up to 32
#: are what the tests verify.
SUPERQUADRIC_MAX_EXPONENT: float = 32.0

#: Smallest segment length (mm) of a :class:`Cylinder` axis: its caps need a direction.
#: 1e-9 mm is far below any anatomical size and far above rounding of mm coordinates.
MIN_AXIS_LENGTH_MM: float = 1e-9

_EPS = 2.220446049250313e-16  # double machine epsilon
_ROOT_MAX_ITER = 200  # safeguarded Newton: ~10 steps typical; bisection bounds the rest
_INNER_MAX_ITER = 100  # per-coordinate Newton of the superquadric (monotone, ~5 steps)
_REFINE_MAX_ITER = 100  # projected Newton on the surface (quadratic, ~5-15 steps)
_LINE_SEARCH_HALVINGS = 40  # step shrunk 2^-40 at most before declaring convergence
_GRID_DIVISIONS = 8  # simplex grid of 45 surface points: starting points inside
_REFINE_STEP_TOL_REL = 1e-13  # stop the projected Newton when a step is this x shape size
_CURVATURE_FLOOR = 1e-8  # smallest Hessian eigenvalue kept (relative), for a descent step
_SNAP_REL = 1e-100  # coordinates below this x semi-axis are set to 0 (a 1e-100 x a error)

# ----------------------------------------------------------------------------------------
# argument checks


def _vector3(value, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(name, f"expected 3 numbers, got {type(value).__name__}") from exc
    if arr.shape != (3,):
        raise InvalidInputError(name, f"expected shape (3,), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = "NaN" if np.any(np.isnan(arr)) else "infinity"
        raise InvalidInputError(name, f"must be finite, got {bad}")
    return arr.copy()


def _positive3(value, name: str) -> np.ndarray:
    arr = _vector3(value, name)
    if np.any(arr <= 0.0):
        raise InvalidInputError(name, f"every entry must be > 0, got {arr.tolist()}")
    return arr


def _exponents3(value, name: str) -> np.ndarray:
    arr = _vector3(value, name)
    if np.any(arr < 2.0) or np.any(arr > SUPERQUADRIC_MAX_EXPONENT):
        raise InvalidInputError(
            name,
            f"every exponent must lie in [2, {SUPERQUADRIC_MAX_EXPONENT:g}] (convex, smooth), "
            f"got {arr.tolist()}",
        )
    return arr


def _fmt(v) -> str:
    arr = np.atleast_1d(np.asarray(v, dtype=float))
    text = ", ".join(f"{x:.6g}" for x in arr)
    return text if arr.size == 1 and np.ndim(v) == 0 else f"({text})"


# ----------------------------------------------------------------------------------------
# the pose, written once


class _Primitive(DistanceField):
    """A shape defined in a local frame and placed by ``world_T_local``.

    Subclasses implement :meth:`_local_eval` (signed distance and outward unit normal of
    local points) and :meth:`_local_bounds`, and may override :meth:`_local_distance`
    when the distance alone is cheaper than with its normal (distance queries are most of
    a planner's calls); the pose, gradients, closest points and world bounds are handled
    here.
    """

    error_bound_mm = 0.0
    lipschitz_bound = 1.0  # exact distances

    def _set_pose(self, world_T_local) -> None:
        if world_T_local is None:
            pose = np.eye(4)
        else:
            g, single = as_poses(world_T_local, "world_T_local")
            if not single:
                raise InvalidInputError("world_T_local", "expected one 4x4 pose")
            pose = g[0]
        self.world_T_local = pose
        self._rot = np.ascontiguousarray(pose[:3, :3])
        self._trans = pose[:3, 3].copy()
        self._posed = not np.array_equal(pose, np.eye(4))

    @abstractmethod
    def _local_eval(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance ``(n,)`` and outward unit normal ``(n, 3)`` of local points."""

    @abstractmethod
    def _local_bounds(self) -> np.ndarray:
        """Local axis-aligned bounds ``(2, 3)``."""

    def _to_local(self, points: np.ndarray) -> np.ndarray:
        if not self._posed:
            return points
        return np.ascontiguousarray((points - self._trans) @ self._rot)

    def _to_world_vectors(self, v: np.ndarray) -> np.ndarray:
        return v @ self._rot.T if self._posed else v

    def _local_distance(self, q: np.ndarray) -> np.ndarray:
        """Signed distance ``(n,)`` of local points alone (the normals not computed)."""
        return self._local_eval(q)[0]

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self._local_distance(self._to_local(points))

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        return self._to_world_vectors(self._local_eval(self._to_local(points))[1])

    def value_and_gradient(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance and its unit gradient (world) of points, from one evaluation.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            World points (RAS, mm).

        Returns
        -------
        signed_distance : ndarray, shape (n,)
        gradient : ndarray, shape (n, 3)
        """
        p, _ = as_points(points, "points")
        sd, normal = self._local_eval(self._to_local(p))
        return sd, self._to_world_vectors(normal)

    def closest_point(self, points) -> np.ndarray:
        """Closest surface point ``p - d(p) * grad d(p)`` (world RAS, mm).

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            A closest surface point (world, mm); on the medial axis one of several.
        """
        p, single = as_points(points, "points")
        sd, normal = self._local_eval(self._to_local(p))
        return unbatch(p - sd[:, None] * self._to_world_vectors(normal), single)

    def bounds(self) -> np.ndarray:
        """Axis-aligned world box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm)
        containing the shape (the posed corners of the local box).

        Returns
        -------
        ndarray, shape (2, 3)
        """
        lb = self._local_bounds()
        if not self._posed:
            return lb.copy()
        if not np.all(np.isfinite(lb)):
            return np.array([[-np.inf] * 3, [np.inf] * 3])
        corners = np.array(
            [[lb[i, 0], lb[j, 1], lb[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
        )
        world = corners @ self._rot.T + self._trans
        return np.stack([world.min(axis=0), world.max(axis=0)])

    def _pose_repr(self) -> str:
        if not self._posed:
            return ""
        return f", world_T_local=<pose t={_fmt(self._trans)}>"


def _unit_perpendicular(u: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to the unit vector ``u``."""
    axis = np.zeros(3)
    axis[int(np.argmin(np.abs(u)))] = 1.0
    v = np.cross(u, axis)
    return v / np.linalg.norm(v)


def _safe_unit(v: np.ndarray, norm: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Rows of ``v / norm``; ``fallback`` where the norm is zero."""
    out = np.empty_like(v)
    ok = norm > 0.0
    out[ok] = v[ok] / norm[ok, None]
    out[~ok] = fallback
    return out


@numba.njit(cache=True, error_model="numpy", inline="always")
def _snap(y, a):  # pragma: no cover - compiled
    """0 for coordinates below _SNAP_REL * a: moves the point by less than that (the
    distance is 1-Lipschitz) and keeps y / a out of the subnormal range."""
    return 0.0 if y < _SNAP_REL * a else y
