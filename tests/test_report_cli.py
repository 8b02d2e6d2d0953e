"""``needlekit report RESULT... --out page.html``: every result kind drawn again from its
file, several in one page, and the errors before any work.

The results are made here by the commands themselves, with small budgets. The values the
pages must show come from the result files, and the independent checks from ``needlekit
verify`` (a separate path to the same rules); a run among moving obstacles is measured
against the tip's clearance to the moving vessel computed in closed form every 1 ms.
"""

import html
import importlib
import inspect
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
TOY = EXAMPLES / "toy.yaml"
#: The two-needle scenario of tests/planning/test_straight_cli.py, with a coarse grid.
TWO = (
    (Path(__file__).parent / "planning" / "test_straight_cli.py")
    .read_text()
    .split('SCENARIO = """\\\n')[1]
    .split('"""')[0]
    .replace("resolution_deg: 4", "resolution_deg: 8")
)
#: The fast drift of tests/planning/test_dynamic.py as a scenario: a vessel (capsule, axis
#: along x at z = 25 mm, 3.4 mm to the +y side of the straight path at t = 0) drifting -y
#: at 0.4 mm/s across a 50 mm insertion at 2 mm/s in a ball; RRT, 300 iterations, a re-plan
#: every 10 mm. The plan made once at t = 0 (straight) meets the vessel.
BALL = """\
version: 1
name: ball, drifting vessel
structures:
  - {name: body, role: allowed_region, sphere: {center_mm: [0, 0, 0], radius_mm: 200}}
  - {name: vessel, role: obstacle,
     capsule: {p0_mm: [-10, 3.4, 25], p1_mm: [10, 3.4, 25], radius_mm: 1.5},
     moving: {velocity_mm_s: [0, -0.4, 0]}}
needle: {diameter_mm: 1.0, max_length_mm: 100, start_exclusion_mm: 0}
start: {point_mm: [0, 0, 0], direction: [0, 0, 1]}
goal: {point_mm: [0, 0, 50]}
planner: {name: rrt, time_limit_s: 60, seed: 0, max_iterations: 300}
dynamic: {insertion_speed_mm_s: 2.0, step_mm: 10.0}
"""


def _run(argv, ok=(0,)):
    code = main([str(a) for a in argv])
    assert code in ok, argv
    return code


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """One small real result of each kind (puncture: see the slow test)."""
    d = tmp_path_factory.mktemp("results")
    two = d / "two.yaml"
    two.write_text(TWO)
    _run(["plan", TOY, "--max-iterations", "200", "--out", d / "plan.json"])
    _run(["plan", TOY, "--planner", "rrt", "--goals", "20,30,40", "10,35,45",
          "--max-iterations", "300", "--out", d / "goals.json"])  # fmt: skip
    _run(["sweep", TOY, "--directions", "48", "--max-iterations", "20", "--planner", "rcs_star",
          "rrt", "--out", d / "sweep.json", "--plan", d / "best.json"])  # fmt: skip
    _run(["cfrw", two, "--target", "2", "--layers", "50", "60", "--out", d / "cfrw.json"])
    _run(["multi", two, "--out", d / "multi.json"])
    return d


@pytest.fixture(scope="module")
def dynamic(tmp_path_factory):
    """A run among moving obstacles (``plan --dynamic``) and the page the command drew."""
    d = tmp_path_factory.mktemp("dynamic")
    (d / "ball.yaml").write_text(BALL)
    _run(["plan", d / "ball.yaml", "--dynamic", "--out", d / "dynamic.json", "--report",
          d / "plan-dynamic.html"])  # fmt: skip
    return d


def _page(path: Path) -> str:
    return html.unescape(path.read_text(encoding="utf-8"))


def _rows(page: str, heading: str) -> list[list[str]]:
    """The cells of the table under ``heading`` (its header row first)."""
    after = page.split(f">{heading}</h", 1)[1]
    table = after[after.index("<table>") : after.index("</table>")]
    rows = re.findall(r"<tr>(.*?)</tr>", table, flags=re.S)
    return [re.findall(r"<t[hd][^>]*>(.*?)</t[hd]>", r, flags=re.S) for r in rows]


def _one_error_line(capsys, argv) -> str:
    capsys.readouterr()  # what earlier calls printed
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and not captured.out, captured
    assert lines[0].startswith("error: "), lines
    return lines[0]


def _verify(capsys, scenario, plan_doc, tmp_path) -> dict:
    """``needlekit verify --json`` on one plan record: the independent oracle."""
    path = tmp_path / "one-plan.json"
    path.write_text(json.dumps(plan_doc))
    capsys.readouterr()
    main(["verify", str(scenario), str(path), "--json", *_goal_flag(plan_doc)])
    return json.loads(capsys.readouterr().out)


def _goal_flag(plan_doc) -> list[str]:
    return ["--goal", ",".join(str(c) for c in plan_doc["goal_mm"])]


def _mm(x: float) -> str:
    return f"{x:.3f}".replace("-", "\N{MINUS SIGN}")


# ---------------------------------------------------------------------------------------
# each kind


