"""Med-RAD lung 1 against the reference planner's facts (issue: curved-needle planning).

The reference RCS* certifies, for Patient 1, the cost of the direct goal connection from
the start (turn at r_min, then straight to tau before the target) whenever that connection
is collision-free. These tests check our goal connection and exact collision test give the
same verdicts and costs; the planners build on both.
"""

import numpy as np
import pytest

from needlekit.planning.steerable.goal import goal_connection
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.verify import verify_plan

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

# reference RCS* costs (mm) on Patient 1, None = unreachable; start 2 collides
REFERENCE = {
    (1, 50): 58.26, (3, 50): 53.24, (4, 50): 58.12, (5, 50): 58.09,
    (1, 100): None, (3, 100): 54.83, (4, 100): None, (5, 100): 58.41,
}  # fmt: skip
#: The reference's plans from start 5 pass its test at their 0.5 mm samples but keep only
#: 0.0008 mm (r_min 50) and 0.023 mm (r_min 100) from the obstacle voxel balls between
#: them (measured every 0.01 mm): less than half the sample gap, so the certified rule
#: (docs/steerable.md, "Certified clearance") cannot vouch for them.
NOT_CERTIFIABLE = {(5, 50), (5, 100)}


@pytest.fixture(scope="module")
def lung1(medrad_lung1):
    return medrad_lung1, medrad_lung1.voxel_obstacles(needle_diameter_mm=1.0)


def _problem(case, obstacles, start, r_min):
    return SteerableProblem(
        case.scene,
        goal_mm=case.targets_mm["target"],
        start_pose=case.start(start).world_T_tip,
        r_min_mm=r_min,
        collision_model="voxel_centres",
        voxel_obstacles=obstacles,
    )


@pytest.mark.parametrize(("start", "r_min"), sorted(REFERENCE))
def test_direct_connection_reproduces_the_reference(lung1, start, r_min):
    case, obstacles = lung1
    s = case.start(start)
    target = case.targets_mm["target"]
    conn = goal_connection(s.world_T_tip, target, r_min, 1.0)
    expected = REFERENCE[(start, r_min)]
    if expected is None:
        assert conn is None
        return
    assert conn.length_mm == pytest.approx(expected, abs=0.005)
    plan = SteerablePlan(s.world_T_tip, conn.primitives)
    # the reference's own test at its samples: clear
    hits = obstacles.collides(plan.points_mm(0.5), exclude_near=s.world_T_tip[:3, 3], exclusion_mm=3.0)
    assert not hits.any()
    prob = _problem(case, obstacles, start, r_min)
    v = verify_plan(prob, plan)
    if (start, r_min) in NOT_CERTIFIABLE:
        assert not v.ok and v.violations[0].startswith("collision")
        assert 0.0 < v.metrics["min_clearance_mm"] < 0.125
    else:
        assert v.ok, v.violations


@pytest.mark.parametrize("r_min", [50, 100])
def test_start2_direct_connection_collides(lung1, r_min):
    case, obstacles = lung1
    s = case.start(2)
    target = case.targets_mm["target"]
    conn = goal_connection(s.world_T_tip, target, r_min, 1.0)
    prob = _problem(case, obstacles, 2, r_min)
    v = verify_plan(prob, SteerablePlan(s.world_T_tip, conn.primitives), spacing_mm=0.5)
    assert not v.ok and v.violations[0].startswith("collision")
    assert np.isfinite(v.metrics["min_clearance_mm"])


@pytest.mark.parametrize(("start", "r_min"), [*sorted(REFERENCE), (2, 50), (2, 100)])
def test_rcs_star_reproduces_the_reference_verdicts_and_costs(lung1, start, r_min):
    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.rcs import solve_rcs

    case, obstacles = lung1
    prob = _problem(case, obstacles, start, r_min)
    expected = REFERENCE.get((start, r_min), "none")
    if expected == "none":  # start 2: the reference finds no plan within 1 s
        # needlekit proves there is none: the start sits among gaps one voxel wide, which
        # the search's finer proof (cells half a voxel wide) closes once it has found
        # nothing for 5 ms (before: approximate, 55.2 mm short, after 3000 iterations)
        res = solve_rcs(prob, time_limit_s=120.0)
        assert res.status is PlanStatus.INFEASIBLE, (res.status, res.stats.get("reason"))
        assert "cells half a voxel wide" in res.stats["reason"]
        return
    res = solve_rcs(prob, time_limit_s=1.0)  # the reference's budget; these certify
    if expected is None:
        assert res.status is PlanStatus.INFEASIBLE
    elif (start, r_min) in NOT_CERTIFIABLE:  # no plan it can certify clear: the nearest
        assert res.status is not PlanStatus.SOLVED
    else:
        assert res.status is PlanStatus.SOLVED and res.stats["certified"]
        assert res.cost_mm <= expected + 0.5
        assert verify_plan(prob, res.plan).ok


def test_bench_steerable_records_cases_and_the_reference(tmp_path):
    import json

    from needlekit.cli import main

    out = tmp_path / "bench.json"
    assert (
        main(
            [
                "bench",
                "steerable",
                "--patients",
                "1",
                "--radii",
                "100",
                "--planners",
                "rcs_star",
                "--out",
                str(out),
            ]
        )
        == 0
    )
    rec = json.loads(out.read_text())
    assert rec["benchmark"] == "steerable" and len(rec["results"]) == 5
    assert {"versions", "cpu"} <= set(rec["machine"]) and rec["fields"][0]["total_s"] > 0
    by_start = {r["start"]: r for r in rec["results"]}
    assert by_start[3]["status"] == "solved" and by_start[3]["certified"]
    assert by_start[1]["status"] == "infeasible"
    # start 5: the reference's plan is not certifiable (NOT_CERTIFIABLE)
    assert by_start[5]["status"] != "solved"
    assert rec["summary"]["lung1_reference_agreement"] == "4/5"


@pytest.mark.parametrize("planner", ["rcs_star", "rcs", "rrt"])
def test_a_goal_40_mm_behind_start_1_is_infeasible_before_searching(lung1, planner):
    from dataclasses import replace

    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.solve import solve

    case, obstacles = lung1
    prob = _problem(case, obstacles, 1, 50)
    s = prob.start_pose
    behind = replace(prob, goal_mm=s[:3, 3] - 40.0 * s[:3, 2], start_point_mm=None)
    res = solve(behind, planner, time_limit_s=1.0)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0
    assert "beyond the heading limit of 90 deg" in res.stats["reason"]


@pytest.mark.parametrize("planner", ["rcs_star", "rcs", "rrt"])
def test_a_goal_in_an_obstacle_voxel_is_said_so(lung1, planner):
    from dataclasses import replace

    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.solve import solve

    case, obstacles = lung1
    prob = _problem(case, obstacles, 1, 50)
    # the obstacle voxel nearest the target, a few mm away
    idx = np.argwhere(obstacles.occupancy[::4, ::4, ::4]) * 4
    centres = idx @ obstacles.affine[:3, :3].T + obstacles.affine[:3, 3]
    inside = centres[np.argmin(np.linalg.norm(centres - prob.goal_mm, axis=1))]
    res = solve(replace(prob, goal_mm=inside, start_point_mm=None), planner, time_limit_s=1.0)
    assert res.status is PlanStatus.INVALID_PROBLEM
    assert res.stats["reason"] == "goal lies inside an obstacle (for this needle)"
