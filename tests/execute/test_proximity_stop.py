"""The closed loop's stop near obstacles (needlekit.execute.proximity) and the recorded
path's clearance certified piece by piece (needlekit.execute.record.certify_in_pieces).

The oracle is a plane: the needle's clearance is the signed distance to it, so the first
point where a stop must fire, and every certificate, are known in closed form.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from needlekit.anatomy.collision import ClearanceCertificate
from needlekit.cli._verdicts import execute_failures
from needlekit.errors import InvalidInputError
from needlekit.execute.proximity import STOP_CLEARANCE_MM, ProximityStop, stop_distance_mm
from needlekit.execute.record import LoopRecord, certify_in_pieces, path_record, trial_status
from needlekit.execute.run import ExecutionSettings, execute_plan
from needlekit.execute.trials import proximity_stop
from needlekit.records import Status
from needlekit.scenario.problems import ScenarioSource
from needlekit.scenario.results import read_plan_json

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"


class Wall:
    """A checker whose obstacle is the half-space beyond a plane: clearance ``(p0 - p) . n``;
    certified as a sampled path is, less half the gap."""

    name, reads_scene = "wall", False

    def __init__(self, point, normal, value=None) -> None:
        self.p0, self.n = np.asarray(point, float), np.asarray(normal, float)
        self.value, self.calls = value, 0

    def certify(self, points, spacing_mm):
        self.calls += 1
        if self.value is not None:
            c = self.value
            return ClearanceCertificate(0, c, c, None if c >= 0 or math.isnan(c) else "x")
        d = (self.p0 - np.asarray(points)) @ self.n
        low = float(d.min()) - 0.5 * spacing_mm
        return ClearanceCertificate(int((d < 0).sum()), float(d.min()), low,
                                    None if low >= 0 else "crossed the wall")  # fmt: skip


def test_the_stop_fires_where_checking_every_step_would():
    rng = np.random.default_rng(4)
    # an estimate going in 0.01 mm a step towards a wall 20 mm ahead, jumping 0.05 mm SD
    # now and then as samples correct it
    steps = np.zeros((3000, 3))
    steps[:, 2] = 0.01
    jumps = rng.random(3000) < 0.02
    steps[jumps] += rng.normal(0.0, 0.05, (jumps.sum(), 3))
    tips = np.cumsum(steps, axis=0)
    wall = Wall([0, 0, 20.0], [0, 0, 1.0])
    stop = ProximityStop(wall, 0.1, 0.25)
    fired = next(i for i, p in enumerate(tips) if stop.breached(p) is not None)
    # brute force: the first tip whose clearance, less half the 0.25 mm gap, is below 0.1
    brute = int(np.flatnonzero(20.0 - tips[:, 2] - 0.125 < 0.1)[0])
    assert fired == brute
    assert stop.breached(tips[fired]) == pytest.approx(20.0 - tips[fired, 2] - 0.125)
    assert stop.checks < fired / 20  # the 1-Lipschitz skip: asked rarely far from the wall


@pytest.mark.parametrize(("value", "stops"), [(-math.inf, True), (math.nan, True),
                                              (math.inf, False), (0.5, False), (0.05, True)])  # fmt: skip
def test_a_clearance_that_cannot_be_bounded_stops_and_an_unbounded_one_is_asked_again(value, stops):
    wall = Wall([0, 0, 0], [0, 0, 1.0], value=value)
    stop = ProximityStop(wall, 0.1, 0.25)
    assert (stop.breached(np.zeros(3)) is not None) is stops
    stop.breached(np.zeros(3))
    # inf (no bound: within the start's exclusion) is asked again at the next step;
    # a finite clearance far from the stop is not, for a tip that has not moved
    assert wall.calls == (2 if stops or math.isinf(value) else 1)


def test_the_stop_distance_is_at_most_half_the_plans_margin():
    assert stop_distance_mm(STOP_CLEARANCE_MM, 0.5) == STOP_CLEARANCE_MM == 0.1
    assert stop_distance_mm(0.1, 0.1) == 0.05 and stop_distance_mm(0.1, 0.0) == 0.0
    for bad in (-0.1, math.nan, math.inf, "0.1"):
        with pytest.raises(InvalidInputError, match="stop_clearance_mm"):
            ExecutionSettings(stop_clearance_mm=bad)


@pytest.fixture(scope="module")
def toy_plan(toy_execution):
    """The toy's plan the session made once (tests/conftest.py ``toy_execution``)."""
    return toy_execution / "plan.json"


