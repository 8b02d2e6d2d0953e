"""The adaptation off the control tick (``ProcedureSettings.adaptation_delay_steps``): D = 0
is the loop as it was, bit for bit; the mailbox and its schedule. A study's outcome with the
adaptation 2 ms off the tick: tests/reproduce/test_tang.py, beside the reproduction whose
defaults' row runs the same trials."""

import dataclasses
import importlib.util
import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from needlekit.control.procedure import ProcedureSettings, TrialResult, run_trial
from needlekit.control.schedule import AdaptationMailbox, delay_steps_from_ms
from needlekit.errors import InvalidInputError
from needlekit.studies.puncture_study import (
    PunctureScenario,
    TrialOptions,
    sample_trial,
    trial_settings,
)


def _legacy_run_trial():
    """``run_trial`` as it was before the schedule (tests/control/_legacy_procedure.py)."""
    path = Path(__file__).with_name("_legacy_procedure.py")
    spec = importlib.util.spec_from_file_location("_legacy_procedure", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.legacy_run_trial


def _short_trial(index=1, phase_timeout_s=3.0, **procedure):
    """A study trial cut short by its phase time limit: the initial adaptation (about 2.5 s
    of 100 Hz samples), then the alignment until it times out."""
    scenario = PunctureScenario()
    setup, _ = sample_trial(scenario, np.random.default_rng(index), index)
    adaptation, ps, spec = trial_settings(scenario, TrialOptions(), setup.nominal_parameters)
    ps = dataclasses.replace(ps, phase_timeout_s=phase_timeout_s, **procedure)
    return setup, adaptation, ps, spec


def _same(a, b) -> bool:
    """Equal to the bit (NaN equal to NaN), arrays of the same dtype."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        a, b = np.asarray(a), np.asarray(b)
        return (
            a.dtype == b.dtype
            and a.shape == b.shape
            and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
        )
    if isinstance(a, dict):
        return isinstance(b, dict) and list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return type(a) is type(b) and len(a) == len(b) and all(map(_same, a, b))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return type(a) is type(b) and a == b  # fmt: skip


def test_without_a_delay_a_trial_is_the_loop_before_the_schedule_field_by_field():
    # noisy sensors with dropouts and an outage in the alignment (the robot stops and
    # resumes), the history of keyframes, the adaptation's task error from the controller
    setup, adaptation, ps, spec = _short_trial(adaptation_delay_steps=0)
    needle = dataclasses.replace(
        spec, dropout_probability=0.02, dropout_burst_mean=2.0, outages=((3.3, 3.6),)
    )
    runs = [
        fn(
            setup, np.random.default_rng(7), procedure=ps, adaptation=adaptation,
            needle_sensor=needle, scope_sensor=spec,
        )
        for fn in (run_trial, _legacy_run_trial())
    ]  # fmt: skip
    new, old = runs
    # the comparison is not empty: adaptation, a phase change, stops, logs
    assert old.counts["needle_samples"] > 200 and list(old.phase_times_s) == ["adapt", "align"]
    assert old.events and len(old.log["t_s"]) > 200
    for f in dataclasses.fields(TrialResult):
        if f.name in _AFTER_THE_LEGACY_COPY:
            continue
        assert _same(getattr(new, f.name), getattr(old, f.name)), f.name
    # the fields the legacy loop did not have agree with the ones it had
    miss = float(np.linalg.norm(new.final_tip_pose[:3, 3] - setup.target_mm))
    assert miss == new.position_error_mm
    assert math.isnan(new.min_needle_gap_mm)  # no placed needles


#: TrialResult fields added after the legacy loop was copied.
_AFTER_THE_LEGACY_COPY = {"final_tip_pose", "final_estimated_tip_pose", "min_needle_gap_mm"}


def test_without_a_delay_every_needle_sample_is_adapted_in_its_own_tick():
    setup, adaptation, ps, spec = _short_trial(phase_timeout_s=1.0, adaptation_delay_steps=0)
    timings: list = []
    r = run_trial(
        setup, np.random.default_rng(0), procedure=ps, adaptation=adaptation,
        needle_sensor=spec, scope_sensor=spec, timings=timings,
    )  # fmt: skip
    kinds = [k for _, k, _ in timings]
    assert len(kinds) == r.counts["steps"]
    assert kinds.count("control+adaptation") == r.counts["needle_samples"]
    assert set(kinds) == {"control", "control+adaptation"}
    assert "adaptation_jobs" not in r.counts  # the counts are those of the loop before


def test_the_mailbox_keeps_the_newest_waiting_job_and_applies_exactly_d_ticks_after_start():
    box = AdaptationMailbox(3)
    assert box.due(0) is None and box.start(0) is None  # nothing posted
    box.post(0, "s0")
    assert box.start(0) == "s0" and box.busy
    box.finish("u0")
    box.post(1, "s1")  # the worker is busy: s1 waits
    assert box.start(1) is None and box.waiting == "s1"
    box.post(2, "s2")  # a newer sample replaces the one waiting
    assert box.waiting == "s2" and box.replaced == 1
    assert [box.due(t) for t in (1, 2)] == [None, None]
    assert box.due(3) == "u0" and not box.busy  # exactly at 0 + D
    assert box.start(3) == "s2"  # the waiting job starts when the worker is free
    box.finish("u2")
    assert [box.due(t) for t in (4, 5)] == [None, None] and box.due(6) == "u2"
    assert (box.posted, box.started, box.replaced, box.applied) == (3, 2, 1, 2)


def test_a_result_not_taken_at_its_tick_is_an_error():
    box = AdaptationMailbox(2)
    box.post(0, "s0")
    box.start(0)
    box.finish("u0")
    with pytest.raises(RuntimeError, match="due at tick 2"):
        box.due(3)


@pytest.mark.parametrize("bad", [0, -1, 1.5, "2"])
def test_the_mailbox_needs_a_delay_of_at_least_one_tick(bad):
    with pytest.raises(InvalidInputError, match="adaptation_delay_steps"):
        AdaptationMailbox(bad)


@pytest.mark.parametrize("bad", [-1, 2.0])
def test_run_trial_refuses_a_delay_that_is_not_a_whole_number_of_ticks(bad):
    setup, adaptation, ps, _ = _short_trial(adaptation_delay_steps=bad)
    with pytest.raises(InvalidInputError, match="adaptation_delay_steps"):
        run_trial(setup, np.random.default_rng(0), procedure=ps, adaptation=adaptation)


def _tick_kinds_and_jobs(timings):
    """Per tick its kind, and the ticks in which a job started."""
    ticks, started = [], []
    for _, kind, _ in timings:
        if kind == "adaptation_job":
            started.append(len(ticks) - 1)  # appended after the tick that started it
        else:
            ticks.append(kind)
    return ticks, started


def test_off_the_tick_each_update_is_applied_d_ticks_after_its_job_starts():
    d = 3
    setup, adaptation, ps, spec = _short_trial(phase_timeout_s=1.0, adaptation_delay_steps=d)
    timings: list = []
    r = run_trial(
        setup, np.random.default_rng(0), procedure=ps, adaptation=adaptation,
        needle_sensor=spec, scope_sensor=spec, timings=timings,
    )  # fmt: skip
    ticks, started = _tick_kinds_and_jobs(timings)
    applied = [i for i, k in enumerate(ticks) if k == "control+apply"]
    assert len(ticks) == r.counts["steps"] and "control+adaptation" not in ticks
    # every sample became a job (one every 10 ticks: none waited), applied at n + D
    assert len(started) == r.counts["needle_samples"] == r.counts["adaptation_jobs"]
    assert r.counts["adaptation_replaced"] == 0
    assert applied == [n + d for n in started if n + d < len(ticks)]


def test_a_delay_longer_than_the_sensor_period_replaces_waiting_samples():
    d = 25  # 2.5 sensor periods: about every other sample finds the worker busy
    setup, adaptation, ps, spec = _short_trial(phase_timeout_s=1.0, adaptation_delay_steps=d)
    timings: list = []
    r = run_trial(
        setup, np.random.default_rng(0), procedure=ps, adaptation=adaptation,
        needle_sensor=spec, scope_sensor=spec, timings=timings,
    )  # fmt: skip
    ticks, started = _tick_kinds_and_jobs(timings)
    c = r.counts
    assert c["adaptation_replaced"] > 0 and c["adaptation_jobs"] == len(started)
    # each sample was run, replaced, or still waits at the end
    assert c["needle_samples"] - c["adaptation_jobs"] - c["adaptation_replaced"] in (0, 1)
    # one job at a time: each starts when (or after) the one before was applied
    assert all(b >= a + d for a, b in itertools.pairwise(started))
    applied = [i for i, k in enumerate(ticks) if k == "control+apply"]
    assert applied == [n + d for n in started if n + d < len(ticks)]


def test_a_delay_in_ms_is_a_whole_number_of_control_periods():
    assert delay_steps_from_ms(0, 0.001) == 0 and delay_steps_from_ms(2.0, 0.001) == 2
    assert delay_steps_from_ms(0.003 * 1e3, 0.001) == 3
    for bad in (2.5, -1.0, float("nan"), float("inf"), "x"):
        with pytest.raises(InvalidInputError, match=r"^--adaptation-delay-ms: expected a whole"):
            delay_steps_from_ms(bad, 0.001, "--adaptation-delay-ms")


def test_the_parser_knows_the_controller_period():
    from needlekit.cli.puncture import CONTROL_PERIOD_MS

    assert CONTROL_PERIOD_MS == ProcedureSettings().dt_s * 1e3


def test_the_default_schedule_is_the_same_everywhere():
    """2 ms off the tick by default: the settings, the study's options, both commands'
    flags and the benchmark's default agree."""
    import inspect

    from needlekit.benchmarks.control import run_control_benchmark
    from needlekit.cli.puncture import DEFAULT_ADAPTATION_DELAY_MS
    from needlekit.control.schedule import DEFAULT_ADAPTATION_DELAY_STEPS
    from needlekit.studies.puncture_study import TrialOptions

    assert DEFAULT_ADAPTATION_DELAY_STEPS == 2
    assert ProcedureSettings().adaptation_delay_steps == DEFAULT_ADAPTATION_DELAY_STEPS
    assert TrialOptions().adaptation_delay_steps == DEFAULT_ADAPTATION_DELAY_STEPS
    ms = DEFAULT_ADAPTATION_DELAY_STEPS * ProcedureSettings().dt_s * 1e3
    assert DEFAULT_ADAPTATION_DELAY_MS == ms
    default = inspect.signature(run_control_benchmark).parameters["adaptation_delay_ms"].default
    assert default == ms
