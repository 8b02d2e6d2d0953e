"""Signed distance fields: the one interface through which planners see anatomy.

A :class:`DistanceField` answers, for world points (RAS, mm), the signed Euclidean
distance to a structure's surface: negative inside, zero on the surface, positive outside.
Every field states how far its answers may be from the true distance
(:attr:`DistanceField.error_bound_mm`): 0 for closed forms (up to rounding), a voxel-size
bound for sampled grids. Safety checks subtract that bound, so a needle is never declared
clear by more than the field can vouch for.

Composition: :meth:`DistanceField.inflated` (offset by a radius and margin, as for a needle
of finite diameter), :func:`union` (minimum of several fields: a union of structures) and
:class:`TransformedField` (a field defined in a local frame, placed in the world by a pose).
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

import numpy as np

from needlekit._validation import as_points, as_poses, unbatch
from needlekit.errors import InvalidInputError

__all__ = [
    "GRADIENT_STEP_MM",
    "BoundedField",
    "ComplementField",
    "DistanceField",
    "LazyField",
    "OffsetField",
    "TransformedField",
    "UnionField",
    "union",
]

#: Step (mm) of the central differences that give the default gradient. Small against
#: anatomical curvature radii (> 1 mm) yet far above rounding of mm-scale distances.
GRADIENT_STEP_MM: float = 1e-4


class DistanceField(ABC):
    """Signed Euclidean distance to a surface, in the world frame (RAS, mm).

    Subclasses implement :meth:`_signed_distance` on a validated ``(n, 3)`` float64 array
    and set :attr:`error_bound_mm` and :meth:`bounds`.
    """

    #: Largest possible |reported - true| signed distance (mm) anywhere.
    error_bound_mm: float = 0.0
    #: A Lipschitz constant of the reported field (``|d(x) - d(y)| <= L |x - y|``), or
    #: None when not known: 1 for exact distances; an interpolated grid states its own. A
    #: ray that steps ``|d| / L`` never steps over a sign change of the field itself.
    lipschitz_bound: float | None = None

    @abstractmethod
    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distances of validated points ``(n, 3)``; returns ``(n,)``."""

    @abstractmethod
    def bounds(self) -> np.ndarray:
        """Axis-aligned box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm) containing
        the structure (entries may be infinite for unbounded shapes such as half-spaces).

        Returns
        -------
        ndarray, shape (2, 3)
        """

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance of points to the surface (negative inside).

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).

        Returns
        -------
        ndarray, shape () or (n,)
            Signed distance (mm), within :attr:`error_bound_mm` of the truth.
        """
        p, single = as_points(points, "points")
        return unbatch(self._signed_distance(p), single)

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        h = GRADIENT_STEP_MM
        n = points.shape[0]
        stacked = np.empty((6 * n, 3))
        for axis in range(3):
            for k, sign in enumerate((1.0, -1.0)):
                block = points.copy()
                block[:, axis] += sign * h
                stacked[(2 * axis + k) * n : (2 * axis + k + 1) * n] = block
        d = self._signed_distance(stacked).reshape(6, n)
        return np.stack([(d[2 * a] - d[2 * a + 1]) / (2.0 * h) for a in range(3)], axis=1)

    def gradient(self, points) -> np.ndarray:
        """Gradient of the signed distance (central differences unless overridden).

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Unit-length where the distance is differentiable; on the medial axis the
            direction is arbitrary and the length may be below 1.
        """
        p, single = as_points(points, "points")
        return unbatch(self._gradient(p), single)

    def normal(self, points) -> np.ndarray:
        """Outward unit surface normal (the normalised gradient) at or near the surface.

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Unit vectors; NaN where the gradient vanishes.
        """
        p, single = as_points(points, "points")
        g = self._gradient(p)
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(norm > 1e-12, g / norm, np.nan)
        return unbatch(out, single)

    def capped_distance(self, points: np.ndarray, cap_mm: float) -> np.ndarray:
        """Signed distance where it is below ``cap_mm``; elsewhere any value between
        ``cap_mm`` and the distance (a lower bound that is at least the cap).

        Queries that only need ``min(distance, cap)`` (certified clearance along paths,
        sphere tracing) call this, so fields whose exact distance is costly can answer far
        points from a cheap bound (:class:`BoundedField`). This default is exact.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Validated world points (float64).
        cap_mm : float

        Returns
        -------
        ndarray, shape (n,)
        """
        return self._signed_distance(points)

    def near(self, point_mm, radius_mm: float) -> DistanceField | None:
        """A field equal to this one near a point, wherever the distance is at most
        ``radius_mm``: for questions about one point (the surface a start lies on, its
        normal) that should not build a large field whole.

        Parameters
        ----------
        point_mm : array_like, shape (3,)
        radius_mm : float

        Returns
        -------
        DistanceField or None
            Its value and gradient at points within a voxel diagonal of ``point_mm`` equal
            this field's where ``|d| <= radius_mm``; where this field has ``|d| >
            radius_mm`` at ``point_mm``, the value there keeps its sign and exceeds
            ``radius_mm`` in magnitude. None when the
            structure lies farther than ``radius_mm`` from the point. This default returns
            the field itself; :class:`LazyField` answers from a local window when it can.
        """
        return self

    def near_box(self, box_mm, radius_mm: float) -> DistanceField | None:
        """:meth:`near` over a box: a field equal to this one at the points of ``box_mm``
        where the distance is at most ``radius_mm`` (e.g. the surfaces a figure draws
        around a path, without building a whole CT's field).

        Parameters
        ----------
        box_mm : array_like, shape (2, 3)
            ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``.
        radius_mm : float

        Returns
        -------
        DistanceField or None
            None when the structure lies farther than ``radius_mm`` from the box. This
            default returns the field itself.
        """
        return self

    def inflated(self, margin_mm: float) -> DistanceField:
        """The field of this structure grown by ``margin_mm`` (e.g. needle radius plus a
        safety margin): ``d - margin_mm``.

        Parameters
        ----------
        margin_mm : float
            Offset (mm), >= 0.

        Returns
        -------
        DistanceField
        """
        m = float(margin_mm)
        if not (np.isfinite(m) and m >= 0.0):
            raise InvalidInputError("margin_mm", f"must be a finite number >= 0, got {margin_mm}")
        return OffsetField(self, m)


class OffsetField(DistanceField):
    """``base - margin``: the base structure grown by a margin (exact for true distance
    fields outside the base; a lower bound on the true distance inside)."""

    def __init__(self, base: DistanceField, margin_mm: float) -> None:
        self.base = base
        self.margin_mm = float(margin_mm)
        self.error_bound_mm = base.error_bound_mm

    @property
    def lipschitz_bound(self) -> float | None:  # the base's, asked for only when needed
        return self.base.lipschitz_bound

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self.base._signed_distance(points) - self.margin_mm

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        return self.base._gradient(points)

    def bounds(self) -> np.ndarray:
        b = self.base.bounds().copy()
        b[0] -= self.margin_mm
        b[1] += self.margin_mm
        return b


class BoundedField(DistanceField):
    """A field with a cheap enclosing shape: exact everywhere, and cheap for capped
    queries far from it.

    Parameters
    ----------
    field : DistanceField
        The exact, costly field (e.g. a superquadric).
    bound : DistanceField
        A shape containing ``field``'s (so its distance is a lower bound of ``field``'s
        outside), e.g. an enclosing capsule.

    Examples
    --------
    >>> from needlekit.anatomy.primitives import Capsule, Sphere
    >>> f = BoundedField(Sphere([0, 0, 0], 1.0), Sphere([0, 0, 0], 2.0))
    >>> pts = np.array([[10.0, 0, 0], [1.5, 0, 0]])
    >>> f.signed_distance(pts).tolist(), f.capped_distance(pts, 5.0).tolist()
    ([9.0, 0.5], [8.0, 0.5])
    """

    def __init__(self, field: DistanceField, bound: DistanceField) -> None:
        for name, f in (("field", field), ("bound", bound)):
            if not isinstance(f, DistanceField):
                raise InvalidInputError(name, f"expected a DistanceField, got {type(f).__name__}")
        self.field = field
        self.bound = bound
        self.error_bound_mm = field.error_bound_mm

    @property
    def lipschitz_bound(self) -> float | None:  # the field's, asked for only when needed
        return self.field.lipschitz_bound

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self.field._signed_distance(points)

    def capped_distance(self, points: np.ndarray, cap_mm: float) -> np.ndarray:
        lower = self.bound._signed_distance(points) - self.bound.error_bound_mm
        near = lower < cap_mm
        if near.any():
            lower[near] = self.field.capped_distance(points[near], cap_mm)
        return lower

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        return self.field._gradient(points)

    def bounds(self) -> np.ndarray:
        return self.field.bounds()


class UnionField(DistanceField):
    """Minimum of several fields: the signed distance to their union (exact outside all
    of them; inside, a bound on the depth)."""

    def __init__(self, fields: Sequence[DistanceField]) -> None:
        if len(fields) == 0:
            raise InvalidInputError("fields", "a union needs at least one field")
        for i, f in enumerate(fields):
            if not isinstance(f, DistanceField):
                raise InvalidInputError(
                    f"fields[{i}]", f"expected a DistanceField, got {type(f).__name__}"
                )
        self.fields = tuple(fields)
        self.error_bound_mm = max(f.error_bound_mm for f in self.fields)

    @property  # type: ignore[override]
    def lipschitz_bound(self) -> float | None:
        # the minimum of L_i-Lipschitz functions is max(L_i)-Lipschitz
        ls = [f.lipschitz_bound for f in self.fields]
        return None if any(v is None for v in ls) else max(ls)

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        out = self.fields[0]._signed_distance(points)
        for f in self.fields[1:]:
            np.minimum(out, f._signed_distance(points), out=out)
        return out

    def capped_distance(self, points: np.ndarray, cap_mm: float) -> np.ndarray:
        out = self.fields[0].capped_distance(points, cap_mm)
        for f in self.fields[1:]:
            np.minimum(out, f.capped_distance(points, cap_mm), out=out)
        return out

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        d = np.stack([f._signed_distance(points) for f in self.fields])
        which = np.argmin(d, axis=0)
        out = np.empty_like(points)
        for i, f in enumerate(self.fields):
            sel = which == i
            if np.any(sel):
                out[sel] = f._gradient(points[sel])
        return out

    def bounds(self) -> np.ndarray:
        b = np.stack([f.bounds() for f in self.fields])
        return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])


def union(*fields: DistanceField) -> DistanceField:
    """Signed distance to the union of structures (one field is returned as it is).

    Parameters
    ----------
    *fields : DistanceField

    Returns
    -------
    DistanceField
    """
    return fields[0] if len(fields) == 1 else UnionField(fields)


class TransformedField(DistanceField):
    """A field defined in a local frame, placed in the world by ``world_T_local``.

    Rigid motions preserve distances, so the error bound carries over unchanged.
    """

    def __init__(self, local: DistanceField, world_T_local) -> None:
        g, single = as_poses(world_T_local, "world_T_local")
        if not single:
            raise InvalidInputError("world_T_local", "expected one 4x4 pose")
        self.local = local
        self.world_T_local = g[0]
        self._rot = g[0, :3, :3]
        self._trans = g[0, :3, 3]
        self.error_bound_mm = local.error_bound_mm

    @property
    def lipschitz_bound(self) -> float | None:  # the local field's, asked for when needed
        return self.local.lipschitz_bound

    def _to_local(self, points: np.ndarray) -> np.ndarray:
        return (points - self._trans) @ self._rot

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self.local._signed_distance(self._to_local(points))

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        return self.local._gradient(self._to_local(points)) @ self._rot.T

    def bounds(self) -> np.ndarray:
        lb = self.local.bounds()
        if not np.all(np.isfinite(lb)):
            return np.array([[-np.inf] * 3, [np.inf] * 3])
        corners = np.array(
            [[lb[i, 0], lb[j, 1], lb[k, 2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)]
        )
        world = corners @ self._rot.T + self._trans
        return np.stack([world.min(axis=0), world.max(axis=0)])


class ComplementField(DistanceField):
    """The outside of a structure as a structure: ``-base``. An allowed region (where the
    needle must stay) becomes an obstacle this way."""

    def __init__(self, base: DistanceField) -> None:
        self.base = base
        self.error_bound_mm = base.error_bound_mm

    @property
    def lipschitz_bound(self) -> float | None:  # the base's, asked for only when needed:
        return self.base.lipschitz_bound  # a voxel grid's takes a pass over all its values

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return -self.base._signed_distance(points)

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        return -self.base._gradient(points)

    def bounds(self) -> np.ndarray:
        return np.array([[-np.inf] * 3, [np.inf] * 3])


class LazyField(DistanceField):
    """A field built on first use: for large voxel grids that a given task may not need.

    Parameters
    ----------
    build : callable
        Returns the real :class:`DistanceField`; called once, under a lock.
    description : str
        What will be built (for ``repr`` and error messages).
    local : callable, optional
        ``local(point, radius[, half_size])``: a cheap field of the same structure that is
        exact near ``point`` (or over the box ``point +- half_size``) where
        ``|d| <= radius``, or None when the structure is farther (see
        :meth:`DistanceField.near` and :meth:`DistanceField.near_box`). Lets one-point
        questions, and figures of a small region, skip the build.
    preview : callable, optional
        ``preview(max_cells)``: a coarse field of the same structure, at most about
        ``max_cells`` samples along an axis, for drawing it whole (:meth:`preview`).
    bounds : callable, optional
        ``bounds()``: what the built field's ``bounds()`` returns, found without building
        it (e.g. :meth:`~needlekit.anatomy.voxel.VoxelSDF.mask_bounds`), so that boxing
        or drawing a scene does not build every structure's field.
    """

    def __init__(
        self,
        build: Callable[[], DistanceField],
        description: str = "",
        *,
        local: Callable[..., DistanceField | None] | None = None,
        preview: Callable[[int], DistanceField] | None = None,
        bounds: Callable[[], np.ndarray] | None = None,
    ) -> None:
        self._build = build
        self._bounds = bounds
        self._field: DistanceField | None = None
        self._lock = threading.Lock()
        self.description = description
        self._local = local
        self._near: dict[tuple, DistanceField | None] = {}
        self._preview = preview
        self._previews: dict[int, DistanceField] = {}

    @property
    def built(self) -> bool:
        """Whether the field has been built yet."""
        return self._field is not None

    def near(self, point_mm, radius_mm: float) -> DistanceField | None:
        """The built field when there is one; else, when the builder gave a ``local``
        function, a field of a small window around the point (the last few are kept);
        else the field, built now.

        Parameters
        ----------
        point_mm : array_like, shape (3,)
        radius_mm : float

        Returns
        -------
        DistanceField or None
            As :meth:`DistanceField.near`.
        """
        if self._field is not None or self._local is None:
            return self.get()
        p = np.asarray(point_mm, dtype=np.float64).reshape(3)
        return self._local_field(p, float(radius_mm), None)

    def preview(self, max_cells: int) -> DistanceField:
        """A field to draw the whole structure with at most about ``max_cells`` samples per
        axis: the builder's ``preview`` (kept), whether or not the field is built, so that
        a figure does not depend on what ran before it; else the field itself.

        Parameters
        ----------
        max_cells : int

        Returns
        -------
        DistanceField
            Display only: a coarse field's error bound is its own, not this field's.
        """
        if self._preview is None:
            return self.get()
        with self._lock:
            if max_cells not in self._previews:
                self._previews[max_cells] = self._preview(int(max_cells))
            return self._previews[max_cells]

    def near_box(self, box_mm, radius_mm: float) -> DistanceField | None:
        """The built field when there is one; else, when the builder gave a ``local``
        function, a field of the window around the box; else the field, built now.

        Parameters
        ----------
        box_mm : array_like, shape (2, 3)
        radius_mm : float

        Returns
        -------
        DistanceField or None
            As :meth:`DistanceField.near_box`.
        """
        if self._field is not None or self._local is None:
            return self.get()
        b = np.asarray(box_mm, dtype=np.float64).reshape(2, 3)
        return self._local_field(0.5 * (b[0] + b[1]), float(radius_mm), 0.5 * (b[1] - b[0]))

    def _local_field(self, centre, radius: float, half) -> DistanceField | None:
        key = (*centre.tolist(), radius, *(() if half is None else half.tolist()))
        with self._lock:
            if key not in self._near:
                if len(self._near) >= 8:
                    self._near.pop(next(iter(self._near)))
                self._near[key] = (
                    self._local(centre, radius) if half is None
                    else self._local(centre, radius, half)
                )  # fmt: skip
            return self._near[key]

    def get(self) -> DistanceField:
        """The built field (building it now if needed).

        Returns
        -------
        DistanceField
        """
        if self._field is None:
            with self._lock:
                if self._field is None:
                    field = self._build()
                    if not isinstance(field, DistanceField):
                        raise InvalidInputError(
                            self.description or "field",
                            f"builder returned {type(field).__name__}, not a DistanceField",
                        )
                    self._field = field
        return self._field

    @property  # type: ignore[override]
    def error_bound_mm(self) -> float:
        return self.get().error_bound_mm

    @property  # type: ignore[override]
    def lipschitz_bound(self) -> float | None:
        return self.get().lipschitz_bound

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self.get()._signed_distance(points)

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        return self.get()._gradient(points)

    def bounds(self) -> np.ndarray:
        if self._field is None and self._bounds is not None:
            return np.array(self._bounds(), dtype=np.float64).reshape(2, 3)
        return self.get().bounds()

    def __repr__(self) -> str:
        state = "built" if self.built else "not built"
        return f"LazyField({self.description!r}, {state})"
