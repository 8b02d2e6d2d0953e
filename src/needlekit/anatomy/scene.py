"""A scene: named anatomical structures, each with a role, in one world frame (RAS, mm).

Roles say what a planner does with a structure:

* ``obstacle``: the needle must keep clear of it (vessels, airways, ribs, placed needles);
* ``target``: the goal region (a nodule, a tumour);
* ``entry_surface``: the surface of the body the needle enters (the skin); its inward normal
  gives the puncture angle. (An airway a transbronchial needle leaves through its wall is an
  ``obstacle``: a problem whose start lies on an obstacle takes it as the entry surface and
  measures the angle to its outward normal.)
* ``allowed_region``: the needle must stay inside it (the lung inside the pleura, the
  body inside the skin). Its outside is treated as an obstacle, except where a target is;
* ``context``: shown and measured, ignored by planners (e.g. the liver around a tumour
  that a percutaneous needle reaches through the body wall).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from needlekit._validation import as_points
from needlekit.anatomy.clearance import Clearance, arc_clearance, segment_clearance
from needlekit.anatomy.fields import ComplementField, DistanceField, union
from needlekit.constants import DEFAULT_SAMPLE_SPACING_MM
from needlekit.errors import InvalidInputError

__all__ = ["Role", "Structure", "Scene"]


class Role(enum.Enum):
    """What a planner does with a structure."""

    OBSTACLE = "obstacle"
    TARGET = "target"
    ENTRY_SURFACE = "entry_surface"
    ALLOWED_REGION = "allowed_region"
    CONTEXT = "context"

    @classmethod
    def parse(cls, value: str | Role, field_name: str = "role") -> Role:
        """A role from its name (``"obstacle"``, ...), with a clear error otherwise."""
        if isinstance(value, Role):
            return value
        try:
            return cls(str(value))
        except ValueError:
            allowed = ", ".join(r.value for r in cls)
            raise InvalidInputError(
                field_name, f"expected one of {allowed}, got {value!r}"
            ) from None


@dataclass(frozen=True)
class Structure:
    """One named structure of a scene.

    Attributes
    ----------
    name : str
        Unique within the scene (e.g. ``"vessels"``).
    role : Role
    field : DistanceField
        Signed distance to the structure's surface (world RAS, mm).
    color : str, optional
        Display colour (any CSS colour) for figures and 3D views.
    source : str
        Where the structure came from (file path, primitive, phantom), for reports.
    metadata : dict
        Anything else worth keeping (voxel size, label value, ...).
    """

    name: str
    role: Role
    field: DistanceField
    color: str | None = None
    source: str = ""
    metadata: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise InvalidInputError(
                "name", f"a structure needs a non-empty name, got {self.name!r}"
            )
        object.__setattr__(self, "role", Role.parse(self.role, f"{self.name}.role"))
        if not isinstance(self.field, DistanceField):
            raise InvalidInputError(
                f"{self.name}.field", f"expected a DistanceField, got {type(self.field).__name__}"
            )


class Scene:
    """Named structures with roles, queried in batches.

    Parameters
    ----------
    structures : sequence of Structure
        Names must be unique.
    name : str
        A label for reports (e.g. ``"Med-RAD lung 1"``).
    obstacle_field : DistanceField, optional
        A precomputed field equal to the union of the obstacles and of the outsides of
        the allowed regions (e.g. one distance transform of a whole segmentation's free
        space, much cheaper than one per structure). Used by :meth:`obstacle_field` when
        nothing is excluded; the per-structure fields serve exclusions and queries.

    Examples
    --------
    >>> from needlekit.anatomy.primitives import Sphere
    >>> scene = Scene([
    ...     Structure("lung", Role.ALLOWED_REGION, Sphere([0, 0, 0], 100.0)),
    ...     Structure("vessel", Role.OBSTACLE, Sphere([30, 0, 0], 5.0)),
    ... ])
    >>> [round(float(c), 6) for c in scene.clearance([[0.0, 0.0, 0.0], [0.0, 0.0, 90.0]])]
    [25.0, 10.0]
    """

    def __init__(
        self,
        structures: Sequence[Structure],
        *,
        name: str = "",
        obstacle_field: DistanceField | None = None,
    ) -> None:
        structures = tuple(structures)
        seen: set[str] = set()
        for i, s in enumerate(structures):
            if not isinstance(s, Structure):
                raise InvalidInputError(
                    f"structures[{i}]", f"expected a Structure, got {type(s).__name__}"
                )
            if s.name in seen:
                raise InvalidInputError(
                    f"structures[{i}].name", f"duplicate structure name {s.name!r}"
                )
            seen.add(s.name)
        self.structures = structures
        self.name = name
        self._by_name = {s.name: s for s in structures}
        self._obstacle_cache: dict[tuple, DistanceField] = {}
        if obstacle_field is not None:
            if not isinstance(obstacle_field, DistanceField):
                raise InvalidInputError(
                    "obstacle_field",
                    f"expected a DistanceField, got {type(obstacle_field).__name__}",
                )
            self._obstacle_cache[(0.0, ())] = obstacle_field

    # -- access ---------------------------------------------------------------------------

    @property
    def names(self) -> list[str]:
        """Structure names in order."""
        return [s.name for s in self.structures]

    def __getitem__(self, name: str) -> Structure:
        try:
            return self._by_name[name]
        except KeyError:
            raise InvalidInputError(
                "structure",
                f"no structure named {name!r}; the scene has {', '.join(self.names) or 'none'}",
            ) from None

    def __contains__(self, name: object) -> bool:
        return name in self._by_name

    def __len__(self) -> int:
        return len(self.structures)

    def __repr__(self) -> str:
        roles = ", ".join(f"{s.name}:{s.role.value}" for s in self.structures)
        return f"Scene({self.name!r}, [{roles}])"

    def by_role(self, role: Role | str) -> list[Structure]:
        """Structures with the given role, in order.

        Parameters
        ----------
        role : Role or str

        Returns
        -------
        list of Structure
        """
        r = Role.parse(role)
        return [s for s in self.structures if s.role is r]

    # -- queries --------------------------------------------------------------------------

    def signed_distance(self, points, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """Signed distance of points to each structure.

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).
        names : iterable of str, optional
            Structures to query (default all).

        Returns
        -------
        dict of str to ndarray, shape (n,)
            Negative inside the structure.
        """
        p, _ = as_points(points, "points")
        chosen = self.names if names is None else list(names)
        return {n: self[n].field._signed_distance(p) for n in chosen}

    def obstacle_field(
        self, margin_mm: float = 0.0, *, exclude: Iterable[str] = ()
    ) -> DistanceField:
        """One field for everything the needle must avoid: the union of the obstacles and
        of the outside of the allowed space (the allowed regions together with the
        targets), grown by ``margin_mm``.

        Parameters
        ----------
        margin_mm : float
            Needle radius plus safety margin (mm), >= 0.
        exclude : iterable of str
            Obstacles to leave out (e.g. the structure the needle starts in).

        Returns
        -------
        DistanceField
            Positive where the needle (of that radius) is clear.

        Raises
        ------
        InvalidInputError
            The scene has neither obstacles nor allowed regions.
        """
        excluded = tuple(sorted(set(exclude)))
        for n in excluded:
            self[n]  # raises for unknown names
        key = (float(margin_mm), excluded)
        if key not in self._obstacle_cache:
            base = self._obstacle_cache.get((0.0, excluded))
            if base is None:
                parts: list[DistanceField] = [
                    s.field for s in self.by_role(Role.OBSTACLE) if s.name not in excluded
                ]
                regions = [s.field for s in self.by_role(Role.ALLOWED_REGION)]
                if regions:
                    # targets are never obstacles: a tumour may reach past the organ's
                    # segmentation (Med-RAD's liver masks leave the nodules out)
                    targets = [s.field for s in self.by_role(Role.TARGET)]
                    parts.append(ComplementField(union(*regions, *targets)))
                if not parts:
                    raise InvalidInputError("scene", "has no obstacles and no allowed regions")
                base = union(*parts)
                self._obstacle_cache[(0.0, excluded)] = base
            self._obstacle_cache[key] = base.inflated(margin_mm) if margin_mm else base
        return self._obstacle_cache[key]

    def clearance(self, points, margin_mm: float = 0.0) -> np.ndarray:
        """Signed clearance of points: distance to the nearest obstacle or to leaving an
        allowed region, minus ``margin_mm``.

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
        margin_mm : float

        Returns
        -------
        ndarray, shape () or (n,)
            Negative where a needle of radius ``margin_mm`` would collide.
        """
        return self.obstacle_field(margin_mm).signed_distance(points)

    def normal(self, points, name: str) -> np.ndarray:
        """Outward unit normal of a structure's surface near points (distance gradient).

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
        name : str

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
        """
        return self[name].field.normal(points)

    def segment_clearance(
        self,
        start_mm,
        end_mm,
        *,
        margin_mm: float = 0.0,
        spacing_mm: float = DEFAULT_SAMPLE_SPACING_MM,
    ) -> Clearance:
        """Conservative minimum clearance along straight segments
        (:func:`needlekit.anatomy.clearance.segment_clearance`).

        Parameters
        ----------
        start_mm, end_mm : array_like, shape (3,) or (n, 3)
        margin_mm : float
        spacing_mm : float

        Returns
        -------
        Clearance
        """
        return segment_clearance(
            self.obstacle_field(margin_mm), start_mm, end_mm, spacing_mm=spacing_mm
        )

    def arc_clearance(
        self,
        world_T_tip,
        spin_rad,
        kappa_per_mm,
        length_mm,
        *,
        margin_mm: float = 0.0,
        spacing_mm: float = DEFAULT_SAMPLE_SPACING_MM,
    ) -> Clearance:
        """Conservative minimum clearance along arcs
        (:func:`needlekit.anatomy.clearance.arc_clearance`).

        Parameters
        ----------
        world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
        spin_rad, kappa_per_mm, length_mm : float or array_like, shape (n,)
        margin_mm : float
        spacing_mm : float

        Returns
        -------
        Clearance
        """
        return arc_clearance(
            self.obstacle_field(margin_mm),
            world_T_tip,
            spin_rad,
            kappa_per_mm,
            length_mm,
            spacing_mm=spacing_mm,
        )

    def bounds(self) -> np.ndarray:
        """Box around all bounded structures.

        Returns
        -------
        ndarray, shape (2, 3)
            ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm); infinite when no structure
            is bounded.
        """
        boxes = [s.field.bounds() for s in self.structures]
        finite = [b for b in boxes if np.all(np.isfinite(b))]
        if not finite:
            return np.array([[-np.inf] * 3, [np.inf] * 3])
        b = np.stack(finite)
        return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])
