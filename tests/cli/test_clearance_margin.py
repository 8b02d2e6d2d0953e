"""``plan`` and ``verify`` report the one certified clearance (the rule of
:mod:`needlekit.constants`, :func:`verify_plan`) identically, with the margin kept;
``--safety-margin-mm`` replaces the scenario's; a margin that leaves no plan is said
plainly, with the margin that does plan (checked by planning at it)."""

from __future__ import annotations

import io
import json
import math
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.planning.steerable.verify import search_clearance_mm, verify_plan
from needlekit.scenario.problems import load_problem
from needlekit.scenario.results import read_plan_json

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"


def _run(argv) -> tuple[int, list[str]]:
    out = io.StringIO()
    with redirect_stdout(out):
        code = main([str(a) for a in argv])
    return code, out.getvalue().splitlines()


def _clearance(lines: list[str]) -> str:
    (line,) = [x for x in lines if x.startswith("clearance: ")]
    return line


@pytest.fixture(scope="module")
def planned(tmp_path_factory):
    d = tmp_path_factory.mktemp("clearance")
    code, lines = _run(["plan", TOY, "--out", d / "plan.json"])
    assert code == 0
    return d, lines


def test_plan_verify_and_the_file_report_one_clearance(planned):
    d, plan_lines = planned
    code, verify_lines = _run(["verify", TOY, d / "plan.json"])
    assert code == 0
    # the oracle: the library's check of the plan file against the scenario
    _, problem = load_problem(TOY)
    plan, _, data = read_plan_json(d / "plan.json")
    m = verify_plan(problem, plan).metrics
    want = (f"clearance: certified {m['certified_clearance_mm']:.3f} mm over the whole path "
            f"(smallest sampled distance {m['min_clearance_mm']:.3f} mm; field), safety "
            "margin kept 0 mm")  # fmt: skip
    assert _clearance(plan_lines) == _clearance(verify_lines) == want
    assert data["stats"]["certified_clearance_mm"] == m["certified_clearance_mm"]
    assert data["stats"]["min_clearance_mm"] == m["min_clearance_mm"]
    code, text = _run(["verify", TOY, d / "plan.json", "--json"])
    out = json.loads("\n".join(text))
    assert out["metrics"]["certified_clearance_mm"] == m["certified_clearance_mm"]
    assert out["safety_margin_mm"] == 0.0


def test_the_margin_flag_replaces_the_scenarios_in_plan_and_verify(planned):
    d, _ = planned
    code, lines = _run(["plan", TOY, "--safety-margin-mm", "1", "--out", d / "m1.json"])
    assert code == 0 and _clearance(lines).endswith("safety margin kept 1 mm")
    _, _, data = read_plan_json(d / "m1.json")
    assert data["stats"]["certified_clearance_mm"] >= 1.0
    # the same plan checked against a margin it does not keep: exit 1, the rule named
    above = math.ceil(data["stats"]["certified_clearance_mm"]) + 1
    code, lines = _run(["verify", TOY, d / "m1.json", "--safety-margin-mm", above])
    assert code == 1 and lines[0].startswith("VIOLATED")
    assert _clearance(lines).endswith(f"safety margin kept {above:g} mm")


def test_a_margin_that_leaves_no_plan_says_so_and_names_one_that_plans(planned):
    d, _ = planned
    code, lines = _run(["plan", TOY, "--safety-margin-mm", "3", "--out", d / "m3.json"])
    assert code == 1
    assert lines[0].startswith("rcs_star: approximate, no plan to the goal with a 3 mm safety "
                               "margin")  # fmt: skip
    assert "not a plan to execute" in lines[1]
    # the oracle: the plan made without a margin, by the search's own clearance test
    _, problem = load_problem(TOY)
    free, _, data = read_plan_json(d / "plan.json")
    bound = math.floor(1000 * search_clearance_mm(problem, free)) / 1000
    assert bound == 2.557  # the toy's certified clearance, as measured
    assert lines[2] == (
        f"  without a margin it plans (cost {data['cost_mm']:.4f} mm, certified clearance "
        f"{data['stats']['certified_clearance_mm']:.3f} mm); the largest margin that plans is "
        f"at least {bound:g} mm (checked: --safety-margin-mm {bound:g} plans, cost "
        f"{data['cost_mm']:.4f} mm; a costlier path may keep more)"
    )
    code, lines = _run(["plan", TOY, "--safety-margin-mm", bound, "--out", d / "b.json"])
    assert code == 0


