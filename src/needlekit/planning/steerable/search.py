"""What every steerable-needle search shares, written once: the set-up outside the clock,
the verdicts provable before searching, the check of every plan before it is reported,
the nearest-path fallback and the result.

Pre-checks, in order (each answers at once, before any search):

1. the start collides beyond the start exclusion: ``INVALID_PROBLEM``;
2. the goal lies in an obstacle (for the problem's collision model): ``INVALID_PROBLEM``;
3. the start direction makes less than alpha with the entry surface: ``INVALID_PROBLEM``;
4. the goal is farther than l_max (as the reference planner counts it): ``INFEASIBLE``;
5. the goal lies outside the heading cone: with a heading limit ``H <= 90`` degrees every
   direction of a path lies within ``H`` of the start direction, so every point it reaches
   lies in the convex cone of half-angle ``H`` around it; a goal whose tau-ball misses the
   cone is unreachable: ``INFEASIBLE``;
6. the goal is outside the start's forward reachable set (behind the tip, or deeper than
   tau inside the r_min horn torus; the reference's "goal point not in FRS"):
   ``INFEASIBLE``;
7. the shortest curvature-bounded path to the goal's tau-ball is not shorter than l_max:
   ``INFEASIBLE``;
8. the collision checker proves that no chain of free space connects the start to the goal
   within the region a path of length l_max can visit (``voxel_centres``:
   :func:`~needlekit.anatomy.voxel_connectivity.goal_connected`; the reference's
   "reachable workspace is not connected"): ``INFEASIBLE``.

And once during the search:

9. a search with no plan after :data:`LATE_PROOF_AFTER_S` asks the checker for its finer
   proof (``voxel_centres``: the same fill over cells half a voxel wide, which seals gaps
   of one voxel that the needle cannot pass; costlier on an open goal, so easy problems
   never run it): ``INFEASIBLE``.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from needlekit._validation_kernels import rotation_errors
from needlekit.constants import MOTION_SPACING_MM
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import propagate_arcs
from needlekit.needle.reachability import arc_line_lengths_from, is_reachable
from needlekit.planning.interface import SearchRun, Termination
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable._rcs_kernels import child_motion, se3_gap
from needlekit.planning.steerable.cost import chain_cost
from needlekit.planning.steerable.goal import (
    connection_length_unchecked,
    goal_connection,
    single_arc_connection,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.validity import MotionValidator
from needlekit.planning.steerable.verify import verify_approximate, verify_plan

__all__ = ["LATE_PROOF_AFTER_S", "SteerableSearch", "precheck"]

log = logging.getLogger(__name__)

#: Heading limits up to this (deg) make the set of reachable displacements a convex cone.
CONVEX_HEADING_DEG: float = 90.0
#: A search that has found no plan after this long (s) runs the collision checker's finer
#: proof once (:meth:`SteerableSearch.late_verdict`): easy problems, solved sooner, never
#: pay for it.
LATE_PROOF_AFTER_S: float = 0.005


def geometric_refusal(
    problem: SteerableProblem, start_pose: np.ndarray, goal_mm: np.ndarray
) -> tuple[PlanStatus, str] | None:
    """The pre-check's verdicts that need geometry alone (no anatomy): the goal beyond the
    maximum length, outside the heading cone, outside the start's reachable set, or its
    shortest curvature-bounded path not shorter than the maximum length.

    Parameters
    ----------
    problem : SteerableProblem
        Its limits (the start pose may differ).
    start_pose : ndarray, shape (4, 4)
    goal_mm : ndarray, shape (3,)

    Returns
    -------
    (PlanStatus, str) or None
        ``INFEASIBLE`` and the reason, or None when geometry allows a path.
    """
    start = np.asarray(start_pose, dtype=float)
    p0, d0 = start[:3, 3], start[:3, 2]
    tau = problem.goal_tolerance_mm
    gap = goal_mm - p0
    dist = float(np.linalg.norm(gap))
    if dist > problem.max_length_mm:
        return PlanStatus.INFEASIBLE, "goal farther than the maximum length"
    heading = problem.max_heading_change_deg
    if heading <= CONVEX_HEADING_DEG and dist > tau:
        off = math.degrees(math.acos(float(np.clip(gap @ d0 / dist, -1.0, 1.0))))
        slack = math.degrees(math.asin(tau / dist))
        if off - slack > heading + 1e-9:
            return (
                PlanStatus.INFEASIBLE,
                f"goal {off:.1f} deg off the start direction: beyond the heading limit "
                f"of {heading:g} deg (every path stays inside that cone)",
            )
    conn = goal_connection(start, goal_mm, problem.r_min_mm, tau)
    if conn is None:
        return (
            PlanStatus.INFEASIBLE,
            "goal outside the start's reachable set (behind the tip or inside the r_min torus)",
        )
    if conn.length_mm >= problem.max_length_mm:
        return (
            PlanStatus.INFEASIBLE,
            f"the shortest curvature-bounded path to the goal is {conn.length_mm:.2f} mm, "
            f"not under the maximum length {problem.max_length_mm:g} mm",
        )
    return None


def _path_limits(problem: SteerableProblem, start_pose: np.ndarray) -> dict:
    """The limits a checker's connectivity proofs take (where a valid path can go)."""
    return {
        "max_length_mm": problem.max_length_mm,
        "goal_tolerance_mm": problem.goal_tolerance_mm,
        "start_direction": start_pose[:3, 2],
        "r_min_mm": problem.r_min_mm,
        "max_heading_change_deg": problem.max_heading_change_deg,
    }


