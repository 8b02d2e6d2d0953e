"""Tissue displacement caused by the needles placed so far (Liu et al. 2016, Fig. 4 steps 6-7).

Liu et al. plan needles one after another; after each insertion they "analyze the
deformation of the liver" and move the next target by ``delta_j``
(``P'_Bj = P_Bj + delta_j``, Eq. 1). Their deformation model (their refs. 31 and 38) is not
given in the paper, so here it is an interface with built-in models:

=============================  ==============================================================
model                          displacement
=============================  ==============================================================
:class:`NoDeformation`         zero: rigid anatomy
:class:`NeedleDragDeformation` the documented default: drag along the insertion direction
                               and a radial push off the shaft, both vanishing 30 mm from it
:class:`GridDeformation`       a user-supplied displacement field on a regular grid (array +
                               affine, NIfTI vector image or ``.npz``), trilinear
:class:`CallableDeformation`   a user function
=============================  ==============================================================

The contract (:class:`DeformationModel`): ``displacement(points_mm, placed)`` returns, for
points of the anatomy as planned (the reference configuration, world RAS, mm), the
displacement (mm) caused by all the needles in ``placed`` (in insertion order); the tissue
point moves to ``points + displacement`` (:func:`deform_points`). For needle ``k`` a
planner moves its target by ``displacement(target, placed[:k])``; the same call can move
obstacle geometry given as points. Displacements are treated as small: the placed needles'
coordinates and the points are taken in the same configuration, and the contributions of
several needles add up.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from needlekit._validation import as_points, as_positive, as_scalar, unbatch
from needlekit.anatomy.needle_body import (
    DEFAULT_SHAFT_OUTSIDE_MM,
    LIU_HEAD,
    NeedleBody,
    NeedleHead,
)
from needlekit.anatomy.primitives import MIN_AXIS_LENGTH_MM
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.displacement_grid import (
    GRID_INSIDE_TOL_VOXELS,
    MAX_PLAUSIBLE_DISPLACEMENT_MM,
    DisplacementGrid,
)

__all__ = [
    "DEFAULT_DRAG_MM",
    "DEFAULT_SUPPORT_RADIUS_MM",
    "GRID_INSIDE_TOL_VOXELS",
    "MAX_PLAUSIBLE_DISPLACEMENT_MM",
    "CallableDeformation",
    "DeformationModel",
    "DisplacementGrid",
    "GridDeformation",
    "NeedleDragDeformation",
    "NoDeformation",
    "PlacedNeedle",
    "deform_points",
]

#: Drag (mm) of tissue on the shaft along the insertion direction in
#: :class:`NeedleDragDeformation`. An assumption: Liu et al. give no deformation
#: parameters, and their in-vitro target error after compensation was 2.1 +- 0.6 mm, so
#: tissue moves by displacements of that order; 2 mm at the shaft is taken as the default.
DEFAULT_DRAG_MM: float = 2.0

#: Distance (mm) from the shaft beyond which :class:`NeedleDragDeformation` moves nothing.
#: An assumption: the diameter of the paper's smaller tumour (3 cm), so a needle moves the
#: targets of its own tumour (1.4 mm at 10 mm, 0.8 mm at 15 mm from the shaft, the spacing
#: of ablation needles) and leaves distant anatomy exactly at rest.
DEFAULT_SUPPORT_RADIUS_MM: float = 30.0


# ----------------------------------------------------------------------------------------
# placed needles and the interface


@dataclass(frozen=True, eq=False)
class PlacedNeedle:
    """A straight needle already in place: its tip, entry point and radius.

    Parameters
    ----------
    tip_mm : array_like, shape (3,)
        Tip (world RAS, mm).
    entry_mm : array_like, shape (3,)
        Entry point on the skin (world RAS, mm), distinct from the tip.
    radius_mm : float
        Needle radius (mm), > 0.

    Examples
    --------
    >>> n = PlacedNeedle([0.0, 0.0, 0.0], [0.0, 0.0, 80.0], 0.5)
    >>> n.direction.tolist(), n.length_mm
    ([0.0, 0.0, -1.0], 80.0)
    """

    tip_mm: np.ndarray
    entry_mm: np.ndarray
    radius_mm: float

    def __post_init__(self) -> None:
        for name in ("tip_mm", "entry_mm"):
            p, single = as_points(getattr(self, name), name)
            if not single:
                raise InvalidInputError(name, f"expected one point of shape (3,), got {p.shape}")
            arr = p[0].copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)
        object.__setattr__(self, "radius_mm", as_positive(self.radius_mm, "radius_mm"))
        if self.length_mm <= MIN_AXIS_LENGTH_MM:
            raise InvalidInputError(
                "entry_mm", "must differ from tip_mm (the needle needs an axis)"
            )

    @property
    def length_mm(self) -> float:
        """Inserted length ``|tip - entry|`` (mm)."""
        return float(np.linalg.norm(self.tip_mm - self.entry_mm))

    @property
    def direction(self) -> np.ndarray:
        """Unit insertion direction, entry to tip, shape (3,)."""
        return (self.tip_mm - self.entry_mm) / self.length_mm

    def body(
        self,
        *,
        head: NeedleHead | None = LIU_HEAD,
        shaft_outside_mm: float = DEFAULT_SHAFT_OUTSIDE_MM,
    ) -> NeedleBody:
        """This needle as an obstacle for the next one (tube and head).

        Parameters
        ----------
        head : NeedleHead or None
            The head (Liu et al.'s Eq. 4 by default), None for a bare tube.
        shaft_outside_mm : float
            Shaft length (mm) between the entry point and the head, >= 0 (0: the head on
            the skin).

        Returns
        -------
        NeedleBody
        """
        return NeedleBody(
            self.tip_mm,
            self.entry_mm,
            radius_mm=self.radius_mm,
            head=head,
            shaft_outside_mm=shaft_outside_mm,
        )

    def __repr__(self) -> str:
        return (
            f"PlacedNeedle(tip_mm={self.tip_mm.tolist()}, entry_mm={self.entry_mm.tolist()}, "
            f"radius_mm={self.radius_mm:g})"
        )


def _as_placed(placed) -> tuple[PlacedNeedle, ...]:
    """The needles as PlacedNeedle; any object with ``tip_mm``, ``entry_mm`` and
    ``radius_mm`` is accepted (and checked) too."""
    if isinstance(placed, PlacedNeedle) or not isinstance(placed, Sequence):
        raise InvalidInputError(
            "placed", f"expected a sequence of PlacedNeedle, got {type(placed).__name__}"
        )
    out = []
    for i, n in enumerate(placed):
        if isinstance(n, PlacedNeedle):
            out.append(n)
            continue
        if not all(hasattr(n, a) for a in ("tip_mm", "entry_mm", "radius_mm")):
            raise InvalidInputError(
                f"placed[{i}]",
                f"expected a PlacedNeedle (tip_mm, entry_mm, radius_mm), got {type(n).__name__}",
            )
        try:
            out.append(PlacedNeedle(n.tip_mm, n.entry_mm, n.radius_mm))
        except InvalidInputError as exc:
            raise InvalidInputError(f"placed[{i}].{exc.field}", exc.reason) from exc
    return tuple(out)


@runtime_checkable
class DeformationModel(Protocol):
    """What a planner asks of a tissue deformation model (see the module notes)."""

    def displacement(self, points_mm, placed: Sequence[PlacedNeedle]) -> np.ndarray:
        """Displacement of tissue points caused by the needles placed so far.

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Tissue points in the reference (planned) anatomy, world RAS (mm).
        placed : sequence of PlacedNeedle
            The needles inserted so far, in insertion order (may be empty). The built-in
            models also take any objects with ``tip_mm``, ``entry_mm`` and ``radius_mm``.

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Displacement (mm, world RAS) of each point; zero when ``placed`` is empty.
        """
        ...


def deform_points(model: DeformationModel, points_mm, placed: Sequence[PlacedNeedle]):
    """Where tissue points are after the placed needles: ``points + displacement``.

    Parameters
    ----------
    model : DeformationModel
    points_mm : array_like, shape (3,) or (n, 3)
        Points of the reference anatomy (world RAS, mm), e.g. the next targets.
    placed : sequence of PlacedNeedle
        Needles inserted so far, in order.

    Returns
    -------
    ndarray, shape (3,) or (n, 3)
        Displaced points (world RAS, mm).

    Examples
    --------
    >>> needle = PlacedNeedle([0.0, 0.0, 0.0], [0.0, 0.0, 80.0], 0.5)
    >>> deform_points(NoDeformation(), [10.0, 0.0, 40.0], [needle]).tolist()
    [10.0, 0.0, 40.0]
    """
    if not isinstance(model, DeformationModel):
        raise InvalidInputError(
            "model",
            f"expected a DeformationModel (with displacement()), got {type(model).__name__}",
        )
    p, single = as_points(points_mm, "points_mm")
    u = np.asarray(model.displacement(p, placed), dtype=np.float64)
    if u.shape != p.shape:
        raise InvalidInputError(
            "model", f"displacement() returned shape {u.shape}, expected {p.shape}"
        )
    return unbatch(p + u, single)


# ----------------------------------------------------------------------------------------
# built-in models


@dataclass(frozen=True)
class NoDeformation:
    """Rigid anatomy: every displacement is zero.

    Examples
    --------
    >>> NoDeformation().displacement([[1.0, 2.0, 3.0]], []).tolist()
    [[0.0, 0.0, 0.0]]
    """

    def displacement(self, points_mm, placed: Sequence[PlacedNeedle]) -> np.ndarray:
        """Zero displacement.

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Tissue points (world RAS, mm).
        placed : sequence of PlacedNeedle
            Needles inserted so far (checked, not used).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Zeros (mm).
        """
        p, single = as_points(points_mm, "points_mm")
        _as_placed(placed)
        return unbatch(np.zeros_like(p), single)


@dataclass(frozen=True)
class NeedleDragDeformation:
    """Default model: friction drag along the insertion and a radial push off the shaft.

    For one needle from entry ``E`` to tip ``T`` (unit insertion direction ``v``, radius
    ``R``), let ``w`` be the offset of a point from its closest point on the segment E-T
    and ``r = |w|`` its distance from the shaft. The displacement is

    ``u = D g(r) v + (R^2 / (2 (r^2 + R^2))) g(r) w``,   ``g(r) = (1 - r^2/rho^2)^3`` for
    ``r < rho``, else 0,

    summed over the placed needles. The first term is tissue dragged along by friction on
    the shaft (``D`` at the shaft). The second is the volume the needle takes up: in an
    incompressible medium the ring of tissue at radius ``r`` around a shaft of radius
    ``R`` moves out by about ``R^2 / (2 r)`` (plane-strain area balance); the rational form
    keeps that far from the shaft and goes to zero on the axis, where symmetry forces it
    (it peaks at ``R / 4`` at the shaft wall). The window ``g`` (smooth, C2) makes both
    vanish exactly at ``rho``, so distant anatomy is untouched. Beyond the tip the closest
    segment point is the tip itself, so tissue just ahead of the tip is pushed forward, as
    a tip pushes tissue before it cuts. The displacement is continuous, finite everywhere
    (at most ``D + R / 4`` per needle) and zero from ``rho`` on.

    Parameters
    ----------
    drag_mm : float
        Drag ``D`` at the shaft (mm), >= 0 (:data:`DEFAULT_DRAG_MM`, an assumption).
    support_radius_mm : float
        Distance ``rho`` from the shaft (mm) where the displacement ends, > 0
        (:data:`DEFAULT_SUPPORT_RADIUS_MM`, an assumption).
    radial_push : bool
        Include the radial term (True by default).

    Examples
    --------
    >>> model = NeedleDragDeformation()
    >>> needle = PlacedNeedle([0.0, 0.0, 0.0], [0.0, 0.0, 80.0], 0.5)  # inserted along -z
    >>> model.displacement([[0.0, 0.0, 40.0], [50.0, 0.0, 40.0]], [needle]).round(6).tolist()
    [[0.0, 0.0, -2.0], [0.0, 0.0, 0.0]]
    """

    drag_mm: float = DEFAULT_DRAG_MM
    support_radius_mm: float = DEFAULT_SUPPORT_RADIUS_MM
    radial_push: bool = True

    def __post_init__(self) -> None:
        drag = as_scalar(self.drag_mm, "drag_mm")
        if drag < 0.0:
            raise InvalidInputError("drag_mm", f"must be >= 0, got {drag}")
        object.__setattr__(self, "drag_mm", drag)
        object.__setattr__(
            self, "support_radius_mm", as_positive(self.support_radius_mm, "support_radius_mm")
        )
        if not isinstance(self.radial_push, bool):
            raise InvalidInputError(
                "radial_push", f"expected True or False, got {type(self.radial_push).__name__}"
            )

    def window(self, r_mm) -> np.ndarray:
        """The decay ``g(r) = (1 - r^2 / rho^2)^3`` inside ``rho``, 0 outside.

        Parameters
        ----------
        r_mm : array_like, shape (n,)
            Distances from the shaft (mm), >= 0.

        Returns
        -------
        ndarray, shape (n,)
            Dimensionless weights in [0, 1], 1 at the shaft.
        """
        x = np.square(np.asarray(r_mm, dtype=np.float64) / self.support_radius_mm)
        return np.where(x < 1.0, (1.0 - np.minimum(x, 1.0)) ** 3, 0.0)

    def displacement(self, points_mm, placed: Sequence[PlacedNeedle]) -> np.ndarray:
        """Sum over the placed needles of drag and radial push (see the class notes).

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Tissue points in the reference anatomy (world RAS, mm).
        placed : sequence of PlacedNeedle
            Needles inserted so far.

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Displacement (mm, world RAS).
        """
        p, single = as_points(points_mm, "points_mm")
        needles = _as_placed(placed)
        out = np.zeros_like(p)
        for n in needles:
            seg = n.tip_mm - n.entry_mm
            s = np.clip((p - n.entry_mm) @ seg / (seg @ seg), 0.0, 1.0)
            w = p - (n.entry_mm + s[:, None] * seg)
            r2 = np.einsum("ij,ij->i", w, w)
            g = self.window(np.sqrt(r2))
            out += (self.drag_mm * g)[:, None] * n.direction
            if self.radial_push:
                r0 = n.radius_mm**2
                out += (g * r0 / (2.0 * (r2 + r0)))[:, None] * w
        return unbatch(out, single)


class GridDeformation:
    """User-supplied displacement fields on grids (:class:`DisplacementGrid`).

    One grid: the tissue's displacement once any needle is in place (``per_needle=False``)
    or the displacement each insertion adds, scaled by the number of needles placed
    (``per_needle=True``). A sequence of grids: the k-th is the displacement the k-th
    insertion adds; after ``m`` needles the displacement is the sum of the first ``m``
    (more needles than grids is an error). The grids do not look at the needles' positions:
    they are computed for the planned sequence by the user.

    Parameters
    ----------
    grids : DisplacementGrid, path, or sequence of them
        Grids, or files read with :meth:`DisplacementGrid.load`.
    per_needle : bool
        With one grid, scale it by the number of needles placed.
    outside : {"error", "zero"}
        Points outside a grid raise (default) or get zero displacement from it.

    Examples
    --------
    >>> field = np.zeros((2, 2, 2, 3))
    >>> field[..., 2] = -1.5
    >>> model = GridDeformation(DisplacementGrid(field, np.diag([50.0, 50.0, 50.0, 1.0])))
    >>> needle = PlacedNeedle([0.0, 0.0, 0.0], [0.0, 0.0, 80.0], 0.5)
    >>> model.displacement([[10.0, 10.0, 10.0]], [needle]).round(9).tolist()
    [[0.0, 0.0, -1.5]]
    """

    def __init__(self, grids, *, per_needle: bool = False, outside: str = "error") -> None:
        if outside not in ("error", "zero"):
            raise InvalidInputError("outside", f"expected 'error' or 'zero', got {outside!r}")
        if not isinstance(per_needle, bool):
            raise InvalidInputError("per_needle", f"expected True or False, got {per_needle!r}")
        single = isinstance(grids, (DisplacementGrid, str, os.PathLike))
        items = [grids] if single else grids
        if not single and not isinstance(items, Sequence):
            raise InvalidInputError(
                "grids",
                f"expected a DisplacementGrid, a path or a sequence, got {type(grids).__name__}",
            )
        if len(items) == 0:
            raise InvalidInputError("grids", "needs at least one displacement grid")
        loaded = []
        for i, g in enumerate(items):
            if isinstance(g, (str, os.PathLike)):
                g = DisplacementGrid.load(g)
            if not isinstance(g, DisplacementGrid):
                where = "grids" if single else f"grids[{i}]"
                raise InvalidInputError(
                    where, f"expected a DisplacementGrid, got {type(g).__name__}"
                )
            loaded.append(g)
        if per_needle and not single:
            raise InvalidInputError(
                "per_needle", "applies to one grid; a sequence already gives one per insertion"
            )
        self.grids = tuple(loaded)
        self.per_insertion = not single
        self.per_needle = per_needle
        self.outside = outside

    def displacement(self, points_mm, placed: Sequence[PlacedNeedle]) -> np.ndarray:
        """Displacement after the placed needles (see the class notes).

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Tissue points in the reference anatomy (world RAS, mm).
        placed : sequence of PlacedNeedle
            Needles inserted so far (only their number is used).

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Displacement (mm, world RAS).
        """
        p, single = as_points(points_mm, "points_mm")
        m = len(_as_placed(placed))
        out = np.zeros_like(p)
        if m == 0:
            return unbatch(out, single)
        if self.per_insertion:
            if m > len(self.grids):
                raise InvalidInputError(
                    "placed",
                    f"{m} needles placed but {len(self.grids)} displacement grids given "
                    "(one per insertion)",
                )
            for g in self.grids[:m]:
                out += g.sample(p, outside=self.outside)
        else:
            scale = float(m) if self.per_needle else 1.0
            out += scale * self.grids[0].sample(p, outside=self.outside)
        return unbatch(out, single)

    def __repr__(self) -> str:
        return (
            f"GridDeformation({list(self.grids)!r}, per_needle={self.per_needle}, "
            f"outside={self.outside!r})"
        )


class CallableDeformation:
    """A user function as a deformation model; its answers are checked.

    Parameters
    ----------
    fn : callable
        ``fn(points_mm, placed) -> displacement``: points ``(n, 3)`` (world RAS, mm, a
        copy), ``placed`` a tuple of :class:`PlacedNeedle`; returns ``(n, 3)`` finite
        displacements (mm).

    Examples
    --------
    >>> shift = CallableDeformation(lambda p, n: np.tile([0.0, 0.0, -len(n)], (len(p), 1)))
    >>> needle = PlacedNeedle([0.0, 0.0, 0.0], [0.0, 0.0, 80.0], 0.5)
    >>> shift.displacement([1.0, 2.0, 3.0], [needle, needle]).tolist()
    [0.0, 0.0, -2.0]
    """

    def __init__(self, fn: Callable[[np.ndarray, tuple[PlacedNeedle, ...]], np.ndarray]) -> None:
        if not callable(fn):
            raise InvalidInputError("fn", f"expected a callable, got {type(fn).__name__}")
        self.fn = fn

    def displacement(self, points_mm, placed: Sequence[PlacedNeedle]) -> np.ndarray:
        """Call the function and check its answer.

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Tissue points in the reference anatomy (world RAS, mm).
        placed : sequence of PlacedNeedle
            Needles inserted so far.

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Displacement (mm, world RAS).
        """
        p, single = as_points(points_mm, "points_mm")
        needles = _as_placed(placed)
        answer = self.fn(p.copy(), needles)
        try:
            u = np.asarray(answer, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError("fn", f"did not return numbers ({exc})") from exc
        if u.shape != p.shape:
            raise InvalidInputError(
                "fn", f"returned shape {u.shape} for {len(p)} points, expected {p.shape}"
            )
        if not np.all(np.isfinite(u)):
            raise InvalidInputError("fn", "returned NaN or infinite displacements")
        return unbatch(u, single)

    def __repr__(self) -> str:
        return f"CallableDeformation({self.fn!r})"
