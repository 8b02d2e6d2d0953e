"""What every planner returns: a status, the cost, statistics, and JSON.

Modelled on OMPL's ``PlannerStatus``: ``solve(problem, budget)`` always returns a result;
the status (:class:`needlekit.records.Status`) says what it means.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from needlekit.records import Status

__all__ = ["PlanStatus", "Verification"]


#: The status of every planner's result: :class:`needlekit.records.Status` (one vocabulary
#: for the steerable and straight planners and the controller's trials), under the name
#: planning has always used.
PlanStatus = Status


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
