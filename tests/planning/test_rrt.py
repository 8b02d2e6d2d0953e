"""RRT: seeded determinism, success over seeds, one tree to several targets, budgets."""

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.planning.steerable.rrt import solve_rrt, solve_rrt_multi, solve_rrt_per_target
from needlekit.planning.steerable.verify import verify_approximate, verify_plan

GOAL = np.array([0.0, -20.0, 60.0])


def _problem(*obstacles, goal=GOAL):
    structures = [Structure("region", Role.ALLOWED_REGION, Sphere([0, 0, 30], 120.0))]
    structures += [Structure(f"o{i}", Role.OBSTACLE, f) for i, f in enumerate(obstacles)]
    return SteerableProblem(Scene(structures), goal_mm=goal, start_pose=np.eye(4), r_min_mm=50.0)


BLOCKER = Capsule([-20.0, -8.0, 30.0], [20.0, -8.0, 30.0], 3.0)


def test_same_seed_same_tree():
    prob = _problem(BLOCKER)
    a = solve_rrt(prob, time_limit_s=60.0, seed=7, max_iterations=300)
    b = solve_rrt(prob, time_limit_s=60.0, seed=7, max_iterations=300)
    assert a.status is PlanStatus.SOLVED and b.status is PlanStatus.SOLVED
    assert a.stats["iterations"] == b.stats["iterations"] == 300
    assert a.stats["nodes"] == b.stats["nodes"] == 195
    assert np.array_equal(a.plan.primitives, b.plan.primitives) and a.cost_mm == b.cost_mm
    assert a.cost_mm == pytest.approx(63.713350268209226, abs=1e-6)


def test_success_over_seeds_and_every_plan_passes_the_check():
    prob = _problem(BLOCKER)
    star = solve_rcs(prob, time_limit_s=60.0, max_iterations=300)
    assert star.cost_mm == pytest.approx(63.42908917682746, abs=1e-6)
    results = [solve_rrt(prob, time_limit_s=60.0, seed=s, max_iterations=800) for s in range(8)]
    solved = [r for r in results if r.status is PlanStatus.SOLVED]
    assert len(solved) == 8  # success over seeded runs (iteration budgets: the same anywhere)
    for r in solved:
        assert verify_plan(prob, r.plan).ok
        assert r.cost_mm >= star.cost_mm - 1.0 - 1e-6  # RCS* ends tau short; RRT at the goal


def test_one_tree_reaches_several_targets():
    goals = np.array([[0.0, -20.0, 60.0], [15.0, 5.0, 55.0], [-10.0, 10.0, 70.0]])
    prob = _problem()
    results = solve_rrt_multi(prob, goals, time_limit_s=60.0, seed=1, max_iterations=1500)
    assert len(results) == 3
    for g, r in zip(goals, results, strict=True):
        assert r.status is PlanStatus.SOLVED
        assert np.allclose(r.goal_mm, g)
        assert np.linalg.norm(r.plan.end_pose()[:3, 3] - g) <= 1.0 + 1e-9
        # all plans start on the same tree: the same start pose
        assert np.allclose(r.plan.start_pose, np.eye(4))


def test_the_lecture_s_multi_target_rrt_starts_a_tree_from_the_start_for_each_target():
    goals = np.array([[0.0, -20.0, 60.0], [15.0, 5.0, 55.0], [-10.0, 10.0, 70.0]])
    prob = _problem(BLOCKER)
    # the same total iteration budget: one tree of 1500, or three trees of 500
    one = solve_rrt_multi(prob, goals, time_limit_s=60.0, seed=1, max_iterations=1500)
    per = solve_rrt_per_target(prob, goals, time_limit_s=60.0, seed=1, max_iterations=500)
    assert [r.stats["iterations"] for r in per] == [500, 500, 500]
    assert [r.stats["nodes"] for r in per] == [339, 416, 429]  # a tree each
    assert {r.stats["nodes"] for r in one} == {1231}  # one tree for all
    for g, r in zip(goals, per, strict=True):
        assert r.status is PlanStatus.SOLVED and verify_plan(_problem(BLOCKER, goal=g), r.plan).ok
        assert np.allclose(r.plan.start_pose, np.eye(4))
    # measured: the shared tree is as good or slightly better at the same budget
    assert [r.cost_mm for r in one] == pytest.approx([63.904089, 56.454084, 70.488174], abs=1e-6)
    assert [r.cost_mm for r in per] == pytest.approx([63.907788, 56.454084, 70.488174], abs=1e-6)
    with pytest.raises(InvalidInputError, match="goals_mm"):
        solve_rrt_per_target(prob, np.zeros((0, 3)))


