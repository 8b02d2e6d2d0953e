"""The ablation zone of one needle: a sphere, or a spheroid whose long axis is the needle.

Centred at the needle target or ``tip_offset_mm`` behind it, toward the entry; an inside
test and the exact signed distance (:class:`AblationZone`). Directions are *insertion*
directions (entry to tip), in patient RAS millimetres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_points, as_positive, as_scalar, unbatch
from needlekit.anatomy.primitives.ellipsoid import ellipsoid_distance
from needlekit.errors import InvalidInputError
from needlekit.records import field_of

__all__ = [
    "AblationZone",
    "DEFAULT_TIP_OFFSET_MM",
    "DEFAULT_ZONE_DIAMETER_MM",
    "DEFAULT_ZONE_LENGTH_MM",
]


#: Ablation-zone length along the needle (mm). An assumption: Liu et al. give no zone size.
#: Vendors' tables for one microwave antenna at 60-100 W for 5-10 min list ellipsoidal
#: zones of about 3-5 cm along by 2-4 cm across; 30 x 20 mm is a modest single ablation.
DEFAULT_ZONE_LENGTH_MM: float = 30.0

#: Ablation-zone diameter across the needle (mm); see :data:`DEFAULT_ZONE_LENGTH_MM`.
DEFAULT_ZONE_DIAMETER_MM: float = 20.0

#: Distance (mm) from the needle tip back to the zone centre. Microwave antennas heat
#: around their feed gap, a few mm behind the tip, so real zones sit 0-10 mm behind it
#: (the vendor's table says how far); 0 puts the centre at the target, the plain choice
#: when no table is at hand.
DEFAULT_TIP_OFFSET_MM: float = 0.0


# -- the zone ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class AblationZone:
    """The region one needle ablates: a sphere, or a spheroid whose long axis is the needle.

    Attributes
    ----------
    kind : {"sphere", "ellipsoid"}
        ``"sphere"`` needs ``length_mm == diameter_mm`` (use :meth:`sphere`).
    length_mm : float
        Extent along the needle (mm): semi-axis ``length_mm / 2``.
    diameter_mm : float
        Extent across the needle (mm): semi-axes ``diameter_mm / 2``.
    tip_offset_mm : float
        How far the zone centre sits behind the needle tip (target), toward the entry,
        along the needle (mm, >= 0; see :data:`DEFAULT_TIP_OFFSET_MM`).

    Examples
    --------
    >>> z = AblationZone.ellipsoid(30.0, 20.0)
    >>> z.contains([[0.0, 0.0, 14.0], [0.0, 11.0, 0.0]], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    array([ True, False])
    >>> round(float(AblationZone.sphere(15.0).volume_ml), 3)
    14.137
    """

    kind: str = "ellipsoid"
    length_mm: float = DEFAULT_ZONE_LENGTH_MM
    diameter_mm: float = DEFAULT_ZONE_DIAMETER_MM
    tip_offset_mm: float = DEFAULT_TIP_OFFSET_MM

    def __post_init__(self) -> None:
        if self.kind not in ("sphere", "ellipsoid"):
            raise InvalidInputError("kind", f"expected 'sphere' or 'ellipsoid', got {self.kind!r}")
        object.__setattr__(self, "length_mm", as_positive(self.length_mm, "length_mm"))
        object.__setattr__(self, "diameter_mm", as_positive(self.diameter_mm, "diameter_mm"))
        offset = as_scalar(self.tip_offset_mm, "tip_offset_mm")
        if offset < 0.0:
            raise InvalidInputError("tip_offset_mm", f"must be >= 0 (behind the tip), got {offset}")
        object.__setattr__(self, "tip_offset_mm", offset)
        if self.kind == "sphere" and self.length_mm != self.diameter_mm:
            raise InvalidInputError(
                "length_mm", f"a sphere has length_mm == diameter_mm, got {self.length_mm} "
                f"and {self.diameter_mm}"
            )  # fmt: skip

    @classmethod
    def sphere(cls, radius_mm: float, tip_offset_mm: float = DEFAULT_TIP_OFFSET_MM):
        """A spherical zone.

        Parameters
        ----------
        radius_mm : float
            Radius (mm), > 0.
        tip_offset_mm : float
            Centre behind the tip (mm).

        Returns
        -------
        AblationZone
        """
        r = as_positive(radius_mm, "radius_mm")
        return cls("sphere", 2.0 * r, 2.0 * r, tip_offset_mm)

    @classmethod
    def ellipsoid(cls, length_mm: float, diameter_mm: float,
                  tip_offset_mm: float = DEFAULT_TIP_OFFSET_MM):  # fmt: skip
        """A spheroidal zone, ``length_mm`` along the needle and ``diameter_mm`` across.

        Parameters
        ----------
        length_mm, diameter_mm : float
            Full extents (mm), > 0.
        tip_offset_mm : float
            Centre behind the tip (mm).

        Returns
        -------
        AblationZone
        """
        return cls("ellipsoid", length_mm, diameter_mm, tip_offset_mm)

    @property
    def semi_axes_mm(self) -> tuple[float, float]:
        """``(along, across)`` the needle (mm)."""
        return 0.5 * self.length_mm, 0.5 * self.diameter_mm

    @property
    def radius_mm(self) -> float:
        """The sphere's radius (mm); for an ellipsoid, its largest semi-axis."""
        return 0.5 * max(self.length_mm, self.diameter_mm)

    @property
    def volume_ml(self) -> float:
        """Volume (mL): ``4/3 pi a b^2 / 1000``."""
        a, b = self.semi_axes_mm
        return 4.0 / 3.0 * math.pi * a * b * b / 1000.0

    @property
    def needs_direction(self) -> bool:
        """Whether the zone depends on the needle direction (not a sphere at the tip)."""
        return self.kind == "ellipsoid" or self.tip_offset_mm > 0.0

    def to_dict(self) -> dict:
        """JSON-ready fields (a ``zone`` of ``multi.json``).

        Returns
        -------
        dict
            ``kind``, ``length_mm``, ``diameter_mm``, ``tip_offset_mm``.
        """
        return {
            "kind": self.kind,
            "length_mm": self.length_mm,
            "diameter_mm": self.diameter_mm,
            "tip_offset_mm": self.tip_offset_mm,
        }

    @classmethod
    def from_dict(cls, data: dict, where: str) -> AblationZone:
        """A zone from its record, as :meth:`to_dict` writes it.

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.

        Returns
        -------
        AblationZone

        Raises
        ------
        InvalidInputError
            A field missing or out of range (named after ``where``).
        """
        try:
            return cls(
                field_of(data, "kind", where, "str"),
                field_of(data, "length_mm", where),
                field_of(data, "diameter_mm", where),
                field_of(data, "tip_offset_mm", where),
            )
        except InvalidInputError as exc:
            if exc.field.startswith(where):
                raise
            raise InvalidInputError(f"{where}.{exc.field}", exc.reason) from None

    def centre_of(self, targets_mm, directions=None) -> np.ndarray:
        """Zone centres of needles with these targets (tips) and directions.

        Parameters
        ----------
        targets_mm : array_like, shape (3,) or (m, 3)
            Needle targets (tips), RAS mm.
        directions : array_like, shape (3,) or (m, 3), optional
            Insertion directions (entry to tip; any length > 0). Needed unless
            ``needs_direction`` is False.

        Returns
        -------
        centres_mm : ndarray, shape (3,) or (m, 3)
            ``target - tip_offset_mm * unit(direction)``.
        """
        t, single = as_points(targets_mm, "targets_mm")
        w = _directions(directions, len(t), self.needs_direction)
        return unbatch(t - self.tip_offset_mm * w, single)

    def target_of(self, centres_mm, directions=None) -> np.ndarray:
        """Needle targets (tips) that put the zone centres at ``centres_mm``.

        Parameters
        ----------
        centres_mm : array_like, shape (3,) or (m, 3)
            Zone centres, RAS mm.
        directions : array_like, shape (3,) or (m, 3), optional
            Insertion directions, as in :meth:`centre_of`.

        Returns
        -------
        targets_mm : ndarray, shape (3,) or (m, 3)
            ``centre + tip_offset_mm * unit(direction)``.
        """
        c, single = as_points(centres_mm, "centres_mm")
        w = _directions(directions, len(c), self.needs_direction)
        return unbatch(c + self.tip_offset_mm * w, single)

    def _local(self, points_mm, targets_mm, directions):
        """Axial and radial coordinates of points about each zone: two (m, n) arrays."""
        p, _ = as_points(points_mm, "points_mm")
        t, single = as_points(targets_mm, "targets_mm")
        w = _directions(directions, len(t), self.needs_direction)
        d = p[None, :, :] - (t - self.tip_offset_mm * w)[:, None, :]
        axial = np.einsum("mnk,mk->mn", d, w)
        radial = np.sqrt(np.maximum(np.einsum("mnk,mnk->mn", d, d) - axial * axial, 0.0))
        return axial, radial, single

    def contains(self, points_mm, targets_mm, directions=None) -> np.ndarray:
        """Whether points lie in the zones of needles at ``targets_mm`` (boundary included).

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Query points, RAS mm.
        targets_mm : array_like, shape (3,) or (m, 3)
            Needle targets (tips), RAS mm.
        directions : array_like, shape (3,) or (m, 3), optional
            Insertion directions (see :meth:`centre_of`).

        Returns
        -------
        inside : ndarray of bool, shape (n,) for one target or (m, n)
        """
        axial, radial, single = self._local(points_mm, targets_mm, directions)
        a, b = self.semi_axes_mm
        return unbatch((axial / a) ** 2 + (radial / b) ** 2 <= 1.0, single)

    def signed_distance(self, points_mm, targets_mm, directions=None) -> np.ndarray:
        """Exact Euclidean signed distance to the zone surfaces (negative inside).

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            Query points, RAS mm.
        targets_mm : array_like, shape (3,) or (m, 3)
            Needle targets (tips), RAS mm.
        directions : array_like, shape (3,) or (m, 3), optional
            Insertion directions (see :meth:`centre_of`).

        Returns
        -------
        distance_mm : ndarray, shape (n,) for one target or (m, n)
            For spheroids, Eberly's exact distance
            (:func:`needlekit.anatomy.primitives.ellipsoid.ellipsoid_distance`).
        """
        axial, radial, single = self._local(points_mm, targets_mm, directions)
        a, b = self.semi_axes_mm
        if self.kind == "sphere":
            return unbatch(np.hypot(axial, radial) - a, single)
        local = np.stack([radial.ravel(), np.zeros(radial.size), axial.ravel()], axis=1)
        sd, _ = ellipsoid_distance(local, [b, b, a])
        return unbatch(sd.reshape(axial.shape), single)


def _directions(directions, m: int, needed: bool, name: str = "directions") -> np.ndarray:
    """Unit directions, shape (m, 3); +z when the zone does not depend on them."""
    if directions is None:
        if needed and m > 0:
            raise InvalidInputError(name, "this zone depends on the needle direction: give it")
        return np.tile([0.0, 0.0, 1.0], (m, 1))
    w, single = as_points(directions, name)
    if single:
        w = np.repeat(w, m, axis=0)
    elif len(w) != m:
        raise InvalidInputError(name, f"expected one direction or {m}, got {len(w)}")
    norm = np.linalg.norm(w, axis=1, keepdims=True)
    if np.any(norm == 0.0):
        raise InvalidInputError(name, "a needle direction is the zero vector")
    return w / norm
