"""The closed loop sees the target move and re-plans to where it is seen: the sensing
policies em, checkpoints and tracking in the loop, side by side on the same draws, their
records, and their flags.

Every run here is seeded, with re-plans on an iteration budget and a fixed simulated delay:
the runs are reproducible to the bit, and the expectations are fixed."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.execute import imaging
from needlekit.execute.imaging import CheckpointSpec, TargetSample, TrackingSpec
from needlekit.execute.needle_sim import ExecutionNoise, SimulatedNeedle
from needlekit.execute.plugins import TRUTHS, Models
from needlekit.execute.record import LoopRecord, TrialRecord, path_record
from needlekit.execute.replan import ReplanPolicy
from needlekit.execute.run import ExecutionSettings, execute_plan
from needlekit.execute.target_sensing import SensingPolicy
from needlekit.execute.trials import ExecuteOptions, run_execute_trial, trial_seed
from needlekit.scenario.problems import ScenarioSource
from needlekit.scenario.results import read_plan_json

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"
REPRODUCIBLE = ["--replan-delay-ms", "5", "--replan-iterations", "500", "--seed", "3"]
#: How far the tissue carries the target (mm), sideways to the plan's end.
MOVE_MM = 4.0
#: Noise-free imaging: a scan or a tracker sample is where the target (and the tip) is.
EXACT = SensingPolicy(
    checkpoints=CheckpointSpec(every_mm=10.0, position_sigma_mm=0.0, orientation_sigma_deg=0.0),
    tracking=TrackingSpec(position_sigma_mm=0.0),
)


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("sensing") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(path)]) == 0
    return path


class _MovingTarget(SimulatedNeedle):
    """The needle follows its model exactly; the tissue carries the target MOVE_MM sideways
    (along the plan's end x axis) while 40 % to 50 % of the plan goes in."""

    def __init__(self, setup, plan):
        super().__init__(setup.start_pose, setup.r_min_mm, ExecutionNoise.none(), setup.rng)
        self.goal = np.array(setup.goal_mm, dtype=float)
        self.side = MOVE_MM * plan.end_pose()[:3, 0]
        self.ramp = (0.4 * plan.length_mm, 0.5 * plan.length_mm)

    def target_mm(self):
        a, b = self.ramp
        return self.goal + float(np.clip((self.inserted_mm - a) / (b - a), 0.0, 1.0)) * self.side


def _toy_trial(plan, truth, policy, sensing, loops=None):
    """One seeded trial of ``plan`` on the toy scenario with the truth ``truth(setup,
    plan)`` registered for it, under ``policy`` and the ``sensing`` policies side by
    side (re-plans on an iteration budget, a fixed simulated delay)."""
    TRUTHS.register("test_truth", lambda setup: truth(setup, plan))
    try:
        source = ScenarioSource.of(TOY)
        _, problem = source.cached()
        settings = ExecutionSettings(sensing=policy, models=Models(truth="test_truth"))
        options = ExecuteOptions(settings, ReplanPolicy(max_iterations=500, delay_s=0.005),
                                 sensing=sensing)  # fmt: skip
        kw = {} if loops is None else {"loops": loops}
        return run_execute_trial(problem, source.without_margin(), plan, trial_seed(3, 0),
                                 options, **kw)  # fmt: skip
    finally:
        TRUTHS.unregister("test_truth")


@pytest.fixture(scope="module")
def moving_trial(toy_plan):
    """One trial on the toy scenario, its target moving under the needle, under the three
    policies side by side."""
    plan, _, _ = read_plan_json(toy_plan)
    # the truth follows its model exactly; the estimator assumes the default noise (closed
    # loop only: nothing here reads the open loop)
    rec = _toy_trial(plan, _MovingTarget, EXACT, ("em", "checkpoints", "tracking"),
                     loops=("closed_loop",))  # fmt: skip
    return plan, rec


def test_em_misses_the_moved_target_and_the_imaged_loops_reach_it(moving_trial):
    _, rec = moving_trial
    em, scanned, tracked = (rec.sensing[k] for k in ("em", "checkpoints", "tracking"))
    assert rec.closed_loop == em  # the first policy's run is the trial's closed loop
    for run in (em, scanned, tracked):
        assert run.target_displacement_mm == pytest.approx(MOVE_MM, abs=1e-9)
        assert run.target_displacement_max_mm == pytest.approx(MOVE_MM, abs=1e-9)
        assert not run.violated
    # em steers to the plan's target, assumed still: it ends about MOVE_MM from the true one
    assert em.final_error_mm > 3.0 and em.target_error_mm == pytest.approx(MOVE_MM, abs=1e-9)
    assert em.scans == 0 and em.target_samples_used == 0
    # imaged, the loop re-plans to the target where it is seen and reaches it
    for run in (scanned, tracked):
        assert run.final_error_mm < 1.0, run.final_error_mm
        assert run.target_error_mm == pytest.approx(0.0, abs=1e-9)  # noise-free imaging
        assert run.replans >= 1 and run.target_samples_refused == {}
    # a scan every 10 mm of insertion and one on arrival: the dose counted, the needle
    # held 20 s for each
    assert scanned.scans == int(scanned.inserted_mm // 10.0) + 1 == 7
    assert scanned.target_samples_used == scanned.scans == scanned.scan_tip_used
    assert scanned.procedure_s == pytest.approx(tracked.procedure_s + 7 * 20.0, abs=2.0)
    assert tracked.scans == 0 and tracked.target_samples_used > 100


def test_em_alone_gives_the_loop_it_always_was(toy_plan, tmp_path):
    flags = ["--trials", "1", *REPRODUCIBLE]
    assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--out", str(tmp_path / "a"), *flags]) == 0
    assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--out", str(tmp_path / "b"), *flags,
                 "--sensing", "em"]) == 0  # fmt: skip
    a, b = (json.loads((tmp_path / d / "execute.json").read_text()) for d in ("a", "b"))
    assert a["trials"] == b["trials"] and a["summary"] == b["summary"]
    closed = a["trials"][0]["closed_loop"]
    # nothing of the target is recorded: the kinematic truth carries none, em sees none
    assert not {"sensing", "scans", "target_error_mm", "points_rest_mm"} & set(closed)


