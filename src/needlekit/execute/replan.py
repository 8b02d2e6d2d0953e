"""Re-planning from the sensed tip, and the clearance margin that execution noise asks for.

When the estimated tip has drifted from the plan by more than ``cross_track_mm`` (and at
least ``min_interval_mm`` has been inserted since the last re-plan), RCS* plans again
from the estimated tip: the needle is already inside, so the problem is the continuation
of the original one (:func:`needlekit.planning.steerable.continuation.continuation_from_pose`:
no entry rules, what is left of the length and heading budgets). A re-plan is adopted only
when it passes the independent check (:func:`needlekit.planning.steerable.verify.verify_plan`)
against that problem; otherwise the needle keeps following the plan it has.

When the target is seen to have moved (:mod:`needlekit.execute.target_sensing`), the
re-plan goes to where it is seen: the continuation problem's goal is replaced
(``Replanner.replan(..., goal_mm=...)``), the warm starts join the new goal, and the check
verifies the plan against it.

The needle does not wait for the planner: the search's measured time (or a fixed
``delay_s``, for reproducible tests) passes in the simulation while the needle goes on
along the old plan, and the new plan applies from where the tip is when the search
returns.

The search is warm-started from the rest of the plan being followed
(:func:`rest_of_plan`): the plan's remaining primitives, from the estimated tip in the
plan's own roll, kept for the whole, three quarters, half, a quarter or none of the rest and
then joined to the goal by the shortest turn-then-straight connection. The cheapest that
passes the check is RCS*'s first best plan: it prunes against it from the first node, and
a search that runs out of time returns it instead of nothing.

Plans and re-plans keep a clearance margin for the noise (:func:`noise_margin_mm`): the
obstacles are grown by ``k`` standard deviations of the tip's lateral error, ``k`` the
one-sided normal quantile of the stated crossing probability.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.interface import Termination
from needlekit.planning.registry import check_replanner
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.continuation import continuation_from_pose
from needlekit.planning.steerable.goal import goal_connection_unchecked
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.solve import build_planner
from needlekit.planning.steerable.verify import verify_plan

__all__ = [
    "WARM_START_KEPT",
    "ReplanPolicy",
    "Replanner",
    "first_mm",
    "noise_margin_mm",
    "rest_of_plan",
]

#: A re-plan's search gets at least this long (s), whatever its set-up took.
MIN_SEARCH_S: float = 0.001
#: The first re-plan's guess (s) of the time outside the search's clock (set-up, check).
INITIAL_OVERHEAD_S: float = 0.005
#: How many of the latest re-plans that guess is taken from (their largest).
OVERHEAD_MEMORY: int = 10

#: The parts of the rest of the plan that the warm starts keep before joining the goal.
WARM_START_KEPT: tuple[float, ...] = (1.0, 0.75, 0.5, 0.25, 0.0)


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


def rest_of_plan(
    plan: SteerablePlan, arc_mm: float, tip_pose, problem: SteerableProblem
) -> list[SteerablePlan]:
    """Warm starts for a re-plan from ``tip_pose``: the rest of ``plan`` after ``arc_mm``,
    carried over to the tip, then joined to the goal.

    The remaining primitives are applied from the tip after a spin that turns the tip's
    roll into the plan's roll at ``arc_mm`` (so that they bend the way the plan bends);
    each of :data:`WARM_START_KEPT` of the rest is kept and the goal joined from its end by
    the shortest turn-then-straight connection to within the goal tolerance, where there
    is one. Nothing here is checked against the anatomy: the search does that.

    Parameters
    ----------
    plan : SteerablePlan
        The plan being followed.
    arc_mm : float
        Where along it the tip is (e.g. the nearest point's arc length).
    tip_pose : array_like, shape (4, 4)
        The estimated tip: the re-plan's start pose.
    problem : SteerableProblem
        Its goal, tolerance and ``r_min``.

    Returns
    -------
    list of SteerablePlan
        From ``tip_pose``, in the order of :data:`WARM_START_KEPT` (those with no
        connection left out).
    """
    tip = np.asarray(tip_pose, dtype=np.float64)
    prims = plan.primitives
    rest = np.zeros((0, 3))
    if len(prims):
        ends = np.cumsum(prims[:, 2])
        i = min(int(np.searchsorted(ends, arc_mm, "right")), len(prims) - 1)
        begin = ends[i] - prims[i, 2]
        into = min(max(0.0, arc_mm - begin), prims[i, 2])
        here = SteerablePlan(plan.start_pose, np.vstack([prims[:i], [[*prims[i, :2], into]]]))
        x = here.end_pose()[:3, 0]  # the plan's roll there, seen from the tip
        roll = math.atan2(float(x @ tip[:3, 1]), float(x @ tip[:3, 0]))
        rest = np.array(prims[i:], dtype=np.float64)
        rest[0, 2] -= into
        rest[0, 0] = roll + (rest[0, 0] if into <= 0.0 else 0.0)
    total = float(rest[:, 2].sum())
    goal = np.ascontiguousarray(problem.goal_mm, dtype=np.float64)
    out = []
    for kept in WARM_START_KEPT:
        part = first_mm(rest, kept * total)
        end = np.ascontiguousarray(SteerablePlan(tip, part).end_pose())
        conn = goal_connection_unchecked(end, goal, problem.r_min_mm, problem.goal_tolerance_mm)
        if conn is not None:
            out.append(SteerablePlan(tip, np.vstack([part, conn.primitives])))
    return out


def first_mm(prims: np.ndarray, length_mm: float) -> np.ndarray:
    """The first ``length_mm`` of a chain of primitives.

    Parameters
    ----------
    prims : ndarray, shape (m, 3)
        ``(spin, kappa, length)`` rows.
    length_mm : float

    Returns
    -------
    ndarray, shape (k, 3)
        The rows up to that length, the last one cut there.

    Examples
    --------
    >>> first_mm(np.array([[0.5, 0.0, 10.0], [0.0, 0.02, 10.0]]), 12.0).tolist()
    [[0.5, 0.0, 10.0], [0.0, 0.02, 2.0]]
    """
    out = []
    left = length_mm
    for spin, kappa, length in prims:
        if left <= 1e-9:
            break
        out.append([spin, kappa, min(length, left)])
        left -= length
    return np.array(out, dtype=np.float64).reshape(-1, 3)


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
        The budget of a whole re-plan: RCS* gets what the continuation problem, the warm
        starts, the search's set-up and the final check leave of it (those estimated from
        the latest re-plans).
    max_iterations : int or None
        Its iteration budget (reproducible runs).
    delay_s : float or None
        The time a re-plan takes in the simulation; None: the search's measured time.
    warm_start : bool
        Start the search from the rest of the plan being followed (:func:`rest_of_plan`).
    planner : str
        The registered steerable planner that searches; it must declare the
        ``"warm_start"`` capability (:func:`needlekit.planning.registry.check_replanner`):
        RCS* (the default) or RCS among needlekit's own.
    """

    cross_track_mm: float = 0.5
    min_interval_mm: float = 2.0
    time_limit_s: float = 0.025
    max_iterations: int | None = None
    delay_s: float | None = None
    warm_start: bool = True
    planner: str = "rcs_star"

    def __post_init__(self) -> None:
        check_replanner(self.planner, "planner")


class Replanner:
    """The policy's planner (RCS* by default) from the estimated tip (see the module notes).

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
    warm_kept : int
        Adopted re-plans that are a warm start itself (the search found nothing cheaper).
    """

    def __init__(self, problem: SteerableProblem, policy: ReplanPolicy | None = None) -> None:
        self.problem = problem
        self.policy = policy or ReplanPolicy()
        self.planner = build_planner(self.policy.planner)
        self.latencies_s: list[float] = []
        self.adopted = 0
        self.refused = 0
        self.warm_kept = 0
        # the latest re-plans' time outside the search's clock (its set-up, the check)
        self._overheads_s: list[float] = [INITIAL_OVERHEAD_S]
        self._last_mm = -math.inf

    def due(self, cross_track_mm: float, inserted_mm: float, goal_distance_mm: float) -> bool:
        """Whether the drift asks for a re-plan now: off the plan by more than
        ``cross_track_mm``, ``min_interval_mm`` in since the last re-plan, past the start
        exclusion (the tip still touches the entry there: a start a continuation refuses) and
        farther from the goal than its tolerance (nothing left to plan).

        Parameters
        ----------
        cross_track_mm, inserted_mm, goal_distance_mm : float

        Returns
        -------
        bool
        """
        return cross_track_mm > self.policy.cross_track_mm and self.may(
            inserted_mm, goal_distance_mm
        )

    def may(self, inserted_mm: float, goal_distance_mm: float) -> bool:
        """Whether a re-plan may run now, whatever asks for it (the drift, or a target
        seen to have moved): ``min_interval_mm`` in since the last re-plan, past the start
        exclusion, and farther from the goal than its tolerance.

        Parameters
        ----------
        inserted_mm, goal_distance_mm : float

        Returns
        -------
        bool
        """
        problem = self.problem
        return (
            inserted_mm - self._last_mm >= self.policy.min_interval_mm
            and inserted_mm > problem.start_exclusion_mm
            and goal_distance_mm > problem.goal_tolerance_mm
        )

    def replan(
        self,
        tip_pose,
        inserted_mm: float,
        following: tuple[SteerablePlan, float] | None = None,
        *,
        goal_mm=None,
    ) -> tuple[PlanResult | None, float]:
        """Plan from ``tip_pose`` and check the plan.

        Parameters
        ----------
        tip_pose : ndarray, shape (4, 4)
            The estimated tip.
        inserted_mm : float
        following : (SteerablePlan, float), optional
            The plan being followed and the tip's arc length along it: the warm start.
        goal_mm : array_like, shape (3,), optional
            Where the target is now seen (:mod:`needlekit.execute.target_sensing`): the
            continuation problem's goal, instead of the original one. The warm starts join
            it, and the check verifies the plan against it.

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
            if goal_mm is not None:
                cont = cont.with_goal(goal_mm)
        except InvalidInputError:  # no length or heading left: follow what there is
            cont = None
        result = None
        if cont is not None:
            warm = []
            if following is not None and self.policy.warm_start:
                warm = rest_of_plan(following[0], following[1], cont.start_pose, cont)
            p = self.policy
            before = time.perf_counter() - t0
            # the search gets what the set-up and the check leave of the budget
            left = max(p.time_limit_s - before - max(self._overheads_s), MIN_SEARCH_S)
            res = self.planner.solve(cont, Termination(left, p.max_iterations), warm_start=warm)
            if res.plan is not None:
                check = verify_plan(cont, res.plan, expected_cost_mm=res.cost_mm)
                result = res if check.ok and res.status is PlanStatus.SOLVED else None
            overhead = time.perf_counter() - t0 - before - res.stats.get("planner_wall_s", 0.0)
            self._overheads_s = [*self._overheads_s[1 - OVERHEAD_MEMORY :], overhead]
        elapsed = time.perf_counter() - t0
        self.latencies_s.append(elapsed)
        if result is None:
            self.refused += 1
        else:
            self.adopted += 1
            self.warm_kept += bool(result.stats.get("warm_start_kept"))
        return result, elapsed if self.policy.delay_s is None else self.policy.delay_s
