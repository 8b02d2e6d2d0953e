"""RRT for bevel-tip needles, to one target or to several (the lecture's multi-target mode).

The tree grows from the start pose. Each iteration samples a point: a target itself with
probability :data:`GOAL_BIAS` until that target has a plan, otherwise a uniform point in
the ball spanned by the start and the target(s), kept only when it is reachable from the
start (the lecture's condition, :func:`~needlekit.needle.reachability.is_reachable`). The
nearest node is the one with the shortest turn-then-straight path to the sample
(reachability-guided), and the tree is extended by one constant-curvature arc toward the
sample (radius at least r_min; cut at the sample's bearing when the sample needs a tighter
turn). Every new node tries a greedy connection to every target, by default an arc then a
line (turn at r_min, then straight into the tau-ball: the shortest forward connection,
``connection="arc_line"``); ``connection="arc"`` uses one arc to the target itself, as
the reference implementation of RCS*'s authors does (and so Feng et al.'s tables). The search is anytime: it keeps going until the budget runs out
and reports the cheapest plan found per target. There is no rewiring.
"""

from __future__ import annotations

import math
import time

import numpy as np

from needlekit.anatomy.occupancy import VoxelObstacles
from needlekit.constants import PLANNER_FINISH_RESERVE_S
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import propagate_arcs
from needlekit.needle.reachability import arc_line_lengths_from, is_reachable
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.cost import chain_cost, motion_cost
from needlekit.planning.steerable.goal import goal_connection, single_arc_connection
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.validity import MotionValidator
from needlekit.planning.steerable.verify import verify_approximate, verify_plan

__all__ = ["GOAL_BIAS", "solve_rrt", "solve_rrt_multi"]

#: Probability of sampling a target itself while it has no plan yet.
GOAL_BIAS: float = 0.05
#: Samples drawn per iteration before giving up on finding a reachable one.
MAX_SAMPLE_TRIES: int = 50


def solve_rrt(
    problem: SteerableProblem,
    *,
    time_limit_s: float = 1.0,
    seed: int | None = 0,
    obstacles: VoxelObstacles | None = None,
    max_iterations: int | None = None,
    connection: str = "arc_line",
) -> PlanResult:
    """Plan to the problem's goal with RRT (see :func:`solve_rrt_multi`).

    Parameters
    ----------
    problem : SteerableProblem
    time_limit_s : float
    seed : int, optional
    obstacles : VoxelObstacles, optional
    max_iterations : int, optional
    connection : {"arc_line", "arc"}

    Returns
    -------
    PlanResult
    """
    return solve_rrt_multi(
        problem,
        problem.goal_mm[None],
        time_limit_s=time_limit_s,
        seed=seed,
        obstacles=obstacles,
        max_iterations=max_iterations,
        connection=connection,
    )[0]


