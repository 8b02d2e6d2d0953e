"""``execute`` exits as its ``--help`` says, in every mode: 1 when a run crossed an
obstacle (open loop, closed loop, or the closed loop under any breathing policy: ignore,
gate, track, or any sensing policy run side by side), a trial crashed, or an insertion was aborted on a sensor fault; else 0. A
multi plan: 1 when a needle touched a placed one, left its constraints, or a trial
crashed.

The studies are replaced by records of known outcomes (the simulations have tests of
their own): what is checked is the command's verdict on each, over every combination of
its modes (open and closed loop, re-planning or not, breathing, sensing policies side by
side, faults held or aborted),
through the real parser and handler."""

from __future__ import annotations

import io
import itertools
import json
from contextlib import redirect_stdout
from pathlib import Path
from types import SimpleNamespace

import pytest

import needlekit.cli.execute as execute_cli
import needlekit.cli.execute_multi as multi_cli
from needlekit.cli import main
from needlekit.cli._parser import _build_parser, walk_commands

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"
POLICIES = ("ignore", "gate", "track")

#: The modes, as flags: each trial runs open and closed loop; with --breathing the closed
#: loop also under each policy; with --faults the closed loops meet faults (held or not).
MODES = {
    "closed loop, re-planning": [],
    "closed loop, no re-planning": ["--no-replan"],
    "breathing lung": ["--breathing", "lung"],
    "breathing liver, no re-planning": ["--breathing", "liver", "--no-replan"],
    "faults, hold": ["--faults", "dropout", "--on-fault", "hold"],
    "faults, abort": ["--faults", "freeze", "--on-fault", "abort"],
    "breathing and faults, abort": [
        "--breathing", "lung", "--faults", "mixed", "--on-fault", "abort"
    ],
    "sensing side by side": ["--sensing", "em,checkpoints,tracking"],
    "sensing and faults, abort": [
        "--sensing", "checkpoints,tracking", "--faults", "dropout", "--on-fault", "abort"
    ],
}
SENSING = {"sensing side by side": ("em", "checkpoints", "tracking"),
           "sensing and faults, abort": ("checkpoints", "tracking")}  # fmt: skip


def _loop(runs: int, violated: int = 0, aborted: int | None = None, replans: bool = True):
    out = {
        "runs": runs, "final_error_mm": {"mean": 0.2, "sd": 0.1, "max": 0.4},
        "within_1mm": 1.0, "min_clearance_mm": {"min": 1.5}, "violated": violated,
        "replans": {"mean": 1.0 if replans else 0.0},
        "replan_latency_ms": {"p95": 5.0} if replans else {},
    }  # fmt: skip
    if aborted is not None:
        out["aborted"] = aborted
    return out


def _summary(options, runs: int, crossed: str | None, aborted: str | None, crashed: bool):
    """The summary a study of these options would write, with one run crossing
    (``crossed``: "open loop", "closed loop" or "breathing, POLICY") and one aborted."""
    faults = options.settings.faults is not None

    def loop(name, replans=True):
        return _loop(runs, violated=int(crossed == name),
                     aborted=int(aborted == name) if faults and name != "open loop" else None,
                     replans=replans)  # fmt: skip

    s = {
        "trials": runs, "crashed": [{"trial": 0, "error": "boom"}] if crashed else [],
        "margin_mm": 0.0, "open_loop": loop("open loop", replans=False),
        "closed_loop": loop("closed loop"),
    }  # fmt: skip
    if options.breathing is not None:
        s["breathing"] = {
            p: {**loop(f"breathing, {p}"), "procedure_s": {"mean": 30.0}} for p in POLICIES
        }
    if len(options.sensing) > 1:
        s["sensing"] = {
            p: {**loop(f"sensing, {p}"), "procedure_s": {"mean": 30.0},
                "target_displacement_max_mm": {}, "target_error_mm": {}, "scans": {}}
            for p in options.sensing
        }  # fmt: skip
    return s


def _cases():
    for mode, flags in MODES.items():
        runs = ["open loop", "closed loop"]
        if "--breathing" in flags:
            runs += [f"breathing, {p}" for p in POLICIES]
        runs += [f"sensing, {p}" for p in SENSING.get(mode, ())]
        yield mode, flags, None, None, False, 0
        for name in runs:
            yield mode, flags, name, None, False, 1
        if "--faults" in flags:
            for name in runs[1:]:  # the open loop has no sensor
                yield mode, flags, None, name, False, 1
        yield mode, flags, None, None, True, 1


@pytest.fixture
def fake_study(monkeypatch, tmp_path):
    import needlekit.execute.trials as study

    outcome = {}

    def load(args, record=None):
        return None, SimpleNamespace(kappa_max_per_mm=0.02), None, "toy"

    def run(out, source, plan, *, trials, options, **_):
        doc = {"summary": _summary(options, len(trials), **outcome)}
        return SimpleNamespace(document=doc, path=Path(out) / "execute.json")

    monkeypatch.setattr(execute_cli, "load_checked_plan", load)
    monkeypatch.setattr(study, "run_execute_study", run)
    plan = tmp_path / "plan.json"
    plan.write_text("{}")
    return outcome, plan