def test_budget_and_bad_input():
    wall = [
        Capsule([x, -130.0, 40.0], [x, 130.0, 40.0], 1.6) for x in np.arange(-130.0, 131.0, 3.0)
    ]
    prob = _problem(*wall)
    # no plan exists: the iteration budget ends the search (the 60 s clock never does)
    res = solve_rrt(prob, time_limit_s=60.0, seed=0, max_iterations=200)
    assert res.stats["iterations"] == 200 and res.stats["reason"] == "iteration limit"
    # the nearest valid path, short of the goal: every rule but the goal holds
    assert res.status is PlanStatus.APPROXIMATE and res.stats["nodes"] == 25
    assert res.stats["goal_distance_mm"] == pytest.approx(24.7617869653478, abs=1e-6)
    assert res.cost_mm == pytest.approx(39.761513620742114, abs=1e-6)
    assert [v.split(":")[0] for v in verify_plan(prob, res.plan).violations] == ["goal"]
    check = verify_approximate(prob, res.plan)
    assert check.ok, check.violations
    # a goal outside the reachable set: refused before the first iteration
    inf = solve_rrt(_problem(goal=np.array([0.0, -40.0, 10.0])))
    assert inf.status is PlanStatus.INFEASIBLE and inf.plan is None
    assert inf.stats["iterations"] == 0 and "reachable set" in inf.stats["reason"]
    with pytest.raises(InvalidInputError, match="goals_mm"):
        solve_rrt_multi(_problem(), np.zeros((0, 3)))
    with pytest.raises(InvalidInputError, match="time_limit_s"):
        solve_rrt(_problem(), time_limit_s=-1.0)


def test_solve_dispatches_to_each_planner():
    from needlekit.planning.steerable.solve import solve

    prob = _problem()
    for name in ("rcs_star", "rcs", "rrt"):
        assert solve(prob, name, time_limit_s=60.0, seed=0, max_iterations=50).planner == name
    with pytest.raises(InvalidInputError, match="planner"):
        solve(prob, "astar")


@pytest.mark.slow
def test_success_rates_from_the_lung_phantoms_start_poses(exact_clearance):
    """From every start pose of the lung phantom (seed 0): RCS* certifies a plan, RRT
    succeeds on seeded runs, and every plan passes the independent check and clears the
    phantom's exact anatomy."""
    from needlekit.anatomy.phantoms import lung_phantom
    from needlekit.planning.steerable.solve import solve

    ph = lung_phantom(0)
    rrt_ok = rrt_runs = 0
    for pose in ph.start_poses:
        prob = SteerableProblem(
            ph.scene, goal_mm=ph.targets_mm[0], start_pose=pose, r_min_mm=50.0, max_length_mm=100.0
        )
        star = solve(prob, "rcs_star", time_limit_s=60.0, max_iterations=300)
        assert star.status is PlanStatus.SOLVED and star.stats["certified"]
        assert verify_plan(prob, star.plan).ok
        exact_clearance(ph, prob, star.plan, star.stats["certified_clearance_mm"])
        for seed in range(3):
            res = solve(prob, "rrt", time_limit_s=60.0, seed=seed, max_iterations=300)
            rrt_runs += 1
            if res.status is PlanStatus.SOLVED:
                rrt_ok += 1
                assert verify_plan(prob, res.plan).ok
                exact_clearance(ph, prob, res.plan, res.stats["certified_clearance_mm"])
                assert res.cost_mm >= star.cost_mm  # RCS* is optimal at its resolution here
    assert rrt_ok / rrt_runs >= 0.9


def test_greedy_connections_arc_then_line_and_single_arc():
    from needlekit.planning.steerable.goal import goal_connection, single_arc_connection
    from needlekit.planning.steerable.solve import solve

    prob = _problem()  # nothing in the way: the start's own connection is the plan
    arc_line = solve_rrt(prob, time_limit_s=60.0, seed=0, max_iterations=50)
    arc = solve_rrt(prob, time_limit_s=60.0, seed=0, max_iterations=50, connection="arc")
    shortest = goal_connection(np.eye(4), GOAL, 50.0, 1.0).length_mm
    assert arc_line.cost_mm == pytest.approx(shortest, abs=1e-9)
    # one arc to the target itself: no better than the start's own arc, worse than arc+line
    one_arc = single_arc_connection(np.eye(4), GOAL, 50.0, 1.0).length_mm
    assert arc_line.cost_mm < arc.cost_mm <= one_arc + 1e-9
    assert arc_line.stats["connection"] == "arc_line" and arc.stats["connection"] == "arc"
    via_solve = solve(prob, "rrt", seed=0, max_iterations=50, options={"connection": "arc"})
    assert via_solve.cost_mm == arc.cost_mm
    with pytest.raises(InvalidInputError, match="connection"):
        solve_rrt(prob, connection="line")
    with pytest.raises(InvalidInputError, match="options"):
        solve(prob, "rcs_star", options={"connection": "arc"})