@pytest.mark.parametrize("value", ["-1", "nan", "inf", "1e300"])
def test_the_margin_flag_passes_the_numeric_gate(value, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["plan", str(TOY), "--safety-margin-mm", value])
    assert exc.value.code == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: argument --safety-margin-mm: expected a number")


def test_sweep_plans_under_the_flags_margin(planned):
    d, _ = planned
    code, lines = _run(["sweep", TOY, "--directions", "100", "--max-iterations", "200",
                        "--safety-margin-mm", "1", "--out", d / "sweep.json",
                        "--plan", d / "best.json"])  # fmt: skip
    assert code == 0
    _, _, data = read_plan_json(d / "best.json")
    assert data["stats"]["certified_clearance_mm"] >= 1.0
    code, lines = _run(["verify", TOY, d / "best.json", "--any-start-direction",
                        "--safety-margin-mm", "1"])  # fmt: skip
    assert code == 0 and _clearance(lines).endswith("safety margin kept 1 mm")


def test_execute_checks_the_plan_against_the_flags_margin(planned, capsys):
    d, _ = planned
    # the plan made without a margin keeps 2.557 mm: at 3 mm it fails before any trial
    assert main(["execute", "--truth", "kinematic", str(TOY), str(d / "plan.json"), "--safety-margin-mm", "3",
                 "--trials", "1", "--out", str(d / "e3")]) == 2  # fmt: skip
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: plan: plan.json fails its check against toy.yaml: "
                           "collision: certified clearance 2.5574 mm")
    assert line.endswith("below the safety margin 3 mm, outside the start exclusion")
    assert not (d / "e3").exists()
    code, _ = _run(["execute", "--truth", "kinematic", TOY, d / "plan.json", "--safety-margin-mm", "1", "--trials", "1",
                    "--replan-iterations", "500", "--replan-delay-ms", "5", "--out", d / "e1"])  # fmt: skip
    doc = json.loads((d / "e1" / "execute.json").read_text())
    assert doc["summary"]["margin_mm"] == 1.0
    assert code == (1 if doc["summary"]["closed_loop"]["violated"] else 0)


def test_a_sweep_resumes_only_under_the_margin_it_ran_with(planned, capsys):
    from needlekit.studies.sweep_study import write_partial_sweep

    d, _ = planned
    _run(["sweep", TOY, "--directions", "12", "--max-iterations", "200",
          "--safety-margin-mm", "1", "--out", d / "s1.json"])  # fmt: skip
    record = json.loads((d / "s1.json").read_text())
    assert record["safety_margin_mm"] == 1.0
    # the record an interrupted run would have left, with the same head
    from needlekit.planning.steerable.sweep_result import sweeps_from_dict

    head = {k: record[k] for k in ("scenario", "time_limit_s", "max_iterations", "seed",
                                   "options", "safety_margin_mm")}  # fmt: skip
    write_partial_sweep(d / "s1.json", head, sweeps_from_dict(record, "s1.json"))
    flags = ["sweep", str(TOY), "--directions", "12", "--max-iterations", "200", "--out",
             str(d / "s1.json"), "--resume"]  # fmt: skip
    assert main([*flags, "--safety-margin-mm", "0.5"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line == (f"error: --resume: {d / 's1.partial.json'} was written with other "
                    "safety_margin_mm than this run's")  # fmt: skip
    assert main([*flags, "--safety-margin-mm", "1"]) != 2  # the same margin: carried on
