"""Re-planning from the sensed tip: RCS* from the estimated
tip as a continuation of the original problem, adopted only when its plan passes the
independent check, applied after the search's time while the needle goes on."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from needlekit.execute.needle_sim import ExecutionNoise
from needlekit.execute.replan import Replanner, ReplanPolicy, noise_margin_mm
from needlekit.execute.run import ExecutionSettings, execute_plan
from needlekit.planning.steerable.continuation import continuation_from_pose, continuation_problem
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.solve import solve
from needlekit.scenario.problems import load_problem

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"


@pytest.fixture(scope="module")
def toy():
    _, problem = load_problem(TOY)
    res = solve(problem, "rcs_star", max_iterations=2000, time_limit_s=30)
    assert res.status.value == "solved"
    return problem, res


def test_a_continuation_from_a_pose_is_the_continuation_of_the_path_that_ends_there(toy):
    problem, res = toy
    done = SteerablePlan(res.plan.start_pose, res.plan.primitives[:1])
    a = continuation_problem(problem, done)
    b = continuation_from_pose(problem, done.end_pose(), done.length_mm)
    assert np.array_equal(a.start_pose, b.start_pose)
    for name in ("max_length_mm", "max_heading_change_deg", "start_exclusion_mm", "start_inside"):
        assert getattr(a, name) == getattr(b, name)


def test_the_margin_is_k_sigma_for_the_crossing_probability():
    assert noise_margin_mm(1.0, 0.5) == pytest.approx(0.0, abs=1e-12)
    assert noise_margin_mm(0.2, 0.02275013194817921) == pytest.approx(0.4, rel=1e-9)  # 2 sigma
    with pytest.raises(Exception, match="crossing_probability"):
        noise_margin_mm(0.2, 0.0)


def test_a_drifting_needle_is_replanned_from_its_tip_and_still_reaches_the_goal(toy):
    problem, res = toy
    goal = problem.goal_mm
    r_min = 1.0 / problem.kappa_max_per_mm
    # a strong push, and a re-plan at every 0.2 mm off the plan: re-plans must happen
    settings = ExecutionSettings(noise=ExecutionNoise(deflection_sigma=0.03))
    policy = ReplanPolicy(cross_track_mm=0.2, min_interval_mm=2.0, max_iterations=2000,
                          time_limit_s=5.0, delay_s=0.05)  # fmt: skip
    rep = Replanner(problem, policy)
    run = execute_plan(res.plan, goal, r_min, closed_loop=True, seed=4, settings=settings,
                       replanner=rep)  # fmt: skip
    assert run.replans >= 1 and rep.adopted == run.replans
    assert len(run.replan_latency_s) == rep.adopted + rep.refused
    assert run.final_error_mm < 1.0
    opened = execute_plan(res.plan, goal, r_min, closed_loop=False, seed=4, settings=settings)
    assert opened.final_error_mm > 2.0 * run.final_error_mm
