"""``needlekit execute``'s default truth: the needle bent by mechanics (``physical``: in the
scenario's organ, which deforms; ``mechanics`` where the scenario has no organ to mesh,
said in one line), a steerable plan's tip pre-bent by 20 degrees and a multi plan's
straight; a plan that turns tighter than the calibrated needle is warned about before any
trial; ``--truth physical`` given on such a scenario is refused."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from needlekit.cli._parser import _build_parser
from needlekit.cli.execute import execute_options
from needlekit.cli.execute_models import (
    STEERABLE_PREBEND_DEG,
    check_physics_flags,
    checked_models,
    physics_options,
    say_model,
)
from needlekit.cli.execute_multi import straight_physics
from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.scenario.problems import ScenarioSource

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = EXAMPLES / "toy.yaml"
MULTI = EXAMPLES / "liver_phantom_multi.yaml"


def _args(scenario: Path, *extra: str):
    args = _build_parser().parse_args(["execute", str(scenario), "plan.json", "--out", "o", *extra])
    args.models = checked_models(args)
    check_physics_flags(args)
    return args


@pytest.fixture(scope="module")
def toy():
    source = ScenarioSource.of(TOY)
    scenario, problem = source.cached()
    res = solve_rcs(problem, time_limit_s=5.0, max_iterations=2000)
    assert res.status.value == "solved"
    return scenario, problem, res.plan


def test_without_truth_a_steerable_plan_is_carried_out_by_mechanics(toy, capsys, caplog):
    scenario, problem, plan = toy
    args = _args(TOY, "--calibration-insertions", "2")
    assert (args.truth, args.truth_given, args.prebend_deg) == ("physical", False, None)
    options = physics_options(args, scenario, plan, problem,
                              execute_options(args, 1.0 / problem.kappa_max_per_mm))  # fmt: skip
    s = options.settings
    # the toy has no organ: the rod in still tissue, said in one line
    assert capsys.readouterr().out == (
        "toy.yaml has no organ to mesh: its needle bends by mechanics in still tissue (--truth "
        "mechanics; --truth kinematic for the planner's own needle)\n"
    )
    assert s.models.truth == "mechanics" and s.tissue is None
    assert s.mechanics.prebend_deg == STEERABLE_PREBEND_DEG == 20.0
    # the loop's model is calibrated on it; its radius is twice the plan's: warned
    assert s.model is not None and s.model.r_min_mm > 100.0
    with caplog.at_level(logging.WARNING):
        say_model(s, problem)
    assert capsys.readouterr().out.startswith("calibrated on 4 insertions of the mechanics truth")
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and warned[0].startswith("the plan turns at r_min 50.0 mm, tighter "
                                                      "than this needle's 1")  # fmt: skip
    assert "needle.r_min_mm at least 1" in warned[0] and "--truth kinematic" in warned[0]


def test_truth_physical_given_on_a_scenario_without_an_organ_is_refused(toy):
    scenario, problem, plan = toy
    for extra, field in ((["--truth", "physical"], "--truth"),
                         (["--tissue-boundary", "sliding"], "--tissue-boundary")):  # fmt: skip
        args = _args(TOY, *extra)
        with pytest.raises(InvalidInputError) as exc:
            physics_options(args, scenario, plan, problem,
                            execute_options(args, 1.0 / problem.kappa_max_per_mm))  # fmt: skip
        assert exc.value.field == field


def test_a_multi_plans_needles_are_straight_by_default(capsys):
    scenario = ScenarioSource.of(MULTI).cached()[0]
    args = _args(MULTI)
    physics = straight_physics(args, scenario)
    assert capsys.readouterr().out.startswith("liver_phantom_multi.yaml has no organ to mesh")
    assert physics.truth == "mechanics" and physics.mechanics.prebend_deg == 0.0
    assert straight_physics(_args(MULTI, "--truth", "kinematic"), scenario) is None
    given = _args(MULTI, "--prebend-deg", "10", "--truth", "mechanics")
    assert straight_physics(given, scenario).mechanics.prebend_deg == 10.0
