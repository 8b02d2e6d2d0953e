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
from dataclasses import dataclass

import numpy as np

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import arc_end_unchecked
from needlekit.needle.reachability import (
    arc_line_lengths_from_unchecked,
    is_reachable_unchecked,
)
from needlekit.planning.interface import Termination, cyclic_gc_paused
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.cost import chain_cost, motion_cost
from needlekit.planning.steerable.goal import (
    goal_connection_unchecked,
    single_arc_connection_unchecked,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.search import SteerableSearch, precheck

__all__ = [
    "CONNECTIONS",
    "GOAL_BIAS",
    "RRTOptions",
    "RRTPlanner",
    "solve_rrt",
    "solve_rrt_multi",
    "solve_rrt_per_target",
]

#: Probability of sampling a target itself while it has no plan yet.
GOAL_BIAS: float = 0.05
#: The greedy goal connections RRT can use.
CONNECTIONS: tuple[str, ...] = ("arc_line", "arc")
#: Samples drawn per iteration before giving up on finding a reachable one.
MAX_SAMPLE_TRIES: int = 50


@dataclass(frozen=True)
class RRTOptions:
    """Settings of RRT.

    Attributes
    ----------
    connection : {"arc_line", "arc"}
        Greedy connection from every new node to the targets: turn at r_min then straight
        into the tau-ball, or one arc to the target itself (the reference's rule).
    seed : int
        Seed of the random samples (same seed and iteration budget, same tree).
    """

    connection: str = "arc_line"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.connection not in CONNECTIONS:
            raise InvalidInputError(
                "connection", f"expected 'arc_line' or 'arc', got {self.connection!r}"
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise InvalidInputError("seed", f"expected a whole number >= 0, got {self.seed!r}")


class RRTPlanner:
    """Reachability-guided RRT with a greedy goal connection (anytime, multi-target)."""

    name = "rrt"
    family = "steerable"
    options_type = RRTOptions

    def __init__(self, options: RRTOptions | None = None) -> None:
        self.options = RRTOptions() if options is None else options

    def solve(self, problem: SteerableProblem, termination: Termination) -> PlanResult:
        """Plan to the problem's goal (see :meth:`solve_multi`).

        Parameters
        ----------
        problem : SteerableProblem
        termination : Termination

        Returns
        -------
        PlanResult
        """
        return self.solve_multi(problem, problem.goal_mm[None], termination)[0]

    def solve_multi(
        self, problem: SteerableProblem, goals_mm, termination: Termination
    ) -> list[PlanResult]:
        """Grow one tree and plan to several targets (see :func:`solve_rrt_multi`).

        Parameters
        ----------
        problem : SteerableProblem
            Start pose, limits and collision model (its own goal is ignored).
        goals_mm : array_like, shape (k, 3)
        termination : Termination
            The budget of the whole tree.

        Returns
        -------
        list of PlanResult
            One per target, in order.
        """
        return _grow(problem, goals_mm, termination, self.options)


def solve_rrt(
    problem: SteerableProblem,
    *,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    seed: int | None = 0,
    max_iterations: int | None = None,
    connection: str = "arc_line",
) -> PlanResult:
    """Plan to the problem's goal with RRT (see :func:`solve_rrt_multi`).

    Parameters
    ----------
    problem : SteerableProblem
    time_limit_s : float
    seed : int, optional
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
        max_iterations=max_iterations,
        connection=connection,
    )[0]


def solve_rrt_multi(
    problem: SteerableProblem,
    goals_mm,
    *,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    seed: int | None = 0,
    max_iterations: int | None = None,
    connection: str = "arc_line",
) -> list[PlanResult]:
    """Grow one tree and plan to several targets.

    Parameters
    ----------
    problem : SteerableProblem
        Start pose, limits, tolerance and collision model (its own goal is ignored in
        favour of ``goals_mm``).
    goals_mm : array_like, shape (k, 3)
        Targets (RAS mm).
    time_limit_s : float
        Budget for the whole tree.
    seed : int, optional
        Seed of the random samples (same seed, same tree; default 0).
    max_iterations : int, optional
    connection : {"arc_line", "arc"}
        Greedy connection from every new node to the targets: turn at r_min then straight
        into the tau-ball, or one arc to the target itself (the reference's rule).

    Returns
    -------
    list of PlanResult
        One per target, in order: ``SOLVED`` with the cheapest plan found, else
        ``APPROXIMATE`` (the valid tree path that ended nearest the target,
        ``stats["goal_distance_mm"]``) or ``TIMEOUT`` (or ``INFEASIBLE`` /
        ``INVALID_PROBLEM`` when a pre-check proves it,
        :mod:`needlekit.planning.steerable.search`).
    """
    options = RRTOptions(connection, 0 if seed is None else seed)
    return _grow(problem, goals_mm, Termination(time_limit_s, max_iterations), options)


def solve_rrt_per_target(
    problem: SteerableProblem,
    goals_mm,
    *,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    seed: int | None = 0,
    max_iterations: int | None = None,
    connection: str = "arc_line",
) -> list[PlanResult]:
    """The lecture's multi-target RRT: a new tree from the start node for each target.

    The lecture reaches several targets one after another, "for each target, we start from
    the start node and repeat this process"; :func:`solve_rrt_multi` grows one tree that
    serves every target instead. Here each target gets a tree of its own, grown toward it
    alone (the same goal bias, sampling ball of start and that target, and connection).

    Parameters
    ----------
    problem : SteerableProblem
        Start pose, limits, tolerance and collision model (its own goal is ignored).
    goals_mm : array_like, shape (k, 3)
        Targets (RAS mm), planned in order.
    time_limit_s : float
        Budget of each target's tree.
    seed : int, optional
        Seed of each tree's random samples (default 0; every tree starts from it).
    max_iterations : int, optional
        Iteration budget of each tree.
    connection : {"arc_line", "arc"}

    Returns
    -------
    list of PlanResult
        One per target, in order, as :func:`solve_rrt` returns it.
    """
    options = RRTOptions(connection, 0 if seed is None else seed)
    goals = np.asarray(goals_mm, dtype=float).reshape(-1, 3)
    if len(goals) == 0 or not np.all(np.isfinite(goals)):
        raise InvalidInputError("goals_mm", "expected one or more finite points (k, 3)")
    return [
        _grow(problem, g[None], Termination(time_limit_s, max_iterations), options)[0]
        for g in goals
    ]


@cyclic_gc_paused
def _grow(
    problem: SteerableProblem, goals_mm, termination: Termination, options: RRTOptions
) -> list[PlanResult]:
    goals = np.asarray(goals_mm, dtype=float).reshape(-1, 3)
    if len(goals) == 0 or not np.all(np.isfinite(goals)):
        raise InvalidInputError("goals_mm", "expected one or more finite points (k, 3)")
    connection = options.connection
    connect = (
        goal_connection_unchecked if connection == "arc_line" else single_arc_connection_unchecked
    )
    rng = np.random.default_rng(options.seed)
    search = SteerableSearch(problem, termination, "rrt")
    run = search.run
    validator = search.validator
    start = problem.start_pose
    r, tau, kappa = problem.r_min_mm, problem.goal_tolerance_mm, problem.kappa_max_per_mm
    bound = problem.objective.lower_bound_per_mm  # cost >= bound * length, when declared
    k = len(goals)
    verdicts = [precheck(problem, goals[i], validator) for i in range(k)]
    open_goals = [i for i in range(k) if verdicts[i] is None]
    # the sampling region: the ball spanned by the start and the targets
    centre = 0.5 * (start[:3, 3] + goals.mean(axis=0))
    origin, axis = start[:3, 3].tolist(), start[:3, 2].tolist()
    radius = (
        0.5 * np.linalg.norm(goals.mean(axis=0) - start[:3, 3])
        + np.linalg.norm(goals - goals.mean(axis=0), axis=1).max()
        + 2 * tau
    )

    poses = [start]
    tree = np.empty((64, 4, 4))
    tree[0] = start
    parents = [-1]
    prims = [np.zeros(3)]
    costs = [0.0]
    lengths = [0.0]
    best = [math.inf] * k
    best_plans: list[SteerablePlan | None] = [None] * k
    history: list[list] = [[] for _ in range(k)]  # per target: [time_s, cost] of each plan

    def chain(idx: int) -> list:
        out = []
        while parents[idx] >= 0:
            out.append(prims[idx].tolist())
            idx = parents[idx]
        return out[::-1]

    def try_goals(idx: int) -> None:
        for i in open_goals:
            conn = connect(poses[idx], goals[i], r, tau)
            if conn is None or conn.primitives[0, 1] > kappa * (1 + 1e-12):
                continue
            if lengths[idx] + conn.length_mm >= problem.max_length_mm:
                continue
            if bound is not None and costs[idx] + bound * conn.length_mm >= best[i]:
                continue
            if not validator.primitives_valid(poses[idx], conn.primitives):
                continue
            cost = costs[idx] + chain_cost(problem, poses[idx], conn.primitives)
            if cost >= best[i]:
                continue
            plan = SteerablePlan(
                start, np.array(chain(idx) + conn.primitives.tolist()).reshape(-1, 3)
            )
            if not search.check(plan, None if single else goals[i]):
                continue
            run.improved(cost)
            history[i].append([run.elapsed_s, cost])
            best[i], best_plans[i] = cost, plan

    def sample() -> np.ndarray | None:
        unsolved = [i for i in open_goals if best_plans[i] is None]
        if unsolved and rng.random() < GOAL_BIAS:
            return goals[rng.choice(unsolved)]
        for _ in range(MAX_SAMPLE_TRIES):
            d = rng.normal(size=3)
            p = centre + radius * rng.random() ** (1 / 3) * d / np.linalg.norm(d)
            if is_reachable_unchecked(origin, axis, p.tolist(), r):
                return p
        return None

    single = k == 1 and np.allclose(goals[0], problem.goal_mm)
    try_goals(0)
    run.reason = "time limit"  # RRT never exhausts its space: it stops on its budget
    while open_goals and run.keep_going():
        if search.late_due():  # the finer proof of sealed goals, once, if still unsolved
            for i in [i for i in open_goals if best_plans[i] is None]:
                verdicts[i] = search.late_verdict(None if single else goals[i])
            open_goals[:] = [i for i in open_goals if verdicts[i] is None]
            if not open_goals:
                break
        q = sample()
        if q is None:
            continue
        near = int(np.argmin(arc_line_lengths_from_unchecked(tree[: len(poses)], q, r)))
        ext = single_arc_connection_unchecked(poses[near], q, r, math.inf)
        if ext is None:
            continue
        spin, kap, length = ext.primitives[0]
        if length <= 1e-9 or lengths[near] + length >= problem.max_length_mm:
            continue
        if not validator.motion_valid(poses[near], spin, kap, length):
            continue
        new_pose = arc_end_unchecked(poses[near], spin, kap, length)
        if len(poses) == tree.shape[0]:  # the poses as one array, grown by doubling
            tree = np.concatenate([tree, np.empty_like(tree)])
        tree[len(poses)] = new_pose
        poses.append(new_pose)
        parents.append(near)
        prims.append(np.array([spin, kap, length]))
        costs.append(costs[near] + motion_cost(problem, poses[near], spin, kap, length))
        lengths.append(lengths[near] + length)
        try_goals(len(poses) - 1)

    out = []
    stats = {"nodes": len(poses), "connection": connection}
    pts = np.array(poses)[:, :3, 3]
    for i in range(k):
        goal = None if single else goals[i]
        stats["cost_history"] = history[i]
        stats["first_solution_s"] = history[i][0][0] if history[i] else None
        if verdicts[i] is not None:
            out.append(search.result(verdicts[i][0], goal_mm=goal, reason=verdicts[i][1], **stats))
        elif best_plans[i] is not None:
            out.append(search.result(PlanStatus.SOLVED, best_plans[i], best[i], goal, **stats))
        else:  # the valid tree path that ended nearest the target
            idx = int(np.argmin(np.linalg.norm(pts - goals[i], axis=1)))
            out.append(search.approximate(chain(idx), costs[idx], goal, **stats))
    return out
