"""Plan costs (path length, clearance cost map) and RCS* optimality against brute force."""

import math

import numpy as np
import pytest

from needlekit.anatomy.primitives import HalfSpace, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import propagate_arcs
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.cost import chain_cost, clearance_cost_rate, plan_cost
from needlekit.planning.steerable.goal import goal_connection
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import CostKind, SteerableProblem
from needlekit.planning.steerable.rcs import Resolution, solve_rcs
from needlekit.planning.steerable.rrt import solve_rrt
from needlekit.planning.steerable.validity import MotionValidator
from needlekit.planning.steerable.verify import verify_plan


def _wall_problem(**kw):
    # an obstacle filling x < -5: a needle of radius 0.5 along the z axis keeps 4.5 mm
    wall = Structure("wall", Role.OBSTACLE, HalfSpace([-5.0, 0.0, 0.0], [1.0, 0.0, 0.0]))
    return SteerableProblem(Scene([wall]), goal_mm=[0.0, 0.0, 40.0], start_pose=np.eye(4), **kw)


def test_path_length_cost_is_the_length():
    prob = _wall_problem()
    plan = SteerablePlan(np.eye(4), np.array([[0.3, 0.02, 10.0], [1.0, 0.0, 7.5]]))
    assert plan_cost(prob, plan) == pytest.approx(plan.length_mm, abs=1e-12)


def test_clearance_cost_of_a_straight_path_beside_a_wall_is_analytic():
    w, reach = 2.0, 10.0
    prob = _wall_problem(cost=CostKind.CLEARANCE, cost_weight=w, cost_reach_mm=reach)
    rate = 1.0 + w * (1.0 - 4.5 / reach)
    plan = SteerablePlan(np.eye(4), np.array([[0.0, 0.0, 30.0]]))
    assert plan_cost(prob, plan) == pytest.approx(rate * 30.0, rel=1e-12)
    # leaving the wall at angle b: clearance 4.5 + s sin b, linear in s until it reaches R
    b = math.radians(10.0)
    tilt = np.eye(4)
    tilt[:3, :3] = [[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]]
    s_reach = (reach - 4.5) / math.sin(b)
    exact = s_reach + w * (s_reach - (4.5 * s_reach + 0.5 * s_reach**2 * math.sin(b)) / reach)
    exact += 40.0 - s_reach  # beyond the reach every mm costs 1
    costs = [
        chain_cost(prob, tilt, [[0.0, 0.0, s_reach], [0.0, 0.0, 40.0 - s_reach]], spacing_mm=sp)
        for sp in (0.5, 0.05)
    ]
    assert costs[0] == pytest.approx(exact, rel=1e-12) == costs[1]


def test_clearance_cost_rate_is_at_least_one_and_validated():
    prob = _wall_problem(cost="clearance", cost_weight=3.0, cost_reach_mm=2.0)
    pts = np.array([[-4.5, 0, 0], [-3.5, 0, 0], [10.0, 0, 0]])
    np.testing.assert_allclose(clearance_cost_rate(prob, pts), [4.0, 2.5, 1.0])
    for field, value in [("cost", "risk"), ("cost_weight", -1.0), ("cost_reach_mm", 0.0)]:
        with pytest.raises(InvalidInputError, match=field):
            _wall_problem(**{field: value})


def test_verify_recomputes_the_claimed_cost():
    prob = _wall_problem(cost="clearance", cost_weight=1.0)
    conn = goal_connection(np.eye(4), prob.goal_mm, prob.r_min_mm, prob.goal_tolerance_mm)
    plan = SteerablePlan(np.eye(4), conn.primitives)
    cost = plan_cost(prob, plan)
    assert verify_plan(prob, plan, expected_cost_mm=cost).ok
    bad = verify_plan(prob, plan, expected_cost_mm=plan.length_mm)
    assert not bad.ok and bad.violations[0].startswith("cost:")


def _brute_force(problem, res: Resolution, bound: float) -> float:
    """Cheapest plan below ``bound`` over every sequence of the resolution's primitives
    followed by the turn-then-straight goal connection: exhaustive depth-first enumeration,
    cut only by collisions, the length limit and the Euclidean lower bound of the
    remaining cost (inf when no plan is cheaper than ``bound``)."""
    lengths, spins = res.lengths(), res.spins()
    kappa = problem.kappa_max_per_mm
    motions = [(s, kappa, ell) for s in spins for ell in lengths]
    motions += [(0.0, 0.0, ell) for ell in lengths]
    val = MotionValidator(problem)
    goal, tau, r = problem.goal_mm, problem.goal_tolerance_mm, problem.r_min_mm
    best = bound
    visited = 0

    def visit(pose, g, s):
        nonlocal best, visited
        visited += 1
        conn = goal_connection(pose, goal, r, tau)
        if conn is not None and s + conn.length_mm < problem.max_length_mm:
            if val.primitives_valid(pose, conn.primitives):
                best = min(best, g + chain_cost(problem, pose, conn.primitives))
        for spin, k, ell in motions:
            if s + ell >= problem.max_length_mm:
                continue
            end = propagate_arcs(pose, spin, k, ell)
            g2 = g + chain_cost(problem, pose, [[spin, k, ell]])
            if g2 + max(0.0, np.linalg.norm(end[:3, 3] - goal) - tau) >= best:
                continue
            if val.motion_valid(pose, spin, k, ell):
                visit(end, g2, s + ell)

    visit(problem.start_pose, 0.0, 0.0)
    assert visited > 50  # the enumeration really branched
    return best if best < bound else math.inf