def _wild_tracker(monkeypatch, wild: dict):
    """The tracker delivers ``wild[k]`` in place of its k-th sample."""
    real = imaging.TargetTracking.update
    count = {"n": 0}

    def update(self, t, true_target):
        got = real(self, t, true_target)
        if got is not None:
            count["n"] += 1
            if count["n"] in wild:
                return TargetSample(got.taken_s, got.arrives_s, wild[count["n"]](got.target_mm))
        return got

    monkeypatch.setattr(imaging.TargetTracking, "update", update)


def test_a_wild_target_sample_is_refused_counted_and_does_not_steer(toy_plan, monkeypatch):
    plan, goal, _ = read_plan_json(toy_plan)
    settings = ExecutionSettings(sensing=replace(EXACT, name="tracking"))

    def run():
        return execute_plan(plan, goal, 50.0, closed_loop=True, seed=11, settings=settings)

    calm = run()
    _wild_tracker(monkeypatch, {
        50: lambda p: np.array([np.nan, p[1], p[2]]),
        120: lambda p: p + [40.0, 0.0, 0.0],
    })  # fmt: skip
    wild = run()
    assert calm.target["target_samples_refused"] == {}
    assert wild.target["target_samples_refused"] == {"not_finite": 1, "jump": 1}
    assert wild.target["target_samples_used"] == calm.target["target_samples_used"] - 2
    # the belief never left the (still) target: the same insertion, to the bit
    assert np.array_equal(wild.points_mm, calm.points_mm)
    assert wild.final_error_mm == calm.final_error_mm
    assert wild.target["target_error_mm"] == 0.0


class _PushedTarget(SimulatedNeedle):
    """The needle follows its model exactly; the needle's own push carries the target
    PUSH_MM on along the plan's end direction while the last 10 % of the plan goes in,
    after the last set checkpoint."""

    def __init__(self, setup, plan):
        super().__init__(setup.start_pose, setup.r_min_mm, ExecutionNoise.none(), setup.rng)
        self.goal = np.array(setup.goal_mm, dtype=float)
        self.ahead = PUSH_MM * plan.end_pose()[:3, 2]
        self.ramp = (0.9 * plan.length_mm, plan.length_mm)

    def target_mm(self):
        a, b = self.ramp
        return self.goal + float(np.clip((self.inserted_mm - a) / (b - a), 0.0, 1.0)) * self.ahead


