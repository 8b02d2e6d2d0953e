"""The result contract: every result kind's ``to_dict`` and ``from_dict`` round trip
(to_dict -> JSON -> from_dict -> to_dict gives the same record), one status vocabulary,
the records written before it still read, and a budget stop is never infeasible."""

from __future__ import annotations

import json

import numpy as np
import pytest

from needlekit.anatomy.fields import ComplementField
from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus, Verification
from needlekit.planning.steerable.dynamic import Cycle, DynamicResult, DynamicStatus
from needlekit.planning.steerable.dynamic_record import DynamicRecord
from needlekit.planning.steerable.moving import Motion, MovingObstacle
from needlekit.planning.steerable.plan import SteerablePlan, plan_from_dict
from needlekit.planning.steerable.result import PlanResult, goals_from_dict
from needlekit.planning.steerable.sweep_result import (
    SweepResult,
    sweep_stats,
    sweeps_from_dict,
    sweeps_to_dict,
)
from needlekit.planning.straight.ablation import AblationOutcome
from needlekit.planning.straight.coverage import (
    AblationZone,
    CoveragePlan,
    CoverageReport,
    CoverageStatus,
)
from needlekit.planning.straight.entry import Entry
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
from needlekit.planning.straight.sequence import MultiNeedlePlan, NeedleRecord, plan_needles
from needlekit.records import Status, enum_of, field_of

GOAL = np.array([0.0, 0.0, 30.0])


def _json(record: dict) -> dict:
    return json.loads(json.dumps(record, allow_nan=False))