def solve_rrt_multi(
    problem: SteerableProblem,
    goals_mm,
    *,
    time_limit_s: float = 1.0,
    seed: int | None = 0,
    obstacles: VoxelObstacles | None = None,
    max_iterations: int | None = None,
    connection: str = "arc_line",
) -> list[PlanResult]:
    """Grow one tree and plan to several targets.

    Parameters
    ----------
    problem : SteerableProblem
        Start pose, limits and tolerance (its own goal is ignored in favour of ``goals_mm``).
    goals_mm : array_like, shape (k, 3)
        Targets (RAS mm).
    time_limit_s : float
        Budget for the whole tree.
    seed : int, optional
        Seed of the random samples (same seed, same tree).
    obstacles : VoxelObstacles, optional
        Exact voxel-centre collision test (default: the scene's obstacle field).
    max_iterations : int, optional
    connection : {"arc_line", "arc"}
        Greedy connection from every new node to the targets: turn at r_min then straight
        into the tau-ball, or one arc to the target itself (the reference's rule).

    Returns
    -------
    list of PlanResult
        One per target, in order: ``SOLVED`` with the cheapest plan found, else
        ``APPROXIMATE`` (the valid tree path that ended nearest the target,
        ``stats["goal_distance_mm"]``) or ``TIMEOUT``
        (or ``INFEASIBLE`` / ``INVALID_PROBLEM`` when that is known up front).
    """
    if problem.start_pose is None:
        raise InvalidInputError("start_pose", "RRT needs a start pose")
    if not (np.isfinite(time_limit_s) and time_limit_s > 0):
        raise InvalidInputError("time_limit_s", f"must be a finite number > 0, got {time_limit_s}")
    goals = np.asarray(goals_mm, dtype=float).reshape(-1, 3)
    if len(goals) == 0 or not np.all(np.isfinite(goals)):
        raise InvalidInputError("goals_mm", "expected one or more finite points (k, 3)")
    if connection not in ("arc_line", "arc"):
        raise InvalidInputError("connection", f"expected 'arc_line' or 'arc', got {connection!r}")
    connect = goal_connection if connection == "arc_line" else single_arc_connection
    rng = np.random.default_rng(seed)
    start = problem.start_pose
    r, tau, kappa = problem.r_min_mm, problem.goal_tolerance_mm, problem.kappa_max_per_mm
    validator = MotionValidator(problem, obstacles)
    validator.warm_up()  # JIT compilation is not search time
    t0 = time.perf_counter()
    search_s = time_limit_s - min(PLANNER_FINISH_RESERVE_S, 0.05 * time_limit_s)
    k = len(goals)

    def finish(i, status, plan=None, cost=math.inf, **stats):
        return PlanResult(
            status, "rrt", plan, cost, time.perf_counter() - t0, goals[i], stats, start
        )

    if validator.points_collide(start[:3, 3][None]):
        return [
            finish(
                i, PlanStatus.INVALID_PROBLEM, reason="start collides beyond the start exclusion"
            )
            for i in range(k)
        ]
    open_goals = [
        i
        for i in range(k)
        if goal_connection(start, goals[i], r, tau) is not None
        and np.linalg.norm(goals[i] - start[:3, 3]) <= problem.max_length_mm
    ]
    # the sampling region: the ball spanned by the start and the targets
    centre = 0.5 * (start[:3, 3] + goals.mean(axis=0))
    radius = (
        0.5 * np.linalg.norm(goals.mean(axis=0) - start[:3, 3])
        + np.linalg.norm(goals - goals.mean(axis=0), axis=1).max()
        + 2 * tau
    )

    poses = [start]
    parents = [-1]
    prims = [np.zeros(3)]
    costs = [0.0]
    lengths = [0.0]
    best = [math.inf] * k
    best_plans: list[SteerablePlan | None] = [None] * k
    iterations = refused = 0

    def chain(idx: int) -> list:
        out = []
        while parents[idx] >= 0:
            out.append(prims[idx].tolist())
            idx = parents[idx]
        return out[::-1]

    def try_goals(idx: int) -> None:
        nonlocal refused
        for i in open_goals:
            conn = connect(poses[idx], goals[i], r, tau)
            if conn is None or conn.primitives[0, 1] > kappa * (1 + 1e-12):
                continue
            if lengths[idx] + conn.length_mm >= problem.max_length_mm:
                continue
            if costs[idx] + conn.length_mm >= best[i]:  # the cost is at least the length
                continue
            if not validator.primitives_valid(poses[idx], conn.primitives):
                continue
            cost = costs[idx] + chain_cost(problem, poses[idx], conn.primitives)
            if cost >= best[i]:
                continue
            plan = SteerablePlan(
                start, np.array(chain(idx) + conn.primitives.tolist()).reshape(-1, 3)
            )
            sub = (
                problem
                if i == 0 and np.allclose(goals[i], problem.goal_mm)
                else _with_goal(problem, goals[i])
            )
            if not verify_plan(sub, plan, obstacles=obstacles, spacing_mm=validator.spacing_mm).ok:
                refused += 1
                continue
            best[i], best_plans[i] = cost, plan

    def sample() -> np.ndarray | None:
        unsolved = [i for i in open_goals if best_plans[i] is None]
        if unsolved and rng.random() < GOAL_BIAS:
            return goals[rng.choice(unsolved)]
        for _ in range(MAX_SAMPLE_TRIES):
            d = rng.normal(size=3)
            p = centre + radius * rng.random() ** (1 / 3) * d / np.linalg.norm(d)
            if is_reachable(start, p, r):
                return p
        return None

    try_goals(0)
    reason = "time limit"
    while open_goals:
        if time.perf_counter() - t0 > search_s:
            break
        if max_iterations is not None and iterations >= max_iterations:
            reason = "iteration limit"
            break
        iterations += 1
        q = sample()
        if q is None:
            continue
        near = int(np.argmin(arc_line_lengths_from(np.array(poses), q, r)))
        ext = single_arc_connection(poses[near], q, r, math.inf)
        if ext is None:
            continue
        spin, kap, length = ext.primitives[0]
        if length <= 1e-9 or lengths[near] + length >= problem.max_length_mm:
            continue
        if not validator.motion_valid(poses[near], spin, kap, length):
            continue
        new_pose = propagate_arcs(poses[near], spin, kap, length)
        poses.append(new_pose)
        parents.append(near)
        prims.append(np.array([spin, kap, length]))
        costs.append(costs[near] + motion_cost(problem, poses[near], spin, kap, length))
        lengths.append(lengths[near] + length)
        try_goals(len(poses) - 1)

    def _approximate(i: int, stats: dict) -> PlanResult:
        """The valid tree path that ended nearest target ``i``, else a timeout."""
        gaps = np.linalg.norm(np.array(poses)[:, :3, 3] - goals[i], axis=1)
        idx = int(np.argmin(gaps))
        if idx > 0:
            plan = SteerablePlan(start, np.array(chain(idx)).reshape(-1, 3))
            sub = _with_goal(problem, goals[i])
            check = verify_approximate(
                sub, plan, obstacles=obstacles, spacing_mm=validator.spacing_mm
            )
            if check.ok:
                stats = {**stats, "goal_distance_mm": check.metrics["goal_distance_mm"]}
                return finish(i, PlanStatus.APPROXIMATE, plan, costs[idx], **stats)
            stats = {**stats, "refused_by_check": stats["refused_by_check"] + 1}
        return finish(i, PlanStatus.TIMEOUT, **stats)

    out = []
    for i in range(k):
        stats = {
            "iterations": iterations,
            "nodes": len(poses),
            "reason": reason,
            "refused_by_check": refused,
            "connection": connection,
        }
        if i not in open_goals:
            out.append(
                finish(
                    i,
                    PlanStatus.INFEASIBLE,
                    reason="goal outside the start's reachable set or too far",
                )
            )
        elif best_plans[i] is not None:
            out.append(finish(i, PlanStatus.SOLVED, best_plans[i], best[i], **stats))
        else:
            out.append(_approximate(i, stats))
    return out


def _with_goal(problem: SteerableProblem, goal: np.ndarray) -> SteerableProblem:
    from dataclasses import replace

    return replace(problem, goal_mm=goal, start_point_mm=None)