def _tiny_problem(cost):
    # a ball on the straight route and a wall beside it, small enough to enumerate
    structures = [
        Structure("ball", Role.OBSTACLE, Sphere([0.0, 0.0, 12.0], 3.5)),
        Structure("wall", Role.OBSTACLE, HalfSpace([-7.0, 0.0, 0.0], [1.0, 0.0, 0.0])),
    ]
    return SteerableProblem(
        Scene(structures), goal_mm=[0.0, 0.0, 24.0], start_pose=np.eye(4), r_min_mm=10.0,
        max_length_mm=36.0, cost=cost, cost_weight=4.0, cost_reach_mm=4.0,
    )  # fmt: skip


def test_clearance_cost_trades_length_for_clearance():
    res = Resolution(max_length_mm=8.0, length_levels=1, spin_levels=1)
    by_length = solve_rcs(_tiny_problem(CostKind.PATH_LENGTH), time_limit_s=60.0, resolution=res)
    clear_prob = _tiny_problem(CostKind.CLEARANCE)
    by_clearance = solve_rcs(clear_prob, time_limit_s=60.0, resolution=res)
    for r in (by_length, by_clearance):
        assert r.status is PlanStatus.SOLVED and r.stats["certified"]
    v_len = verify_plan(clear_prob, by_length.plan)
    v_clear = verify_plan(clear_prob, by_clearance.plan, expected_cost_mm=by_clearance.cost_mm)
    assert v_clear.ok, v_clear.violations
    # each plan is the best at its own objective, and they differ
    assert by_length.cost_mm < by_clearance.plan.length_mm - 0.1
    assert by_clearance.cost_mm < v_len.metrics["cost"] - 0.1
    assert v_clear.metrics["min_clearance_mm"] > v_len.metrics["min_clearance_mm"]
    rrt = solve_rrt(clear_prob, time_limit_s=60.0, seed=1, max_iterations=2000)
    assert rrt.status is PlanStatus.SOLVED
    assert verify_plan(clear_prob, rrt.plan, expected_cost_mm=rrt.cost_mm).ok


@pytest.mark.slow
@pytest.mark.parametrize(
    ("cost", "spin_levels"), [(CostKind.PATH_LENGTH, 1), (CostKind.CLEARANCE, 0)]
)
def test_rcs_star_is_optimal_against_brute_force_on_a_tiny_problem(cost, spin_levels):
    res = Resolution(max_length_mm=8.0, length_levels=1, spin_levels=spin_levels)
    prob = _tiny_problem(cost)
    star = solve_rcs(prob, time_limit_s=60.0, resolution=res)
    assert star.status is PlanStatus.SOLVED and star.stats["certified"]
    assert verify_plan(prob, star.plan, expected_cost_mm=star.cost_mm).ok
    # the enumeration looks for anything cheaper than RCS*'s plan (and finds that plan)
    assert _brute_force(prob, res, bound=star.cost_mm + 1e-6) == pytest.approx(
        star.cost_mm, abs=1e-9
    )
    rcs = solve_rcs(prob, time_limit_s=60.0, resolution=res, optimal=False, max_iterations=3000)
    assert rcs.status is PlanStatus.SOLVED and rcs.cost_mm >= star.cost_mm - 1e-9


def test_resolution_tables_and_errors():
    r = Resolution(max_length_mm=16.0, length_levels=2, spin_levels=1)
    assert sorted(r.lengths().tolist()) == [4.0, 8.0, 12.0, 16.0]
    np.testing.assert_allclose(np.sort(r.spins()), np.arange(8) * math.pi / 4)
    default = Resolution()
    assert default.lengths().min() == 0.125 and len(default.spins()) == 64
    with pytest.raises(InvalidInputError, match="length_levels"):
        Resolution(length_levels=-1)
    with pytest.raises(InvalidInputError, match="resolution"):
        solve_rcs(_tiny_problem(CostKind.PATH_LENGTH), resolution=(16.0, 7, 4))
