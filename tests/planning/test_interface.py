"""The planner interface: termination conditions, typed options, the registry, and a
planner written outside needlekit running through ``needlekit plan``."""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import (
    Termination,
    get_planner,
    planner_names,
    register_planner,
    unregister_planner,
)
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.rcs import RCSOptions, Resolution
from needlekit.planning.steerable.solve import solve
from needlekit.scenario.problems import load_problem, planner_settings

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

# A planner as a user would write it outside needlekit, from needlekit's public pieces: the
# shared search (set-up, pre-checks, plan check, result) and the goal connection.
USER_PLANNER = textwrap.dedent(
    '''
    from dataclasses import dataclass

    import numpy as np

    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.goal import goal_connection
    from needlekit.planning.steerable.plan import SteerablePlan
    from needlekit.planning.steerable.search import SteerableSearch, precheck


    @dataclass(frozen=True)
    class DirectOptions:
        stop_short_mm: float = 0.0


    class DirectPlanner:
        """Tries the turn-then-straight connection from the start, nothing else."""

        name = "direct"
        family = "steerable"
        options_type = DirectOptions

        def __init__(self, options=None):
            self.options = options or DirectOptions()

        def solve(self, problem, termination):
            search = SteerableSearch(problem, termination, self.name)
            verdict = precheck(problem, problem.goal_mm, search.validator)
            if verdict is not None:
                return search.result(verdict[0], reason=verdict[1])
            while search.run.keep_going():
                conn = goal_connection(
                    problem.start_pose, problem.goal_mm, problem.r_min_mm,
                    problem.goal_tolerance_mm,
                )
                plan = SteerablePlan(problem.start_pose, conn.primitives)
                if search.validator.primitives_valid(problem.start_pose, conn.primitives) and (
                    search.check(plan)
                ):
                    search.run.improved(plan.length_mm)
                    return search.result(PlanStatus.SOLVED, plan, plan.length_mm)
                search.run.stop("the direct connection collides")
            return search.result(PlanStatus.TIMEOUT)
    '''
)


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    pkg = tmp_path / "userplanners"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(USER_PLANNER)
    monkeypatch.syspath_prepend(str(tmp_path))
    import importlib

    mod = importlib.import_module("userplanners")
    yield mod
    sys.modules.pop("userplanners", None)
    unregister_planner("direct")


def test_termination_composes_its_conditions():
    run = Termination(time_limit_s=5.0, max_iterations=3).start()
    assert [run.keep_going() for _ in range(4)] == [True, True, True, False]
    assert run.reason == "iteration limit" and run.iterations == 3

    run = Termination(time_limit_s=5.0, stop_at_first_solution=True).start()
    assert run.keep_going() and run.keep_going()
    run.improved(42.0)
    assert not run.keep_going() and run.reason == "first solution"
    assert run.stats()["cost_history"][0][1] == 42.0 and run.stats()["first_solution_s"] >= 0

    seen = []
    run = Termination(
        time_limit_s=5.0, callback=lambda r: seen.append(r.iterations) or len(seen) > 2
    ).start()
    assert [run.keep_going() for _ in range(4)] == [True, True, False, False]
    assert run.reason == "callback" and seen == [0, 1, 2]

    run = Termination(time_limit_s=1e-9).start()  # the deadline has passed at the first poll
    assert not run.keep_going() and run.reason == "time limit"


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"time_limit_s": 0.0}, "time_limit_s"),
        ({"time_limit_s": float("nan")}, "time_limit_s"),
        ({"max_iterations": -1}, "max_iterations"),
        ({"max_iterations": 2.5}, "max_iterations"),
        ({"callback": 3}, "callback"),
    ],
)
def test_termination_refuses_bad_budgets(kwargs, field):
    with pytest.raises(InvalidInputError, match=field):
        Termination(**kwargs)


def test_registry_serves_typed_options_and_refuses_unknown_ones():
    assert planner_names("steerable")[:3] == ["rcs_star", "rcs", "rrt"]
    assert planner_names("straight")[0] == "liu_cfrw"
    p = get_planner("rcs_star", {"resolution": {"max_length_mm": 8.0, "length_levels": 3}})
    assert p.options == RCSOptions(Resolution(8.0, 3, 4))
    with pytest.raises(InvalidInputError, match="rcs_star takes resolution; unknown: bogus_option"):
        get_planner("rcs_star", {"bogus_option": 42})
    with pytest.raises(InvalidInputError, match="unknown planner 'nope'"):
        get_planner("nope")
    with pytest.raises(InvalidInputError, match="connection"):
        get_planner("rrt", {"connection": "zigzag"})


def test_plan_refuses_a_scenarios_unknown_planner_option(tmp_path, capsys):
    text = (
        (EXAMPLES / "toy.yaml")
        .read_text()
        .replace(
            "planner: {name: rcs_star, time_limit_s: 1.0, seed: 0}",
            "planner: {name: rcs_star, time_limit_s: 1.0, seed: 0, options: {bogus_option: 42}}",
        )
    )
    scenario = tmp_path / "toy.yaml"
    scenario.write_text(text)
    for cmd in (["plan", str(scenario), "--out", str(tmp_path / "p.json")],
                ["sweep", str(scenario), "--out", str(tmp_path / "s.json")]):  # fmt: skip
        assert main(cmd) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(
            "error: planner.options: rcs_star takes resolution; unknown: bogus_option"
        )
        assert len(err.splitlines()) == 1
    assert not (tmp_path / "p.json").exists() and not (tmp_path / "s.json").exists()