#: How far the needle's push carries the target on (mm).
PUSH_MM = 2.0


def test_a_target_pushed_on_after_the_last_checkpoint_is_reached_by_an_arrival_scan(toy_plan):
    """Without confirmation scans the loop stops where the last image put the target, 2 mm
    short; one scan on arrival shows it ahead, the needle goes on, and a second scan
    finds it there."""
    plan, _, _ = read_plan_json(toy_plan)
    runs = {}
    for confirm in (0, 2):
        spec = replace(EXACT.checkpoints, every_mm=1000.0, confirm_scans=confirm)
        policy = replace(EXACT, name="checkpoints", checkpoints=spec)
        rec = _toy_trial(plan, _PushedTarget, policy, ("checkpoints",), loops=("closed_loop",))
        runs[confirm] = rec.closed_loop
    short, confirmed = runs[0], runs[2]
    assert short.scans == 0 and short.final_error_mm == pytest.approx(PUSH_MM, abs=0.05)
    assert confirmed.scans == 2 and confirmed.final_error_mm < 0.05
    assert confirmed.inserted_mm == pytest.approx(short.inserted_mm + PUSH_MM, abs=0.05)
    # the needle held 20 s for each scan, and the 2 mm more at 4 mm/s (and a re-plan's
    # steps toward the moved target)
    assert 2 * 20.0 + PUSH_MM / 4.0 <= confirmed.procedure_s - short.procedure_s < 42.0


def test_the_side_by_side_run_writes_a_block_and_a_row_per_policy(toy_plan, tmp_path, capsys):
    out = tmp_path / "side"
    assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "1", "--out", str(out),
                 "--sensing", "em,checkpoints,tracking", *REPRODUCIBLE]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    doc = json.loads((out / "execute.json").read_text())
    trial = doc["trials"][0]
    assert list(trial["sensing"]) == ["em", "checkpoints", "tracking"]
    assert trial["sensing"]["em"] == trial["closed_loop"]
    assert list(doc["summary"]["sensing"]) == ["em", "checkpoints", "tracking"]
    assert doc["options"]["sensing"] == ["em", "checkpoints", "tracking"]
    for name in ("em", "checkpoints", "tracking"):
        assert sum(line.startswith(f"sensing, {name} ") for line in printed.splitlines()) == 1
    scanned = trial["sensing"]["checkpoints"]
    # the toy plan is 62.9 mm: checkpoints at 20, 40 and 60 mm, and one on arrival
    assert scanned["scans"] == 4 and scanned["sensing"] == "checkpoints"
    assert doc["summary"]["sensing"]["checkpoints"]["scans"]["mean"] == 4.0
    assert trial["sensing"]["tracking"]["scans"] == 0
    assert trial["sensing"]["tracking"]["target_samples_used"] > 100
    # every record reads back as written, the target's fields included
    rec = TrialRecord.from_dict(trial, "execute.json: trials[0]")
    assert rec.to_dict() == trial and rec.sensing["checkpoints"].scans == 4


class _Shifted(SimulatedNeedle):
    """Tissue displaced by -C: the anatomy at rest is the world point plus C."""

    C = np.array([0.0, 0.0, 3.0])

    def to_rest(self, points):
        return np.asarray(points) + self.C


def test_a_deformed_path_is_judged_at_rest_and_both_paths_read_back(toy_plan):
    plan, goal, _ = read_plan_json(toy_plan)
    TRUTHS.register("shifted_toy", lambda s: _Shifted(s.start_pose, s.r_min_mm,
                                                      ExecutionNoise.none(), s.rng))  # fmt: skip
    try:
        settings = ExecutionSettings(noise=ExecutionNoise.none(), models=Models(truth="shifted_toy"))
        run = execute_plan(plan, goal, 50.0, closed_loop=False, seed=1, settings=settings)
    finally:
        TRUTHS.unregister("shifted_toy")
    source = ScenarioSource.of(TOY)
    rec = path_record(run, source.without_margin())
    assert np.allclose(rec.points_rest_mm, np.asarray(rec.points_mm) + _Shifted.C, atol=2e-4)
    # the clearance is the rest path's: the same as the world path moved by C
    moved = replace(run, points_mm=run.points_rest_mm, points_rest_mm=None)
    assert rec.min_clearance_mm == path_record(moved, source.without_margin()).min_clearance_mm
    assert rec.min_clearance_mm != path_record(replace(run, points_rest_mm=None),
                                               source.without_margin()).min_clearance_mm  # fmt: skip
    back = LoopRecord.from_dict(json.loads(json.dumps(rec.to_dict())), "r")
    assert back == LoopRecord.from_dict(rec.to_dict(), "r") and back.points_rest_mm is not None


