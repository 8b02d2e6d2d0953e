"""``needlekit execute`` and its input checks: trials open loop
beside closed loop on the same draws, written to execute.json; one trial replayed alone
by --replay-trial; bad input refused in one line with exit 2 before any work; a crashing trial
recorded with its seed while the others go on; Ctrl-C keeps the trials done.

Re-plans run with an iteration budget and a fixed simulated delay: the runs are
reproducible to the bit, so replays are compared for equality."""

from __future__ import annotations

import copy
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import Interrupted, InvalidInputError
from needlekit.execute import trials as execute_study
from needlekit.execute.record import TrialRecord, trial_status
from needlekit.execute.replan import ReplanPolicy
from needlekit.execute.run import ExecutionSettings
from needlekit.execute.trials import (
    ExecuteOptions,
    read_partial_execute,
    run_execute_study,
)
from needlekit.records import Status
from needlekit.scenario.problems import ScenarioSource
from needlekit.scenario.results import read_plan_json

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"
REPRODUCIBLE = ["--replan-delay-ms", "5", "--replan-iterations", "500", "--seed", "3"]
RUN_KEYS = {"final_error_mm", "min_clearance_mm", "violated", "replans", "replan_latency_s",
            "points_mm"}  # fmt: skip


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("execute") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def three_trials(toy_plan):
    out = toy_plan.parent / "three"
    assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "3", "--out", str(out),
                 *REPRODUCIBLE]) == 0  # fmt: skip
    return json.loads((out / "execute.json").read_text())


def test_every_trial_runs_open_and_closed_loop_on_the_same_needle(toy_plan, three_trials):
    doc = three_trials
    start = read_plan_json(toy_plan)[0].start_pose[:3, 3]
    assert [t["trial"] for t in doc["trials"]] == [0, 1, 2]
    for t in doc["trials"]:
        assert t["seed"] == 3 and t["seed_spawn_key"] == [t["trial"]]
        for loop in ("open_loop", "closed_loop"):
            assert RUN_KEYS <= set(t[loop]) and not t[loop]["violated"]
            assert np.allclose(t[loop]["points_mm"][0], start, atol=1e-4)
        # the same needle: open loop misses by the noise (1.5-2.2 mm on these draws, as
        # measured), closed loop corrects it to well under a millimetre
        assert 1.4 < t["open_loop"]["final_error_mm"] < 2.2
        assert t["closed_loop"]["final_error_mm"] < 0.6
    s = doc["summary"]
    assert s["trials"] == 3 and s["crashed"] == [] and s["margin_mm"] == 0.0
    assert s["closed_loop"]["within_1mm"] == 1.0 and s["open_loop"]["within_1mm"] == 0.0
    assert s["closed_loop"]["final_error_mm"]["mean"] < s["open_loop"]["final_error_mm"]["mean"]
    assert len(s["literature"]) == 9


def test_one_trial_replays_alone_to_the_bit(toy_plan, three_trials, tmp_path):
    assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "3", "--replay-trial", "1",
                 "--out", str(tmp_path), *REPRODUCIBLE]) == 0  # fmt: skip
    alone = json.loads((tmp_path / "execute.json").read_text())["trials"]
    assert len(alone) == 1 and alone[0] == three_trials["trials"][1]


def _plan_with(toy_plan: Path, tmp_path: Path, **change) -> Path:
    data = json.loads(toy_plan.read_text())
    data.update(change)
    path = tmp_path / "changed.json"
    path.write_text(json.dumps(data))
    return path


@pytest.mark.parametrize(
    ("change", "flags", "words"),
    [
        ({}, ["--trials", "0"], "--trials"),
        ({}, ["--orientation-noise-rad", "1"], "--orientation-noise-rad"),
        ({}, ["--deflection-sd", "nan"], "--deflection-sd"),
        ({}, ["--radius-sd-mm", "20"], "--radius-sd-mm"),
        ({}, ["--trials", "2", "--replay-trial", "2"], "--replay-trial"),
        ({"goal_mm": [0.0, 0.0, 1.0]}, [], "made for another scenario"),
        (
            {"primitives": [{"rotation_rad": 0.0, "curvature_per_mm": 0.0, "length_mm": 500.0}]},
            [],
            "fails its check",
        ),
    ],
)
def test_bad_input_is_one_line_and_exit_2_before_any_work(
    toy_plan, tmp_path, capsys, change, flags, words
):
    plan = _plan_with(toy_plan, tmp_path, **change) if change else toy_plan
    out = tmp_path / "out"
    try:
        code = main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--out", str(out), *flags])
    except SystemExit as exc:  # the parser's own refusals
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err and "Traceback" not in err
    assert not out.exists()