def precheck(
    problem: SteerableProblem, goal_mm: np.ndarray, validator: MotionValidator
) -> tuple[PlanStatus, str] | None:
    """The verdict provable without searching (module notes), or None.

    Parameters
    ----------
    problem : SteerableProblem
        With a start pose.
    goal_mm : ndarray, shape (3,)
    validator : MotionValidator

    Returns
    -------
    (PlanStatus, str) or None
        The status and the reason.
    """
    start = problem.start_pose
    p0, d0 = start[:3, 3], start[:3, 2]
    gap = float(np.linalg.norm(np.asarray(goal_mm, float) - p0))
    if gap <= problem.goal_tolerance_mm:
        return (
            PlanStatus.INVALID_PROBLEM,
            f"the goal is {gap:.3f} mm from the start, within the goal tolerance "
            f"{problem.goal_tolerance_mm:g} mm: there is nothing to insert",
        )
    if validator.points_collide(p0[None]):
        return PlanStatus.INVALID_PROBLEM, "start collides beyond the start exclusion"
    if gap > problem.max_length_mm:  # out of reach whatever lies there (the scene may end)
        return PlanStatus.INFEASIBLE, "goal farther than the maximum length"
    if validator.goal_collides(goal_mm):
        return PlanStatus.INVALID_PROBLEM, "goal lies inside an obstacle (for this needle)"
    if problem.puncture_normal is not None and problem.min_puncture_angle_deg > 0:
        angle = math.degrees(math.asin(float(np.clip(d0 @ problem.puncture_normal, -1, 1))))
        if angle < problem.min_puncture_angle_deg - 1e-7:
            return (
                PlanStatus.INVALID_PROBLEM,
                f"the start direction makes {angle:.2f} deg with the {problem.entry_surface or 'entry'} "
                f"surface, below the minimum puncture angle {problem.min_puncture_angle_deg:g} deg",
            )
    refusal = geometric_refusal(problem, start, goal_mm)
    if refusal is not None:
        return refusal
    connected = validator.checker.connected(goal_mm, **_path_limits(problem, start))
    if connected is False:
        return (
            PlanStatus.INFEASIBLE,
            "reachable workspace is not connected to the goal: no chain of free voxels "
            "leads there within the region a valid path can visit",
        )
    return None


def warm_up(problem: SteerableProblem, validator: MotionValidator) -> None:
    """Run every kernel a search and its plan check call once, on this problem, so that
    numba's compilation (or loading from its cache) happens before the clock starts.

    Parameters
    ----------
    problem : SteerableProblem
        With a start pose.
    validator : MotionValidator
    """
    validator.warm_up()  # the checker's kernels, the connectivity proof's included
    start, goal = problem.start_pose, problem.goal_mm
    kappa, r, tau = problem.kappa_max_per_mm, problem.r_min_mm, problem.goal_tolerance_mm
    goal_connection(start, goal, r, tau)
    connection_length_unchecked(np.ascontiguousarray(start), np.ascontiguousarray(goal), r, tau)
    single_arc_connection(start, goal, r, tau)

    se3_gap(start, start)

    child_motion(
        np.ascontiguousarray(start), 0.1, kappa, 1.0, np.ascontiguousarray(goal), r, tau, 1e-3, 1e-6
    )
    propagate_arcs(start, 0.0, kappa, 1.0)
    propagate_arcs(start, np.zeros(2), np.full(2, kappa), np.ones(2))
    arc_line_lengths_from(start[None], goal, r)
    is_reachable(start, goal, r)
    prims = np.array([[0.0, kappa, 1.0], [0.0, 0.0, 1.0]])
    chain_cost(problem, start, prims)
    tiny = SteerablePlan(start, prims)
    verify_plan(problem, tiny)
    verify_approximate(problem, tiny)
    # long plans check their poses' rotations in the numba kernel (a tiny plan's few poses
    # go through numpy): load it here too
    rotation_errors(np.ascontiguousarray(start[None, :3, :3]))


