"""What every planner returns: a status, the cost, statistics, and JSON.

Modelled on OMPL's ``PlannerStatus``: ``solve(problem, budget)`` always returns a result;
the status says what it means.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

__all__ = ["PlanStatus", "Verification"]


class PlanStatus(enum.Enum):
    """Outcome of a planning run.

    SOLVED
        A plan that reaches the goal and passed the independent check; for
        resolution-optimal planners that finished their search, certified optimal at the
        resolution searched (see the result's statistics).
    APPROXIMATE
        A valid path that ends near, but not within tolerance of, the goal.
    INFEASIBLE
        No plan exists at the resolution searched (the search space was exhausted), or the
        goal is provably out of reach (e.g. outside the reachable set of the start).
    TIMEOUT
        The budget ran out before a plan was found (or, for anytime planners, before the
        search finished; a best plan so far is then reported as SOLVED).
    INVALID_PROBLEM
        The problem itself is malformed (start in collision beyond the start exclusion,
        goal outside the allowed region, ...).
    """

    SOLVED = "solved"
    APPROXIMATE = "approximate"
    INFEASIBLE = "infeasible"
    TIMEOUT = "timeout"
    INVALID_PROBLEM = "invalid_problem"

    @property
    def has_plan(self) -> bool:
        """Whether a path comes with this status."""
        return self in (PlanStatus.SOLVED, PlanStatus.APPROXIMATE)


@dataclass(frozen=True)
class Verification:
    """Outcome of an independent check of a plan (steerable ``verify_plan``, straight
    ``verify_multi``).

    Attributes
    ----------
    ok : bool
        No violation.
    violations : tuple of str
        One line per broken rule, naming it and the measured value.
    metrics : dict
        ``cost`` (recomputed), ``length_mm``, ``goal_distance_mm``, ``max_curvature_per_mm``,
        ``max_heading_change_deg``, ``puncture_angle_deg`` (or None),
        ``min_clearance_mm`` (the smallest sampled clearance of the needle's surface, outside
        the start exclusion: an estimate), ``certified_clearance_mm`` (a lower bound for the
        whole path), ``collision_model`` and ``colliding_samples``.
    """

    ok: bool
    violations: tuple[str, ...]
    metrics: dict = field(default_factory=dict)