def _study(out, plan, **kw):
    source = ScenarioSource.of(TOY)
    options = ExecuteOptions(policy=ReplanPolicy(max_iterations=500, delay_s=0.005))
    return run_execute_study(out, source, plan, seed=3, options=options, **kw)


def test_a_trial_that_crashes_is_recorded_with_its_seed_and_the_others_go_on(
    toy_plan, three_trials, tmp_path, monkeypatch
):
    plan, _, _ = read_plan_json(toy_plan)
    real = execute_study.run_execute_trial

    def flaky(problem, truth, plan, seed, options, **kw):
        if seed.spawn_key == (1,):
            raise FloatingPointError("the needle broke")
        return real(problem, truth, plan, seed, options, **kw)

    monkeypatch.setattr(execute_study, "run_execute_trial", flaky)
    doc = _study(tmp_path, plan, trials=[0, 1, 2]).document
    crashed = doc["summary"]["crashed"]
    assert len(crashed) == 1 and crashed[0]["trial"] == 1
    assert "FloatingPointError: the needle broke" in crashed[0]["error"]
    assert doc["trials"][1]["seed"] == 3 and "open_loop" not in doc["trials"][1]
    assert doc["trials"][1]["status"] == "invalid_input"
    assert doc["summary"]["status"] == {"invalid_input": 1, "solved": 2}
    assert doc["trials"][2] == three_trials["trials"][2]
    assert doc["summary"]["closed_loop"]["runs"] == 2


def test_ctrl_c_keeps_the_trials_done_and_resume_carries_on_to_the_same_record(
    toy_plan, three_trials, tmp_path
):
    plan, _, _ = read_plan_json(toy_plan)
    seen = []

    def stop_after_one(trial):
        seen.append(trial["trial"])
        raise KeyboardInterrupt

    with pytest.raises(Interrupted, match="1 of 3 trials done"):
        _study(tmp_path, plan, trials=[0, 1, 2], progress=stop_after_one)
    partial = json.loads((tmp_path / "execute.partial.json").read_text())
    assert partial["partial"] is True and [t["trial"] for t in partial["trials_done"]] == seen
    options = ExecuteOptions(policy=ReplanPolicy(max_iterations=500, delay_s=0.005))
    kept = read_partial_execute(tmp_path, "", plan, 3, [0, 1, 2], options)
    with pytest.raises(Exception, match="--resume"):  # another seed: refused
        read_partial_execute(tmp_path, "", plan, 4, [0, 1, 2], options)
    doc = _study(tmp_path, plan, trials=[0, 1, 2], resume=kept).document
    assert doc["trials"] == three_trials["trials"]


@pytest.fixture(scope="module")
def pushed(toy_plan):
    """Three trials under a strong push (a trial's draws are its own: trial 0 here is the
    run of ``--trials 1``), with the report page: the folder holding execute.json and
    page.html."""
    out = toy_plan.parent / "push"
    assert main(["execute", "--truth", "kinematic", str(TOY), str(toy_plan), "--trials", "3", "--out", str(out),
                 "--report", str(out / "page.html"), "--deflection-sd", "0.03", "--cross-track-mm", "0.2",
                 *REPRODUCIBLE]) == 0  # fmt: skip
    return out


def test_the_closed_loop_replans_under_a_strong_push_and_says_so(pushed):
    closed = json.loads((pushed / "execute.json").read_text())["trials"][0]["closed_loop"]
    assert closed["replans"] >= 1
    assert len(closed["replan_latency_s"]) == closed["replan_attempts"] >= closed["replans"]
    assert closed["final_error_mm"] < 1.0
    assert ExecutionSettings().record_mm == 0.25  # the clearance's sample gap, as documented


@pytest.mark.slow
@pytest.mark.browser
def test_the_page_renders_the_trial_and_the_histograms(pushed, tmp_path, browser, rendered):
    page = pushed / "page.html"
    plots, pngs = rendered(page)
    assert plots == 2 and len(pngs) == 1  # the animated trial (3D), the histograms
    (tmp_path / "trial.png").write_bytes(pngs[0])
    text = page.read_text()
    for words in ("Open loop beside closed loop", "Published closed-loop errors",
                  "Vrooijink et al.", "re-plan latency"):  # fmt: skip
        assert words in text
    doc = json.loads((pushed / "execute.json").read_text())
    shown = max(doc["trials"], key=lambda t: (t["closed_loop"]["replans"], -t["trial"]))
    assert f"Trial {shown['trial']} going in" in text and shown["closed_loop"]["replans"] >= 1
    assert len(shown["closed_loop"]["replan_events"]) == shown["closed_loop"]["replans"]


