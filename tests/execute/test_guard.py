"""A loop that fails safe: every sample passes the sensor guard (non-finite, frozen, jump,
innovation gate), input that stops or lies holds the needle within 0.5 s of the loop's
clock, the needle never goes in while held, a hold ends in a resume or an abort, and the
faults a profile injects replay from the trial's seed. Times are the loop's simulated
clock, never the wall clock."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.control.em import EMSample
from needlekit.execute.estimator import TipEstimator
from needlekit.execute.faults import PROFILES, Fault, FaultSchedule, FaultySensor
from needlekit.execute.guard import STALE_S, GuardSpec, SensorGuard
from needlekit.execute.needle_sim import ExecutionNoise
from needlekit.execute.run import DEFAULT_SENSOR, ExecutionSettings, LoopHooks, execute_plan
from needlekit.planning.steerable.plan import SteerablePlan

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"
#: 60 mm straight at 2 mm/s: 30 s of insertion.
PLAN = SteerablePlan(np.eye(4), [[0.0, 0.0, 60.0]])
GOAL = np.array([0.0, 0.0, 60.0])
FAULT_AT_S = 5.0


class _Faulted:
    """The simulated sensor with one hand-made fault from ``FAULT_AT_S`` for ``length_s``."""

    def __init__(self, kind: str, length_s: float = 100.0, **given) -> None:
        self.kind, self.length_s, self.given = kind, length_s, given

    def hooks(self, seed: int, seen: list) -> LoopHooks:
        from needlekit.control.em import EMSensor

        inner = EMSensor(DEFAULT_SENSOR, np.random.default_rng(seed))
        sch = FaultSchedule.__new__(FaultSchedule)
        sch.rng = np.random.default_rng(0)
        sch.faults = (Fault(self.kind, FAULT_AT_S, FAULT_AT_S + self.length_s, **self.given),)
        return LoopHooks(sensor=FaultySensor(inner, sch), observe_every_s=0.005,
                         observe=lambda t, true, est, pts, state: seen.append((t, state)))  # fmt: skip


def _run(kind, length_s=100.0, guard=None, seed=4, **given):
    guard = GuardSpec(hold_timeout_s=2.0) if guard is None else guard
    seen: list = []
    settings = ExecutionSettings(noise=ExecutionNoise.none(), guard=guard)
    run = execute_plan(PLAN, GOAL, 50.0, closed_loop=True, seed=seed, settings=settings,
                       hooks=_Faulted(kind, length_s, **given).hooks(seed, seen))  # fmt: skip
    return run, seen


def _never_advanced_while_held(seen) -> None:
    """Every observed step spent held left the insertion where the step before had it."""
    held = [i for i, (_, st) in enumerate(seen) if st["phase"] == "held"]
    assert held
    for i in held:
        assert seen[i][1]["inserted_mm"] == seen[i - 1][1]["inserted_mm"]


@pytest.mark.parametrize(
    ("kind", "verdict", "given"),
    [
        ("freeze", "frozen", {"variant": "value"}),
        ("freeze", "frozen", {"variant": "stamp"}),
        ("nan", "non_finite", {}),
        ("dropout", "stopped", {}),
        ("distortion", "jump", {"offset_mm": (15.0, 0.0, 0.0)}),
    ],
)
def test_input_that_fails_holds_the_needle_within_half_a_second(kind, verdict, given):
    run, seen = _run(kind, **given)
    g = run.guard
    hold = g["faults"][0]
    assert (hold["kind"], hold["action"]) == (verdict, "hold")
    assert FAULT_AT_S <= hold["time_s"] <= FAULT_AT_S + 0.5
    assert hold["time_s"] <= FAULT_AT_S + STALE_S + 0.025 + 1e-6  # one sensor period late at most
    # the fault never ends: after the hold timeout (2 s) the insertion is aborted
    abort = g["faults"][1]
    assert (abort["kind"], abort["action"]) == (verdict, "abort")
    assert abort["time_s"] == pytest.approx(hold["time_s"] + 2.0, abs=1e-6)
    assert g["aborted"] and g["holds"] == 1
    assert g["held_s"] == pytest.approx(2.0, abs=0.01)
    # not one step in blind beyond the detection: 2 mm/s up to the hold, nothing after
    assert run.inserted_mm <= 2.0 * hold["time_s"] + 1e-6
    _never_advanced_while_held(seen)
    assert seen[-1][1]["phase"] == "aborted"
    if verdict != "stopped":
        assert g["rejected"][verdict] > 0


def test_a_15_mm_jump_for_a_second_is_rejected_counted_and_the_insertion_resumes():
    run, seen = _run("distortion", length_s=1.0, offset_mm=(0.0, 15.0, 0.0))
    g = run.guard
    assert [(e["kind"], e["action"]) for e in g["faults"]] == [("jump", "hold"), ("jump", "resume")]
    # 40 samples a second: every one of the second's rejected, none used
    assert 38 <= g["rejected"]["jump"] <= 41 and set(g["rejected"]) == {"jump"}
    resume = g["faults"][1]
    assert FAULT_AT_S + 1.0 <= resume["time_s"] <= FAULT_AT_S + 1.0 + 0.1
    assert not g["aborted"] and run.final_error_mm < 1.0
    _never_advanced_while_held(seen)


def test_on_fault_abort_stops_at_the_first_hold():
    run, _ = _run("nan", guard=GuardSpec(on_fault="abort"))
    (event,) = run.guard["faults"]
    assert (event["kind"], event["action"]) == ("non_finite", "abort")
    assert run.guard["aborted"] and run.guard["holds"] == 0


def test_without_faults_no_sample_is_refused_and_nothing_changes():
    settings = ExecutionSettings()
    run = execute_plan(PLAN, GOAL, 50.0, closed_loop=True, seed=2, settings=settings)
    assert run.guard["faults"] == [] and run.guard["rejected"] == {}
    assert run.samples == run.guard["accepted"] > 1000


def _sample(taken, p=(0.0, 0.0, 0.0)):
    g = np.eye(4)
    g[:3, 3] = p
    return EMSample(taken, taken, g)


def _estimator():
    return TipEstimator(np.eye(4), start_sigma_mm=0.4, start_sigma_rad=0.01, r_min_mm=50.0,
                        noise=ExecutionNoise(), position_sigma_mm=0.4,
                        orientation_sigma_rad=0.01)  # fmt: skip


def test_a_repeated_value_is_frozen_only_when_the_needle_moved():
    guard, est = SensorGuard(GuardSpec(), np.eye(4), 0.4), _estimator()
    assert guard.admit(0.025, _sample(0.025), est, 0.0)
    assert guard.admit(0.05, _sample(0.05), est, 0.0)  # held needle, noise-free tracker
    assert not guard.admit(0.075, _sample(0.075), est, 0.05)  # it moved; the value did not
    assert guard.rejected["frozen"] == 1
    # the frozen value stays refused, even when the needle stops
    assert not guard.admit(0.1, _sample(0.1), est, 0.05)
    assert guard.admit(0.125, _sample(0.125, (0.0, 0.0, 0.05)), est, 0.05)


def test_a_timestamp_that_does_not_advance_is_frozen_and_nan_is_non_finite():
    guard, est = SensorGuard(GuardSpec(), np.eye(4), 0.4), _estimator()
    assert guard.admit(0.025, _sample(0.025), est, 0.0)
    assert not guard.admit(0.05, _sample(0.025, (0.0, 0.0, 0.01)), est, 0.0)
    nan = EMSample(0.075, 0.075, np.full((4, 4), np.nan))
    assert not guard.admit(0.075, nan, est, 0.0)
    reflected = _sample(0.1)
    reflected.pose[0, 0] = -1.0
    assert not guard.admit(0.1, reflected, est, 0.0)
    assert dict(guard.rejected) == {"frozen": 1, "non_finite": 1, "invalid": 1}
    assert est.n_updates == 1


def test_the_innovation_gate_refuses_what_the_plausibility_test_lets_through():
    guard, est = SensorGuard(GuardSpec(), np.eye(4), 0.4), _estimator()
    # 3.5 mm: within the plausible reach of 0.4 mm noise (5.5 sqrt 2 sigma + 0.5 = 3.6 mm),
    # and over 6 SD of the innovation (its SD 0.57 mm per axis)
    assert not guard.admit(0.025, _sample(0.025, (3.5, 0.0, 0.0)), est, 0.0)
    assert dict(guard.rejected) == {"gated": 1} and est.last_d2 > 33.1


def test_a_failed_or_late_replan_keeps_the_plan_and_is_recorded():
    guard = SensorGuard(GuardSpec(), np.eye(4), 0.4)
    assert guard.check_replan(1.0, object(), "fail") is None
    assert guard.check_replan(1.0, None) is None
    assert not guard.replan_in_time(2.0, 10.0, 11.5)
    assert guard.replan_in_time(2.0, 10.0, 10.5)
    kinds = [(e["kind"], e["action"]) for e in guard.events]
    assert kinds == [("replan_failed", "kept_plan")] * 2 + [("replan_overrun", "kept_plan")]


def test_a_profile_draws_its_schedule_from_the_seed():
    a = FaultSchedule(PROFILES["mixed"], np.random.default_rng(5), 30.0).to_list()
    b = FaultSchedule(PROFILES["mixed"], np.random.default_rng(5), 30.0).to_list()
    assert a == b and len(a) == 4
    for f in a:
        assert 1.0 <= f["start_s"] <= 27.0 and 0.2 <= f["end_s"] - f["start_s"] <= 2.0
        if f["kind"] == "distortion":
            assert 5.0 <= math.hypot(*f["offset_mm"]) <= 20.0


def test_faults_replay_with_trial_k_and_no_obstacle_is_crossed(tmp_path):
    plan = tmp_path / "plan.json"
    assert main(["plan", str(TOY), "--out", str(plan)]) == 0
    common = ["--seed", "3", "--faults", "mixed", "--replan-delay-ms", "5",
              "--replan-iterations", "200", "--speed-mm-s", "10"]  # fmt: skip
    assert main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--trials", "3", "--out", str(tmp_path / "a"),
                 *common]) == 0  # fmt: skip
    assert main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--replay-trial", "2", "--out", str(tmp_path / "b"),
                 *common]) == 0  # fmt: skip
    import json

    every = json.loads((tmp_path / "a" / "execute.json").read_text())
    one = json.loads((tmp_path / "b" / "execute.json").read_text())
    a, b = every["trials"][2]["closed_loop"], one["trials"][0]["closed_loop"]
    for key in ("faults_injected", "faults", "rejected", "final_error_mm", "points_mm"):
        assert a[key] == b[key]
    s = every["summary"]["closed_loop"]
    assert s["violated"] == 0 and sum(s["faults_injected"].values()) == 12


@pytest.mark.parametrize(
    ("flags", "flag"),
    [
        (["--faults", "lies"], "--faults"),
        (["--on-fault", "pray"], "--on-fault"),
        (["--hold-timeout-s", "nan"], "--hold-timeout-s"),
        (["--hold-timeout-s", "7200"], "--hold-timeout-s"),
    ],
)
def test_bad_fault_flags_are_one_line_naming_the_flag(flags, flag, tmp_path, capsys):
    try:
        code = main(["execute", "--truth", "kinematic", str(TOY), str(tmp_path / "missing.json"), "--out",
                     str(tmp_path / "x"), *flags])  # fmt: skip
    except SystemExit as exc:  # the parser's own refusal
        code = exc.code
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and flag in err


def test_the_cli_names_every_profile_the_library_has():
    from needlekit.cli.execute import FAULT_PROFILES

    assert set(FAULT_PROFILES) == set(PROFILES)


def test_a_timestamp_a_rounding_early_is_read_at_its_step():
    """An OpenIGTLink timestamp (the epoch plus seconds) comes back 0.2 us early: the
    echo of a held needle must not be taken for a frozen tracker."""
    guard, est = SensorGuard(GuardSpec(), np.eye(4), 0.4), _estimator()
    guard.admit(0.150, None, est, 0.30)
    guard.admit(0.155, None, est, 0.31)  # the last step in, then held
    at = (0.0, 0.0, 0.31)
    assert guard.admit(0.160, _sample(0.155 - 2e-7, at), est, 0.31)
    assert guard.admit(0.185, _sample(0.180 - 2e-7, at), est, 0.31)  # held: the same value
    assert not guard.rejected


def test_a_rotation_a_tracker_rounds_is_taken_and_one_the_guard_refuses_is_not_a_pose():
    # a tracker that sends its rotation to four decimals (orthonormal to about 1e-4): the
    # guard passes it (within ORTHONORMAL_TOL), and the filter takes it. Before, the
    # filter's checked log refused anything past 1e-6 and the insertion ended in an error.
    from needlekit.execute.guard import ORTHONORMAL_TOL, is_pose
    from needlekit.geometry.so3 import so3_exp

    guard, est = SensorGuard(GuardSpec(), np.eye(4), 0.4), _estimator()
    rounded = _sample(0.025)
    rounded.pose[:3, :3] = np.round(so3_exp([0.01, -0.02, 0.005]), 4)
    gram = rounded.pose[:3, :3].T @ rounded.pose[:3, :3] - np.eye(3)
    assert 1e-6 < np.abs(gram).max() and np.linalg.norm(gram) < ORTHONORMAL_TOL
    assert guard.admit(0.025, rounded, est, 0.0)
    assert est.n_updates == 1 and np.all(np.isfinite(est.pose))
    # the same screen, for an image's tip pose (execute.target_sensing)
    assert is_pose(rounded.pose) and is_pose(np.eye(4))
    for bad in (np.diag([1.01, 1.0, 1.0, 1.0]), np.diag([-1.0, 1.0, 1.0, 1.0]),
                np.full((4, 4), np.nan)):  # fmt: skip
        assert not is_pose(bad)
