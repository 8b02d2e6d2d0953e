"""The straight multi-needle planner on the shared planner interface.

:class:`LiuPlanner` (``"liu_cfrw"``, family ``straight``) plans a :class:`MultiNeedleProblem`
with :func:`~needlekit.planning.straight.sequence.plan_needles`: the registry serves it to
``needlekit multi`` as it serves the steerable planners to ``needlekit plan``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.interface import Termination
from needlekit.planning.straight.entry import Objective
from needlekit.planning.straight.problem import StraightProblem
from needlekit.planning.straight.sequence import MultiNeedlePlan, plan_needles

__all__ = ["LiuOptions", "LiuPlanner", "MultiNeedleProblem"]


@dataclass(frozen=True)
class MultiNeedleProblem:
    """Several targets of one straight-needle problem.

    Attributes
    ----------
    problem : StraightProblem
        Anatomy, needle and limits (its target is the first one's).
    targets_mm : ndarray, shape (k, 3)
    deformation : object or None
        A :class:`~needlekit.planning.straight.deformation.DeformationModel` (None: rigid).
    """

    problem: StraightProblem
    targets_mm: np.ndarray
    deformation: object = None

    def __post_init__(self) -> None:
        t = np.asarray(self.targets_mm, dtype=float).reshape(-1, 3)
        if len(t) == 0 or not np.all(np.isfinite(t)):
            raise InvalidInputError("targets_mm", "expected one or more finite points (k, 3)")
        object.__setattr__(self, "targets_mm", t)


@dataclass(frozen=True)
class LiuOptions:
    """Settings of the straight multi-needle planner.

    Attributes
    ----------
    resolution_deg : float
        CFRW grid step (degrees).
    objective : str
        ``min_length`` (the paper's), ``max_clearance`` or ``min_normal_angle``.
    order : tuple of int or None
        A fixed insertion order (target indices); None: searched.
    """

    resolution_deg: float = 1.0
    objective: str = Objective.MIN_LENGTH.value
    order: tuple | None = None

    def __post_init__(self) -> None:
        r = float(self.resolution_deg)
        if not (np.isfinite(r) and 0 < r <= 45):
            raise InvalidInputError(
                "resolution_deg", f"must lie in (0, 45], got {self.resolution_deg!r}"
            )
        try:
            Objective(self.objective)
        except ValueError:
            kinds = ", ".join(o.value for o in Objective)
            raise InvalidInputError(
                "objective", f"expected one of {kinds}, got {self.objective!r}"
            ) from None
        if self.order is not None:
            object.__setattr__(self, "order", tuple(int(i) for i in self.order))


class LiuPlanner:
    """Liu et al.'s procedure: CFRW per needle, the optimal entry in it, needles in order."""

    name = "liu_cfrw"
    family = "straight"
    options_type = LiuOptions

    def __init__(self, options: LiuOptions | None = None) -> None:
        self.options = LiuOptions() if options is None else options

    def solve(self, problem: MultiNeedleProblem, termination: Termination) -> MultiNeedlePlan:
        """Plan every needle (see :func:`~needlekit.planning.straight.sequence.plan_needles`).

        Parameters
        ----------
        problem : MultiNeedleProblem
        termination : Termination
            Polled before each CFRW map; a stop leaves the plan unsolved, saying why.

        Returns
        -------
        MultiNeedlePlan
        """
        if not isinstance(problem, MultiNeedleProblem):
            raise InvalidInputError(
                "problem", f"liu_cfrw plans a MultiNeedleProblem, got {type(problem).__name__}"
            )
        run = termination.start()
        o = self.options
        return plan_needles(
            problem.problem,
            problem.targets_mm,
            order=o.order,
            objective=o.objective,
            deformation=problem.deformation,
            resolution_deg=o.resolution_deg,
            keep_going=run.keep_going,
        )
