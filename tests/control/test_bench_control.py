"""``needlekit bench control``: the per-kind statistics, the garbage-collection watch, the
TRO 2022 yardstick (measured, or skipped with its reason). No timing is asserted."""

import gc
import sys
from importlib.metadata import PackageNotFoundError

import numpy as np
import pytest

import needlekit.benchmarks.tro2022 as tro2022
from needlekit.benchmarks import control as bench
from needlekit.errors import InvalidInputError


def test_the_recorder_keeps_each_step_phase_kind_and_time():
    rec = bench._StepRecorder()
    for entry in [("adapt", "control", 1e-4), ("adapt", "control+apply", 2e-4),
                  ("align", "adaptation_job", 1e-3), ("align", "control", 5e-5)]:  # fmt: skip
        rec.append(entry)
    phases, kinds, secs = rec.arrays()
    assert phases.tolist() == ["adapt", "adapt", "align", "align"]
    assert kinds.tolist() == ["control", "control+apply", "adaptation_job", "control"]
    assert secs.tolist() == [1e-4, 2e-4, 1e-3, 5e-5]
    with pytest.raises(KeyError):
        rec.append(("adapt", "unknown kind", 1.0))


def test_statistics_and_verdicts_of_a_tick_kind():
    st = bench.step_statistics(np.array([50, 60, 70, 80, 1000]) * 1e-6)
    assert (st["n"], st["median"], st["max"]) == (5, 70.0, 1000.0)
    assert bench.tick_verdict(st) == {
        "median_ok": True, "p99_ok": False, "p999_ok": True, "pass": False,
    }  # fmt: skip
    assert bench.tick_verdict(bench.step_statistics([])) == {
        "median_ok": None, "p99_ok": None, "p999_ok": None, "pass": None,
    }  # fmt: skip


def test_the_p999_is_reported_and_judged_for_each_kind():
    tail = np.r_[np.full(998, 50.0), 2000.0, 2000.0] * 1e-6  # 2 in 1000 past the 1 ms period
    st = bench.step_statistics(tail)
    assert st["p99"] == pytest.approx(50.0) and st["p99.9"] > 1000.0
    assert bench.tick_verdict(st) == {
        "median_ok": True, "p99_ok": True, "p999_ok": False, "pass": False,
    }  # fmt: skip
    assert bench.TICK_TARGET_US == {"median": 100.0, "p99": 300.0, "p99.9": 1000.0}
    rows = bench._rows(st | {"verdict": bench.tick_verdict(st)}, {"control": st | {
        "verdict": bench.tick_verdict(st)}}, {}, None, {"collections_by_generation": [0, 0, 0],
        "pause_us_total": 0.0, "pause_us_max": 0.0}, ([0.0] * 3, [0.0] * 3),
        {"status": "skipped", "reason": "not requested"})  # fmt: skip
    assert rows[1]["name"] == "  control" and rows[1]["summary"].endswith("FAIL (p99.9)")
    assert "p99.9 <= 1000 us" in rows[0]["summary"]


def test_the_gc_watch_counts_collections_by_generation():
    with bench._GCWatch() as watch:
        gc.collect()
    assert watch not in gc.callbacks
    record = watch.record()
    assert record["collections_by_generation"][2] >= 1 and record["pause_us_max"] >= 0.0


def test_bad_inputs_fail_before_any_trial():
    with pytest.raises(InvalidInputError, match=r"^trials: "):
        bench.run_control_benchmark(trials=0)
    with pytest.raises(InvalidInputError, match=r"^adaptation_delay_ms: expected a whole"):
        bench.run_control_benchmark(adaptation_delay_ms=0.5)
    with pytest.raises(InvalidInputError, match=r"^qp_solver: unknown QP solver 'nope'"):
        bench.run_control_benchmark(qp_solver="nope")