@pytest.mark.parametrize(
    ("flags", "words"),
    [
        (["--sensing", "em,sonar"], "argument --sensing: expected policies among"),
        (["--sensing", "em,em"], "argument --sensing: expected each policy once"),
        (["--sensing", "tracking", "--tracking-rate-hz", "0"], "argument --tracking-rate-hz"),
        (["--sensing", "tracking", "--tracking-latency-ms", "-5"],
         "argument --tracking-latency-ms"),
        (["--sensing", "tracking", "--tracking-sigma-mm", "nan"], "argument --tracking-sigma-mm"),
        (["--sensing", "checkpoints", "--checkpoint-every-mm", "0"],
         "argument --checkpoint-every-mm"),
        (["--sensing", "checkpoints", "--scan-s", "-1"], "argument --scan-s"),
        (["--sensing", "checkpoints", "--image-sigma-mm", "inf"], "argument --image-sigma-mm"),
        (["--scan-s", "5"], "--scan-s: sets the checkpoints sensor: add checkpoints to --sensing"),
        (["--retarget-mm", "1"], "--retarget-mm: applies when the target is seen"),
    ],
)  # fmt: skip
def test_bad_sensing_flags_are_one_line_naming_the_flag(toy_plan, tmp_path, capsys, flags,
                                                        words):  # fmt: skip
    out = tmp_path / "out"
    try:
        code = main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--out", str(out), *flags])
    except SystemExit as exc:  # the parser's own refusals
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err, err
    assert not out.exists()


#: The tip's sudden turn (rad) where the kinked needle meets its layer.
KINK_RAD = 0.12


class _Kinked(SimulatedNeedle):
    """The needle follows its model exactly, but where 40 % of the plan is in, its tip turns
    by KINK_RAD about its own x axis at once (a tougher layer deflects it): an honest
    sensor then reports a pose the filter's model cannot reach, and the filter's gate
    refuses every sample after it."""

    def __init__(self, setup, plan):
        super().__init__(setup.start_pose, setup.r_min_mm, ExecutionNoise.none(), setup.rng)
        self.at_mm = 0.4 * plan.length_mm
        self.kinked = False

    def step(self, spin_rad, kappa_per_mm, ds_mm, dt_s):
        pose = super().step(spin_rad, kappa_per_mm, ds_mm, dt_s)
        if not self.kinked and self.inserted_mm >= self.at_mm:
            c, s = np.cos(KINK_RAD), np.sin(KINK_RAD)
            turn = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
            self.pose = np.ascontiguousarray(pose.copy())
            self.pose[:3, :3] = pose[:3, :3] @ turn
            self.kinked = True
        return self.pose


def test_a_gated_hold_is_settled_by_a_confirmation_scan(toy_plan):
    """An honest sensor the filter refuses (the needle kinked): under ``em`` alone the guard
    holds and, nothing settling it, aborts at the timeout; under ``checkpoints`` a
    confirmation scan is taken at once, its tip fails the estimate's gate too, so the
    estimate restarts from the image, the sensor's samples are accepted again, the hold
    ends and the needle reaches the target."""
    plan, _, _ = read_plan_json(toy_plan)
    rec = _toy_trial(plan, _Kinked, EXACT, ("em", "checkpoints"), loops=("closed_loop",))
    em, seen = rec.sensing["em"], rec.sensing["checkpoints"]
    assert [e["action"] for e in em.faults] == ["hold", "abort"]
    assert em.faults[0]["kind"] == "gated" and em.aborted
    assert em.scan_tip_reseeded is None  # em takes no image
    assert [e["action"] for e in seen.faults][:2] == ["hold", "resume"]
    assert seen.faults[0]["kind"] == "gated" and not seen.aborted
    assert seen.scan_tip_reseeded == 1
    assert not seen.violated and seen.final_error_mm <= 1.0
