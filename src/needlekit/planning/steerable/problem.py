"""The curved-needle planning problem, separate from the planners that solve it.

A :class:`SteerableProblem` says what a plan must satisfy (OMPL's ``ProblemDefinition``):
start, goal and tolerance, the needle's limits, the puncture-angle and heading limits, the
start exclusion, and the cost. Planners read it; :mod:`needlekit.planning.steerable.verify`
checks their plans against it independently.
"""

from __future__ import annotations

import copy
import enum
from dataclasses import dataclass, field, replace

import numpy as np

from needlekit._validation import as_points, as_poses, as_positive
from needlekit.anatomy.collision import CollisionChecker, CollisionSetup, make_collision_checker
from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.occupancy import VoxelObstacles
from needlekit.anatomy.scene import Role, Scene
from needlekit.constants import (
    DEFAULT_GOAL_TOLERANCE_MM,
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_MAX_LENGTH_MM,
    DEFAULT_NEEDLE_DIAMETER_MM,
    DEFAULT_R_MIN_MM,
    DEFAULT_START_EXCLUSION_MM,
    MIN_NORMAL_GRADIENT,
    MOTION_SPACING_MM,
)
from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.cost import ClearanceCostMap, CostObjective, PathLength

__all__ = ["CollisionModel", "CostKind", "SteerableProblem"]


class CollisionModel(enum.StrEnum):
    """The built-in collision models' names (a problem's ``collision_model`` is the name of
    any registered :class:`~needlekit.anatomy.collision.CollisionChecker`; these two are
    built in). Members compare equal to their names.

    FIELD
        The scene's obstacle field: a point is clear when its distance to every obstacle,
        less the field's stated error bound and half the sampling gap, is at least the
        needle radius plus margin (certified: never clear when the truth is not).
    VOXEL_CENTRES
        The reference planner's test (``docs/notes/steerable-reference-planner.md``,
        section 7), certified: a sample collides when an obstacle voxel centre lies closer
        than the needle radius plus half a voxel diagonal (plus margin) plus half the
        sample gap, or it leaves the image. Needs the problem's ``voxel_obstacles``;
        reproduces the reference's verdicts wherever its plans can be certified.
    """

    FIELD = "field"
    VOXEL_CENTRES = "voxel_centres"


class CostKind(enum.Enum):
    """What a plan's cost measures.

    PATH_LENGTH
        Inserted length (mm).
    CLEARANCE
        Integral along the path of the clearance cost map
        ``1 + cost_weight * max(0, 1 - clearance / cost_reach_mm)`` (mm-equivalents, never
        below the length; :mod:`needlekit.planning.steerable.cost`).
    """

    PATH_LENGTH = "path_length"
    CLEARANCE = "clearance"


def _nonneg(value, name: str) -> float:
    v = float(value)
    if not (np.isfinite(v) and v >= 0):
        raise InvalidInputError(name, f"must be a finite number >= 0, got {value!r}")
    return v