def _equal(a, b, where="record") -> None:
    """Records equal, each number to the last bits a unit conversion (deg <-> rad) rounds."""
    assert type(a) is type(b) or {type(a), type(b)} <= {int, float}, where
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for k in a:
            _equal(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _equal(x, y, f"{where}[{i}]")
    elif isinstance(a, float):
        assert a == pytest.approx(b, rel=1e-14, abs=1e-12), where
    else:
        assert a == b, where


def _same_after_round_trip(obj, from_dict, *args):
    first = _json(obj.to_dict())
    again = from_dict(first, "record", *args)
    _equal(_json(again.to_dict()), first)
    return again


def _plan() -> SteerablePlan:
    return SteerablePlan(np.eye(4), [[0.0, 0.01, 10.0], [0.5, 0.0, 20.5]])


def _result(status=PlanStatus.SOLVED, planner="rcs_star") -> PlanResult:
    plan = _plan() if status.has_plan else None
    cost = plan.length_mm if plan is not None else float("inf")
    stats = {"iterations": 12, "certified": True, "reason": "search finished"}
    return PlanResult(status, planner, plan, cost, 0.25, GOAL, stats, np.eye(4))


# -- the status vocabulary ----------------------------------------------------------------


def test_one_status_vocabulary_for_every_planner():
    assert PlanStatus is Status
    assert [s.value for s in Status] == [
        "solved", "approximate", "infeasible", "timeout", "invalid_input",
    ]  # fmt: skip
    # records written before the one result contract say invalid_problem: they still read
    assert Status("invalid_problem") is Status.INVALID_INPUT is Status.INVALID_PROBLEM
    old = {**_result(PlanStatus.INVALID_INPUT).to_dict(), "status": "invalid_problem"}
    assert PlanResult.from_dict(old, "plan.json").status is Status.INVALID_INPUT
    with pytest.raises(InvalidInputError, match=r"^plan.json: status: expected one of solved"):
        enum_of(Status, "done", "plan.json: status")
    with pytest.raises(InvalidInputError, match=r"^r: seed: expected a whole number"):
        field_of({"seed": 1.5}, "seed", "r", "int")


# -- steerable results ----------------------------------------------------------------------


@pytest.mark.parametrize("status", list(Status))
def test_a_plan_result_round_trips(status):
    again = _same_after_round_trip(_result(status), PlanResult.from_dict)
    assert again.status is status and again.stats["iterations"] == 12
    if status.has_plan:
        assert np.allclose(again.plan.primitives, _plan().primitives)


def test_a_plan_round_trips_and_a_plan_record_without_motions_holds_none():
    again = _same_after_round_trip(_plan(), SteerablePlan.from_dict)
    assert again.length_mm == pytest.approx(30.5)
    plan, goal = plan_from_dict(_json(_result(Status.TIMEOUT).to_dict()), "plan.json")
    assert plan is None and goal.tolist() == GOAL.tolist()
    with pytest.raises(InvalidInputError, match="status solved without motions"):
        PlanResult.from_dict({**_result().to_dict(), "primitives": []}, "plan.json")


def test_the_goals_record_reads_one_result_per_target():
    record = _json(
        {"planner": "rrt", "mode": "per-target",
         "targets": [_result(planner="rrt").to_dict(), _result(Status.TIMEOUT, "rrt").to_dict()]}
    )  # fmt: skip
    got = goals_from_dict(record, "goals.json")
    assert [r.status for r in got] == [Status.SOLVED, Status.TIMEOUT]
    assert [_json(r.to_dict()) for r in got] == record["targets"]


def _sweep(planner: str) -> SweepResult:
    dirs = np.eye(3)[[2, 0, 1, 2]] * [1, 1, 1]
    eff = np.array([True, True, False, True])
    solved = _result(planner=planner)
    results = [solved, _result(Status.TIMEOUT, planner), None, _result(Status.INFEASIBLE, planner)]
    return SweepResult(dirs, eff, results, planner, sweep_stats(dirs, eff, results, 1.5))


def test_a_sweep_and_a_sweep_file_round_trip():
    one = _same_after_round_trip(_sweep("rcs"), SweepResult.from_dict)
    assert [None if r is None else r.status for r in one.results] == [
        Status.SOLVED, Status.TIMEOUT, None, Status.INFEASIBLE,
    ]  # fmt: skip
    sweeps = {"rcs_star": _sweep("rcs_star"), "rrt": _sweep("rrt")}
    record = _json(sweeps_to_dict(sweeps))
    again = sweeps_from_dict(record, "sweep.json")
    assert list(again) == ["rcs_star", "rrt"]
    _equal(_json(sweeps_to_dict(again)), record)
    assert again["rrt"].best.plan is not None


# -- straight results -----------------------------------------------------------------------


def _entry(target=(0.0, 0.0, 0.0)) -> Entry:
    return Entry(np.array([0.0, 0.0, 100.0]), np.array(target), 0.1, 0.2, 100.0, 3.5, 4.0, 7)


def test_an_entry_and_a_needle_round_trip():
    again = _same_after_round_trip(_entry(), Entry.from_dict)
    assert again.iterations == 7
    needle = NeedleRecord(1, 0, np.zeros(3), np.zeros(3), _entry(), np.inf, {"free": 3})
    _same_after_round_trip(needle, NeedleRecord.from_dict)
    blocked = NeedleRecord(2, 1, np.ones(3), np.ones(3), None, 2.0, {"free": 0})
    assert _same_after_round_trip(blocked, NeedleRecord.from_dict).entry is None


def _straight_problem():
    scene = Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 100.0)),
            Structure("vessel", Role.OBSTACLE, Capsule([-60, 5, 35], [60, 5, 35], 4.0)),
        ]
    )
    return StraightProblem(scene, [0, 0, 0], "skin", StraightNeedle(1.0, 150.0))


TARGETS = np.array([[0.0, 0.0, 0.0], [0.0, -15.0, 0.0]])


def test_a_multi_needle_plan_round_trips():
    plan = plan_needles(_straight_problem(), TARGETS, order=[0, 1], resolution_deg=6.0)
    assert plan.status is Status.SOLVED
    again = _same_after_round_trip(plan, MultiNeedlePlan.from_dict)
    assert again.solved and again.status is Status.SOLVED
    # a record written before the status said timeouts: solved or infeasible, read as such
    old = {**_json(plan.to_dict()), "status": "solved"}
    assert MultiNeedlePlan.from_dict(old, "multi.json").status is Status.SOLVED
    with pytest.raises(InvalidInputError, match=r"multi\.json: status: infeasible does not go"):
        MultiNeedlePlan.from_dict({**old, "status": "infeasible"}, "multi.json")