@pytest.mark.parametrize(("mode", "flags", "crossed", "aborted", "crashed", "status"),
                         list(_cases()))  # fmt: skip
def test_execute_exits_as_its_help_says(mode, flags, crossed, aborted, crashed, status,
                                        fake_study, tmp_path):  # fmt: skip
    outcome, plan = fake_study
    outcome.update(crossed=crossed, aborted=aborted, crashed=crashed)
    out = io.StringIO()
    with redirect_stdout(out):
        code = main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--trials", "3", "--out",
                     str(tmp_path / "o"), *flags])  # fmt: skip
    assert code == status
    said = [x for x in out.getvalue().splitlines() if x.startswith("exit 1: ")]
    if crossed:
        assert said == [f"exit 1: {crossed}: 1 of 3 runs crossed an obstacle"]
    elif aborted:
        assert said == [f"exit 1: {aborted}: 1 of 3 insertions aborted on a sensor fault "
                        "(execute.json: faults)"]  # fmt: skip
    elif crashed:
        assert said == ["exit 1: 1 of 3 trials crashed"]
    else:
        assert said == []


def test_every_breathing_policy_and_fault_action_is_covered():
    parser = dict((w, p) for w, p, _ in walk_commands(_build_parser()))[("execute",)]
    actions = {a.dest: a for a in parser._actions}
    assert set(actions["breathing"].choices) == {"lung", "liver"}
    assert set(actions["on_fault"].choices) == {"hold", "abort"}
    from needlekit.execute.breathing import POLICIES as LIBRARY_POLICIES

    assert tuple(LIBRARY_POLICIES) == POLICIES
    covered = {tuple(f) for _, f, *_ in _cases()}
    assert {tuple(f) for f in MODES.values()} == covered


def test_the_help_says_what_the_code_does(capsys):
    for words, text in [
        (["execute"], "under any --breathing policy: ignore, gate or track"),
        (["execute"], "aborted on a sensor fault"),
        (["execute"], "exit 1 when a needle touched a placed one"),
        (["plan"], "exit 0 with a plan, 1 without"),
        (["verify"], "exit 0 when every rule holds, exit 1 on any violation"),
        (["sweep"], "exit 0 when some direction is solved and the best plan passes its check"),
        (["multi"], "exit 0 when every needle is planned"),
        (["puncture"], "exit 1 when a trial aborted or a constraint was violated"),
    ]:
        with pytest.raises(SystemExit):
            main([*words, "--help"])
        help_text = " ".join(capsys.readouterr().out.split()).lower()
        assert " ".join(text.lower().split()) in help_text, (words, text)


# -- a multi plan -------------------------------------------------------------------------


def _multi_summary(touched: bool, constraints: int, crashed: bool) -> dict:
    e = {"mean": 0.5, "sd": 0.1, "max": 0.7}
    return {
        "by_needle": {"1": {"error_mm": e, "target_shift_mm": {"mean": 0.2}}},
        "error_mm": e, "literature": [{"source": "Liu et al.", "mean_mm": 1.0, "sd_mm": 0.5}],
        "min_needle_gap_mm": 2.0, "needles": 1, "trials": 2,
        "touched": [{"trial": 0}] if touched else [], "constraints": {"total": constraints},
        "crashed": [{"trial": 1, "error": "boom"}] if crashed else [],
    }  # fmt: skip


@pytest.mark.parametrize(("touched", "constraints", "crashed"),
                         list(itertools.product([False, True], [0, 2], [False, True])))  # fmt: skip
def test_execute_of_a_multi_plan_exits_as_its_help_says(touched, constraints, crashed,
                                                         monkeypatch, tmp_path):  # fmt: skip
    import needlekit.studies.execute_multi as study

    def run(out, record, multi, **_):
        doc = {"summary": _multi_summary(touched, constraints, crashed)}
        return SimpleNamespace(document=doc, path=Path(out) / "execute.json")

    monkeypatch.setattr(multi_cli, "load_checked_multi", lambda args, record: (
        SimpleNamespace(name="m"), None, None))  # fmt: skip
    monkeypatch.setattr(study, "run_multi_execution", run)
    plan = tmp_path / "multi.json"
    plan.write_text(json.dumps({"needles": []}))
    out = io.StringIO()
    with redirect_stdout(out):
        code = main(["execute", "--truth", "kinematic", str(TOY), str(plan), "--trials", "2", "--out",
                     str(tmp_path / "o")])  # fmt: skip
    assert code == (1 if touched or constraints or crashed else 0)
    assert "nan" not in out.getvalue()