def test_plan_and_sweep_read_the_planner_block_the_same_way(tmp_path):
    block = {"name": "rrt", "time_limit_s": 3.0, "seed": 7, "max_iterations": 40,
             "options": {"connection": "arc"}}  # fmt: skip
    s = planner_settings(block)
    assert (s.names, s.time_limit_s, s.seed, s.max_iterations) == (("rrt",), 3.0, 7, 40)
    assert s.options == {"rrt": {"connection": "arc", "seed": 7}}
    # flags override the block; the block's options go with the block's planner only
    s = planner_settings(block, names=["rcs_star", "rrt"], seed=1, time_limit_s=0.5)
    assert s.options == {"rcs_star": {}, "rrt": {"connection": "arc", "seed": 1}}
    assert (s.time_limit_s, s.max_iterations) == (0.5, 40)


def test_a_planner_registered_in_code_runs_through_needlekit_plan(user_module, tmp_path, capsys):
    register_planner("direct", user_module.DirectPlanner)
    out = tmp_path / "plan.json"
    goal = "--goal", "10,40,20"  # in front of the toy start, no obstacle on the way
    assert (
        main(["plan", str(EXAMPLES / "toy.yaml"), "--planner", "direct", *goal, "--out", str(out)])
        == 0
    )
    data = json.loads(out.read_text())
    assert data["planner"] == "direct" and data["status"] == "solved"
    # the same plan as RCS*'s certified one: the direct connection is optimal here
    _, problem = load_problem(EXAMPLES / "toy.yaml", goal_mm=[10.0, 40.0, 20.0])
    star = solve(problem, "rcs_star", max_iterations=2000, time_limit_s=60.0)
    assert data["cost_mm"] == pytest.approx(star.cost_mm, abs=1e-9)
    assert main(["verify", str(EXAMPLES / "toy.yaml"), str(out), "--goal", "10,40,20"]) == 0


@pytest.mark.slow
def test_a_planner_declared_by_an_entry_point_runs_with_no_edit_to_needlekit(tmp_path):
    site = tmp_path / "site"
    (site / "userplanners").mkdir(parents=True)
    (site / "userplanners" / "__init__.py").write_text(USER_PLANNER)
    dist = site / "userplanners-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: userplanners\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[needlekit.planners]\ndirect = userplanners:DirectPlanner\n"
    )
    out = tmp_path / "plan.json"
    env = {**os.environ, "PYTHONPATH": str(site)}
    cmd = [sys.executable, "-m", "needlekit.cli", "plan", str(EXAMPLES / "toy.yaml")]
    cmd += ["--planner", "direct", "--goal", "10,40,20", "--out", str(out)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("direct: solved, cost ")
    data = json.loads(out.read_text())
    _, problem = load_problem(EXAMPLES / "toy.yaml", goal_mm=[10.0, 40.0, 20.0])
    star = solve(problem, "rcs_star", max_iterations=2000, time_limit_s=60.0)
    assert data["planner"] == "direct" and data["cost_mm"] == pytest.approx(star.cost_mm, abs=1e-9)


def test_solve_dispatches_through_the_registry_with_seeds_and_budgets():
    _, problem = load_problem(EXAMPLES / "toy.yaml", goal_mm=[10.0, 40.0, 20.0])
    a = solve(problem, "rrt", seed=3, max_iterations=30, time_limit_s=60.0)
    b = solve(problem, "rrt", options={"seed": 3}, max_iterations=30, time_limit_s=60.0)
    assert a.status is b.status is PlanStatus.SOLVED and a.cost_mm == b.cost_mm
    assert a.stats["iterations"] <= 30 and "planner_wall_s" in a.stats and "setup_s" in a.stats
    with pytest.raises(InvalidInputError, match="not both"):
        solve(problem, "rcs", termination=Termination(), time_limit_s=1.0)
    star = solve(problem, "rcs_star", termination=Termination(60.0, stop_at_first_solution=True))
    assert star.status is PlanStatus.SOLVED and star.stats["reason"] in (
        "first solution",
        "search space exhausted",
    )
    assert np.isfinite(star.stats["first_solution_s"])


def test_an_unknown_planner_is_refused_before_the_anatomy_loads(tmp_path, capsys, monkeypatch):
    import needlekit.scenario.problems as problems

    def no_load(*a, **k):
        raise AssertionError("the anatomy was loaded")

    monkeypatch.setattr(problems, "load_problem", no_load)
    out = str(tmp_path / "p.json")
    assert main(["plan", str(EXAMPLES / "toy.yaml"), "--planner", "astar", "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --planner: unknown planner 'astar'; available: rcs_star, rcs, rrt, liu_cfrw"
    assert main(["plan", str(EXAMPLES / "toy.yaml"), "--planner", "liu_cfrw", "--out", out]) == 2
    err = capsys.readouterr().err.strip()
    assert (
        err
        == "error: --planner: 'liu_cfrw' plans straight needles; steerable planners: rcs_star, rcs, rrt"
    )


@pytest.mark.parametrize("planner", ["rcs_star", "rcs", "rrt"])
def test_searches_pause_the_cyclic_collector_and_restore_it(planner):
    # a full collection walks every live object: the search pauses the collector (its
    # callback sees it off) and gives it back as it was, also when the search fails
    import gc

    _, problem = load_problem(EXAMPLES / "toy.yaml")
    seen = []

    def record(run):
        seen.append(gc.isenabled())
        return len(seen) >= 5

    assert gc.isenabled()
    solve(problem, planner, termination=Termination(60.0, 1000, callback=record))
    assert seen and not any(seen) and gc.isenabled()
    gc.disable()
    try:
        solve(problem, planner, termination=Termination(60.0, 1000, callback=record))
        assert not gc.isenabled()  # left as the caller had it
    finally:
        gc.enable()

    def fail(run):
        raise RuntimeError("stop")

    with pytest.raises(RuntimeError, match="stop"):
        solve(problem, planner, termination=Termination(60.0, 1000, callback=fail))
    assert gc.isenabled()