def test_a_sequence_cut_by_its_budget_is_never_infeasible():
    calls = []

    def budget(n):
        def keep_going():
            calls.append(1)
            return len(calls) <= n

        return keep_going

    # the order is given: one needle placed, then the budget runs out
    cut = plan_needles(
        _straight_problem(), TARGETS, order=[0, 1], resolution_deg=6.0, keep_going=budget(1)
    )
    assert cut.status is Status.APPROXIMATE and not cut.solved
    assert len(cut.needles) == 1 and cut.needles[0].entry is not None
    assert "budget ran out before needle 2" in cut.reason
    record = _json(cut.to_dict())
    assert record["status"] == "approximate"
    assert MultiNeedlePlan.from_dict(record, "multi.json").status is Status.APPROXIMATE
    # the order is searched: the budget runs out while mapping, before any needle
    calls.clear()
    none = plan_needles(_straight_problem(), TARGETS, resolution_deg=6.0, keep_going=budget(0))
    assert none.status is Status.TIMEOUT and none.needles == ()
    assert _json(none.to_dict())["status"] == "timeout"
    # a needle with no trajectory is the infeasible verdict, with its reason
    shell = ComplementField(Sphere([0, 0, 0], 20.0))  # the target sealed in a pocket
    walled = StraightProblem(
        Scene([Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 100.0)),
               Structure("shell", Role.OBSTACLE, shell)]),
        [0, 0, 0], "skin", StraightNeedle(1.0, 150.0),
    )  # fmt: skip
    blocked = plan_needles(walled, [[0.0, 0.0, 0.0]], resolution_deg=10.0)
    assert blocked.status is Status.INFEASIBLE and "no trajectory" in blocked.reason


def _coverage_report(needles=2) -> CoverageReport:
    return CoverageReport(0.98, 1.0, needles, 12.0, 4.0, 15.0, 11.0, 3.0, 0.24, 1.0)


def test_the_coverage_records_round_trip():
    zone = AblationZone.ellipsoid(30.0, 20.0)
    assert AblationZone.from_dict(_json(zone.to_dict()), "zone") == zone
    _same_after_round_trip(_coverage_report(), CoverageReport.from_dict)
    pts = np.array([[0.0, 0.0, 0.0], [0.0, -15.0, 0.0]])
    chosen = CoveragePlan(CoverageStatus.COVERED, pts, pts + [0, 0, 2.0], np.tile([0, 0, 1.0], (2, 1)),
                          zone, _coverage_report(), 0.95, 40, 2.5, 3, 2)  # fmt: skip
    again = _same_after_round_trip(chosen, CoveragePlan.from_dict, zone)
    assert again.needles == 2 and again.status is CoverageStatus.COVERED
    outcome = AblationOutcome(chosen, _coverage_report(), True, "")
    assert _same_after_round_trip(outcome, AblationOutcome.from_dict).ok
    assert AblationOutcome.from_dict(None, "multi.json: coverage") is None
    with pytest.raises(InvalidInputError, match=r"^c: zone: kind: missing"):
        AblationOutcome.from_dict({**_json(outcome.to_dict()), "zone": {}}, "c")


# -- a run among moving obstacles -----------------------------------------------------------


def test_a_dynamic_run_round_trips_through_its_record():
    plan = _plan()
    motion = Motion([0.0, 1.0, 0.0], [0.5, 0.0, 0.0], 4.0, 30.0)
    moving = (MovingObstacle("vessel", Sphere([10.0, 0.0, 20.0], 2.0), motion, None),)
    check = Verification(True, (), {"certified_moving_clearance_mm": 1.25, "length_mm": 30.5})
    cycles = (
        Cycle(0, 0.0, 0.0, np.eye(4), {"vessel": [0.0, 0.0, 0.0]}, (0.0, 3.0), _result(),
              "planned", 10.0),
        Cycle(1, 2.0, 10.0, np.eye(4),
              {"vessel": [0.0, 2.0, 0.0]}, (2.0, 2.0), _result(Status.TIMEOUT), "kept", 0.0),
    )  # fmt: skip
    settings = {"planner": "rcs_star", "insertion_speed_mm_s": 5.0, "step_mm": 10.0,
                "predict": "arrival", "lookahead_s": None}  # fmt: skip
    failed = Verification(
        False, ("clearance 0.2 mm < 1 mm",), {"certified_moving_clearance_mm": 0.2}
    )
    run = DynamicResult(DynamicStatus.REACHED, "", plan, check, cycles, settings, moving,
                        (_result(), failed))  # fmt: skip
    record = _json(run.to_dict())
    again = DynamicRecord.from_dict(record, "dynamic.json")
    _equal(_json(again.to_dict()), record)
    assert again.status is DynamicStatus.REACHED
    assert again.motions["vessel"].to_dict() == motion.to_dict()
    assert again.checks["static"]["ok"] is False and again.static.status is Status.SOLVED