def test_each_trial_record_reads_back_as_written_with_its_status(three_trials):
    for t in three_trials["trials"]:
        where = f"execute.json: trials[{t['trial']}]"
        rec = TrialRecord.from_dict(t, where)
        assert rec.to_dict() == t
        assert TrialRecord.from_dict(json.loads(json.dumps(rec.to_dict())), where) == rec
        # closed loop within the toy's goal tolerance, nothing crossed, nothing aborted
        assert rec.status is Status.SOLVED and rec.closed_loop.samples > 0
    assert three_trials["summary"]["status"] == {"solved": 3}


def test_a_trial_record_refuses_a_field_not_as_written(three_trials):
    good = three_trials["trials"][0]
    cases = [
        (("closed_loop", "samples"), "12", "closed_loop: samples: expected a whole number"),
        (("open_loop", "points_mm"), [[0, 1]], "open_loop: points_mm: expected a list of points"),
        (("closed_loop", "violated"), "no", "closed_loop: violated: expected true or false"),
        (("status",), "done", "status: expected one of solved, approximate, infeasible"),
        (("open_loop", "colour"), "red", "open_loop: colour: not a field of a run's record"),
    ]
    for keys, value, words in cases:
        bad = copy.deepcopy(good)
        target = bad
        for k in keys[:-1]:
            target = target[k]
        target[keys[-1]] = value
        with pytest.raises(InvalidInputError) as exc:
            TrialRecord.from_dict(bad, "execute.json: trials[0]")
        assert str(exc.value).startswith(f"execute.json: trials[0]: {words}"), str(exc.value)


def test_the_status_says_how_the_judged_run_ended(three_trials):
    run = TrialRecord.from_dict(three_trials["trials"][0], "t").closed_loop
    assert trial_status(run, 1.0) is Status.SOLVED
    assert trial_status(replace(run, final_error_mm=1.5), 1.0) is Status.APPROXIMATE
    assert trial_status(replace(run, violated=True), 1.0) is Status.INFEASIBLE
    assert trial_status(replace(run, aborted=True), 1.0) is Status.TIMEOUT
    assert trial_status(run, 1.0, "FloatingPointError: x") is Status.INVALID_INPUT


def test_a_sweeps_plan_is_carried_out_from_the_direction_the_sweep_chose(tmp_path, capsys):
    """``sweep --plan`` chooses the start direction; ``execute`` refuses such a plan against
    the scenario's own direction, saying which flag carries it out, and with
    ``--any-start-direction`` inserts it from the plan's start pose (held to the scenario's
    start point, as ``verify --any-start-direction`` holds it)."""
    best = tmp_path / "best.json"
    assert main(["sweep", str(TOY), "--directions", "24", "--max-iterations", "300",
                 "--out", str(tmp_path / "sweep.json"), "--plan", str(best)]) == 0  # fmt: skip
    record = json.loads(best.read_text())
    start = np.array(record["start_pose"])
    capsys.readouterr()
    out = tmp_path / "ex"
    assert main(["execute", "--truth", "kinematic", str(TOY), str(best), "--trials", "2", "--out", str(out)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "error: plan: best.json was made for another scenario: its start pose differs from "
        "toy.yaml's (a sweep chose its direction: --any-start-direction carries it out)"
    ]
    assert not out.exists()
    assert main(["execute", "--truth", "kinematic", str(TOY), str(best), "--trials", "2", "--out", str(out),
                 "--any-start-direction", *REPRODUCIBLE]) == 0  # fmt: skip
    doc = json.loads((out / "execute.json").read_text())
    for trial in doc["trials"]:
        for run in ("open_loop", "closed_loop"):
            first, second = np.array(trial[run]["points_mm"][:2])
            assert np.allclose(first, start[:3, 3], atol=1e-9)
            heading = (second - first) / np.linalg.norm(second - first)
            assert heading @ start[:3, 2] > 0.999  # the sweep's direction, not the scenario's
    moved = copy.deepcopy(record)
    moved["start_pose"][0][3] += 1.0
    other = tmp_path / "moved.json"
    other.write_text(json.dumps(moved))
    capsys.readouterr()
    assert main(["execute", "--truth", "kinematic", str(TOY), str(other), "--trials", "2", "--out", str(out),
                 "--any-start-direction"]) == 2  # fmt: skip
    assert capsys.readouterr().err.splitlines() == [
        "error: plan: moved.json was made for another scenario: its start point differs from "
        "toy.yaml's"
    ]
