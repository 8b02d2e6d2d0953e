"""A placed straight needle as an obstacle: its tube and its head (Liu et al. 2016, Fig. 6).

Liu et al. plan needles one after another; every needle already in place is an obstacle
for the next one (their Fig. 4 and 5). The paper's needle has two parts (Fig. 6): the
*tube* (the thin shaft, inserted through the skin) and the *head* (the handle or hub
outside the patient), which Eq. 4 describes as a superquadric in a frame ``Sigma'`` at the
head's geometric centre whose ``x'`` axis is the needle axis.

:class:`NeedleBody` is the signed distance (RAS, mm, negative inside) to the union of

- the tube: an exact :class:`~needlekit.anatomy.primitives.Capsule` of the needle radius
  from the tip through the entry point to where the head starts, and
- the head: a :class:`~needlekit.anatomy.primitives.Superquadric` given by
  :class:`NeedleHead` (Eq. 4 by default), or nothing.

Why a capsule and not a flat-ended cylinder: a real needle tip (bevel, trocar or conical)
lies inside the cylinder of the shaft radius, and that cylinder lies inside the capsule,
so the capsule never reports a needle clear that touches the physical needle. It reaches
at most one radius (0.5 mm for the default 1 mm needle) beyond the tip and has a smooth,
closed-form distance with a unique normal everywhere off its axis, which the flat-ended
cylinder lacks at its rims. The price is that up to one radius ahead of the tip counts as
needle; a planner that wants the next tip closer than that to a placed tip would be
refused, which is the safe direction.

Reading Eq. 4. ``(x'/60)^8 + (y'/0.1)^2 + (z'/0.1)^2 - 1000 = 0`` is the superquadric
``|x'/a_x|^8 + |y'/a_y|^2 + |z'/a_z|^2 = 1`` with semi-axes ``a_i = s_i * 1000^(1/e_i)``:

========  ========  ========  =======================  ====================
axis      divisor   exponent  semi-axis (mm)           dimension it implies
========  ========  ========  =======================  ====================
``x'``    60        8         60 * 1000^(1/8) = 142.28  length 284.6 mm
``y'``    0.1       2         0.1 * 1000^(1/2) = 3.162  diameter 6.32 mm
``z'``    0.1       2         0.1 * 1000^(1/2) = 3.162  (same)
========  ========  ========  =======================  ====================

The cross-section across the axis is a circle (exponent 2, equal divisors); along the axis
exponent 8 makes a cylinder with rounded, nearly flat ends (the radius is still 91 % of
its maximum at 80 % of the half-length, 58 % at 95 %). Read literally, Eq. 7 puts
``Sigma'`` half a head length from the *target* along the needle, so the superquadric
would start at the tip and cover the first 284.6 mm of the needle, tube included; the text
and Fig. 6 call it the head. Here the head is the handle, as in Fig. 6: it starts where
the tube leaves it, ``shaft_outside_mm`` beyond the entry point (by default 0: the head
sits on the skin at the entry point), and the tube is a separate capsule. Eq. 6 orients
``x'`` from the head toward the tip (its last factor turns ``x'`` onto ``-z''``); the head
is symmetric, so here ``x'`` points from the tip toward the handle, and ``y'``, ``z'``
complete it (any completion gives the same solid, the head being axisymmetric).

Error bound: the capsule is a closed form (exact to rounding); the superquadric's
projection is held to
:data:`~needlekit.anatomy.primitives.SUPERQUADRIC_ERROR_BOUND_MM` (1e-6 mm), so a body
with a head states 1e-6 mm and one without states 0. Outside the body the minimum of the
two parts is the exact distance to their union; inside, it is never deeper than the truth
(the sign is always right).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_points, as_positive, as_scalar
from needlekit.anatomy.fields import BoundedField, UnionField
from needlekit.anatomy.primitives import MIN_AXIS_LENGTH_MM, Capsule, Superquadric
from needlekit.errors import InvalidInputError

__all__ = [
    "DEFAULT_SHAFT_OUTSIDE_MM",
    "LIU_HEAD",
    "LIU_HEAD_EXPONENTS",
    "LIU_HEAD_LEVEL",
    "LIU_HEAD_SCALES_MM",
    "NeedleBody",
    "NeedleHead",
]

#: Divisors ``s_i`` (mm) of Eq. 4 along ``x'`` (the needle axis), ``y'`` and ``z'``, as
#: printed by Liu et al. (2016).
LIU_HEAD_SCALES_MM: tuple[float, float, float] = (60.0, 0.1, 0.1)
#: Exponents of Eq. 4, as printed: 8 along the axis (flat ends), 2 across (a circle).
LIU_HEAD_EXPONENTS: tuple[float, float, float] = (8.0, 2.0, 2.0)
#: Right-hand side of Eq. 4, as printed.
LIU_HEAD_LEVEL: float = 1000.0

#: Length (mm) of shaft left outside the body between the entry point and the head.
#: Liu et al. give none; 0 puts the head on the skin at the entry point, as when a needle
#: is inserted up to its hub (the paper's robot inserts to a planned depth marked on the
#: needle, and the rest of the shaft is what the user should state).
DEFAULT_SHAFT_OUTSIDE_MM: float = 0.0


def _triple(value, name: str) -> tuple[float, float, float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InvalidInputError(name, f"expected 3 numbers, got {type(value).__name__}") from exc
    if arr.shape != (3,):
        raise InvalidInputError(name, f"expected 3 numbers, got shape {arr.shape}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


@dataclass(frozen=True)
class NeedleHead:
    """The head (handle, hub) of a needle: Liu et al.'s superquadric (Eq. 4) in ``Sigma'``.

    The solid is ``sum_i |x'_i / s_i|^{e_i} <= level`` in a frame at the head's centre
    whose ``x'`` axis is the needle axis; the defaults are Eq. 4 as printed (semi-axes
    142.28, 3.162, 3.162 mm: a head 284.6 mm long and 6.32 mm across; see the module
    notes). The head must be axisymmetric (equal divisors and exponents across the axis):
    a needle's roll about its own axis is not planned (Liu et al.: "the needle's rotation
    around its own axis would not affect the position of the needle").

    Parameters
    ----------
    scales_mm : tuple of 3 float
        Divisors ``s_i`` (mm) along ``x'``, ``y'``, ``z'``, each > 0; ``s_y == s_z``.
    exponents : tuple of 3 float
        Exponents ``e_i`` in [2, 32]; ``e_y == e_z``.
    level : float
        The constant on the right-hand side, > 0.

    Examples
    --------
    >>> head = NeedleHead()  # Eq. 4
    >>> round(head.length_mm, 2), round(head.diameter_mm, 3)
    (284.56, 6.325)
    >>> NeedleHead.from_dimensions(length_mm=80.0, diameter_mm=8.0).semi_axes_mm.tolist()
    [40.0, 4.0, 4.0]
    """

    scales_mm: tuple[float, float, float] = LIU_HEAD_SCALES_MM
    exponents: tuple[float, float, float] = LIU_HEAD_EXPONENTS
    level: float = LIU_HEAD_LEVEL

    def __post_init__(self) -> None:
        scales = _triple(self.scales_mm, "scales_mm")
        exps = _triple(self.exponents, "exponents")
        level = as_positive(self.level, "level")
        Superquadric.from_liu(scales, exps, level)  # the primitive's own checks
        if scales[1] != scales[2]:
            raise InvalidInputError(
                "scales_mm", f"the head must be axisymmetric (s_y == s_z), got {list(scales)}"
            )
        if exps[1] != exps[2]:
            raise InvalidInputError(
                "exponents", f"the head must be axisymmetric (e_y == e_z), got {list(exps)}"
            )
        object.__setattr__(self, "scales_mm", scales)
        object.__setattr__(self, "exponents", exps)
        object.__setattr__(self, "level", level)

    @classmethod
    def from_dimensions(
        cls, length_mm: float, diameter_mm: float, *, axial_exponent: float = 8.0
    ) -> NeedleHead:
        """A head of the given length and diameter (the form of Eq. 4 with level 1).

        Parameters
        ----------
        length_mm : float
            Length along the needle axis (mm), > 0.
        diameter_mm : float
            Largest diameter across the axis (mm), > 0.
        axial_exponent : float
            Exponent along the axis in [2, 32]: 8 as in Eq. 4 (nearly flat ends), 2 an
            ellipsoid.

        Returns
        -------
        NeedleHead
        """
        length = as_positive(length_mm, "length_mm")
        diameter = as_positive(diameter_mm, "diameter_mm")
        e = as_scalar(axial_exponent, "axial_exponent")
        return cls((0.5 * length, 0.5 * diameter, 0.5 * diameter), (e, 2.0, 2.0), 1.0)

    @property
    def semi_axes_mm(self) -> np.ndarray:
        """Semi-axes ``a_i = s_i * level^(1 / e_i)`` along ``x'``, ``y'``, ``z'`` (mm),
        shape (3,)."""
        return np.asarray(self.scales_mm) * self.level ** (1.0 / np.asarray(self.exponents))

    @property
    def length_mm(self) -> float:
        """Length of the head along the needle axis (mm): ``2 a_x``."""
        return float(2.0 * self.semi_axes_mm[0])

    @property
    def diameter_mm(self) -> float:
        """Largest diameter of the head across the axis (mm): ``2 a_y``."""
        return float(2.0 * self.semi_axes_mm[1])

    def superquadric(self, world_T_head) -> Superquadric:
        """The head as a superquadric placed by ``world_T_head`` (``T_obs`` of Eq. 6).

        Parameters
        ----------
        world_T_head : array_like, shape (4, 4)
            Pose of ``Sigma'``: origin at the head's centre, ``x'`` along the needle.

        Returns
        -------
        Superquadric
        """
        return Superquadric.from_liu(self.scales_mm, self.exponents, self.level, world_T_head)


#: Eq. 4 as printed: the default head of :class:`NeedleBody` (284.6 mm long, 6.32 mm across).
LIU_HEAD: NeedleHead = NeedleHead()


def _point(value, name: str) -> np.ndarray:
    p, single = as_points(value, name)
    if not single:
        raise InvalidInputError(name, f"expected one point of shape (3,), got {p.shape}")
    return p[0].copy()


def _head_frame(axis: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """Pose whose x axis is the unit vector ``axis`` and whose origin is ``origin``."""
    helper = np.zeros(3)
    helper[int(np.argmin(np.abs(axis)))] = 1.0
    y = np.cross(axis, helper)
    y /= np.linalg.norm(y)
    z = np.cross(axis, y)
    pose = np.eye(4)
    pose[:3, 0] = axis
    pose[:3, 1] = y
    pose[:3, 2] = z
    pose[:3, 3] = origin
    return pose


class NeedleBody(UnionField):
    """Signed distance to a placed straight needle: capsule tube plus superquadric head.

    The tube is the capsule of radius ``radius_mm`` around the segment from the tip to the
    head start, ``shaft_outside_mm`` beyond the entry point along the needle axis; the head
    (if any) begins there and extends ``head.length_mm`` further out, its ``x'`` axis on
    the needle axis. World frame RAS, mm; negative inside. See the module notes for the
    reading of Eq. 4, the capsule and the error bound.

    Parameters
    ----------
    tip_mm : array_like, shape (3,)
        Needle tip (the target reached), world RAS (mm).
    entry_mm : array_like, shape (3,)
        Entry point on the skin, world RAS (mm); distinct from the tip.
    radius_mm : float
        Needle (tube) radius (mm), > 0.
    head : NeedleHead or None
        The head; Eq. 4 (:data:`LIU_HEAD`) by default, None for a bare tube.
    shaft_outside_mm : float
        Shaft length (mm) between the entry point and the head, >= 0
        (:data:`DEFAULT_SHAFT_OUTSIDE_MM`).

    Attributes
    ----------
    axis_unit : ndarray, shape (3,)
        Unit vector from the tip toward the head (opposite to the insertion direction).
    head_start_mm : ndarray, shape (3,)
        Where the tube ends and the head begins (world, mm).
    world_T_head : ndarray, shape (4, 4) or None
        Pose of the head frame ``Sigma'`` (x' along ``axis_unit``); None without a head.
    tube : Capsule
    head_field : Superquadric or None

    Examples
    --------
    >>> body = NeedleBody([0.0, 0.0, 0.0], [0.0, 0.0, 100.0], radius_mm=0.5)
    >>> body.signed_distance([[2.0, 0.0, 50.0], [0.0, 0.0, -1.5]]).round(9).tolist()
    [1.5, 1.0]
    >>> centre = body.head_start_mm + 0.5 * body.head.length_mm * body.axis_unit
    >>> round(float(body.signed_distance(centre + [10.0, 0.0, 0.0])), 6)  # 10 - 3.162
    6.837722
    >>> body.error_bound_mm
    1e-06
    """

    def __init__(
        self,
        tip_mm,
        entry_mm,
        *,
        radius_mm: float,
        head: NeedleHead | None = LIU_HEAD,
        shaft_outside_mm: float = DEFAULT_SHAFT_OUTSIDE_MM,
    ) -> None:
        self.tip_mm = _point(tip_mm, "tip_mm")
        self.entry_mm = _point(entry_mm, "entry_mm")
        self.radius_mm = as_positive(radius_mm, "radius_mm")
        if head is not None and not isinstance(head, NeedleHead):
            raise InvalidInputError(
                "head", f"expected a NeedleHead or None, got {type(head).__name__}"
            )
        outside = as_scalar(shaft_outside_mm, "shaft_outside_mm")
        if outside < 0.0:
            raise InvalidInputError("shaft_outside_mm", f"must be >= 0, got {outside}")
        axis = self.entry_mm - self.tip_mm
        length = float(np.linalg.norm(axis))
        if length <= MIN_AXIS_LENGTH_MM:
            raise InvalidInputError(
                "entry_mm", f"must differ from tip_mm (the needle needs an axis), got {length} mm"
            )
        self.head = head
        self.shaft_outside_mm = outside
        self.inserted_length_mm = length
        self.axis_unit = axis / length
        self.head_start_mm = self.entry_mm + outside * self.axis_unit
        self.tube = Capsule(self.tip_mm, self.head_start_mm, self.radius_mm)
        parts: list = [self.tube]
        self.world_T_head: np.ndarray | None = None
        self.head_field: Superquadric | None = None
        if head is not None:
            centre = self.head_start_mm + 0.5 * head.length_mm * self.axis_unit
            self.world_T_head = _head_frame(self.axis_unit, centre)
            self.head_field = head.superquadric(self.world_T_head)
            # an enclosing capsule answers capped queries far from the head cheaply: the
            # head lies within |x'| <= a_x and, across, within b 2^(1/2 - 1/e) of the axis
            a = head.semi_axes_mm
            e = float(head.exponents[1])
            across = float(max(a[1], a[2])) * 2.0 ** max(0.0, 0.5 - 1.0 / e)
            self.head_bound = Capsule(
                centre - a[0] * self.axis_unit, centre + a[0] * self.axis_unit, across
            )
            parts.append(BoundedField(self.head_field, self.head_bound))
        super().__init__(parts)

    def __repr__(self) -> str:
        tip = ", ".join(f"{v:.6g}" for v in self.tip_mm)
        entry = ", ".join(f"{v:.6g}" for v in self.entry_mm)
        return (
            f"NeedleBody(tip_mm=({tip}), entry_mm=({entry}), radius_mm={self.radius_mm:g}, "
            f"head={self.head!r}, shaft_outside_mm={self.shaft_outside_mm:g})"
        )
