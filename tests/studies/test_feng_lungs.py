"""``needlekit study feng-lungs``: Feng et al.'s protocol on a Med-RAD lung.

Feng's own figures are checked against the rows of their Tables 2-3; the quick run (136
directions, 300 iterations per direction: the same on every machine) against its own sweep
files, the independent check, the direct connection and the anatomy's masks.
"""

import html
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from needlekit.cli import main
from needlekit.cli._parser import FENG_LUNGS_FILES as PARSER_FILES
from needlekit.studies.feng_lungs import (
    FENG_GOAL2_OFFSET_MM,
    FENG_LUNGS_FILES,
    FENG_POINTS_MM,
    FENG_TABLE4,
    feng_lung_scenario,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

#: Feng et al. (2023), Tables 2 (goal 1) and 3 (goal 2): each planner's costs in row order.
FENG_ROWS = {
    "goal1": {
        "rcs": [64.6193, 62.9014, 62.5639, 65.0225, 61.1241, 61.1949, 61.0548, 62.4123,
                61.5018, 64.5335, 62.3829],
        "rcs_star": [63.1118, 61.3853, 60.6194, 60.0265, 60.1770, 59.8760, 60.6104, 60.2192,
                     63.0487, 62.3829],
        "rrt": [64.2937, 63.3354, 62.5386, 61.1850, 61.4550, 61.0429, 62.0652, 64.4184,
                63.6609],
    },
    "goal2": {
        "rcs": [80.7644, 74.9835, 80.4673, 76.5572, 73.0024, 77.1477, 81.8952, 74.6854,
                72.7510, 75.4871, 72.9416, 73.1358, 76.6867, 73.6244, 74.9628, 78.7849,
                75.8855],
        "rcs_star": [79.3278, 73.4151, 74.4401, 71.8050, 81.9360, 72.3398, 71.5848, 71.9168,
                     71.8018, 72.3705, 73.3859, 74.5285],
        "rrt": [80.3665, 74.8899, 80.4152, 75.7056, 73.2365, 76.1870, 74.3561, 72.7260,
                74.9402, 73.0592, 73.1431, 75.9681, 73.9458, 75.3445, 78.4385, 75.6471],
    },
}  # fmt: skip


def test_the_parser_lists_the_files_the_study_writes():
    assert PARSER_FILES == FENG_LUNGS_FILES


@pytest.mark.parametrize("goal", ["goal1", "goal2"])
@pytest.mark.parametrize("planner", ["rcs", "rcs_star", "rrt"])
def test_fengs_table4_is_their_tables_2_and_3(goal, planner):
    rows = np.array(FENG_ROWS[goal][planner])
    printed = FENG_TABLE4[goal][planner]
    lowest = int(np.argmin(rows))
    assert printed["n_solved"] == len(rows)
    assert printed["best_cost_mm"] == rows[lowest]
    assert printed["cost_before_lowest_mm"] == pytest.approx(rows[: lowest + 1].sum(), abs=1e-4)
    if (goal, planner) == ("goal1", "rcs"):  # printed 62.7956; the 11 rows give 62.6647
        assert rows.mean() == pytest.approx(62.66467, abs=1e-5)
        assert printed["mean_cost_mm"] == 62.79560
    else:
        assert printed["mean_cost_mm"] == pytest.approx(rows.mean(), abs=1e-4)


def test_fengs_start_sign_puts_the_goals_within_their_costs():
    start = np.array(FENG_POINTS_MM["start"])
    for goal in ("goal1", "goal2"):
        straight = np.linalg.norm(np.array(FENG_POINTS_MM[goal]) - start)
        # a path is never shorter than the straight line less tau
        assert straight - 1.0 <= min(FENG_ROWS[goal]["rcs_star"])
        printed_sign = np.linalg.norm(np.array(FENG_POINTS_MM[goal]) - start * [-1, 1, 1])
        assert printed_sign > 100.0  # beyond l_max: the printed +64.8324 cannot be right
    offset = np.array(FENG_POINTS_MM["goal2"]) - np.array(FENG_POINTS_MM["goal1"])
    assert offset.tolist() == pytest.approx(list(FENG_GOAL2_OFFSET_MM))


@pytest.mark.realdata
@pytest.mark.parametrize("goal", [1, 2])
def test_the_examples_are_the_studys_scenarios(medrad_dir, goal):
    example = yaml.safe_load((EXAMPLES / f"medrad_lung_feng_goal{goal}.yaml").read_text())
    doc = feng_lung_scenario(goal)
    for key in ("version", "name", "base", "needle", "start", "collision_model", "planner"):
        assert example[key] == doc[key], key
    if goal == 1:
        assert example["goal"] == doc["goal"]
    else:
        assert example["goal"]["tolerance_mm"] == doc["goal"]["tolerance_mm"]
        assert example["goal"]["point_mm"] == pytest.approx(doc["goal"]["point_mm"], abs=1e-9)


@pytest.fixture(scope="module")
def quick(medrad_dir, tmp_path_factory):
    """The quick study, run once through the command line (in this process)."""
    out = tmp_path_factory.mktemp("feng") / "out"
    code = main(["study", "feng-lungs", "--out", str(out), "--quick", "--medrad", str(medrad_dir)])
    assert code == 0
    record = json.loads((out / "feng_lungs.json").read_text())
    sweeps = {g: json.loads((out / g / "sweep.json").read_text()) for g in ("goal1", "goal2")}
    return out, record, sweeps


def _problem(out, goal):
    from needlekit.scenario.problems import load_problem

    return load_problem(out / goal / "scenario.yaml")[1]


@pytest.mark.realdata
@pytest.mark.slow
def test_quick_run_writes_its_files_with_the_quick_settings(quick):
    out, record, _ = quick
    written = {str(p.relative_to(out)) for p in out.rglob("*") if p.is_file()}
    assert written == set(FENG_LUNGS_FILES)
    s = record["settings"]
    assert (s["directions"], s["max_iterations"], s["quick"]) == (136, 300, True)
    assert s["needle"]["diameter_mm"] == 2.0 and s["needle"]["max_length_mm"] == 100
    assert record["case"]["collision_model"] == "field"  # certified
    # Fibonacci lattice: 46 of 136 directions lie in the 70 deg cap about the airway normal
    # ((1 - sin 20 deg) / 2 of the sphere predicts 45)
    for g in ("goal1", "goal2"):
        assert all(t["n_effective"] == 46 for t in record["goals"][g]["table4"].values())


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize("goal", ["goal1", "goal2"])
def test_quick_tables_are_the_sweep_files(quick, goal):
    out, record, sweeps = quick
    sw, rec = sweeps[goal], record["goals"][goal]
    page = (out / "report.html").read_text(encoding="utf-8")
    for name in ("rcs_star", "rcs", "rrt"):
        # Feng's tables count solved plans only (approximate ones keep a cost in the rows)
        solved = [r["status"][name] == "solved" for r in sw["directions"]]
        rows = sw["directions"]
        costs = [r["cost_mm"][name] if ok else np.inf for r, ok in zip(rows, solved, strict=True)]
        costs = np.array(costs, dtype=float)  # a solved row without a cost fails here
        t = rec["table4"][name]
        assert t["n_solved"] == sum(solved) == sw["summary"][name]["n_solved"]
        assert t["n_effective"] == sum(r["effective"] for r in sw["directions"])
        if not any(solved):
            assert t["best_cost_mm"] is None and t["mean_cost_mm"] is None
            continue
        best = int(np.argmin(costs))
        assert t["best_index"] == best
        assert t["best_cost_mm"] == costs[best] == sw["best_plans"][name]["cost_mm"]
        assert t["mean_cost_mm"] == pytest.approx(costs[np.isfinite(costs)].mean(), rel=1e-12)
        before = costs[: best + 1]
        assert t["cost_before_lowest_mm"] == pytest.approx(before[np.isfinite(before)].sum())
        # Table 4 on the page carries the same numbers (3 decimals, true minus sign)
        assert f"{t['best_cost_mm']:.3f}" in page and f"{t['mean_cost_mm']:.3f}" in page
    means = {k: v["mean_cost_mm"] for k, v in rec["table4"].items()}
    if all(v is not None for v in means.values()):
        assert rec["order"] == sorted(means, key=means.get)
        assert rec["order_holds"] == (rec["order"] == ["rcs_star", "rrt", "rcs"])


@pytest.mark.realdata
@pytest.mark.slow
def test_every_solved_plan_passes_the_independent_check(quick, capsys):
    out, record, _ = quick
    for g in ("goal1", "goal2"):
        for name, c in record["goals"][g]["checks"].items():
            assert c["passed"] == c["solved"] and not c["failures"], (g, name)
            if c["solved"]:
                assert c["best"]["ok"] and c["best"]["certified_clearance_mm"] >= 0.0
                assert c["best"]["puncture_angle_deg"] >= 20.0
        # and by the command line, from the files alone
        # (the sweep chose the start direction: verify holds the plan to the start point)
        code = main(["verify", str(out / g / "scenario.yaml"), str(out / g / "plan.json"),
                     "--any-start-direction"])  # fmt: skip
        assert code == 0, capsys.readouterr()


@pytest.mark.realdata
@pytest.mark.slow
def test_the_best_path_bends_where_the_direct_connection_collides(quick):
    """Obstacles matter: from RCS*'s best direction, the direct turn-then-straight
    connection hits the anatomy, and the plan found instead passes."""
    from needlekit.planning.steerable.goal import goal_connection
    from needlekit.planning.steerable.plan import SteerablePlan, plan_from_dict
    from needlekit.planning.steerable.verify import verify_plan

    out, record, sweeps = quick
    problem = _problem(out, "goal1")
    best = sweeps["goal1"]["best_plans"]["rcs_star"]
    plan, _ = plan_from_dict(best, "sweep.json: best_plans.rcs_star")
    start = plan.start_pose
    assert verify_plan(problem.with_start_pose(start), plan, expected_cost_mm=best["cost_mm"]).ok
    direct = goal_connection(start, problem.goal_mm, problem.r_min_mm, problem.goal_tolerance_mm)
    assert direct is not None and direct.length_mm < best["cost_mm"] <= problem.max_length_mm
    check = verify_plan(problem.with_start_pose(start), SteerablePlan(start, direct.primitives))
    assert not check.ok
    assert any(v.startswith("collision") for v in check.violations), check.violations
    assert len(plan.primitives) > len(direct.primitives)
    # and so from every direction RCS* solved in the quick run
    rec = record["goals"]["goal1"]
    assert rec["table4"]["rcs_star"]["solved_not_direct"] == rec["table4"]["rcs_star"]["n_solved"]
    idx = sweeps["goal1"]["summary"]["rcs_star"]["best_index"]
    assert "collision" in rec["direct_fates"][idx]


@pytest.mark.realdata
@pytest.mark.slow
def test_the_second_target_is_free_tissue_within_reach_at_another_depth(quick, medrad_dir):
    from needlekit.io.medrad import load_medrad

    out, record, _ = quick
    p1, p2 = _problem(out, "goal1"), _problem(out, "goal2")
    assert np.allclose(p2.goal_mm - p1.goal_mm, FENG_GOAL2_OFFSET_MM)
    assert np.allclose(p1.start_point_mm, p2.start_point_mm)
    # free space by the certified field: clear of every obstacle by more than the needle
    field = p2.scene.obstacle_field(0.0)
    clearance = float(field.signed_distance(p2.goal_mm)) - field.error_bound_mm
    assert clearance > p2.clearance_margin_mm
    # and by the masks themselves: no obstacle voxel centre within the needle's reach
    case = load_medrad("lung", 5, medrad_dir)
    assert not case.voxel_obstacles(2.0).collides(p2.goal_mm[None]).any()
    inside_lung = case.scene["pleuralBoundary"].field.signed_distance(p2.goal_mm)
    assert float(inside_lung) < -5.0
    d1 = np.linalg.norm(p1.goal_mm - p1.start_point_mm)
    d2 = np.linalg.norm(p2.goal_mm - p2.start_point_mm)
    assert d1 < d2 < p2.max_length_mm  # deeper than goal 1, as Feng's goal 2, within l_max
    assert d2 - d1 > 5.0
    g2 = record["goals"]["goal2"]
    assert g2["straight_distance_mm"] == pytest.approx(d2)
    assert not g2["in_nodule"] and record["goals"]["goal1"]["in_nodule"]


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.browser
def test_the_study_page_renders_in_a_browser(quick, rendered):
    """The page of the quick run (Med-RAD lung 5) in headless Chromium: tables, parts per
    target, Figs. 7-9 and the anatomy around the paths; every 3D view drawn, no console
    warning (``rendered``, tests/conftest.py)."""
    out, _, _ = quick
    plots, pngs = rendered(out / "report.html")
    assert plots >= 4 and pngs


@pytest.mark.slow
@pytest.mark.realdata
def test_an_interrupted_study_keeps_its_sweeps_and_resume_gives_the_whole_tables(
    medrad_dir, tmp_path, monkeypatch, capsys
):
    """Ctrl-C while the sixth direction is planned: both targets'
    sweeps so far are written marked partial, and --resume plans the rest to the tables of
    a run never interrupted (iteration budgets: reproducible)."""
    import needlekit.planning.steerable.sweep_batch as sb
    from needlekit.studies.feng_lungs import run_feng_lungs

    small = ["--directions", "24", "--max-iterations", "40", "--medrad", str(medrad_dir)]
    ref = tmp_path / "ref"
    # the run never interrupted: the command's own call with its defaults (serial, seed 0),
    # without the page, which nothing here reads
    run_feng_lungs(ref, directions=24, max_iterations=40, medrad_dir=medrad_dir, report=False)
    plan_tasks, calls = sb._plan_tasks, []

    def interrupt_sixth(tasks):
        calls.append(len(tasks))
        if len(calls) == 6:
            raise KeyboardInterrupt
        return plan_tasks(tasks)

    monkeypatch.setattr(sb, "_plan_tasks", interrupt_sixth)
    out = tmp_path / "out"
    capsys.readouterr()
    assert main(["study", "feng-lungs", "--out", str(out), *small]) == 130
    (line,) = capsys.readouterr().err.strip().splitlines()
    paths = [out / g / "sweep.partial.json" for g in ("goal1", "goal2")]
    assert line.endswith(
        f"written to {paths[0]} and {paths[1]} marked partial; the same command with "
        "--resume carries on"
    ), line
    partial = [json.loads(p.read_text()) for p in paths]
    assert all(p["partial"] is True for p in partial)
    assert not (out / "feng_lungs.json").exists()
    n_done = sum(
        v is not None
        for p in partial
        for r in p["directions"]
        if r["effective"]
        for v in r["status"].values()
    )
    assert 0 < n_done == sum(calls[:5])  # the five tasks before Ctrl-C
    monkeypatch.setattr(sb, "_plan_tasks", plan_tasks)
    assert main(["study", "feng-lungs", "--out", str(out), *small, "--resume"]) == 0
    want = json.loads((ref / "feng_lungs.json").read_text())
    got = json.loads((out / "feng_lungs.json").read_text())
    assert got["settings"]["resumed"] is True and got["timing"]["within_bound"] is None
    for g in ("goal1", "goal2"):
        for name, t in want["goals"][g]["table4"].items():  # their run times aside
            assert {**got["goals"][g]["table4"][name], "time_s": 0} == {**t, "time_s": 0}
        assert got["goals"][g]["checks"] == want["goals"][g]["checks"]
        a, b = (json.loads((d / g / "sweep.json").read_text()) for d in (out, ref))
        assert "partial" not in a and not (out / g / "sweep.partial.json").exists()
        assert [(r["status"], r["cost_mm"]) for r in a["directions"]] == [
            (r["status"], r["cost_mm"]) for r in b["directions"]
        ]


UUID = re.compile(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}")


@pytest.mark.realdata
@pytest.mark.slow
def test_report_draws_the_study_record_as_the_study_drew_it(quick, tmp_path, capsys):
    """``needlekit report feng_lungs.json``: the study's own page again, from the record
    and the scenarios and sweeps beside it (each sweep keeps every solved plan), alone and
    with another kind; a record away from its folder, or from before the sweeps kept
    their plans, is named in one line."""
    out, record, sweeps = quick
    for g, rec in record["goals"].items():  # every plan kept, per planner, the solved ones
        for name, t in rec["table4"].items():
            kept = sweeps[g]["solved_plans"][name].values()
            assert sum(p["status"] == "solved" for p in kept) == t["n_solved"]
    study = out / "feng_lungs.json"
    page = tmp_path / "page.html"
    capsys.readouterr()
    assert main(["report", str(study), "--out", str(page)]) == 0
    said = capsys.readouterr().out.splitlines()
    solved = sum(c["solved"] for rec in record["goals"].values() for c in rec["checks"].values())
    passed = sum(c["passed"] for rec in record["goals"].values() for c in rec["checks"].values())
    assert passed == solved > 0
    assert said == [
        f"{study}: feng-lungs: 2 targets, 136 directions, rcs_star, rcs, rrt: {solved} of "
        f"{solved} solved plans pass the independent check run again (the study's: {solved})",
        f"drew feng_lungs.json (Feng lung study) -> {page}",
    ]
    drawn = page.read_text(encoding="utf-8")
    # the same page as the study's, tables and figure data (the plots' div ids apart)
    assert UUID.sub("ID", drawn) == UUID.sub("ID", (out / "report.html").read_text("utf-8"))
    assert f"wall time {record['page_wall_s']:.0f} s." in drawn
    # with another kind: the best RCS* plan to goal 1, its scenario loaded once for both
    both = tmp_path / "both.html"
    assert main(["report", str(study), str(out / "goal1" / "plan.json"), "--out", str(both)]) == 0
    said = capsys.readouterr().out.splitlines()
    assert said[-1] == f"drew feng_lungs.json (Feng lung study), plan.json (plan) -> {both}"
    nav = re.findall(
        r"<li><a href='#part-(\d)'>([^<]*)</a></li>", html.unescape(both.read_text("utf-8"))
    )
    # the study's part, its own parts per target, then the plan's
    assert [n for n, _ in nav] == ["1", "2", "3", "4"]
    assert nav[0][1] == "Feng et al.'s protocol on a Med-RAD lung (patient 5, start 1)"
    assert nav[1][1].startswith("Goal 1: (") and nav[2][1].startswith("Goal 2: (")
    assert nav[3][1] == "Steerable-needle plan: Med-RAD lung 5, start 1, Feng's goal 1"
    # the record alone, away from its folder
    alone = tmp_path / "alone" / "feng_lungs.json"
    alone.parent.mkdir()
    shutil.copy(study, alone)
    err = _one_error_line(capsys, ["report", alone, "--out", tmp_path / "x.html"])
    assert err == (
        f"error: {alone}: the study's goal1/scenario.yaml is not beside it "
        f"({str(alone.parent / 'goal1' / 'scenario.yaml')!r}): `needlekit report` draws the "
        "record in the folder the study wrote"
    )
    # a study from before its sweeps kept every solved plan
    old = tmp_path / "old"
    for f in ("feng_lungs.json", "goal1/scenario.yaml", "goal1/sweep.json",
              "goal2/scenario.yaml", "goal2/sweep.json"):  # fmt: skip
        (old / f).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(out / f, old / f)
    (old / "goal2" / "sweep.json").write_text(
        json.dumps({k: v for k, v in sweeps["goal2"].items() if k != "solved_plans"})
    )
    err = _one_error_line(capsys, ["report", old / "feng_lungs.json", "--out", tmp_path / "y.html"])
    assert err == (
        "error: goal2/sweep.json: solved_plans: missing: the study was run before it kept "
        "every solved path, which its page draws (Fig. 7); run `needlekit study feng-lungs` "
        "again"
    )


def _one_error_line(capsys, argv) -> str:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and not captured.out, captured
    return lines[0]
