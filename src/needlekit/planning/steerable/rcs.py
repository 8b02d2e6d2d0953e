"""RCS and RCS*: resolution-complete and resolution-optimal search over needle motions.

The search tree holds tip poses; an edge is a motion primitive ``(spin, curvature,
length)`` with curvature 0 or ``1 / r_min``. Primitives come in resolution levels:

- lengths: 16 mm (level 0), then refined by halving steps down to 0.125 mm (level 7):
  8; 12, 4; 14, 10, 6, 2; ...;
- spins (curved primitives only): {0, pi/2, pi, 3pi/2} (level 0), then refined by halving
  the step down to pi/32 (level 4).

Expanding a valid node adds its 5 coarsest children (4 curved, 1 straight, 16 mm). When a
node is processed, its refinements are added as siblings: shorter, longer (by the next
halving step), spun left and right (curved only). A node's rank is its parent's rank plus
its length and spin levels plus one, so coarse motions come first.

Duplicates: a motion is defined by its *spun start pose* (the parent's pose turned by the
spin) and its kind and length, so a child whose spun start pose another parent reaches
(within :data:`DUPLICATE_TOL`, SE(3) metric ``10 * angle + distance``) is dropped: in
RCS whenever another parent holds the pose, in RCS* when that parent got there no more
expensively. Motions that only extend their parent's (same kind, spin 0, after a refined
length) are not expanded either.

RCS processes the lowest rank first. RCS* orders by cost ``f = g + h``, with ``h`` the
length of the shortest turn-then-straight connection to within tau of the goal
(:func:`~needlekit.planning.steerable.goal.goal_connection`), among the ranks within
:data:`LOOKAHEAD_RANKS` of the lowest one queued; it drops nodes whose parent cannot beat
the best plan, skips expanding nodes that cannot, and treats the goal as unreachable from
nodes with no connection (behind, or deep inside the r_min torus). When its queue empties,
the best plan is certified optimal at the finest resolution; with no plan, the problem is
infeasible at that resolution. Every node tries the goal connection (RCS*: turn then
straight, ending tau short; RCS: one arc to the goal).

A warm start (plans given to begin from, e.g. the rest of a plan being executed) is
checked first: the cheapest that passes the independent check is the first best plan,
pruned against from the first node and returned when the search finds nothing cheaper.

The primitive scheme, ranking, look-ahead and connections follow the reference
implementation of RCS* by its authors (notes in ``docs/notes/steerable-reference-planner.md``).
"""

from __future__ import annotations

import functools
import heapq
import itertools
import logging
import math
from dataclasses import dataclass

