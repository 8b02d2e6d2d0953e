"""The plug points of an execution (needlekit.execute.plugins): the one registry class,
each kind's implementations against its protocol, the truth's optional capabilities as the
loop uses them, and the command line's checks of the names."""

from __future__ import annotations

import functools
import sys
from dataclasses import replace

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.execute import plugins
from needlekit.execute.feedback import PlanReference
from needlekit.execute.needle_sim import ExecutionNoise, SimulatedNeedle
from needlekit.execute.plugins import (
    ESTIMATORS,
    FEEDBACK_LAWS,
    SENSORS,
    TRUTHS,
    Estimator,
    FeedbackLaw,
    Models,
    Setup,
    TipSensor,
    Truth,
)
from needlekit.execute.replan import Replanner, ReplanPolicy
from needlekit.execute.run import ExecutionSettings, execute_plan
from needlekit.execute.target_sensing import SensingPolicy
from needlekit.planning.registry import check_replanner, planner_capabilities
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.registry import Builtin, Registry

#: One arc of curvature 0.01 /mm over 40 mm from the origin (r_min 50 mm: half the needle's).
PLAN = SteerablePlan(np.eye(4), np.array([[0.0, 0.01, 40.0]]))
GOAL = PLAN.end_pose()[:3, 3]
QUIET = ExecutionSettings(noise=ExecutionNoise.none())


# -- the registry ---------------------------------------------------------------------------


def test_a_builtin_is_checked_and_listed_without_its_module_imported():
    reg = Registry("widget", "needlekit.tests.widgets",
                   [Builtin("w", "needlekit_no_such_module:make", ("fast",))])  # fmt: skip
    reg.check("w")
    assert reg.names() == ["w"] and reg.capabilities("w") == ("fast",)
    assert reg.names(keep=lambda n: "slow" in reg.capabilities(n)) == []
    assert "needlekit_no_such_module" not in sys.modules
    with pytest.raises(InvalidInputError, match=r"^widget: widget 'w' \(needlekit_no_such"):
        reg.get("w")  # loaded only now: one line naming it


def test_a_wrong_name_gets_the_names_and_the_nearest():
    with pytest.raises(InvalidInputError) as exc:
        TRUTHS.check("layerd")
    assert exc.value.field == "--truth"
    assert str(exc.value) == ("--truth: unknown truth 'layerd'; available: kinematic, layered, mechanics, physical; "
                              "did you mean layered?")  # fmt: skip


def test_register_replace_and_unregister():
    reg = Registry("widget", "needlekit.tests.widgets", field="--widget")
    reg.register("a", dict)
    with pytest.raises(InvalidInputError, match="already registered"):
        reg.register("a", list)
    reg.register("a", list, replace=True)
    assert reg.get("a") is list and reg.target("a") == "builtins:list"
    reg.unregister("a")
    with pytest.raises(InvalidInputError, match="--widget: unknown widget 'a'"):
        reg.get("a")
    with pytest.raises(InvalidInputError, match="non-empty name"):
        reg.register(" ", dict)


def test_a_factory_that_is_not_callable_is_refused():
    with pytest.raises(InvalidInputError, match="--truth: truth 'x': expected a factory"):
        TRUTHS.register("x", 3)


def test_entry_points_of_the_group_are_found(tmp_path, monkeypatch):
    (tmp_path / "widgetplug.py").write_text("def make(setup):\n    return 'made'\n"
                                            "make.capabilities = ('fast',)\n")  # fmt: skip
    info = tmp_path / "widgetplug-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: widgetplug\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[needlekit.tests.widgets]\nw2 = widgetplug:make\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    reg = Registry("widget", "needlekit.tests.widgets", [Builtin("w", "builtins:dict")])
    assert reg.names() == ["w", "w2"]
    assert "widgetplug" not in sys.modules  # named, not imported
    assert reg.capabilities("w2") == ("fast",)  # read from the factory: loads it
    assert reg.get("w2")(None) == "made" and reg.target("w2") == "widgetplug:make"


# -- each kind's implementations --------------------------------------------------------------


def _setup(seed=0) -> Setup:
    return Setup(PLAN.start_pose, GOAL, 50.0, QUIET, np.random.default_rng(seed))


