"""RCS* warm-started from plans it is given: the cheapest of them that
passes the independent check is its first best plan; it prunes against it, returns it when
the budget runs out, and never takes one that fails the check or starts elsewhere."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.execute.feedback import PlanReference
from needlekit.execute.replan import WARM_START_KEPT, rest_of_plan
from needlekit.geometry.so3 import so3_exp
from needlekit.planning.steerable.continuation import continuation_from_pose
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.scenario.problems import load_problem

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"


@pytest.fixture(scope="module")
def toy():
    _, problem = load_problem(TOY)
    cold = solve_rcs(problem, max_iterations=100_000, time_limit_s=60)
    assert cold.status.value == "solved" and cold.stats["certified"]
    return problem, cold


def test_a_warm_start_is_the_first_best_plan(toy):
    problem, cold = toy
    # one processed node: only the warm start can be the answer
    quick = solve_rcs(problem, max_iterations=1, time_limit_s=60, warm_start=[cold.plan])
    assert quick.status.value == "solved" and quick.plan is cold.plan
    assert quick.cost_mm == pytest.approx(cold.cost_mm, rel=1e-12)
    assert quick.stats["warm_start"] == "adopted" and quick.stats["warm_start_kept"]
    assert not quick.stats["certified"]  # the search did not finish
    # finished: the same optimum, certified, with no more nodes than the cold search
    full = solve_rcs(problem, max_iterations=100_000, time_limit_s=60, warm_start=[cold.plan])
    assert full.stats["certified"] and full.cost_mm == pytest.approx(cold.cost_mm, rel=1e-12)
    assert full.stats["nodes"] <= cold.stats["nodes"]


def test_a_warm_start_that_fails_the_check_is_not_taken(toy):
    problem, cold = toy
    # straight on for 500 mm: beyond the length limit whatever it passes through
    wrong = SteerablePlan(problem.start_pose, [[0.0, 0.0, 500.0]])
    res = solve_rcs(problem, max_iterations=1, time_limit_s=60, warm_start=[wrong])
    assert res.stats["warm_start"] == "none passed" and res.plan is not wrong
    with pytest.raises(InvalidInputError, match="warm_start"):
        solve_rcs(
            problem, max_iterations=1, warm_start=[SteerablePlan(np.eye(4), cold.plan.primitives)]
        )


def _pose_at(plan: SteerablePlan, arc_mm: float) -> np.ndarray:
    prims = plan.primitives
    ends = np.cumsum(prims[:, 2])
    k = int(np.searchsorted(ends, arc_mm, "right"))
    head = np.vstack([prims[:k], [[*prims[k, :2], arc_mm - (ends[k] - prims[k, 2])]]])
    return SteerablePlan(plan.start_pose, head).end_pose()


@pytest.mark.parametrize("roll", [0.0, 0.7, -2.5])
def test_the_rest_of_a_plan_from_a_point_on_it_is_the_plan_in_any_roll(toy, roll):
    problem, cold = toy
    ref = PlanReference.of_plan(cold.plan, problem.goal_mm)
    i = int(np.searchsorted(ref.arc_mm, 0.4 * cold.plan.length_mm))
    s = float(ref.arc_mm[i])
    tip = _pose_at(cold.plan, s)
    tip[:3, :3] = tip[:3, :3] @ so3_exp([0.0, 0.0, roll])  # the tip spun about its axis
    cont = continuation_from_pose(problem, tip, s)
    warm = rest_of_plan(cold.plan, s, tip, cont)
    assert len(warm) == len(WARM_START_KEPT)
    # kept whole: exactly the rest of the plan, point for point
    assert np.allclose(warm[0].end_pose(), cold.plan.end_pose(), atol=1e-9)  # roll too
    dense = cold.plan.points_mm(0.01)
    for p in warm[0].points_mm(0.5):  # on the plan's path (within its 0.01 mm sampling)
        assert np.linalg.norm(dense - p, axis=1).min() < 0.006
    for plan in warm:  # every one reaches the goal's tolerance from the tip
        assert np.allclose(plan.start_pose, tip)
        gap = np.linalg.norm(plan.end_pose()[:3, 3] - problem.goal_mm)
        assert gap <= problem.goal_tolerance_mm + 1e-9
        assert plan.length_mm == pytest.approx(cold.plan.length_mm - s, abs=1e-6)