class SteerableSearch:
    """One steerable-needle search: set-up, clock, checked plans, result.

    Parameters
    ----------
    problem : SteerableProblem
        With a start pose.
    termination : Termination
    planner : str
        Name recorded in results.
    """

    def __init__(self, problem: SteerableProblem, termination: Termination, planner: str):
        if problem.start_pose is None:
            raise InvalidInputError(
                "start_pose", f"{planner} needs a start pose (sweep directions for a start point)"
            )
        if not isinstance(termination, Termination):
            raise InvalidInputError(
                "termination", f"expected a Termination, got {type(termination).__name__}"
            )
        t0 = time.perf_counter()
        self.problem = problem
        self.planner = planner
        self.start = problem.start_pose
        self.validator = MotionValidator(problem)
        warm_up(problem, self.validator)  # compiling kernels is set-up, not search
        self.refused = 0
        self._late_done = False  # the finer proof has been asked for (late_due)
        self.setup_s = time.perf_counter() - t0
        self.run: SearchRun = termination.start()

    def late_due(self) -> bool:
        """True once, the first time it is asked after :data:`LATE_PROOF_AFTER_S` of
        search: then the search calls :meth:`late_verdict` (for each goal it has not
        solved).

        Returns
        -------
        bool
        """
        if self._late_done or self.run.elapsed_s < LATE_PROOF_AFTER_S:
            return False
        self._late_done = True
        return True

    def late_verdict(self, goal_mm: np.ndarray | None = None) -> tuple[PlanStatus, str] | None:
        """The collision checker's finer proof of a sealed goal (module notes, check 9),
        which a search calls when :meth:`late_due` says so and it has found no plan.

        Parameters
        ----------
        goal_mm : ndarray, shape (3,), optional
            Another goal than the problem's (multi-target searches).

        Returns
        -------
        (PlanStatus, str) or None
            ``INFEASIBLE`` and the reason, or None.
        """
        finer = getattr(self.validator.checker, "connected_finer", None)
        if finer is None:  # an optional method of the checker
            return None
        p = self.problem
        goal = p.goal_mm if goal_mm is None else goal_mm
        if finer(goal, **_path_limits(p, self.start)) is False:
            return (
                PlanStatus.INFEASIBLE,
                "reachable workspace is not connected to the goal: no chain of free cells "
                "half a voxel wide leads there within the region a valid path can visit",
            )
        return None

    def check(self, plan: SteerablePlan, goal_mm: np.ndarray | None = None) -> bool:
        """Whether a candidate passes the independent check (counted and logged when not).

        Parameters
        ----------
        plan : SteerablePlan
        goal_mm : ndarray, shape (3,), optional
            Another goal than the problem's (multi-target searches).

        Returns
        -------
        bool
        """
        problem = self.problem if goal_mm is None else _with_goal(self.problem, goal_mm)
        # the search's own samples certify the clearance here (cheap, once per candidate);
        # the returned plan gets the full check of `needlekit verify` in result()
        check = verify_plan(problem, plan, spacing_mm=MOTION_SPACING_MM)
        if not check.ok:  # never report a path the independent check refuses
            self.refused += 1
            log.warning(
                "%s: candidate plan refused by the check: %s",
                self.planner,
                "; ".join(check.violations),
            )
        return check.ok

    def warm_start(self, plans) -> tuple[float, SteerablePlan | None]:
        """The first best of a warm-started search: the cheapest of ``plans`` that passes
        the independent check (the others are not counted as refused: they are guesses,
        not the search's candidates).

        Parameters
        ----------
        plans : sequence of SteerablePlan
            Plans from the problem's start pose to its goal (e.g. the rest of a plan
            being executed, from the tracked tip).

        Returns
        -------
        (float, SteerablePlan or None)
            Its cost and the plan, or ``(inf, None)``.

        Raises
        ------
        InvalidInputError
            Not a plan, or a plan that starts elsewhere than the start pose.
        """
        ranked = []
        for k, plan in enumerate(plans):
            if not isinstance(plan, SteerablePlan):
                raise InvalidInputError(
                    "warm_start", f"item {k}: expected a SteerablePlan, got {type(plan).__name__}"
                )
            if not np.allclose(plan.start_pose, self.start, rtol=0.0, atol=1e-9):
                raise InvalidInputError(
                    "warm_start", f"item {k}: the plan starts elsewhere than the start pose"
                )
            if len(plan.primitives):
                ranked.append((chain_cost(self.problem, self.start, plan.primitives), k, plan))
        for cost, _, plan in sorted(ranked, key=lambda c: c[:2]):
            check = verify_plan(self.problem, plan, spacing_mm=MOTION_SPACING_MM)
            if check.ok:
                self.run.improved(cost)
                return cost, plan
        return math.inf, None

    def result(
        self,
        status: PlanStatus,
        plan: SteerablePlan | None = None,
        cost: float = math.inf,
        goal_mm: np.ndarray | None = None,
        **stats,
    ) -> PlanResult:
        """The result, with the figures every run records (:meth:`SearchRun.stats`),
        ``setup_s`` and ``refused_by_check``.

        Parameters
        ----------
        status : PlanStatus
        plan : SteerablePlan, optional
        cost : float
        goal_mm : ndarray, shape (3,), optional
            Another goal than the problem's (multi-target searches).
        **stats
            Further statistics.

        Returns
        -------
        PlanResult
        """
        goal = self.problem.goal_mm if goal_mm is None else goal_mm
        if plan is not None:
            # the check `needlekit verify` runs, once, on the returned plan: its figures
            # are the ones reported. It passes whenever the candidate check passed (its
            # clearance certificate includes the search's samples); a failure is a bug,
            # and the plan is then withheld, never reported
            problem = self.problem if goal_mm is None else _with_goal(self.problem, goal_mm)
            approx = status is PlanStatus.APPROXIMATE
            full = (verify_approximate if approx else verify_plan)(problem, plan)
            if not full.ok:
                self.refused += 1
                log.error("%s: the returned plan fails the full check: %s", self.planner,
                          "; ".join(full.violations))  # fmt: skip
                stats["reason"] = "the plan failed the full check: " + "; ".join(full.violations)
                status, plan, cost = PlanStatus.TIMEOUT, None, math.inf
            else:
                m = full.metrics
                stats["certified_clearance_mm"] = m["certified_clearance_mm"]
                stats["min_clearance_mm"] = m["min_clearance_mm"]
                stats["collision_model"] = m["collision_model"]
        run = self.run.stats()
        merged = {**run, "setup_s": self.setup_s, "refused_by_check": self.refused, **stats}
        return PlanResult(
            status, self.planner, plan, cost, run["planner_wall_s"], goal, merged, self.start
        )

    def approximate(
        self, prims: list, cost: float, goal_mm: np.ndarray | None = None, **stats
    ) -> PlanResult:
        """The valid path that ended nearest the goal, as ``APPROXIMATE``, or ``TIMEOUT``
        when there is none or it fails its check.

        Parameters
        ----------
        prims : list of [spin, kappa, length]
            Its primitives (empty: the start itself, no path).
        cost : float

        Returns
        -------
        PlanResult
        """
        if prims:
            plan = SteerablePlan(self.start, np.array(prims, dtype=float).reshape(-1, 3))
            problem = self.problem if goal_mm is None else _with_goal(self.problem, goal_mm)
            check = verify_approximate(problem, plan, spacing_mm=MOTION_SPACING_MM)
            if check.ok:
                stats["goal_distance_mm"] = check.metrics["goal_distance_mm"]
                return self.result(PlanStatus.APPROXIMATE, plan, cost, goal_mm, **stats)
            self.refused += 1
        return self.result(PlanStatus.TIMEOUT, goal_mm=goal_mm, **stats)


def _with_goal(problem: SteerableProblem, goal: np.ndarray) -> SteerableProblem:
    return problem.with_goal(goal)