@pytest.mark.parametrize("name", ["kinematic", "layered"])
def test_the_truths_follow_the_protocol_and_without_noise_the_plan(name):
    needle = TRUTHS.get(name)(_setup())
    assert isinstance(needle, Truth)
    for spin, kappa, length in PLAN.primitives:
        for i in range(400):
            needle.step(spin if i == 0 else 0.0, kappa, length / 400, 0.05)
    assert needle.inserted_mm == pytest.approx(40.0)
    assert np.allclose(needle.pose, PLAN.end_pose(), atol=1e-9)


def test_the_sensors_follow_the_protocol_and_igtl_needs_its_link():
    assert isinstance(SENSORS.get("em")(_setup()), TipSensor)
    with pytest.raises(InvalidInputError, match=r"^--sensor: igtl reads a tracker"):
        SENSORS.get("igtl")(_setup())


@pytest.mark.parametrize("name", ["kalman", "unscented"])
def test_the_estimators_follow_the_protocol(name):
    est = ESTIMATORS.get(name)(_setup())
    assert isinstance(est, Estimator)
    est.predict(0.0, 0.01, 1.0, 0.5)
    nominal = SteerablePlan(np.eye(4), np.array([[0, 0.01, 1.0]])).end_pose()
    # the unscented mean lies short of the nominal end by about sigma^2 |a| (1e-4 mm here)
    assert np.allclose(est.pose, nominal, atol=1e-3)


@pytest.mark.parametrize("name", ["pure_pursuit", "sliding_mode"])
def test_the_feedback_laws_follow_the_protocol(name):
    law = FEEDBACK_LAWS.get(name)(_setup())
    assert isinstance(law, FeedbackLaw)
    spin, kappa = law(np.eye(4), PlanReference.of_plan(PLAN, GOAL), 0)
    assert 0.0 < kappa <= 0.02 and abs(spin) <= np.pi


def test_the_planners_that_re_plan_are_those_declaring_warm_start():
    assert planner_capabilities("rcs_star") == planner_capabilities("rcs") == ("warm_start",)
    assert planner_capabilities("rrt") == ()
    check_replanner("rcs")
    with pytest.raises(InvalidInputError) as exc:
        check_replanner("rrt")
    assert str(exc.value) == ("--replanner: planner 'rrt' does not declare the 'warm_start' "
                              "capability a re-planner needs; planners that do: rcs_star, rcs")  # fmt: skip
    with pytest.raises(InvalidInputError, match="planners that re-plan: rcs_star, rcs; did you"):
        check_replanner("rcs_str")


def test_the_record_names_each_model_with_its_parameters():
    rec = plugins.model_record("feedback", "sliding_mode", QUIET)
    assert rec == {"name": "sliding_mode", "factory": "needlekit.execute.sliding_mode:sliding_mode_law",
                   "parameters": {"lookahead_mm": 10.0, "spin_rate_rad_s": 2 * np.pi,
                                  "straight_fraction": 0.1}}  # fmt: skip


# -- the truth's optional capabilities in the loop ---------------------------------------------

#: How far the test truths carry the target or the tissue (mm): |C| = 1.
C = np.array([0.6, 0.8, 0.0])


class _Carried(SimulatedNeedle):
    """A needle that follows its model, in tissue that carries the target by C; it also
    reports a shaft load proportional to the length inserted."""

    def target_mm(self):
        return GOAL + C

    def shaft_loads(self):
        return {"axial_n": 0.01 * self.inserted_mm}


class _Shifted(SimulatedNeedle):
    """A needle that follows its model, in tissue displaced by -C: the rest anatomy is the
    world point plus C."""

    def to_rest(self, points):
        return np.asarray(points) + C


@pytest.fixture
def test_truths():
    TRUTHS.register("carried", lambda s: _Carried(s.start_pose, s.r_min_mm, ExecutionNoise.none(), s.rng))
    TRUTHS.register("shifted", lambda s: _Shifted(s.start_pose, s.r_min_mm, ExecutionNoise.none(), s.rng))
    yield
    TRUTHS.unregister("carried")
    TRUTHS.unregister("shifted")


def _settings(truth: str, **kw) -> ExecutionSettings:
    return ExecutionSettings(noise=ExecutionNoise.none(), models=Models(truth=truth, **kw))