def test_the_yardstick_is_skipped_with_the_reason_when_its_package_is_missing(monkeypatch):
    def missing(name):
        raise PackageNotFoundError(name)

    monkeypatch.setattr(tro2022, "version", missing)
    ref = tro2022.tro2022_reference(steps_per_target=1)
    assert ref["status"] == "skipped"
    assert ref["reason"] == (
        "marinholab-papers-tro2022-adaptivecontrol is not installed "
        "(pip install 'needlekit[tro2022]')"
    )


def test_the_yardstick_is_skipped_with_the_reason_when_it_does_not_import(monkeypatch):
    monkeypatch.setattr(tro2022, "version", lambda name: "0.0")
    monkeypatch.setitem(sys.modules, "marinholab.papers.tro2022", None)  # import fails
    ref = tro2022.tro2022_reference(steps_per_target=1)
    assert ref["status"] == "skipped"
    assert ref["reason"].startswith(
        "marinholab-papers-tro2022-adaptivecontrol 0.0 does not import beside dqrobotics 0.0: "
        "ModuleNotFoundError"
    )


def test_ratios_are_needlekit_over_tro(monkeypatch):
    ref = {"status": "measured", "full": {"median": 200.0, "p99": 400.0},
           "task_only": {"median": 50.0, "p99": 100.0}}  # fmt: skip
    monkeypatch.setattr(tro2022, "tro2022_reference", lambda steps: ref)
    ours = {"adaptive": {"n": 3, "median": 100.0, "p99": 800.0}, "control": {"n": 0}}
    out = bench._tro2022_reference(ours)
    assert out["ratios_needlekit_over_tro"] == {"adaptive_vs_full": {"median": 0.5, "p99": 2.0}}


def test_the_wheel_runs_its_own_example_where_it_is_installed():
    pytest.importorskip("marinholab.papers.tro2022.adaptive_control")
    ref = tro2022.tro2022_reference(steps_per_target=3)
    assert ref["status"] == "measured", ref.get("reason")
    assert (ref["dof"], ref["parameters"], ref["vfis"]) == (6, 36, 36)
    assert ref["full"]["n"] == ref["task_only"]["n"] == 6
    # only the adaptive strategy moves the estimate
    assert ref["full"]["parameter_change"] > 0.0 and ref["task_only"]["parameter_change"] == 0.0


@pytest.mark.slow
def test_one_trial_with_the_adaptation_off_the_tick_is_reported_per_kind():
    record = bench.run_control_benchmark(trials=1, adaptation_delay_ms=2, kinematics_calls=20)
    kinds = record["step_us_by_kind"]
    assert record["inputs"]["adaptation_delay_ms"] == 2.0
    assert kinds["control+adaptation"]["n"] == 0  # no adaptation inside a tick
    ticks = kinds["control"]["n"] + kinds["control+apply"]["n"]
    assert record["step_us"]["n"] == ticks
    assert kinds["adaptation_job"]["n"] - kinds["control+apply"]["n"] in (0, 1)
    job = record["adaptation_job"]
    assert job["budget_us"] == pytest.approx(2000.0)
    assert 0 <= job["overruns"] <= kinds["adaptation_job"]["n"]
    assert set(record["step_us"]["verdict"]) == {"median_ok", "p99_ok", "p999_ok", "pass"}
    assert len(record["gc"]["collections_by_generation"]) == 3
    assert len(record["load_average"]["before"]) == len(record["machine"]["load_average"]) == 3
    assert record["tro2022"]["status"] in ("measured", "skipped")
    assert record["trial_status"] == ["solved"]
    assert record["inputs"]["qp_solver"] == "daqp"
    for kind in ("control", "control+apply"):  # each tick kind judged on its own
        assert set(kinds[kind]["verdict"]) == {"median_ok", "p99_ok", "p999_ok", "pass"}
        assert kinds[kind]["p99"] <= kinds[kind]["p99.9"] <= kinds[kind]["max"]
