"""Re-planning from the sensed tip, and the clearance margin that execution noise asks for.

When the estimated tip has drifted from the plan by more than ``cross_track_mm`` (and at
least ``min_interval_mm`` has been inserted since the last re-plan), RCS* plans again
from the estimated tip: the needle is already inside, so the problem is the continuation
of the original one (:func:`needlekit.planning.steerable.continuation.continuation_from_pose`:
no entry rules, what is left of the length and heading budgets). A re-plan is adopted only
when it passes the independent check (:func:`needlekit.planning.steerable.verify.verify_plan`)
against that problem; otherwise the needle keeps following the plan it has.

The needle does not wait for the planner: the search's measured time (or a fixed
``delay_s``, for reproducible tests) passes in the simulation while the needle goes on
along the old plan, and the new plan applies from where the tip is when the search
returns.

Plans and re-plans keep a clearance margin for the noise (:func:`noise_margin_mm`): the
obstacles are grown by ``k`` standard deviations of the tip's lateral error, ``k`` the
one-sided normal quantile of the stated crossing probability.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from statistics import NormalDist

from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.continuation import continuation_from_pose
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.solve import build_planner, solve
from needlekit.planning.steerable.verify import verify_plan

__all__ = ["ReplanPolicy", "Replanner", "noise_margin_mm"]


def noise_margin_mm(lateral_sigma_mm: float, crossing_probability: float) -> float:
    """The clearance kept for the noise: ``k sigma`` with ``k`` the one-sided normal
    quantile of ``1 - crossing_probability``.

    Parameters
    ----------
    lateral_sigma_mm : float
        SD of the tip's lateral error where the plan passes an obstacle.
    crossing_probability : float
        The probability, in (0, 0.5], that a Gaussian error that large crosses the margin.

    Returns
    -------
    float

    Examples
    --------
    >>> round(noise_margin_mm(0.3, 0.001), 4)
    0.9271
    """
    if not (math.isfinite(lateral_sigma_mm) and lateral_sigma_mm >= 0):
        raise InvalidInputError(
            "lateral_sigma_mm", f"expected a number >= 0, got {lateral_sigma_mm}"
        )
    if not 0.0 < crossing_probability <= 0.5:
        raise InvalidInputError(
            "crossing_probability",
            f"expected a probability in (0, 0.5], got {crossing_probability}",
        )
    return lateral_sigma_mm * NormalDist().inv_cdf(1.0 - crossing_probability)


@dataclass(frozen=True)
class ReplanPolicy:
    """When to re-plan and with what budget.

    Attributes
    ----------
    cross_track_mm : float
        Re-plan when the estimated tip is this far from the plan.
    min_interval_mm : float
        Insertion between two re-plans.
    time_limit_s : float
        RCS*'s budget per re-plan.
    max_iterations : int or None
        Its iteration budget (reproducible runs).
    delay_s : float or None
        The time a re-plan takes in the simulation; None: the search's measured time.
    """

    cross_track_mm: float = 0.5
    min_interval_mm: float = 2.0
    time_limit_s: float = 0.025
    max_iterations: int | None = None
    delay_s: float | None = None


class Replanner:
    """RCS* from the estimated tip (see the module notes).

    Parameters
    ----------
    problem : SteerableProblem
        The original problem, its margin included.
    policy : ReplanPolicy

    Attributes
    ----------
    latencies_s : list of float
        The measured time of every re-plan (search and check).
    adopted, refused : int
        Re-plans that passed their check and were followed, and those that did not.
    """

    def __init__(self, problem: SteerableProblem, policy: ReplanPolicy | None = None) -> None:
        self.problem = problem
        self.policy = policy or ReplanPolicy()
        self.planner = build_planner("rcs_star")
        self.latencies_s: list[float] = []
        self.adopted = 0
        self.refused = 0
        self._last_mm = -math.inf

    def due(self, cross_track_mm: float, inserted_mm: float) -> bool:
        """Whether the drift asks for a re-plan now.

        Parameters
        ----------
        cross_track_mm, inserted_mm : float

        Returns
        -------
        bool
        """
        p = self.policy
        return (
            cross_track_mm > p.cross_track_mm and inserted_mm - self._last_mm >= p.min_interval_mm
        )

    def replan(self, tip_pose, inserted_mm: float) -> tuple[PlanResult | None, float]:
        """Plan from ``tip_pose`` and check the plan.

        Parameters
        ----------
        tip_pose : ndarray, shape (4, 4)
            The estimated tip.
        inserted_mm : float

        Returns
        -------
        (PlanResult or None, float)
            The checked plan (None when there is none, or it fails its check) and the time
            it took in the simulation (s).
        """
        self._last_mm = inserted_mm
        t0 = time.perf_counter()
        try:
            cont = continuation_from_pose(self.problem, tip_pose, inserted_mm)
        except InvalidInputError:  # no length or heading left: follow what there is
            cont = None
        result = None
        if cont is not None:
            res = solve(cont, self.planner, time_limit_s=self.policy.time_limit_s,
                        max_iterations=self.policy.max_iterations)  # fmt: skip
            if res.plan is not None:
                check = verify_plan(cont, res.plan, expected_cost_mm=res.cost_mm)
                result = res if check.ok and res.status is PlanStatus.SOLVED else None
        elapsed = time.perf_counter() - t0
        self.latencies_s.append(elapsed)
        if result is None:
            self.refused += 1
        else:
            self.adopted += 1
        return result, elapsed if self.policy.delay_s is None else self.policy.delay_s