def test_the_closed_loop_stops_short_of_a_wall_across_its_plan(toy_plan):
    plan, goal, _ = read_plan_json(toy_plan)
    pts = plan.points_mm(0.5)
    k = int(0.6 * len(pts))
    normal = (pts[k + 1] - pts[k]) / np.linalg.norm(pts[k + 1] - pts[k])
    wall = Wall(pts[k], normal)
    settings = ExecutionSettings()
    run = execute_plan(plan, goal, 50.0, closed_loop=True, seed=3, settings=settings,
                       stop=ProximityStop(wall, 0.1, settings.record_mm))  # fmt: skip
    stopped = run.stopped_near_obstacle
    assert stopped is not None and stopped["stop_mm"] == 0.1
    assert stopped["estimated_clearance_mm"] < 0.1
    assert stopped["inserted_mm"] == run.inserted_mm < 0.6 * plan.length_mm + 1.0
    # the true tip stopped before the wall (its estimate is within 0.3 mm of it)
    assert (wall.p0 - run.points_mm[-1]) @ normal > 0.0
    # the same run without the stop goes through the wall
    through = execute_plan(plan, goal, 50.0, closed_loop=True, seed=3, settings=settings)
    assert through.stopped_near_obstacle is None and (wall.p0 - through.points_mm[-1]) @ normal < 0
    rec = path_record(run, ScenarioSource.of(TOY).without_margin())
    assert rec.stopped_near_obstacle == stopped
    assert LoopRecord.from_dict(json.loads(json.dumps(rec.to_dict())), "r") == rec
    assert trial_status(rec, 1.0) is Status.APPROXIMATE


def test_a_record_refuses_a_stop_not_as_written(toy_plan):
    plan, goal, _ = read_plan_json(toy_plan)
    run = execute_plan(plan, goal, 50.0, closed_loop=True, seed=0)
    good = path_record(run, ScenarioSource.of(TOY).without_margin()).to_dict()
    assert "stopped_near_obstacle" not in good  # a run not stopped has none
    for stop, words in (({"inserted_mm": 1.0}, "expected the fields"),
                        ({"inserted_mm": "1", "estimated_clearance_mm": 0.0, "stop_mm": 0.1},
                         "inserted_mm: expected a finite number")):  # fmt: skip
        with pytest.raises(InvalidInputError, match=words):
            LoopRecord.from_dict({**good, "stopped_near_obstacle": stop}, "r")
    none = {"inserted_mm": 1.0, "estimated_clearance_mm": None, "stop_mm": 0.1}
    assert LoopRecord.from_dict({**good, "stopped_near_obstacle": none}, "r").stopped_near_obstacle == none


def test_every_closed_loop_of_a_trial_gets_its_own_stop_from_the_settings():
    source = ScenarioSource.of(TOY)
    _, problem = source.cached()
    judge = source.without_margin()
    a = proximity_stop(problem, judge, ExecutionSettings())
    b = proximity_stop(problem, judge, ExecutionSettings())
    assert a is not b and a.stop_mm == stop_distance_mm(0.1, problem.safety_margin_mm)
    assert a.spacing_mm == ExecutionSettings().record_mm
    assert proximity_stop(problem, judge, ExecutionSettings(stop_clearance_mm=None)) is None


def test_a_stopped_insertion_exits_1_with_its_line():
    run = {"runs": 10, "violated": 0, "aborted": 0, "stopped_near_obstacle": 2}
    lines = execute_failures({"open_loop": {"runs": 10, "violated": 0}, "closed_loop": run,
                              "crashed": [], "trials": 10})  # fmt: skip
    assert lines == ["closed loop: 2 of 10 insertions stopped short: the estimated tip came too "
                     "close to an obstacle (execute.json: stopped_near_obstacle)"]  # fmt: skip


def test_each_piece_is_certified_with_its_own_gap():
    wall = Wall([0, 0, 10.0], [0, 0, 1.0])
    # samples 0.25 mm apart, but 1 mm apart far from the wall (z < 3)
    z = np.concatenate([np.arange(0.0, 3.0, 1.0), np.arange(3.0, 9.5 + 1e-9, 0.25)])
    pts = np.stack([np.zeros_like(z), np.zeros_like(z), z], axis=1)
    whole = wall.certify(pts, 1.0)
    pieces = certify_in_pieces(wall, pts)
    assert whole.certified_clearance_mm == pytest.approx(0.5 - 0.5)
    assert pieces.certified_clearance_mm == pytest.approx(0.5 - 0.125)  # the last piece's gap
    assert pieces.sampled_clearance_mm == whole.sampled_clearance_mm == pytest.approx(0.5)
    # every segment is in a piece: moving any one sample across the wall is seen
    for i in range(len(pts)):
        moved = pts.copy()
        moved[i, 2] = 10.5
        assert certify_in_pieces(wall, moved).violation is not None
    # evenly spaced samples: the pieces certify what the whole path does
    even = pts[3:]
    assert certify_in_pieces(wall, even).certified_clearance_mm == pytest.approx(
        wall.certify(even, 0.25).certified_clearance_mm
    )


def test_every_closed_loop_the_package_runs_is_given_its_stop():
    """Each call of ``execute_plan`` in needlekit passes ``stop=``: a closed loop added
    without one would insert blind to the obstacles its estimate nears."""
    import ast

    src = Path(__file__).resolve().parents[2] / "src" / "needlekit"
    calls = []
    for path in sorted(src.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "execute_plan":
                calls.append((path.relative_to(src).as_posix(), node.lineno,
                              {k.arg for k in node.keywords}))  # fmt: skip
    assert len(calls) >= 4, calls  # the trials' three runs and the benchmark's
    assert [c[:2] for c in calls if "stop" not in c[2]] == []