@dataclass(frozen=True)
class SteerableProblem:
    """A steerable-needle planning problem (RAS mm, radians inside, degrees in names).

    Attributes
    ----------
    scene : Scene
        The anatomy; its obstacle field gives clearances.
    goal_mm : ndarray, shape (3,)
        Target point.
    start_pose : ndarray, shape (4, 4) or None
        Start tip pose (z = insertion direction). None when only ``start_point_mm`` is
        fixed and the direction is to be chosen (the effective-puncture-region sweep).
    start_point_mm : ndarray, shape (3,)
        Start point (the pose's origin when a pose is given).
    goal_tolerance_mm : float
        tau: the tip must end within this distance of ``goal_mm``.
    r_min_mm : float
        Minimum radius of curvature, ``1 / kappa_max``.
    max_length_mm : float
        Longest insertion (l_max).
    needle_diameter_mm, safety_margin_mm : float
        The needle keeps ``diameter / 2 + margin`` from obstacles.
    min_puncture_angle_deg : float
        Smallest angle between the needle and the entry surface at the start (Feng's
        alpha; 0 disables the check).
    entry_surface : str or None
        Structure whose surface the needle punctures at the start (its normal is the
        distance gradient); default: the scene's entry surface, else the obstacle the start
        lies on (within the start exclusion; the airway of a transbronchial start).
    max_heading_change_deg : float
        Largest angle between the start direction and any later direction.
    start_exclusion_mm : float
        Obstacles within this distance of the start are ignored.
    cost : CostKind, str or CostObjective
        What plans minimise: a built-in kind (path length, clearance cost map) or an
        objective of one's own (:mod:`needlekit.planning.steerable.cost`).
    cost_weight : float
        ``w`` of the clearance cost map (>= 0; extra cost per mm when touching an obstacle).
    cost_reach_mm : float
        ``R`` of the clearance cost map (> 0): beyond this clearance a mm costs 1.
    collision_model : str
        The name of a registered collision checker
        (:mod:`needlekit.anatomy.collision`): ``"field"`` (default), ``"voxel_centres"`` or
        one registered by a user.
    collision_options : dict, optional
        Settings handed to the collision checker's factory (its own).
    voxel_obstacles : VoxelObstacles, optional
        The obstacle voxels of the ``voxel_centres`` model (required by it, refused by
        ``field``), built for this needle's diameter and margin.
    entry_normal : array_like, shape (3,), optional
        Normal of the entry surface at the start, pointing into the tissue entered, given
        instead of the one the surface's distance gradient gives (e.g. where it is
        undefined).
    start_inside : bool
        The start lies inside the tissue, as when planning goes on from a needle already
        partly inserted (:mod:`needlekit.planning.steerable.dynamic`): no surface is
        punctured there, so there is no entry surface and no puncture angle
        (``min_puncture_angle_deg`` must be 0, ``entry_surface`` and ``entry_normal``
        unset). Default False: the start is a puncture.
    objective : CostObjective
        The cost as an objective (computed): what planners call, with its admissible
        lower bound per mm.
    puncture_normal : ndarray, shape (3,) or None
        The normal the puncture angle is measured against, pointing into the tissue
        (computed by :meth:`tissue_normal` at the start point; None where undefined and
        ``min_puncture_angle_deg`` is 0). ``metadata["puncture_normal_source"]`` says where
        it came from.

    Raises
    ------
    InvalidInputError
        A field out of range, a collision model without what it needs, or a minimum
        puncture angle that cannot be checked (no entry surface, or its normal undefined at
        the start point).
    """

    scene: Scene
    goal_mm: np.ndarray
    start_pose: np.ndarray | None = None
    start_point_mm: np.ndarray | None = None
    goal_tolerance_mm: float = DEFAULT_GOAL_TOLERANCE_MM
    r_min_mm: float = DEFAULT_R_MIN_MM
    max_length_mm: float = DEFAULT_MAX_LENGTH_MM
    needle_diameter_mm: float = DEFAULT_NEEDLE_DIAMETER_MM
    safety_margin_mm: float = 0.0
    min_puncture_angle_deg: float = 0.0
    entry_surface: str | None = None
    max_heading_change_deg: float = DEFAULT_MAX_HEADING_CHANGE_DEG
    start_exclusion_mm: float = DEFAULT_START_EXCLUSION_MM
    cost: CostKind = CostKind.PATH_LENGTH
    cost_weight: float = 1.0
    cost_reach_mm: float = 5.0
    metadata: dict = field(default_factory=dict)
    collision_model: str = "field"
    voxel_obstacles: VoxelObstacles | None = field(default=None, repr=False, compare=False)
    collision_options: dict | None = field(default=None, compare=False)
    entry_normal: np.ndarray | None = None
    start_inside: bool = False
    puncture_normal: np.ndarray | None = field(init=False, default=None)
    objective: CostObjective = field(init=False, default=None, repr=False, compare=False)
    _checkers: dict = field(init=False, default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not isinstance(self.scene, Scene):
            raise InvalidInputError("scene", f"expected a Scene, got {type(self.scene).__name__}")
        goal, single = as_points(self.goal_mm, "goal_mm")
        if not single:
            raise InvalidInputError("goal_mm", "expected one point (3,)")
        object.__setattr__(self, "goal_mm", goal[0])
        if self.start_pose is not None:
            g, single = as_poses(self.start_pose, "start_pose")
            if not single:
                raise InvalidInputError("start_pose", "expected one 4x4 pose")
            object.__setattr__(self, "start_pose", g[0])
            object.__setattr__(self, "start_point_mm", g[0, :3, 3].copy())
        elif self.start_point_mm is None:
            raise InvalidInputError("start_pose", "give a start pose or a start point")
        else:
            p, single = as_points(self.start_point_mm, "start_point_mm")
            if not single:
                raise InvalidInputError("start_point_mm", "expected one point (3,)")
            object.__setattr__(self, "start_point_mm", p[0])
        for name in (
            "goal_tolerance_mm",
            "r_min_mm",
            "max_length_mm",
            "needle_diameter_mm",
            "cost_reach_mm",
        ):
            object.__setattr__(self, name, as_positive(getattr(self, name), name))
        for name in ("safety_margin_mm", "start_exclusion_mm", "cost_weight"):
            object.__setattr__(self, name, _nonneg(getattr(self, name), name))
        alpha = float(self.min_puncture_angle_deg)
        if not (np.isfinite(alpha) and 0.0 <= alpha < 90.0):
            raise InvalidInputError(
                "min_puncture_angle_deg",
                f"must lie in [0, 90), got {self.min_puncture_angle_deg!r}",
            )
        heading = float(self.max_heading_change_deg)
        if not (np.isfinite(heading) and 0.0 < heading <= 360.0):
            raise InvalidInputError(
                "max_heading_change_deg",
                f"must lie in (0, 360], got {self.max_heading_change_deg!r}",
            )
        if self.start_inside:
            self._check_start_inside(alpha)
        elif self.entry_surface is None:
            object.__setattr__(self, "entry_surface", self._default_entry_surface())
        elif self.entry_surface not in self.scene:
            raise InvalidInputError(
                "entry_surface", f"no structure named {self.entry_surface!r} in the scene"
            )
        object.__setattr__(self, "objective", self._objective())
        self._check_collision_model()
        self._resolve_puncture_normal()

    def _objective(self) -> CostObjective:
        """The cost as an objective: a built-in kind's, or the one given."""
        if isinstance(self.cost, CostObjective) and not isinstance(self.cost, (str, CostKind)):
            bound = self.cost.lower_bound_per_mm
            if bound is not None and not (
                isinstance(bound, (int, float)) and np.isfinite(bound) and bound > 0
            ):
                raise InvalidInputError(
                    "cost",
                    f"the objective's lower_bound_per_mm must be a number > 0 or None, got {bound!r}",
                )
            return self.cost
        try:
            object.__setattr__(self, "cost", CostKind(self.cost))
        except ValueError:
            kinds = ", ".join(k.value for k in CostKind)
            raise InvalidInputError(
                "cost", f"expected one of {kinds} or a CostObjective, got {self.cost!r}"
            ) from None
        if self.cost is CostKind.PATH_LENGTH:
            return PathLength()
        return ClearanceCostMap(
            self.scene, self.clearance_margin_mm, self.cost_weight, self.cost_reach_mm
        )

    def _check_start_inside(self, alpha: float) -> None:
        """A start inside the tissue punctures nothing: no angle, surface or normal."""
        if not isinstance(self.start_inside, bool):
            raise InvalidInputError(
                "start_inside", f"expected True or False, got {self.start_inside!r}"
            )
        for name, given in (
            ("min_puncture_angle_deg", alpha > 0),
            ("entry_surface", self.entry_surface is not None),
            ("entry_normal", self.entry_normal is not None),
        ):
            if given:
                raise InvalidInputError(
                    name,
                    "the start lies inside the tissue (start_inside): no surface is punctured there",
                )

    def _check_collision_model(self) -> None:
        model = self.collision_model
        if isinstance(model, CollisionModel):
            model = model.value
        if not isinstance(model, str):
            raise InvalidInputError(
                "collision_model", f"expected a collision checker's name, got {model!r}"
            )
        object.__setattr__(self, "collision_model", model)
        if self.collision_options is not None and not isinstance(self.collision_options, dict):
            raise InvalidInputError(
                "collision_options",
                f"expected a mapping, got {type(self.collision_options).__name__}",
            )
        object.__setattr__(self, "_checkers", {})
        self.collision_checker()  # built once here: its factory checks what it needs

    def collision_checker(self, spacing_mm: float = MOTION_SPACING_MM) -> CollisionChecker:
        """The problem's collision checker for motion samples at most ``spacing_mm`` apart
        (built once per spacing).

        Parameters
        ----------
        spacing_mm : float

        Returns
        -------
        CollisionChecker
        """
        key = float(spacing_mm)
        checker = self._checkers.get(key)
        if checker is None:
            setup = CollisionSetup(
                scene=self.scene,
                needle_diameter_mm=self.needle_diameter_mm,
                safety_margin_mm=self.safety_margin_mm,
                start_point_mm=self.start_point_mm,
                exclusion_mm=self.start_exclusion_mm,
                spacing_mm=key,
                voxel_obstacles=self.voxel_obstacles,
                options=dict(self.collision_options or {}),
            )
            checker = make_collision_checker(self.collision_model, setup)
            self._checkers[key] = checker
        return checker

    def _resolve_puncture_normal(self) -> None:
        alpha = self.min_puncture_angle_deg
        if self.start_inside:
            self.metadata.setdefault(
                "puncture_normal_source", "none: the start is inside the tissue"
            )
            return
        if self.entry_normal is not None:
            n = np.asarray(self.entry_normal, dtype=float).reshape(-1)
            norm = float(np.linalg.norm(n)) if n.shape == (3,) else 0.0
            if not (np.all(np.isfinite(n)) and norm > 1e-12):
                raise InvalidInputError(
                    "entry_normal",
                    f"expected a non-zero finite vector (3,), got {self.entry_normal!r}",
                )
            object.__setattr__(self, "entry_normal", n / norm)
        normal, why = self.tissue_normal(self.start_point_mm)
        if normal is None:
            if alpha > 0:
                raise InvalidInputError(
                    "entry_surface",
                    f"{why}, so min_puncture_angle_deg = {alpha:g} cannot be checked; "
                    "give entry_normal",
                )
            return
        object.__setattr__(self, "puncture_normal", normal)
        self.metadata.setdefault("puncture_normal_source", why)

    def tissue_normal(self, point_mm) -> tuple[np.ndarray | None, str]:
        """The unit normal of the entry surface at a point, pointing into the tissue the
        needle enters: the puncture angle is ``asin(direction . normal)``.

        An ``entry_surface`` structure (skin) is entered: this is its inward normal. The
        obstacle a start lies on (an airway the needle leaves through its wall, the default
        entry surface of a transbronchial start) is left: its outward normal. The normal is the distance field's
        gradient, accepted only where its length is at least
        :data:`~needlekit.constants.MIN_NORMAL_GRADIENT` (a true distance has a unit gradient
        wherever the normal is defined; on the medial axis it does not).

        Parameters
        ----------
        point_mm : array_like, shape (3,)

        Returns
        -------
        normal : ndarray, shape (3,) or None
            None where it is undefined.
        why : str
            Where the normal comes from, or why it is undefined.
        """
        if self.start_inside:
            return None, "the start lies inside the tissue: no surface is punctured there"
        if self.entry_normal is not None:
            return self.entry_normal, "entry_normal"
        if self.entry_surface is None:
            return None, (
                "no entry surface: the scene has none and the start lies on no obstacle; name one"
            )
        s = self.scene[self.entry_surface]
        p = np.asarray(point_mm, dtype=float).reshape(1, 3)
        # a field exact near the point (a window of a large voxel grid, not all of it)
        # where the start lies within its exclusion of the surface; the whole field beyond
        reach = self._start_window_mm()
        field = s.field.near(p[0], reach) or s.field
        if abs(float(field.signed_distance(p[0]))) > reach - 0.5:
            field = s.field
        g = DistanceField._gradient(field, p)[0]  # central differences of the distance
        length = float(np.linalg.norm(g))
        if not (np.isfinite(length) and length >= MIN_NORMAL_GRADIENT):
            return None, (
                f"the normal of {self.entry_surface!r} is undefined at "
                f"{np.round(p[0], 3).tolist()} (distance gradient of length {length:.3g})"
            )
        inward = s.role is Role.ENTRY_SURFACE  # skin: the needle enters the structure
        n = g / length
        return (-n if inward else n), (
            f"{'inward' if inward else 'outward'} normal of {self.entry_surface}"
        )

    def _start_window_mm(self) -> float:
        """The radius of the one-point questions about the start (which surface it lies on,
        its normal): the start exclusion and a millimetre (the normal's differences take
        points 1e-4 mm away), one radius so that both questions share a window."""
        return self.start_exclusion_mm + 1.0

    def _default_entry_surface(self) -> str | None:
        """The scene's entry surface; else the obstacle the start lies on (within the start
        exclusion), e.g. the airway a transbronchial needle leaves through its wall."""
        surfaces = self.scene.by_role(Role.ENTRY_SURFACE)
        if surfaces:
            return surfaces[0].name
        obstacles = self.scene.by_role(Role.OBSTACLE)
        if not obstacles:
            return None
        within = max(self.start_exclusion_mm, 1e-9)
        best: tuple[float, str] | None = None
        for s in obstacles:  # one-point questions: fields near the start, not whole grids
            # the radius the normal asks with, so that its window is this one, kept
            field = s.field.near(self.start_point_mm, self._start_window_mm())
            if field is None:  # the structure lies farther than the exclusion
                continue
            dist = abs(float(field.signed_distance(self.start_point_mm)))
            if best is None or dist < best[0]:
                best = (dist, s.name)
        return best[1] if best is not None and best[0] <= within else None

    @property
    def kappa_max_per_mm(self) -> float:
        """Largest curvature, ``1 / r_min_mm``."""
        return 1.0 / self.r_min_mm

    @property
    def clearance_margin_mm(self) -> float:
        """Needle radius plus safety margin (mm)."""
        return 0.5 * self.needle_diameter_mm + self.safety_margin_mm

    def with_goal(self, goal_mm) -> SteerableProblem:
        """The same problem to another goal. Only the goal is checked: the start, its
        entry surface and normal, the collision checkers and the objective do not depend
        on it and are kept.

        Parameters
        ----------
        goal_mm : array_like, shape (3,)

        Returns
        -------
        SteerableProblem
        """
        goal, single = as_points(goal_mm, "goal_mm")
        if not single:
            raise InvalidInputError("goal_mm", "expected one point (3,)")
        return self._derived(goal_mm=goal[0])

    def with_start_pose(self, start_pose) -> SteerableProblem:
        """The same problem from another start pose. From the same start point (a sweep's
        directions) only the pose is checked and what depends on the point alone (entry
        surface, puncture normal, collision checkers) is kept; from another point the
        problem is built again.

        Parameters
        ----------
        start_pose : array_like, shape (4, 4)

        Returns
        -------
        SteerableProblem
        """
        g, single = as_poses(start_pose, "start_pose")
        if not single:
            raise InvalidInputError("start_pose", "expected one 4x4 pose")
        pose = g[0]
        if not np.array_equal(pose[:3, 3], self.start_point_mm):
            return replace(self, start_pose=pose, start_point_mm=None)
        return self._derived(start_pose=pose, start_point_mm=pose[:3, 3].copy())

    def with_free_start_direction(self) -> SteerableProblem:
        """The same problem from the same start point with the start direction left free
        (a sweep's problem): the start pose is dropped, what depends on the point alone
        (entry surface, puncture normal, collision checkers) is kept.

        Returns
        -------
        SteerableProblem
        """
        return self._derived(start_pose=None)

    def with_goal_tolerance(self, goal_tolerance_mm: float) -> SteerableProblem:
        """The same problem with another goal tolerance (only it is checked).

        Parameters
        ----------
        goal_tolerance_mm : float
            > 0.

        Returns
        -------
        SteerableProblem
        """
        return self._derived(goal_tolerance_mm=as_positive(goal_tolerance_mm, "goal_tolerance_mm"))

    def with_r_min(self, r_min_mm: float) -> SteerableProblem:
        """The same problem for a needle of another radius of curvature (only it is
        checked: nothing else depends on it).

        Parameters
        ----------
        r_min_mm : float
            > 0.

        Returns
        -------
        SteerableProblem
        """
        return self._derived(r_min_mm=as_positive(r_min_mm, "r_min_mm"))

    def with_safety_margin(self, safety_margin_mm: float) -> SteerableProblem:
        """The same problem with another safety margin: built again (the collision
        checkers depend on it); a voxel-centre model's obstacle test is rebuilt from the
        same voxels for the new margin.

        Parameters
        ----------
        safety_margin_mm : float
            >= 0.

        Returns
        -------
        SteerableProblem
        """
        vo = self.voxel_obstacles
        if vo is not None:
            vo = VoxelObstacles(
                vo.occupancy, vo.affine, needle_diameter_mm=self.needle_diameter_mm,
                safety_margin_mm=safety_margin_mm,
            )  # fmt: skip
        return replace(self, safety_margin_mm=safety_margin_mm, voxel_obstacles=vo)

    def _derived(self, **checked) -> SteerableProblem:
        """A copy with checked fields changed, nothing else recomputed."""
        out = copy.copy(self)
        for name, value in checked.items():
            object.__setattr__(out, name, value)
        return out
