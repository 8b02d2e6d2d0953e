"""Breathing: the respiratory model (Lujan et al.'s sin^(2n) cycle, its
end-exhale window), and the three policies checked against exact twins: no motion under
any policy is the still run, tracking a perfectly predicted motion is the still run in the
tissue, gating inserts only in the window and takes as long as the window's share says;
and on the command line the three policies run in one study, bad values refused."""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.execute.breathing import POLICIES, PRESETS, Breathing, Policy
from needlekit.execute.replan import Replanner, ReplanPolicy
from needlekit.execute.run import LoopHooks, execute_plan
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.scenario.problems import load_problem

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"


@pytest.fixture(scope="module")
def toy():
    _, problem = load_problem(TOY)
    res = solve_rcs(problem, max_iterations=2000, time_limit_s=30)
    return problem, res.plan


def _run(toy, seed=5, policy=None):
    problem, plan = toy
    rep = Replanner(problem, ReplanPolicy(max_iterations=500, delay_s=0.005))
    hooks = LoopHooks(breathing=policy) if policy is not None else None
    return execute_plan(plan, problem.goal_mm, 1.0 / problem.kappa_max_per_mm, closed_loop=True,
                        seed=np.random.SeedSequence(seed), replanner=rep, hooks=hooks)  # fmt: skip


@pytest.fixture(scope="module")
def still(toy):
    """The toy's closed-loop run with no breathing, the twin the policies are held to."""
    return _run(toy)


def test_the_cycle_starts_at_end_exhale_peaks_half_way_and_its_window_has_its_share():
    b = replace(PRESETS["lung"], amplitude_jitter=0.0, period_jitter=0.0)
    tr = b.trace(np.random.default_rng(0), 40.0)
    assert np.allclose(tr.starts_s, np.arange(0.0, 40.0 + 1e-9, 4.0)[: len(tr.starts_s)])
    assert np.allclose(tr.actual(8.0), 0.0) and np.allclose(tr.actual(10.0), [0, 0, -5.0])
    assert np.allclose(tr.actual(9.0), [0, 0, -5.0 * math.sin(math.pi / 4) ** 4])
    assert np.allclose(tr.predicted(9.3), tr.actual(9.3))
    # the window: |sin(pi x)|^4 <= 0.1, a share 2 asin(0.1^(1/4)) / pi of every cycle
    t = np.linspace(0.0, 40.0, 400_001)[:-1]
    share = np.mean([tr.in_window(x) for x in t[::10]])
    assert share == pytest.approx(2 * math.asin(0.1**0.25) / math.pi, abs=2e-3)
    assert PRESETS["liver"].amplitude_mm == 13.0 and PRESETS["lung"].period_s == 4.0


def test_values_out_of_range_are_refused_by_name():
    for field, value in (("amplitude_mm", 60.0), ("period_s", 0.5), ("shape", 0),
                         ("direction", (0.0, 0.0, 0.0)), ("amplitude_jitter", 0.5)):  # fmt: skip
        with pytest.raises(InvalidInputError) as err:
            Breathing(**{field: value})
        assert err.value.field == field
    with pytest.raises(InvalidInputError, match="policy"):
        Policy("hold", Breathing().trace(np.random.default_rng(0), 10.0))


def test_with_no_motion_every_policy_is_the_still_run(toy, still):
    trace = Breathing(amplitude_mm=0.0).trace(np.random.default_rng(1), 200.0)
    for name in POLICIES:
        run = _run(toy, policy=Policy(name, trace))
        assert run.final_error_mm == pytest.approx(still.final_error_mm, abs=1e-9), name
        assert run.procedure_s == pytest.approx(still.procedure_s, abs=1e-9), name


def test_tracking_a_perfectly_predicted_motion_is_the_still_run_in_the_tissue(toy, still):
    b = replace(PRESETS["liver"], amplitude_jitter=0.0, period_jitter=0.0)
    run = _run(toy, policy=Policy("track", b.trace(np.random.default_rng(1), 200.0)))
    assert run.final_error_mm == pytest.approx(still.final_error_mm, abs=1e-6)
    assert np.allclose(run.points_mm[-1], still.points_mm[-1], atol=1e-6)
    # ignoring it is not: the tissue moves 13 mm under the held needle (this insertion ends
    # at end-exhale, 8 cycles after it began there, so its end is near; its path is not)
    ignored = _run(toy, policy=Policy("ignore", b.trace(np.random.default_rng(1), 200.0)))
    assert still.cross_track_mm.max() < 1.0 and ignored.cross_track_mm.max() > 3.0


def test_gating_inserts_only_in_the_window_and_takes_its_share_longer(toy, still):
    b = replace(PRESETS["lung"], amplitude_jitter=0.0, period_jitter=0.0)
    trace = b.trace(np.random.default_rng(1), 400.0)
    seen = []
    problem, plan = toy
    rep = Replanner(problem, ReplanPolicy(max_iterations=500, delay_s=0.005))
    hooks = LoopHooks(breathing=Policy("gate", trace), observe_every_s=0.005,
                      observe=lambda t, *a: seen.append((t, a[3]["inserted_mm"])))  # fmt: skip
    run = execute_plan(plan, problem.goal_mm, 1.0 / problem.kappa_max_per_mm, closed_loop=True,
                       seed=np.random.SeedSequence(5), replanner=rep, hooks=hooks)  # fmt: skip
    for (t0, s0), (_, s1) in itertools.pairwise(seen):
        if s1 > s0 + 1e-12:  # inserted in the step after t0: the window was open then
            assert trace.in_window(t0)
    share = 2 * math.asin(0.1**0.25) / math.pi
    assert run.procedure_s == pytest.approx(still.procedure_s / share, rel=0.15)
    assert run.final_error_mm < 1.0


def test_the_command_runs_the_three_policies_beside_each_other(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    assert main(["plan", str(TOY), "--out", str(plan)]) == 0
    assert main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--trials", "1", "--out", str(tmp_path),
                 "--breathing", "lung", "--replan-iterations", "500", "--replan-delay-ms", "5"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert all(f"breathing, {name}" in out for name in POLICIES)
    doc = json.loads((tmp_path / "execute.json").read_text())
    assert doc["options"]["breathing"]["amplitude_mm"] == 5.0
    trial = doc["trials"][0]["breathing"]
    assert set(trial) == set(POLICIES) and set(doc["summary"]["breathing"]) == set(POLICIES)
    assert trial["gate"]["procedure_s"] > 2 * trial["ignore"]["procedure_s"]
    for flags, words in ((["--breathing-amplitude-mm", "3"], "--breathing-amplitude-mm"),
                         (["--breathing", "liver", "--breathing-period-s", "0.5"], "--breathing-period-s"),
                         (["--breathing", "lung", "--breathing-direction", "0,0,0"], "--breathing-direction")):  # fmt: skip
        try:
            code = main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--out", str(tmp_path / "x"), *flags])
        except SystemExit as exc:  # a value out of the flag's range: refused by the parser
            code = exc.code
        assert code == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and words in err
    assert not (tmp_path / "x").exists()
