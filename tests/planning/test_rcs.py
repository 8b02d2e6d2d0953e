"""RCS and RCS*: optimal at the root when the direct connection is free, plans around
obstacles that pass the independent check, RCS* no worse than RCS, termination."""

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.goal import goal_connection
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.planning.steerable.verify import verify_approximate, verify_plan

GOAL = np.array([0.0, -20.0, 60.0])


def _problem(*obstacles, goal=GOAL, **kw):
    structures = [Structure("region", Role.ALLOWED_REGION, Sphere([0, 0, 30], 120.0))]
    structures += [Structure(f"obstacle{i}", Role.OBSTACLE, f) for i, f in enumerate(obstacles)]
    return SteerableProblem(
        Scene(structures), goal_mm=goal, start_pose=np.eye(4), r_min_mm=50.0, **kw
    )


def test_free_direct_connection_is_certified_at_the_root():
    prob = _problem()
    res = solve_rcs(prob, time_limit_s=60.0)  # the search ends it, never the clock
    h0 = goal_connection(np.eye(4), GOAL, 50.0, 1.0).length_mm
    assert res.status is PlanStatus.SOLVED and res.stats["certified"]
    assert (res.stats["iterations"], res.stats["reason"]) == (5, "search space exhausted")
    assert res.cost_mm == pytest.approx(h0)
    assert verify_plan(prob, res.plan).ok


def test_plans_around_an_obstacle_and_rcs_star_is_no_worse_than_rcs():
    # a vessel across the middle of the direct connection
    direct = goal_connection(np.eye(4), GOAL, 50.0, 1.0)
    mid = SteerablePlan(np.eye(4), direct.primitives).points_mm(0.5)
    mid = mid[len(mid) // 2]
    blocker = Capsule(mid + [-20.0, 0.0, 0.0], mid + [20.0, 0.0, 0.0], 3.0)
    prob = _problem(blocker)
    # iteration budgets (the 60 s clock never ends them): the same plans on any machine
    star = solve_rcs(prob, time_limit_s=60.0, max_iterations=300)
    rcs = solve_rcs(prob, time_limit_s=60.0, max_iterations=300, optimal=False)
    assert star.status is PlanStatus.SOLVED and rcs.status is PlanStatus.SOLVED
    for res in (star, rcs):
        assert res.stats["iterations"] == 300 and res.stats["reason"] == "iteration limit"
    assert star.cost_mm == pytest.approx(63.42908917682746, abs=1e-6)
    assert rcs.cost_mm == pytest.approx(64.6431852907362, abs=1e-6)
    for res in (star, rcs):
        v = verify_plan(prob, res.plan)
        assert v.ok, v.violations
        assert res.cost_mm == pytest.approx(res.plan.length_mm, abs=1e-6)
    assert star.cost_mm > direct.length_mm  # the detour costs something
    assert star.cost_mm <= rcs.cost_mm + 1e-9


def test_no_plan_exists_terminates_within_budget():
    # a wall of touching tubes across the whole region between start and goal
    wall = [
        Capsule([x, -130.0, 40.0], [x, 130.0, 40.0], 1.6) for x in np.arange(-130.0, 131.0, 3.0)
    ]
    prob = _problem(*wall)
    # an iteration budget ends the search (the 60 s clock never does): the same outcome on
    # any machine, whatever its load
    res = solve_rcs(prob, time_limit_s=60.0, max_iterations=200)
    assert res.stats["iterations"] == 200 and res.stats["reason"] == "iteration limit"
    assert not res.stats["certified"] and not res.stats["exhausted"]
    # the nearest valid path, short of the goal: every rule but the goal holds
    assert res.status is PlanStatus.APPROXIMATE
    assert res.stats["goal_distance_mm"] == pytest.approx(23.76169049535087, abs=1e-6)
    gap = np.linalg.norm(res.plan.end_pose()[:3, 3] - GOAL)
    assert gap == pytest.approx(res.stats["goal_distance_mm"], abs=1e-9)
    assert res.cost_mm == pytest.approx(40.0, abs=1e-6)
    assert [v.split(":")[0] for v in verify_plan(prob, res.plan).violations] == ["goal"]
    check = verify_approximate(prob, res.plan)
    assert check.ok, check.violations
    # RCS (not optimal) processes its nodes in another order and ends the same way
    rcs = solve_rcs(prob, time_limit_s=60.0, max_iterations=200, optimal=False)
    assert (rcs.status, rcs.stats["iterations"], rcs.stats["reason"]) == (
        PlanStatus.APPROXIMATE,
        200,
        "iteration limit",
    )
    assert rcs.stats["goal_distance_mm"] == pytest.approx(23.76169049535087, abs=1e-6)


def test_unreachable_goal_and_invalid_start():
    inside_torus = _problem(goal=np.array([0.0, -40.0, 10.0]))
    res = solve_rcs(inside_torus)
    assert res.status is PlanStatus.INFEASIBLE and "reachable set" in res.stats["reason"]
    blocked_start = _problem(Sphere([0.0, 0.0, 0.0], 10.0), start_exclusion_mm=0.0)
    assert solve_rcs(blocked_start).status is PlanStatus.INVALID_PROBLEM
    with pytest.raises(InvalidInputError, match="start_pose"):
        solve_rcs(SteerableProblem(Scene([]), goal_mm=GOAL, start_point_mm=[0, 0, 0]))
    with pytest.raises(InvalidInputError, match="time_limit_s"):
        solve_rcs(_problem(), time_limit_s=0.0)


def test_result_json_has_the_plan_file_fields():
    res = solve_rcs(_problem(), time_limit_s=60.0)  # certified after 5 iterations
    assert res.stats["reason"] == "search space exhausted"
    d = res.to_dict()
    for key in (
        "status",
        "planner",
        "cost_mm",
        "length_mm",
        "time_s",
        "primitives",
        "points_mm",
        "start_pose",
        "goal_mm",
    ):
        assert key in d
    assert d["status"] == "solved" and d["planner"] == "rcs_star"
    pts = np.array(d["points_mm"])
    assert np.linalg.norm(np.diff(pts, axis=0), axis=1).max() <= 0.5 + 1e-9
    assert set(d["primitives"][0]) == {"rotation_rad", "curvature_per_mm", "length_mm"}


@pytest.mark.parametrize("planner", ["rcs_star", "rcs", "rrt"])
def test_out_of_budget_the_nearest_valid_path_comes_back_as_approximate(planner):
    from needlekit.planning.steerable.solve import solve

    wall = [
        Capsule([x, -130.0, 40.0], [x, 130.0, 40.0], 1.6) for x in np.arange(-130.0, 131.0, 3.0)
    ]
    prob = _problem(*wall)
    res = solve(prob, planner, time_limit_s=60.0, max_iterations=300, seed=0)
    assert res.status is PlanStatus.APPROXIMATE and res.status is not PlanStatus.SOLVED
    gap = np.linalg.norm(res.plan.end_pose()[:3, 3] - GOAL)
    assert res.stats["goal_distance_mm"] == pytest.approx(gap) and gap > prob.goal_tolerance_mm
    assert gap < np.linalg.norm(GOAL)  # nearer than the start
    check = verify_approximate(prob, res.plan)
    assert check.ok, check.violations  # every rule but the goal holds
    assert [v.split(":")[0] for v in verify_plan(prob, res.plan).violations] == ["goal"]
    assert res.cost_mm == pytest.approx(res.plan.length_mm)