def test_a_plan_gets_its_summary_check_motions_and_scene(made, tmp_path, capsys):
    doc = json.loads((made / "plan.json").read_text())
    oracle = _verify(capsys, TOY, doc, tmp_path)
    assert oracle["ok"]
    out = tmp_path / "plan.html"
    assert main(["report", str(made / "plan.json"), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"{made / 'plan.json'}: plan: rcs_star plan, solved" in said and "check passed" in said
    page = _page(out)
    assert "<title>Steerable-needle plan: toy lung</title>" in page
    assert f"cost {doc['cost_mm']:.3f}" in page
    check = dict(r for r in _rows(page, "Independent check")[1:])
    m = oracle["metrics"]
    assert check["verdict"] == "passed"
    assert check["end to goal"] == f"{m['goal_distance_mm']:.3f} mm"
    assert check["certified clearance (whole path)"] == f"{m['certified_clearance_mm']:.3f} mm"
    assert check["cost (recomputed from the motions)"] == f"{m['cost']:.4f}"
    motions = _rows(page, "Motions")
    assert motions[0] == ["step", "rotation (°)", "curvature (1/mm)", "length (mm)"]
    kappa = [f"{p['curvature_per_mm']:.4g}" for p in doc["primitives"]]
    assert [r[2] for r in motions[1:]] == [k.replace("-", "\N{MINUS SIGN}") for k in kappa]
    assert [r[3] for r in motions[1:]] == [_mm(p["length_mm"]) for p in doc["primitives"]]
    assert "Path in the anatomy" in page and '"type":"mesh3d"' in page  # the anatomy in 3D
    assert "<script src=" not in page and page.count("plotly.js v") == 1  # offline, inlined once


def test_plans_to_several_goals_get_each_target_checked(made, tmp_path, capsys):
    doc = json.loads((made / "goals.json").read_text())
    out = tmp_path / "goals.html"
    assert main(["report", str(made / "goals.json"), "--out", str(out)]) == 0
    page = _page(out)
    rows = _rows(page, "Targets")
    head = rows[0]
    assert head[-1] == "independent check" and len(rows) == 1 + len(doc["targets"])
    for row, t in zip(rows[1:], doc["targets"], strict=True):
        cells = dict(zip(head, row, strict=True))
        assert cells["cost (mm)"] == f"{t['cost_mm']:.3f}" and cells["status"] == t["status"]
        oracle = _verify(capsys, TOY, t, tmp_path)
        assert cells["independent check"] == ("passed" if oracle["ok"] else "FAILED")
    for i, t in enumerate(doc["targets"], start=1):
        lengths = [r[3] for r in _rows(page, f"Target {i}: motions")[1:]]
        assert lengths == [_mm(p["length_mm"]) for p in t["primitives"]]


def test_a_sweep_gets_the_sweep_reports_tables_and_its_best_plan_checked(made, tmp_path):
    doc = json.loads((made / "sweep.json").read_text())
    out = tmp_path / "sweep.html"
    assert main(["report", str(made / "sweep.json"), "--out", str(out)]) == 0
    page = _page(out)
    table4 = _rows(page, "Summary per planner (Table 4)")
    for row, name in zip(table4[1:], doc["planners"], strict=True):
        s = doc["summary"][name]
        assert row[:4] == [name, str(s["n_effective"]), str(s["n_solved"]), _mm(s["best_cost_mm"])]
    solved = [r for r in doc["directions"] if r["cost_mm"]["rcs_star"] is not None]
    assert len(_rows(page, "Cost per solved effective direction (Tables 2-3)")) == 1 + len(solved)
    best = doc["best_plans"]["rcs_star"]
    assert f"Best rcs_star plan: cost {best['cost_mm']:.3f}" in page
    assert "Independent check: passed" in page
    # the file keeps the best plans only: Fig. 7 is said to be missing, not drawn half
    assert f"not the {len(solved)} paths of RCS*'s solved directions" in page
    assert "Best path per planner" in page and "Fig. 8" in page and "Fig. 9" in page


def test_a_cfrw_map_is_recomputed_and_drawn_with_the_files_entries(made, tmp_path):
    doc = json.loads((made / "cfrw.json").read_text())
    out = tmp_path / "cfrw.html"
    assert main(["report", str(made / "cfrw.json"), "--out", str(out)]) == 0
    page = _page(out)
    n = len(doc["theta_deg"]) * len(doc["phi_deg"])
    assert f"{doc['counts']['free']} of {n} directions at {doc['resolution_deg']:g} deg" in page
    counts = _rows(page, "Directions by blocking reason")
    assert dict(zip(counts[0], counts[1], strict=True)) == {
        **{k.replace("_", " "): str(v) for k, v in doc["counts"].items()}, "directions": str(n)
    }  # fmt: skip
    best = {r[0]: r for r in _rows(page, "Best entry per objective")[1:]}
    assert best["min_length"][2] == _mm(doc["best"]["min_length"]["length_mm"])
    assert len(_rows(page, "Pareto front: length against clearance")) == 1 + len(
        doc["pareto_front"]
    )
    assert "boundary z = 50 mm" in page and "boundary z = 60 mm" not in page  # plane (a)
    assert "CFRW layers (as Liu's Fig. 11)" in page and "Accessibility map" in page


def test_a_multi_needle_plan_gets_its_maps_and_the_independent_check(made, tmp_path, capsys):
    doc = json.loads((made / "multi.json").read_text())
    out = tmp_path / "multi.html"
    assert main(["report", str(made / "multi.json"), "--out", str(out)]) == 0
    page = _page(out)
    capsys.readouterr()
    assert main(["verify", str(made / "two.yaml"), str(made / "multi.json"), "--json"]) == 0
    oracle = json.loads(capsys.readouterr().out)
    check = _rows(page, "Independent check: passed")
    cells = [dict(zip(check[0], r, strict=True)) for r in check[1:]]
    for c, n in zip(cells, oracle["needles"], strict=True):
        assert c["length (mm)"] == _mm(n["length_mm"])
        assert c["clearance (mm)"] == _mm(n["clearance_mm"])
    needles = _rows(page, "Needles")
    assert [r[needles[0].index("length (mm)")] for r in needles[1:]] == [
        _mm(n["length_mm"]) for n in doc["needles"]
    ]
    blocked = _rows(page, "Directions of each CFRW map by blocking reason")
    assert [int(r[1]) for r in blocked[1:]] == [n["blocked"]["free"] for n in doc["needles"]]
    for k in range(1, len(doc["needles"]) + 1):
        assert f"CFRW of needle {k}" in page and f"Accessibility map of needle {k}" in page
    assert "3D scene" in page


def test_several_results_make_one_page_with_a_part_each(made, tmp_path, capsys):
    out = tmp_path / "both.html"
    files = [made / "best.json", made / "sweep.json", made / "multi.json"]
    assert main(["report", *map(str, files), "--out", str(out), "--title", "Case 1"]) == 0
    said = capsys.readouterr().out.splitlines()
    assert [line.split(": ")[1] for line in said[:3]] == ["plan", "sweep", "multi"]
    page = _page(out)
    assert "<title>Case 1</title>" in page
    nav = re.findall(r"<li><a href='#part-(\d)'>([^<]*)</a></li>", page)
    assert nav == [
        ("1", "Steerable-needle plan: toy lung"),
        ("2", "Effective puncture region: toy lung"),
        ("3", f"Straight multi-needle plan: {made / 'two.yaml'}"),
    ]
    starts = [page.index(f"<section id='part-{i}'>") for i in (1, 2, 3)]
    assert starts == sorted(starts)
    assert starts[0] < page.index("<h3>Motions</h3>") < starts[1]  # the plan's, in part 1
    assert starts[1] < page.index("<h3>Summary per planner (Table 4)</h3>") < starts[2]
    assert starts[2] < page.index("<h3>Needles</h3>")
    assert page.count("plotly.js v") == 1


def test_a_moved_scenario_is_found_beside_the_result_or_given(made, tmp_path, capsys):
    doc = json.loads((made / "plan.json").read_text())
    moved = tmp_path / "case"
    moved.mkdir()
    shutil.copy(TOY, moved / "toy.yaml")
    (moved / "plan.json").write_text(json.dumps({**doc, "scenario": "toy.yaml"}))
    assert main(["report", str(moved / "plan.json"), "--out", str(tmp_path / "a.html")]) == 0
    (moved / "plan.json").write_text(json.dumps({**doc, "scenario": "gone/toy.yaml"}))
    line = _one_error_line(capsys, ["report", moved / "plan.json", "--out", tmp_path / "b.html"])
    assert line == (
        f"error: --scenario: {moved / 'plan.json'} names the scenario 'gone/toy.yaml' (relative "
        f"to the result: '{moved / 'gone/toy.yaml'}'), which is not there; give its path with "
        "--scenario"
    )
    argv = ["report", moved / "plan.json", "--scenario", TOY, "--out", tmp_path / "b.html"]
    assert _run(argv) == 0 and (tmp_path / "b.html").stat().st_size > 0


def test_a_result_names_its_scenario_relative_to_itself_only(tmp_path, capsys, monkeypatch):
    """The commands write the scenario's path relative to the result, and
    report reads it there, whatever the working folder; a path that only the working
    folder would resolve is not read."""
    out = tmp_path / "runs" / "a" / "plan.json"
    out.parent.mkdir(parents=True)
    assert _run(["plan", TOY, "--max-iterations", "50", "--out", out]) in (0, 1)
    written = json.loads(out.read_text())["scenario"]
    assert written == os.path.relpath(TOY, out.parent) and not os.path.isabs(written)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the report runs from another folder: same scenario
    assert _run(["report", out, "--out", tmp_path / "r.html"]) in (0, 1)
    # a working-folder path (what results used to hold) is not looked up there
    (elsewhere / "toy.yaml").write_text(TOY.read_text())
    doc = {**json.loads(out.read_text()), "scenario": "toy.yaml"}
    out.write_text(json.dumps(doc))
    line = _one_error_line(capsys, ["report", out, "--out", tmp_path / "s.html"])
    assert line.startswith(f"error: --scenario: {out} names the scenario 'toy.yaml' (relative to ")


def test_a_failed_check_is_shown_and_exits_1(made, tmp_path, capsys):
    doc = json.loads((made / "plan.json").read_text())
    bad = tmp_path / "plan.json"
    bad.write_text(json.dumps({**doc, "scenario": str(TOY), "cost_mm": doc["cost_mm"] + 1.0}))
    out = tmp_path / "bad.html"
    assert main(["report", str(bad), "--out", str(out)]) == 1
    said = capsys.readouterr().out
    assert "check FAILED (1 of 1)" in said and "error: an independent check failed" in said
    verdict = dict(r for r in _rows(_page(out), "Independent check")[1:])["verdict"]
    assert verdict.startswith(f"FAILED: cost: the plan claims {doc['cost_mm'] + 1.0:.6f}")


# ---------------------------------------------------------------------------------------
# errors: one line, exit 2, before any work, nothing written


@pytest.mark.parametrize(
    ("content", "expected"),
    [
        ('{"an": "object"}', "not a result of a known kind (plan, goals, sweep, cfrw, multi, puncture, dynamic, scale, execute, execute-multi, approach, feng-lungs)"),
        ('{"study": "medrad_livers", "settings": {}, "summary": {}, "rows": []}',
         "is a study of the Med-RAD livers (`needlekit study livers`), which has no page"),
        ('{"patients": [1], "cases": [], "holds": true, "targets": {}}',
         "is a study of executions on Med-RAD lungs (`needlekit study execute-lungs`), which has no page"),
        ("{not json", "not a JSON result file"),
        ("[1, 2]", "expected a JSON object at the top level"),
    ],
)  # fmt: skip
def test_an_unknown_or_malformed_file_is_named(tmp_path, capsys, content, expected):
    bad = tmp_path / "x.json"
    bad.write_text(content)
    out = tmp_path / "r.html"
    out.write_text("old")
    line = _one_error_line(capsys, ["report", bad, "--out", out])
    assert line.startswith(f"error: {bad}: ") and expected in line
    assert out.read_text() == "old"


@pytest.mark.parametrize(
    ("edit", "field", "expected"),
    [
        (lambda d: d.update(goal_mm=[1, 2]), "goal_mm", "expected three finite numbers"),
        (lambda d: d.update(status="done"), "status", "expected one of solved"),
        (lambda d: d["primitives"][0].pop("length_mm"), "primitives", "rotation_rad"),
        (lambda d: d.update(start_pose=[[1, 0], [0, 1]]), "start_pose", "4x4"),
    ],
)
def test_a_bad_field_of_a_plan_is_named(made, tmp_path, capsys, edit, field, expected):
    doc = json.loads((made / "plan.json").read_text())
    edit(doc)
    bad = tmp_path / "plan.json"
    bad.write_text(json.dumps(doc))
    line = _one_error_line(capsys, ["report", bad, "--out", tmp_path / "r.html"])
    assert line.startswith(f"error: plan.json: {field}") and expected in line


def test_missing_inputs_and_bad_outputs_are_refused_first(made, tmp_path, capsys):
    plan = made / "plan.json"
    gone = tmp_path / "gone.json"
    line = _one_error_line(capsys, ["report", plan, gone, "--out", tmp_path / "r.html"])
    assert line == f"error: RESULT: {gone}: not found"
    line = _one_error_line(capsys, ["report", plan, "--out", tmp_path])
    assert line == f"error: --out: {tmp_path}: is a folder, expected a file"
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        line = _one_error_line(capsys, ["report", plan, "--out", locked / "r.html"])
    finally:
        locked.chmod(0o755)
    assert line == f"error: --out: {locked / 'r.html'}: folder {locked} is read-only"
    line = _one_error_line(capsys, ["report", plan, "--out", plan])
    assert line == f"error: --out: {plan}: is the input RESULT; it would be overwritten"
    line = _one_error_line(capsys, ["report", plan, "--scenario", gone, "--out", tmp_path / "r"])
    assert line == f"error: --scenario: {gone}: not found"
    argv = ["report", plan, "--scenario", TOY, "--scenario", TOY, "--out", tmp_path / "r.html"]
    line = _one_error_line(capsys, argv)
    assert line.startswith("error: --scenario: given 2 times for 1 results that read a scenario")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["locked"]


def test_a_result_from_another_scenario_is_refused(made, tmp_path, capsys):
    other = tmp_path / "other.yaml"
    other.write_text(TWO.replace("gamma_mm: 1.5", "gamma_mm: 3"))
    argv = ["report", made / "multi.json", "--scenario", other, "--out", tmp_path / "r.html"]
    line = _one_error_line(capsys, argv)
    assert line == (
        f"error: {made / 'multi.json'}: gamma_mm is 1.5, the scenario {other} gives 3: it was "
        "made from another scenario (give that one with --scenario)"
    )
    # the same safety distance but a thicker vessel: the recomputed map differs
    moved = TWO.replace("radius_mm: 4}", "radius_mm: 9}")
    other.write_text(moved)
    argv = ["report", made / "cfrw.json", "--scenario", other, "--out", tmp_path / "r.html"]
    line = _one_error_line(capsys, argv)
    assert line.startswith(f"error: {made / 'cfrw.json'}: the map recomputed from {other} ")
    assert "the scenario changed since; give the one it was made from with --scenario" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["other.yaml"]
    steerable = tmp_path / "lung.yaml"
    steerable.write_text(TOY.read_text())
    argv = ["report", made / "multi.json", "--scenario", steerable, "--out", tmp_path / "r.html"]
    line = _one_error_line(capsys, argv)
    assert (
        line
        == f"error: --scenario: {steerable} has no straight block; multi.json was made from another scenario"
    )


# ---------------------------------------------------------------------------------------
# a run among moving obstacles (plan --dynamic)


def _tip_clearance_to_the_vessel(record: dict, dt_s: float = 1e-3) -> float:
    """The oracle: the executed tip every ``dt_s`` seconds (the plain numpy arc
    propagation), against the drifting capsule at that time in closed form (distance to its
    axis segment, less its radius and the needle's)."""
    from needlekit.geometry.arcs import propagate_arcs_reference

    ex = record["executed"]
    rows = np.array([[q["rotation_rad"], q["curvature_per_mm"], q["length_mm"]]
                     for q in ex["primitives"]])  # fmt: skip
    poses = [np.asarray(ex["start_pose"], float)]
    for spin, kappa, length in rows:
        poses.append(propagate_arcs_reference(poses[-1], spin, kappa, length))
    ends = np.cumsum(rows[:, 2])
    s = np.arange(0.0, ends[-1], 2.0 * dt_s)  # 2 mm/s
    i = np.searchsorted(ends, s, side="right")
    before = np.concatenate([[0.0], ends])[i]
    tips = propagate_arcs_reference(np.array(poses)[i], rows[i, 0], rows[i, 1], s - before)
    p, t = tips[:, :3, 3], s / 2.0
    axis_y = 3.4 - 0.4 * t
    dx = np.abs(p[:, 0]) - np.minimum(np.abs(p[:, 0]), 10.0)
    d = np.sqrt(dx**2 + (p[:, 1] - axis_y) ** 2 + (p[:, 2] - 25.0) ** 2)
    return float(d.min()) - 1.5 - 0.5


def test_a_run_among_moving_obstacles_is_rebuilt_and_checked_again(dynamic, tmp_path, capsys):
    doc = json.loads((dynamic / "dynamic.json").read_text())
    assert doc["status"] == "reached" and doc["static"]["check"]["ok"] is False
    out = tmp_path / "dynamic.html"
    capsys.readouterr()
    assert main(["report", str(dynamic / "dynamic.json"), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"{dynamic / 'dynamic.json'}: dynamic: rrt re-planning every 10 mm (arrival): " in said
    assert f"reached after {len(doc['cycles'])} cycles; executed path check passed; " in said
    assert "plan made at t = 0 fails the check" in said
    page, own = _page(out), _page(dynamic / "plan-dynamic.html")
    assert "<title>Re-planning among moving obstacles: ball, drifting vessel</title>" in page
    # the cycles as the file has them, and as the command's own page drew them
    cycles = _rows(page, "Cycles")
    assert cycles == _rows(own, "Cycles")
    cells = [dict(zip(cycles[0], r, strict=True)) for r in cycles[1:]]
    assert len(cells) == len(doc["cycles"])
    for c, rec in zip(cells, doc["cycles"], strict=True):
        assert c["cycle"] == str(rec["index"] + 1) and c["plan"] == rec["source"]
        assert c["t (s)"] == _mm(rec["t_s"]) and c["inserted (mm)"] == _mm(rec["inserted_mm"])
        assert c["advanced (mm)"] == _mm(rec["advanced_mm"])
        assert c["status"] == rec["plan"]["status"]
        assert c["cost (mm)"] == _mm(rec["plan"]["cost_mm"])
        assert (
            c["obstacle offset (mm)"]
            == f"({', '.join(map(_mm, rec['obstacle_offsets_mm']['vessel']))})"
        )
        assert [c["window from (s)"], c["window to (s)"]] == [_mm(w) for w in rec["window_s"]]
    verdicts = page.split(">Verdicts</h", 1)[1].split("</ul>", 1)[0]
    assert verdicts == own.split(">Verdicts</h", 1)[1].split("</ul>", 1)[0]
    m, sm = doc["check"]["metrics"], doc["static"]["check"]["metrics"]
    assert f"reached; {doc['reason']}." in verdicts
    assert (
        f"Executed path: {doc['executed']['length_mm']:.2f} mm in {m['duration_s']:.2f} s"
        in verdicts
    )
    # the checks run again give what the file records, and bound the oracle
    again = _rows(page, "Independent checks run again")
    assert again[1:] == [
        ["executed path", "passed", "passed", _mm(m["certified_moving_clearance_mm"]),
         _mm(m["certified_moving_clearance_mm"])],
        ["plan made once at t = 0", "FAILED", "FAILED", _mm(sm["certified_moving_clearance_mm"]),
         _mm(sm["certified_moving_clearance_mm"])],
    ]  # fmt: skip
    oracle = _tip_clearance_to_the_vessel(doc)
    assert m["certified_moving_clearance_mm"] <= oracle <= m["moving_clearance_mm"] + 1e-6
    assert oracle > 0 and "Violation: moving obstacle 'vessel'" in verdicts  # the static plan's
    assert "Paths and obstacles" in page and "vessel at t = 0.0 s" in page


def test_a_tampered_run_among_moving_obstacles_fails_the_check_run_again(dynamic, tmp_path, capsys):
    doc = json.loads((dynamic / "dynamic.json").read_text())
    # the executed path swapped for the plan made at t = 0: straight into the vessel's way,
    # the file still claiming the check passed
    bad = json.loads(json.dumps(doc))
    bad["executed"]["primitives"] = doc["static"]["plan"]["primitives"]
    bad["scenario"] = str(dynamic / "ball.yaml")
    path = tmp_path / "dynamic.json"
    path.write_text(json.dumps(bad))
    out = tmp_path / "bad.html"
    capsys.readouterr()
    assert main(["report", str(path), "--out", str(out)]) == 1
    said = capsys.readouterr().out
    assert "executed path check FAILED" in said and "error: an independent check failed" in said
    assert "the file records otherwise for the executed path" in said
    page = _page(out)
    assert _rows(page, "Independent checks run again")[1][:3] == [
        "executed path",
        "passed",
        "FAILED",
    ]
    verdicts = page.split(">Verdicts</h", 1)[1].split("</ul>", 1)[0]
    assert _tip_clearance_to_the_vessel(bad) < 0  # the oracle: the tip meets the vessel
    lines = re.findall(
        r"<li>Violation: (moving obstacle 'vessel': certified clearance [^<]*)</li>", verdicts
    )
    assert len(lines) == 2  # the executed path's and the plan made at t = 0's: the same path
    assert lines[0] == lines[1] and "first contact at t = " in lines[0]
    # a file claiming the plan made at t = 0 passes is caught too
    bad = json.loads(json.dumps(doc))
    bad["static"]["check"].update(ok=True, violations=[])
    bad["scenario"] = str(dynamic / "ball.yaml")
    path.write_text(json.dumps(bad))
    assert main(["report", str(path), "--out", str(out)]) == 1
    said = capsys.readouterr().out
    assert "executed path check passed" in said
    assert "the file records otherwise for the plan made once at t = 0" in said


def test_a_run_without_the_plan_made_at_t0_is_drawn_without_it(dynamic, tmp_path, capsys):
    doc = json.loads((dynamic / "dynamic.json").read_text())
    path = tmp_path / "alone.json"
    path.write_text(json.dumps({**doc, "static": None, "scenario": str(dynamic / "ball.yaml")}))
    out = tmp_path / "alone.html"
    capsys.readouterr()
    assert main(["report", str(path), "--out", str(out)]) == 0
    assert capsys.readouterr().out.splitlines()[0].endswith("executed path check passed")
    page = _page(out)
    assert [r[0] for r in _rows(page, "Independent checks run again")[1:]] == ["executed path"]
    assert "Plan made once at t = 0" not in page and "plan made at t = 0" not in page


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: d.update(status="done"), "dynamic.json: status: expected one of reached, no_plan"),
        (lambda d: d["settings"].update(step_mm=0), "dynamic.json: settings: step_mm: "),
        (lambda d: d["settings"].update(predict="oracle"), "dynamic.json: settings: predict: expected one of arrival"),
        (lambda d: d["settings"].pop("insertion_speed_mm_s"), "dynamic.json: settings: insertion_speed_mm_s: missing"),
        (lambda d: d["moving"][0].update(amplitude_mm=[0, 1, 0]), "dynamic.json: moving[0]: period_s: a sinusoid"),
        (lambda d: d["executed"]["primitives"][0].pop("length_mm"), "dynamic.json: executed: primitives[0]: length_mm: missing"),
        (lambda d: d["executed"].update(start_pose=[[1, 0], [0, 1]]), "dynamic.json: executed: start_pose: expected a 4x4"),
        (lambda d: d["cycles"][1].pop("t_s"), "dynamic.json: cycles[1]: t_s: missing"),
        (lambda d: d["cycles"][1].update(window_s=[1.0]), "dynamic.json: cycles[1]: window_s: expected two finite times"),
        (lambda d: d["cycles"][0]["plan"].update(status="done"), "dynamic.json: cycles[0]: plan: status: expected one of solved"),
        (lambda d: d["cycles"][0]["tip_pose"][0].__setitem__(3, 5.0), "dynamic.json: cycles[0]: tip_pose: differs from executed.start_pose"),
        (lambda d: d["cycles"][2]["plan"].update(goal_mm=[0, 0, 60]), "dynamic.json: cycles[2]: plan: goal_mm: differs from the goal of "),
        (lambda d: d["check"].update(ok=False), "dynamic.json: check: ok: is false with 0 violations"),
        (lambda d: d["static"].pop("plan"), "dynamic.json: static: plan: missing"),
    ],
)  # fmt: skip
def test_a_bad_field_of_a_dynamic_run_is_named(dynamic, tmp_path, capsys, edit, expected):
    doc = json.loads((dynamic / "dynamic.json").read_text())
    edit(doc)
    bad = tmp_path / "dynamic.json"
    bad.write_text(json.dumps(doc))
    line = _one_error_line(capsys, ["report", bad, "--out", tmp_path / "r.html"])
    assert line.startswith(f"error: {expected}"), line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dynamic.json"]


def test_a_dynamic_run_from_another_scenario_is_refused(dynamic, tmp_path, capsys):
    result = dynamic / "dynamic.json"
    argv = ["report", result, "--scenario", TOY, "--out", tmp_path / "r.html"]
    line = _one_error_line(capsys, argv)
    assert line == (
        f"error: --scenario: {TOY} has no moving structure; dynamic.json was made from another "
        "scenario"
    )
    other = tmp_path / "faster.yaml"
    other.write_text(BALL.replace("[0, -0.4, 0]", "[0, -0.8, 0]"))
    argv = ["report", result, "--scenario", other, "--out", tmp_path / "r.html"]
    line = _one_error_line(capsys, argv)
    assert line == (
        f"error: {result}: the moving obstacles 'vessel' move otherwise (or not at all) in the "
        f"scenario {other}: it was made from another scenario (give that one with --scenario)"
    )
    other.write_text(BALL.replace("step_mm: 10.0}", "step_mm: 10.0, lookahead_s: 2}"))
    line = _one_error_line(capsys, argv)
    assert line.startswith(
        f"error: --scenario: the run's settings do not go with the dynamic block of {other}: "
        "lookahead_s: only goes with predict='swept'"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["faster.yaml"]


# ---------------------------------------------------------------------------------------
# the puncture study, and the modules' documentation


@pytest.mark.slow
def test_a_puncture_study_gets_its_figures_and_tables(puncture_trial_seed3, tmp_path, capsys):
    puncture_trial = puncture_trial_seed3
    doc = json.loads(puncture_trial.read_text())
    out = tmp_path / "pu.html"
    capsys.readouterr()
    assert main(["report", str(puncture_trial), "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"{doc['completed']} of 1 trials completed" in said
    page = _page(out)
    assert "<title>Robotic needle puncture: simulation study (Tang et al., Section III)" in page
    rows = _rows(page, "Final errors beside Tang et al. (Section III-B)")
    mine = dict(zip(rows[0], rows[1], strict=True))
    assert mine["source"] == "needlekit"
    assert mine["mean (mm)"] == _mm(doc["position_error_mm"]["mean"])
    assert "The puncture (like Fig. 4)" in page


@pytest.mark.slow
@pytest.mark.realdata  # skips, saying why, without the data (tests/conftest.py)
def test_a_plan_on_a_real_lung_is_drawn_with_its_check(tmp_path, capsys):
    lung = EXAMPLES / "medrad_lung1.yaml"
    _run(["plan", lung, "--out", tmp_path / "plan.json"])
    doc = json.loads((tmp_path / "plan.json").read_text())
    oracle = _verify(capsys, lung, doc, tmp_path)
    out = tmp_path / "lung.html"
    assert main(["report", str(tmp_path / "plan.json"), "--out", str(out)]) == 0
    page = _page(out)
    check = dict(r for r in _rows(page, "Independent check")[1:])
    assert oracle["ok"] and check["verdict"] == "passed"
    assert check["collision model"] == "voxel_centres"
    m = oracle["metrics"]
    assert check["certified clearance (whole path)"] == f"{m['certified_clearance_mm']:.3f} mm"
    assert "<title>Steerable-needle plan: Med-RAD lung 1, start 1</title>" in page
    assert "bronchialTree (obstacle)" in page  # the patient's anatomy in the scene


@pytest.mark.parametrize(
    "module",
    [
        "needlekit.records",
        "needlekit.io.results",
        "needlekit.scenario.results",
        "needlekit.planning.steerable.dynamic_record",
        "needlekit.planning.steerable.sweep_result",
        "needlekit.report.result_report",
        "needlekit.report.steerable_report",
    ],
)  # fmt: skip
def test_public_functions_have_numpydoc_sections(module):
    mod = importlib.import_module(module)
    for name in mod.__all__:
        fn = getattr(mod, name)
        assert fn.__doc__, f"{name}: no docstring"
        if inspect.isfunction(fn):
            doc = inspect.getdoc(fn)
            assert "Returns\n-------" in doc and "Parameters\n----------" in doc, name


# ---------------------------------------------------------------------------------------
# one plan drawn from every place, an execution, every kind in one call

#: A page of one plan or one execution weighs at most this (plotly.js inlined: 4.8 MB).
PAGE_BYTES = 6_000_000


@pytest.fixture(scope="module")
def executed(toy_execution):
    """Two trials of the toy plan (``needlekit execute``): ``ex/execute.json``, with the
    plan (``plan.json``) and the page the command drew (``execute-command.html``) beside
    ``ex`` (tests/conftest.py, ``toy_execution``)."""
    return toy_execution / "ex" / "execute.json"


def _framed(page: str) -> dict:
    """The 3D view's camera and axis ranges, as the page gives them to plotly."""
    ranges = re.findall(r'"[xyz]axis":\{"title":\{"text":"[^"]*"\},"range":\[([^\]]*)\]', page)
    eye = re.search(r'"camera":\{"eye":\{"x":([^,]+),"y":([^,]+),"z":([^}]+)\}', page)
    return {"ranges": ranges, "eye": eye}


def test_one_plan_is_drawn_from_every_place_a_newcomer_looks(made, tmp_path, capsys):
    _run(["plan", TOY, "--out", tmp_path / "plan.json", "--report", tmp_path / "plan.html"])
    said = capsys.readouterr().out
    assert f"drew the plan -> {tmp_path / 'plan.html'}" in said
    _run(
        ["scene", "render", TOY, "--plan", tmp_path / "plan.json", "--out", tmp_path / "scene.html"]
    )
    doc = json.loads((tmp_path / "plan.json").read_text())
    length = sum(m["length_mm"] for m in doc["primitives"])
    said = capsys.readouterr().out
    assert said == f"drew plan.json (solved, {length:.1f} mm path) -> {tmp_path / 'scene.html'}\n"
    _run(["report", tmp_path / "plan.json", "--out", tmp_path / "page.html"])
    said = capsys.readouterr().out.splitlines()
    assert said[-1] == f"drew plan.json (plan) -> {tmp_path / 'page.html'}"
    for name in ("plan.html", "scene.html", "page.html"):
        page = (tmp_path / name).read_text()
        assert (tmp_path / name).stat().st_size <= PAGE_BYTES, name
        assert '"color":"#ff00ff"' in page, name  # the path, in its own colour
        view = _framed(page)
        assert len(view["ranges"]) == 3 and view["eye"] is not None, name
        lo, hi = zip(*(map(float, r.split(",")) for r in view["ranges"]), strict=True)
        pts = np.vstack([np.asarray(doc["points_mm"], float), doc["goal_mm"]])
        assert np.all(pts.min(axis=0) >= lo) and np.all(pts.max(axis=0) <= hi), name
        assert max(np.subtract(hi, lo)) <= np.ptp(pts, axis=0).max() + 2 * 15.0 + 1e-6, name
        assert '"height":760' in page, name
    # the same page with plotly.js shared beside it
    _run(["report", tmp_path / "plan.json", "--out", tmp_path / "shared" / "page.html",
          "--plotly", "shared"])  # fmt: skip
    assert (tmp_path / "shared" / "page.html").stat().st_size < 1_500_000
    assert (tmp_path / "shared" / "plotly.min.js").stat().st_size > 4_000_000
    assert 'src="plotly.min.js"' in (tmp_path / "shared" / "page.html").read_text()


def test_an_execution_is_drawn_alone_and_with_its_plan(executed, tmp_path, capsys):
    doc = json.loads(executed.read_text())
    plan = executed.parents[1] / "plan.json"  # the plan it inserted
    assert doc["scenario_file"] == os.path.relpath(TOY, executed.parent)
    out = tmp_path / "case.html"
    assert main(["report", str(plan), str(executed), "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[-1] == f"drew plan.json (plan), execute.json (execution) -> {out}"
    mean = doc["summary"]["closed_loop"]["final_error_mm"]["mean"]
    assert said[1].startswith(f"{executed}: execute: 2 trials: closed loop {mean:.2f} mm off")
    page = _page(out)
    rows = _rows(page, "Open loop beside closed loop")
    closed = dict(zip(rows[0], rows[2], strict=True))
    assert closed["run"] == "closed loop" and closed["error mean (mm)"] == _mm(mean)
    assert page.count("plotly.js v") == 1
    # alone, the same page as the command drew (the same sections)
    alone = tmp_path / "alone.html"
    assert main(["report", str(executed), "--out", str(alone)]) == 0
    assert alone.stat().st_size <= PAGE_BYTES
    assert _rows(_page(alone), "Open loop beside closed loop") == rows
    command = _page(executed.parents[1] / "execute-command.html")
    assert _rows(command, "Open loop beside closed loop") == rows
    # written before execute kept its scenario file: found through its plan only
    old = tmp_path / "old" / "execute.json"
    old.parent.mkdir()
    old.write_text(json.dumps({k: v for k, v in doc.items() if k != "scenario_file"}))
    err = _one_error_line(capsys, ["report", old, "--out", tmp_path / "x.html"])
    assert err.startswith("error: --scenario: ") and "draw it with its plan.json" in err
    assert main(["report", str(plan), str(old), "--out", str(tmp_path / "y.html")]) == 0
    assert (
        main(["report", str(old), "--scenario", str(TOY), "--out", str(tmp_path / "z.html")]) == 0
    )


def test_every_kind_is_drawn_in_one_call_and_named(
    made, dynamic, executed, approached, tmp_path, capsys
):
    files = [made / "plan.json", made / "goals.json", made / "sweep.json", made / "cfrw.json",
             made / "multi.json", dynamic / "dynamic.json", executed,
             approached[0] / "out" / "approach.json"]  # fmt: skip
    out = tmp_path / "all.html"
    assert main(["report", *map(str, files), "--out", str(out)]) in (0, 1)
    said = capsys.readouterr().out.splitlines()
    kinds = ["plan", "plans to several targets", "sweep", "CFRW map", "multi-needle plan",
             "moving-obstacle run", "execution", "approach analysis"]  # fmt: skip
    drew = ", ".join(f"{f.name} ({k})" for f, k in zip(files, kinds, strict=True))
    assert said[-1] == f"drew {drew} -> {out}"
    page = _page(out)
    assert len(re.findall(r"<section id='part-\d'>", page)) == len(files)


# ---------------------------------------------------------------------------------------
# an approach analysis (``needlekit approach``)

#: The skin is an icosphere (radius 60 mm, 1280 triangles) around the target at the
#: origin, the obstacle a 30 x 30 x 2 mm plate above it (tests/test_browser.py's case).
PLATE_LO, PLATE_HI = np.array([-10.0, -15.0, 24.0]), np.array([20.0, 15.0, 26.0])
UUID = re.compile(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}")


@pytest.fixture(scope="module")
def approached(tmp_path_factory):
    """``needlekit approach`` on the plate case: approach.json and the page it drew."""
    import trimesh

    d = tmp_path_factory.mktemp("approach")
    skin = trimesh.creation.icosphere(subdivisions=3, radius=60.0)
    plate = trimesh.creation.box(PLATE_HI - PLATE_LO)
    plate.apply_translation((PLATE_LO + PLATE_HI) / 2)
    skin.export(d / "skin.stl")
    plate.export(d / "plate.stl")
    (d / "plate.yaml").write_text(
        "version: 1\nstructures:\n"
        "  - {name: skin, role: entry_surface, mesh: {path: skin.stl}}\n"
        "  - {name: plate, role: obstacle, mesh: {path: plate.stl}}\n"
        "needle: {diameter_mm: 2.0, max_length_mm: 100}\n"
        "straight: {entry_surface: skin, targets: [[0, 0, 0]], gamma_mm: 1.5}\n"
    )
    _run(["approach", d / "plate.yaml", "--out", d / "out" / "approach.json", "--report",
          d / "command.html"])  # fmt: skip
    return d, skin


def _paa_score_by_slabs(skin) -> float:
    """PAA's score by another route: each line from a triangle's centre to the target
    clipped against the plate's slabs (no triangle test), area-weighted."""
    c = np.asarray(skin.triangles_center)
    d = -c  # to the target at the origin
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (PLATE_LO - c) / d, (PLATE_HI - c) / d
    lo = np.nanmax(np.minimum(t0, t1), axis=1).clip(0.0)
    hi = np.nanmin(np.maximum(t0, t1), axis=1).clip(None, 1.0)
    hit = lo <= hi
    return float(skin.area_faces[~hit].sum() / skin.area_faces.sum())


def test_an_approach_analysis_is_drawn_as_its_command_draws_it(made, approached, tmp_path, capsys):
    d, skin = approached
    record = d / "out" / "approach.json"
    doc = json.loads(record.read_text())
    assert doc["scenario"] == os.path.join("..", "plate.yaml") and doc["max_cells"] == 200
    capsys.readouterr()
    out = tmp_path / "page.html"
    assert main(["report", str(record), "--out", str(out)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[-1] == f"drew approach.json (approach analysis) -> {out}"
    assert said[0].startswith(f"{record}: approach: 1280 skin triangles: score ")
    page, command = _page(out), _page(d / "command.html")
    # the same page as the command's, figure data and all (the plot's div id apart)
    assert UUID.sub("ID", page) == UUID.sub("ID", command)
    rows = _rows(page, "Scores")
    assert [r[1] for r in rows[1:]] == [
        f"{doc['paa']['score']:.4f}",
        f"{doc['needlekit']['score']:.4f}",
    ]
    assert rows[1][1] == f"{_paa_score_by_slabs(skin):.4f}" == "0.9112"
    # with another kind: a part each (the toy plan of the module's results)
    two = tmp_path / "two.html"
    plan = made / "plan.json"
    capsys.readouterr()
    assert main(["report", str(plan), str(record), "--out", str(two)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[-1] == f"drew plan.json (plan), approach.json (approach analysis) -> {two}"
    both = _page(two)
    assert _rows(both, "Scores") == rows
    nav = re.findall(r"<li><a href='#part-(\d)'>([^<]*)</a></li>", both)
    assert nav == [("1", "Steerable-needle plan: toy lung"), ("2", "Approach analysis: plate.yaml")]


def test_an_approach_record_that_cannot_be_drawn_is_named(approached, tmp_path, capsys):
    d, _ = approached
    doc = json.loads((d / "out" / "approach.json").read_text())
    moved = tmp_path / "approach.json"  # its scenario is not beside it: given with --scenario
    moved.write_text(json.dumps(doc))
    err = _one_error_line(capsys, ["report", moved, "--out", tmp_path / "x.html"])
    assert err.startswith("error: --scenario: ") and "which is not there" in err
    assert main(["report", str(moved), "--scenario", str(d / "plate.yaml"), "--out",
                 str(tmp_path / "x.html")]) == 0  # fmt: skip
    summary = tmp_path / "summary.json"  # written with --summary-only
    summary.write_text(json.dumps({k: v for k, v in doc.items() if k != "per_face"}))
    err = _one_error_line(capsys, ["report", summary, "--scenario", d / "plate.yaml", "--out",
                                   tmp_path / "y.html"])  # fmt: skip
    assert err == (
        "error: summary.json: per_face: missing: the record keeps no per-triangle arrays "
        "(written with --summary-only); run `needlekit approach` again without it"
    )
    other = dict(doc, target_mm=[0.0, 0.0, 5.0])  # not the scenario's target
    (tmp_path / "other.json").write_text(json.dumps(other))
    capsys.readouterr()
    code = main(["report", str(tmp_path / "other.json"), "--scenario", str(d / "plate.yaml"),
                 "--out", str(tmp_path / "z.html")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and "its target is not one of the targets of" in err
