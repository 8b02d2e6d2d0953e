"""The curved-needle planning problem, separate from the planners that solve it.

A :class:`SteerableProblem` says what a plan must satisfy (OMPL's ``ProblemDefinition``):
start, goal and tolerance, the needle's limits, the puncture-angle and heading limits, the
start exclusion, and the cost. Planners read it; :mod:`needlekit.planning.steerable.verify`
checks their plans against it independently.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from needlekit._validation import as_points, as_poses, as_positive
from needlekit.anatomy.scene import Role, Scene
from needlekit.errors import InvalidInputError

__all__ = ["CostKind", "SteerableProblem"]


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
    cost : CostKind
        What plans minimise.
    cost_weight : float
        ``w`` of the clearance cost map (>= 0; extra cost per mm when touching an obstacle).
    cost_reach_mm : float
        ``R`` of the clearance cost map (> 0): beyond this clearance a mm costs 1.
    """

    scene: Scene
    goal_mm: np.ndarray
    start_pose: np.ndarray | None = None
    start_point_mm: np.ndarray | None = None
    goal_tolerance_mm: float = 1.0
    r_min_mm: float = 50.0
    max_length_mm: float = 150.0
    needle_diameter_mm: float = 1.0
    safety_margin_mm: float = 0.0
    min_puncture_angle_deg: float = 0.0
    entry_surface: str | None = None
    max_heading_change_deg: float = 90.0
    start_exclusion_mm: float = 3.0
    cost: CostKind = CostKind.PATH_LENGTH
    cost_weight: float = 1.0
    cost_reach_mm: float = 5.0
    metadata: dict = field(default_factory=dict)

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
        if self.entry_surface is None:
            object.__setattr__(self, "entry_surface", self._default_entry_surface())
        elif self.entry_surface not in self.scene:
            raise InvalidInputError(
                "entry_surface", f"no structure named {self.entry_surface!r} in the scene"
            )
        try:
            object.__setattr__(self, "cost", CostKind(self.cost))
        except ValueError:
            kinds = ", ".join(k.value for k in CostKind)
            raise InvalidInputError("cost", f"expected one of {kinds}, got {self.cost!r}") from None

    def _default_entry_surface(self) -> str | None:
        """The scene's entry surface; else the obstacle the start lies on (within the start
        exclusion), e.g. the airway a transbronchial needle leaves through its wall."""
        surfaces = self.scene.by_role(Role.ENTRY_SURFACE)
        if surfaces:
            return surfaces[0].name
        obstacles = self.scene.by_role(Role.OBSTACLE)
        if not obstacles:
            return None
        d = self.scene.signed_distance(self.start_point_mm, [s.name for s in obstacles])
        name, dist = min(((n, abs(float(v[0]))) for n, v in d.items()), key=lambda t: t[1])
        return name if dist <= max(self.start_exclusion_mm, 1e-9) else None

    @property
    def kappa_max_per_mm(self) -> float:
        """Largest curvature, ``1 / r_min_mm``."""
        return 1.0 / self.r_min_mm

    @property
    def clearance_margin_mm(self) -> float:
        """Needle radius plus safety margin (mm)."""
        return 0.5 * self.needle_diameter_mm + self.safety_margin_mm

    def with_start_pose(self, start_pose) -> SteerableProblem:
        """The same problem from another start pose (same start point or not).

        Parameters
        ----------
        start_pose : array_like, shape (4, 4)

        Returns
        -------
        SteerableProblem
        """
        from dataclasses import replace

        return replace(self, start_pose=np.asarray(start_pose, dtype=float), start_point_mm=None)

    @classmethod
    def from_scenario(cls, scenario, **overrides) -> SteerableProblem:
        """The problem a scenario file describes (see ``docs/scenarios.md``).

        Parameters
        ----------
        scenario : needlekit.io.scenario.Scenario
        **overrides
            Attributes to set instead of the scenario's (e.g. ``r_min_mm=100``).

        Returns
        -------
        SteerableProblem

        Raises
        ------
        InvalidInputError
            The scenario has no start or no goal.
        """
        if scenario.start is None:
            raise InvalidInputError("start", "the scenario gives no start")
        if scenario.goal is None:
            raise InvalidInputError("goal", "the scenario gives no goal")
        n = scenario.needle
        kw = {
            "scene": scenario.scene,
            "goal_mm": scenario.goal.point_mm,
            "start_pose": scenario.start.world_T_tip,
            "start_point_mm": scenario.start.point_mm,
            "goal_tolerance_mm": scenario.goal.tolerance_mm,
            "r_min_mm": n.r_min_mm,
            "max_length_mm": n.max_length_mm,
            "needle_diameter_mm": n.diameter_mm,
            "safety_margin_mm": n.safety_margin_mm,
            "min_puncture_angle_deg": n.min_puncture_angle_deg,
            "max_heading_change_deg": n.max_heading_change_deg,
            "start_exclusion_mm": n.start_exclusion_mm,
        }
        cost = (scenario.planner or {}).get("cost")
        if cost:
            kw["cost"] = cost.get("kind", CostKind.PATH_LENGTH.value)
            for key, name in (("weight", "cost_weight"), ("reach_mm", "cost_reach_mm")):
                if key in cost:
                    kw[name] = cost[key]
        kw.update(overrides)
        if kw.get("start_pose") is not None and "start_point_mm" not in overrides:
            kw["start_point_mm"] = None
        return cls(**kw)