def test_a_moving_target_is_judged_where_it_is_and_steered_to_once_it_is_seen(test_truths):
    s = _settings("carried")
    run = execute_plan(PLAN, GOAL, 50.0, closed_loop=False, seed=1, settings=s)
    # open loop the needle ends on the plan's end, the target is C away from it
    assert run.final_error_mm == pytest.approx(1.0, abs=1e-9)
    assert run.shaft_loads == {"axial_n": pytest.approx(0.4, abs=1e-12)}
    # em: nothing sees the target, the loop steers to the plan's and misses by C
    em = execute_plan(PLAN, GOAL, 50.0, closed_loop=True, seed=1, settings=s)
    assert em.final_error_mm == pytest.approx(1.0, abs=0.05)
    assert em.shaft_loads["axial_n"] == pytest.approx(0.01 * em.inserted_mm)
    assert em.target["target_displacement_mm"] == pytest.approx(1.0, abs=1e-12)
    assert em.target["target_error_mm"] == pytest.approx(1.0, abs=1e-12)  # belief: the plan's
    # tracking: the target is seen, and steered to
    tracked = execute_plan(PLAN, GOAL, 50.0, closed_loop=True, seed=1,
                           settings=replace(s, sensing=SensingPolicy("tracking")))  # fmt: skip
    assert tracked.final_error_mm < 0.5 and tracked.target["target_samples_used"] > 100


def test_a_path_in_deformed_tissue_is_recorded_in_the_world_and_at_rest(test_truths):
    run = execute_plan(PLAN, GOAL, 50.0, closed_loop=False, seed=1, settings=_settings("shifted"))
    assert np.allclose(run.points_mm[0], 0.0) and np.allclose(run.points_mm[-1], GOAL)
    assert np.allclose(run.points_rest_mm, run.points_mm + C)
    assert run.final_error_mm == pytest.approx(1.0, abs=1e-9)  # at rest, to the goal
    assert run.shaft_loads is None


#: Two arcs, 100 mm: the second bends a quarter turn away from the first.
LONG = SteerablePlan(np.eye(4), np.array([[0.0, 0.01, 50.0], [np.pi / 2, 0.015, 50.0]]))


@functools.cache
def _open_loop(truth: str):
    """LONG inserted open loop on seed 7's needle in ``truth``, made once per truth: open
    loop, execute_plan builds no estimator and no law, so the run is the same whichever
    the settings name."""
    s = ExecutionSettings(models=Models(truth=truth))
    return execute_plan(LONG, LONG.end_pose()[:3, 3], 50.0, closed_loop=False, seed=7, settings=s)


@pytest.mark.parametrize(("truth", "estimator", "feedback"), [
    ("kinematic", "kalman", "pure_pursuit"), ("kinematic", "unscented", "pure_pursuit"),
    ("kinematic", "kalman", "sliding_mode"), ("layered", "kalman", "sliding_mode"),
])  # fmt: skip
def test_every_estimator_and_law_brings_a_noisy_needle_to_the_goal(truth, estimator, feedback):
    """The default noise and sensor, seed 7: open loop misses by 2.6 mm (kinematic) or
    3.0 mm (layered), as measured; each estimator and law closes the loop to under 0.5 mm,
    the estimate's own error."""
    goal = LONG.end_pose()[:3, 3]
    s = ExecutionSettings(models=Models(truth=truth, estimator=estimator, feedback=feedback))
    open_ = _open_loop(truth)
    closed = execute_plan(LONG, goal, 50.0, closed_loop=True, seed=7, settings=s)
    assert open_.final_error_mm > 2.5
    assert closed.final_error_mm < 0.5 and closed.estimate_error_mm < 0.5


def test_the_command_line_refuses_a_wrong_name_before_any_work(tmp_path, capsys):
    bad = tmp_path / "plan.json"
    bad.write_text("{")
    code = main(["execute", "--truth", "kinematic", "examples/toy.yaml", str(bad), "--feedback", "pure_persuit",
                 "--out", str(tmp_path / "out")])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert err == ("error: --feedback: unknown feedback law 'pure_persuit'; available: "
                   "pure_pursuit, sliding_mode; did you mean pure_pursuit?")  # fmt: skip
    assert not (tmp_path / "out").exists()


def test_the_replanner_searches_with_the_planner_asked_for():
    assert Replanner(None, ReplanPolicy()).planner.name == "rcs_star"
    assert Replanner(None, ReplanPolicy(planner="rcs")).planner.name == "rcs"
    with pytest.raises(InvalidInputError, match=r"^planner: planner 'rrt' does not declare"):
        ReplanPolicy(planner="rrt")
