"""``needlekit report RESULT... --out page.html``: every result kind drawn again from its
file, several in one page, and the errors before any work (issue 12, point 5).

The results are made here by the commands themselves, with small budgets. The values the
pages must show come from the result files, and the independent checks from ``needlekit
verify`` (a separate path to the same rules).
"""

import html
import importlib
import inspect
import json
import re
import shutil
from pathlib import Path

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
        f"error: --scenario: {moved / 'plan.json'} names the scenario gone/toy.yaml, which is "
        "not there; give its path with --scenario"
    )
    argv = ["report", moved / "plan.json", "--scenario", TOY, "--out", tmp_path / "b.html"]
    assert _run(argv) == 0 and (tmp_path / "b.html").stat().st_size > 0


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
        ('{"an": "object"}', "not a result of a known kind (plan, goals, sweep, cfrw, multi, puncture)"),
        ('{"paa": {}, "needlekit": {}, "blocked": {}}', "is an approach analysis"),
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
        (lambda d: d.update(goal_mm=[1, 2]), "goal_mm", "expected three numbers"),
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
# the puncture study, and the modules' documentation


@pytest.mark.slow
def test_a_puncture_study_gets_its_figures_and_tables(tmp_path, capsys):
    _run(["puncture", "--trials", "1", "--seed", "3", "--out", tmp_path / "pu", "--no-report"],
         ok=(0, 1))  # fmt: skip
    doc = json.loads((tmp_path / "pu" / "puncture.json").read_text())
    out = tmp_path / "pu.html"
    assert main(["report", str(tmp_path / "pu" / "puncture.json"), "--out", str(out)]) == 0
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
        "needlekit.io.records",
        "needlekit.io.results",
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