import numpy as np

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import Termination, cyclic_gc_paused
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable._rcs_kernels import child_motion, se3_gap
from needlekit.planning.steerable.cost import chain_cost, motion_cost
from needlekit.planning.steerable.goal import (
    connection_length_unchecked,
    goal_connection_unchecked,
    single_arc_connection_unchecked,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.search import SteerableSearch, precheck

__all__ = [
    "LOOKAHEAD_RANKS",
    "RCSOptions",
    "RCSPlanner",
    "RCSStarPlanner",
    "Resolution",
    "solve_rcs",
]

log = logging.getLogger(__name__)

#: RCS* compares f among the ranks within this many of the lowest queued rank.
LOOKAHEAD_RANKS = 3
#: Slack of the pruning comparisons (mm): rounding only.
PRUNE_EPS_MM = 1e-10
#: Two spun start poses are the same within this SE(3) distance (10 * angle + distance):
#: numerically identical poses only, as in the reference planner.
DUPLICATE_TOL = 1e-6


@dataclass(frozen=True)
class Resolution:
    """The motion primitives' resolution levels.

    Attributes
    ----------
    max_length_mm : float
        Longest primitive (level 0).
    length_levels : int
        Halving levels below it (finest step ``max_length_mm / 2**length_levels``).
    spin_levels : int
        Halving levels of the spin below pi/2 (finest ``pi / 2**(spin_levels + 1)``).

    Examples
    --------
    >>> r = Resolution(max_length_mm=8.0, length_levels=2, spin_levels=1)
    >>> sorted(r.lengths().tolist()), len(r.spins())
    ([2.0, 4.0, 6.0, 8.0], 8)
    """

    max_length_mm: float = 16.0
    length_levels: int = 7
    spin_levels: int = 4

    def __post_init__(self) -> None:
        if not (np.isfinite(self.max_length_mm) and self.max_length_mm > 0):
            raise InvalidInputError("max_length_mm", f"must be > 0, got {self.max_length_mm}")
        for name in ("length_levels", "spin_levels"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 12:
                raise InvalidInputError(name, f"expected a whole number in [0, 12], got {v!r}")

    def lengths(self) -> np.ndarray:
        """Primitive lengths by index (index ``i`` refines index ``i // 2``).

        Returns
        -------
        ndarray, shape (2**length_levels,)
        """
        return _tables(self)[0]

    def spins(self) -> np.ndarray:
        """Spins by index (indices 0-3: multiples of pi/2; ``i`` refines ``i // 2``).

        Returns
        -------
        ndarray, shape (4 * 2**spin_levels,)
        """
        return _tables(self)[2]


@functools.lru_cache(maxsize=16)
def _tables(res: Resolution):
    n = 2**res.length_levels
    top = res.max_length_mm
    lengths, llev = np.zeros(n), np.zeros(n, dtype=np.int64)
    lengths[0] = top
    if n > 1:
        lengths[1], llev[1] = top / 2, 1
    for i in range(2, n):
        parent = i // 2
        llev[i] = llev[parent] + 1
        step = top / 2 ** (llev[parent] + 1)
        lengths[i] = lengths[parent] + (step if i % 2 == 0 else -step)
    m = 4 * 2**res.spin_levels
    spins, slev = np.zeros(m), np.zeros(m, dtype=np.int64)
    for i in range(4):
        spins[i] = i * math.pi / 2
    for i in range(4, min(8, m)):
        spins[i], slev[i] = spins[i - 4] + math.pi / 4, 1
    for i in range(8, m):
        parent = i // 2
        slev[i] = slev[parent] + 1
        step = (math.pi / 2) / 2 ** (slev[parent] + 1)
        spins[i] = spins[parent] + (step if i % 2 == 0 else -step)
    return lengths, llev, spins, slev


class _DuplicateIndex:
    """Spun start poses by cell; finds another parent's pose within the tolerance.

    A pose's cell quantises its position and its x axis (the axis a spin turns) in steps
    of ``1000 * tol``. Two poses within ``tol`` in the SE(3) metric differ by at most
    ``tol`` in every coordinate of both (``|R - Q|_F <= tol * sqrt(2) / 10``), so they lie
    in the same cell or, only when one sits within ``tol`` of a cell face, in a
    neighbouring one: just those cells are visited. Spins of one parent share a position
    but not an x axis, so they do not crowd one cell.
    """

    def __init__(self, tol: float = DUPLICATE_TOL) -> None:
        self.tol = tol
        self.cell = 1e3 * tol
        self.cells: dict[tuple, list] = {}

    def _cells(self, pose) -> list:
        """Every cell that may hold a pose within ``tol`` of this one."""
        keys: list[tuple] = [()]
        for v in (pose[0, 3], pose[1, 3], pose[2, 3], pose[0, 0], pose[1, 0], pose[2, 0]):
            q = float(v) / self.cell
            k = math.floor(q)
            f = q - k
            near = [k]
            if f * self.cell <= self.tol:
                near.append(k - 1)
            if (1.0 - f) * self.cell <= self.tol:
                near.append(k + 1)
            keys = [(*key, n) for key in keys for n in near]
        return keys

    def check_and_add(
        self, pose: np.ndarray, home: tuple, near_face: bool, parent: int, g_parent: float,
        optimal: bool,
    ) -> bool:  # fmt: skip
        """False when another parent holds this pose (no more expensively, for RCS*).

        ``home`` is the pose's own cell and ``near_face`` whether it lies within the
        tolerance of a cell face (:func:`~needlekit.planning.steerable._rcs_kernels.child_motion`).
        """
        mine = False
        for key in self._cells(pose) if near_face else (home,):
            for q, other, g_other in self.cells.get(key, ()):
                if se3_gap(pose, q) > self.tol:
                    continue
                if other == parent:
                    mine = True
                elif not optimal or g_other < g_parent + PRUNE_EPS_MM:
                    return False
        if not mine:
            self.cells.setdefault(home, []).append((pose, parent, g_parent))
        return True


@dataclass
class _Node:
    pose: np.ndarray
    parent: int
    g: float
    h: float
    s: float
    rank: int
    curved: bool
    li: int
    si: int
    explored: set | None = None
    f: float = 0.0  # g + (the objective's bound per mm) * h: a lower bound of the plan's cost


def _cost_to_go(pose, problem: SteerableProblem) -> float:
    # the shortest turn-then-straight length: times the objective's bound per mm, a lower
    # bound of the cost to the goal
    return connection_length_unchecked(
        pose, problem.goal_mm, problem.r_min_mm, problem.goal_tolerance_mm
    )


@dataclass(frozen=True)
class RCSOptions:
    """Settings of RCS and RCS*.

    Attributes
    ----------
    resolution : Resolution
        Primitive resolution (default: 16 mm to 0.125 mm, spins down to pi/32); a mapping
        of its fields in scenario files.
    """

    resolution: Resolution = Resolution()

    def __post_init__(self) -> None:
        if not isinstance(self.resolution, Resolution):
            raise InvalidInputError(
                "resolution", f"expected a Resolution, got {type(self.resolution).__name__}"
            )


class RCSStarPlanner:
    """RCS*: cost-ordered, resolution-optimal; certifies its plan when the search ends."""

    name = "rcs_star"
    family = "steerable"
    #: Its solve takes ``warm_start=`` plans (a re-planner of ``needlekit execute``).
    capabilities = ("warm_start",)
    options_type = RCSOptions
    optimal = True

    def __init__(self, options: RCSOptions | None = None) -> None:
        self.options = RCSOptions() if options is None else options

    def solve(
        self, problem: SteerableProblem, termination: Termination, *, warm_start=()
    ) -> PlanResult:
        """Plan (see :func:`solve_rcs`).

        Parameters
        ----------
        problem : SteerableProblem
        termination : Termination
        warm_start : sequence of SteerablePlan
            See :func:`solve_rcs`.

        Returns
        -------
        PlanResult
        """
        return _search(
            problem, termination, self.optimal, self.name, self.options.resolution, warm_start
        )


class RCSPlanner(RCSStarPlanner):
    """RCS: rank-ordered, resolution-complete and anytime."""

    name = "rcs"
    optimal = False


def solve_rcs(
    problem: SteerableProblem,
    *,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    optimal: bool = True,
    max_iterations: int | None = None,
    resolution: Resolution | None = None,
    warm_start=(),
) -> PlanResult:
    """Plan with RCS* (``optimal=True``) or RCS.

    Parameters
    ----------
    problem : SteerableProblem
        Needs a start pose.
    time_limit_s : float
        Budget; the best plan so far is returned when it runs out.
    optimal : bool
        RCS* (cost-ordered, certifies optimality at the finest resolution) or RCS.
    max_iterations : int, optional
        Budget in processed nodes.
    resolution : Resolution, optional
        Primitive resolution (default: 16 mm to 0.125 mm, spins down to pi/32).
    warm_start : sequence of SteerablePlan
        Plans from the start pose to the goal to start from: the cheapest that passes the
        independent check is the first best plan (``stats["warm_start"]``: ``"adopted"``
        or ``"none passed"``), so RCS* prunes against it from the first node and returns it
        when nothing cheaper turns up in the budget. An empty finished search certifies
        that no plan at the finest resolution beats it.

    Returns
    -------
    PlanResult
        ``SOLVED`` (``stats["certified"]`` when the search finished), ``INFEASIBLE`` (no
        plan at the finest resolution, or a verdict of the pre-checks,
        :mod:`needlekit.planning.steerable.search`), ``APPROXIMATE`` (the budget ran out:
        the valid path that ended nearest the goal, ``stats["goal_distance_mm"]``),
        ``TIMEOUT`` (not even that) or ``INVALID_PROBLEM``.
    """
    planner = (RCSStarPlanner if optimal else RCSPlanner)(
        RCSOptions(Resolution() if resolution is None else resolution)
    )
    return planner.solve(problem, Termination(time_limit_s, max_iterations), warm_start=warm_start)


class _RankQueue:
    """Nodes waiting by rank: RCS pops the lowest rank first (in insertion order), RCS*
    the lowest cost ``f`` among the ranks within :data:`LOOKAHEAD_RANKS` of the lowest."""

    def __init__(self, optimal: bool) -> None:
        self.optimal = optimal
        self.buckets: dict[int, list] = {}
        self.counter = itertools.count()

    def __bool__(self) -> bool:
        return bool(self.buckets)

    def push(self, rank: int, f: float, idx: int) -> None:
        key = (f, next(self.counter), idx) if self.optimal else (next(self.counter), idx)
        heapq.heappush(self.buckets.setdefault(rank, []), key)

    def pop(self) -> int:
        buckets = self.buckets
        r0 = min(buckets)
        if self.optimal:
            choice = min(
                (r for r in range(r0, r0 + LOOKAHEAD_RANKS + 1) if r in buckets),
                key=lambda r: (buckets[r][0][0], r),
            )
        else:
            choice = r0
        item = heapq.heappop(buckets[choice])
        if not buckets[choice]:
            del buckets[choice]
        return item[-1]


@cyclic_gc_paused
def _search(
    problem: SteerableProblem,
    termination: Termination,
    optimal: bool,
    name: str,
    res: Resolution,
    warm_start=(),
) -> PlanResult:
    search = SteerableSearch(problem, termination, name)
    run = search.run
    validator = search.validator
    start, goal = problem.start_pose, problem.goal_mm
    verdict = precheck(problem, goal, validator)
    if verdict is not None:
        return search.result(verdict[0], reason=verdict[1])
    h0 = _cost_to_go(start, problem)
    _, length_level, _, spin_level = _tables(res)
    length_levels, spin_levels = res.length_levels, res.spin_levels
    kappa = problem.kappa_max_per_mm
    duplicates = _DuplicateIndex()
    n_duplicates = 0
    connect = goal_connection_unchecked if optimal else single_arc_connection_unchecked
    bound = problem.objective.lower_bound_per_mm
    scale = 0.0 if bound is None else float(bound)  # no bound: order by g, prune nothing
    prune = optimal and bound is not None
    nodes = [_Node(start, -1, 0.0, h0, 0.0, 0, False, 0, 0, set(), scale * h0)]
    queue = _RankQueue(optimal)
    push_node, pop = queue.push, queue.pop
    best, best_plan = search.warm_start(warm_start)
    warm_plan = best_plan

    goal_c = np.ascontiguousarray(goal, dtype=np.float64)
    r_min, tau = problem.r_min_mm, problem.goal_tolerance_mm
    length_cost = bool(getattr(problem.objective, "exact_length", False))
    spin_list, length_list, spin_rank, length_rank = _table_lists(res)
    dup_cell, dup_tol = duplicates.cell, duplicates.tol

    def add_child(parent_idx: int, curved: bool, li: int, si: int) -> None:
        nonlocal n_duplicates
        parent = nodes[parent_idx]
        key = (curved, li, si)
        if key in parent.explored:
            return
        parent.explored.add(key)
        spin = spin_list[si] if curved else 0.0
        length = length_list[li]
        k = kappa if curved else 0.0
        spun, home, near, pose, h = child_motion(
            parent.pose, spin, k, length, goal_c, r_min, tau, dup_cell, dup_tol
        )
        if curved and not duplicates.check_and_add(spun, home, near, parent_idx, parent.g, optimal):
            n_duplicates += 1
            return
        rank = parent.rank + length_rank[li] + (spin_rank[si] if curved else 0) + 1
        g = parent.g + (
            length if length_cost else motion_cost(problem, parent.pose, spin, k, length)
        )
        f = g + scale * h
        nodes.append(
            _Node(pose, parent_idx, g, h, parent.s + length, rank, curved, li, si, set(), f)
        )
        push_node(rank, f, len(nodes) - 1)

    def expand(idx: int) -> None:
        for si in range(4):
            add_child(idx, True, 0, si)
        add_child(idx, False, 0, 0)

    def refine(idx: int) -> None:
        n = nodes[idx]
        a, b = int(length_level[n.li]), int(spin_level[n.si])
        if a < length_levels:
            add_child(n.parent, n.curved, 1 if a == 0 else 2 * n.li + 1, n.si)
        if 0 < a < length_levels:
            add_child(n.parent, n.curved, 2 * n.li, n.si)
        if n.curved and b < spin_levels:
            add_child(n.parent, True, n.li, n.si + 4 if b == 0 else 2 * n.si)
        if n.curved and 0 < b < spin_levels:
            add_child(n.parent, True, n.li, 2 * n.si + 1)

    def chain(idx: int) -> list:
        return _chain(nodes, idx, spin_list, kappa, length_list)

    def try_goal(idx: int) -> None:
        nonlocal best, best_plan
        n = nodes[idx]
        conn = connect(n.pose, goal, problem.r_min_mm, problem.goal_tolerance_mm)
        if conn is None:
            return
        if n.s + conn.length_mm >= problem.max_length_mm:
            return
        if bound is not None and n.g + bound * conn.length_mm >= best - PRUNE_EPS_MM:
            return  # the objective's bound: no cheaper than this
        if not validator.primitives_valid(n.pose, conn.primitives):
            return
        cost = n.g + chain_cost(problem, n.pose, conn.primitives)
        if cost >= best - PRUNE_EPS_MM:
            return
        plan = SteerablePlan(start, np.array(chain(idx) + conn.primitives.tolist()).reshape(-1, 3))
        if search.check(plan):
            best, best_plan = cost, plan
            run.improved(cost)

    closest = (float(np.linalg.norm(start[:3, 3] - goal)), 0)  # (goal distance, node)
    try_goal(0)
    expand(0)
    while queue and run.keep_going():
        if best_plan is None and search.late_due() and (late := search.late_verdict()):
            stats = _stats(problem, optimal, prune, False, None, len(nodes), n_duplicates)
            return search.result(late[0], reason=late[1], **stats)
        idx = pop()
        n = nodes[idx]
        parent = nodes[n.parent]
        if prune and best < parent.f + PRUNE_EPS_MM:
            continue  # nothing in this family can beat the best plan
        refine(idx)
        # a spin-0 motion of the parent's kind after a shorter parent motion just extends it
        if n.si == 0 and n.parent > 0 and n.curved == parent.curved and parent.li != 0:
            continue
        if n.s >= problem.max_length_mm or not math.isfinite(n.h):
            continue
        if prune and best < n.f + PRUNE_EPS_MM:
            continue
        spin = spin_list[n.si] if n.curved else 0.0
        if not validator.motion_valid(
            parent.pose, spin, kappa if n.curved else 0.0, length_list[n.li]
        ):
            continue
        gap = float(np.linalg.norm(n.pose[:3, 3] - goal))
        if gap < closest[0]:
            closest = (gap, idx)
        try_goal(idx)
        expand(idx)

    stats = _stats(problem, optimal, prune, not queue, best_plan, len(nodes), n_duplicates)
    if warm_start:
        stats["warm_start"] = "none passed" if warm_plan is None else "adopted"
        stats["warm_start_kept"] = warm_plan is not None and best_plan is warm_plan
    if best_plan is not None:
        return search.result(PlanStatus.SOLVED, best_plan, best, **stats)
    if stats["exhausted"]:
        return search.result(
            PlanStatus.INFEASIBLE, reason="no plan at the finest resolution", **stats
        )
    # the valid path that got nearest the goal
    return search.approximate(chain(closest[1]), nodes[closest[1]].g, **stats)


def _table_lists(res: Resolution) -> tuple[list, list, list, list]:
    """The primitive tables as Python lists (spins, lengths, their levels): cheaper to
    index in the search loop than arrays."""
    lengths, length_level, spins, spin_level = _tables(res)
    return (
        [float(v) for v in spins],
        [float(v) for v in lengths],
        [int(v) for v in spin_level],
        [int(v) for v in length_level],
    )


def _chain(nodes: list, idx: int, spins: list, kappa: float, lengths: list) -> list:
    """The primitives ``[spin, kappa, length]`` from the root to node ``idx``."""
    prims = []
    while nodes[idx].parent >= 0:
        n = nodes[idx]
        prims.append([spins[n.si] if n.curved else 0.0, kappa if n.curved else 0.0, lengths[n.li]])
        idx = n.parent
    return prims[::-1]


def _stats(problem, optimal, prune, exhausted, best_plan, n_nodes, n_duplicates) -> dict:
    """The search's own figures beside those every run records."""
    stats = {
        "nodes": n_nodes,
        "certified": bool(exhausted and prune and best_plan is not None),
        "exhausted": exhausted,
        "duplicates": n_duplicates,
    }
    if optimal and problem.objective.lower_bound_per_mm is None:
        stats["not_certified"] = (
            f"the cost {problem.objective.name!r} declares no lower bound per mm, so the "
            "search cannot prove its plan optimal"
        )
    return stats
