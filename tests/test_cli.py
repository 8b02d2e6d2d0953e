"""The command line: outputs checked against the library, one-line errors with exit 2."""

import json
import subprocess
import sys

import numpy as np
import pytest

from needlekit import __version__
from needlekit.cli import main
from needlekit.cli._parser import DEMO_FILES
from needlekit.needle.bevel3d import propagate_bevel
from needlekit.needle.reachability import shortest_arc_line
from needlekit.needle.transform_method import tm_inverse


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_help_and_version():
    done = subprocess.run(
        [sys.executable, "-m", "needlekit.cli", "--version"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0 and done.stdout.strip() == f"needlekit {__version__}"
    done = subprocess.run(
        [sys.executable, "-m", "needlekit.cli", "--help"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0
    for word in ("kinematics", "demo", "bench"):
        assert word in done.stdout


def test_forward_json_matches_library(capsys):
    code, out, _ = run(
        capsys,
        "kinematics",
        "forward",
        "--kappa-per-mm",
        "0.02",
        "--segment",
        "5,0,4",
        "--segment",
        "0,3.14159,1",
        "--segment",
        "5,0.2,4",
        "--json",
    )
    assert code == 0
    data = json.loads(out)
    ref = propagate_bevel(np.eye(4), [[5, 0, 4], [0, 3.14159, 1], [5, 0.2, 4]], 0.02)
    assert np.allclose(data["final_pose"], ref[-1])
    assert np.allclose(data["points_mm"], ref[:, :3, 3])
    assert data["time_s"] == [0.0, 4.0, 5.0, 9.0]


def test_forward_table_with_start_pose(capsys, tmp_path):
    pose = tmp_path / "start.txt"
    g = np.eye(4)
    g[:3, 3] = [10.0, 20.0, 30.0]
    np.savetxt(pose, g)
    code, out, _ = run(
        capsys,
        "kinematics",
        "forward",
        "--kappa-per-mm",
        "0",
        "--segment",
        "2,0,5",
        "--start-pose",
        str(pose),
        "--dt-s",
        "1",
    )
    assert code == 0
    lines = out.splitlines()
    assert lines[0].split()[:4] == ["time_s", "x_mm", "y_mm", "z_mm"]
    last = next(line for line in lines if line.startswith("5.0000"))
    assert last.split()[:4] == ["5.0000", "10.0000", "20.0000", "40.0000"]


def test_inverse_json_matches_library(capsys):
    code, out, _ = run(
        capsys,
        "kinematics",
        "inverse",
        "--target",
        "10,20,80",
        "--target",
        "0,0,50",
        "--r-min-mm",
        "30",
        "--json",
    )
    assert code == 0
    data = json.loads(out)
    sol = tm_inverse([[10, 20, 80], [0, 0, 50]])
    arcs = data["arcs"]
    assert arcs[0]["radius_mm"] == pytest.approx(sol.radius_mm[0])
    assert arcs[1]["radius_mm"] is None and arcs[1]["curvature_per_mm"] == 0.0
    assert arcs[0]["length_mm"] == pytest.approx(sol.length_mm[0])
    short = shortest_arc_line(np.eye(4), [10, 20, 80], 30.0)
    assert arcs[0]["shortest_arc_line_mm"] == pytest.approx(short.length_mm[0])


def test_inverse_table(capsys):
    code, out, _ = run(capsys, "kinematics", "inverse", "--target", "50,0,50")
    assert code == 0
    header, _, row = out.splitlines()[:3]
    assert header.split() == [
        "target",
        "alpha_deg",
        "spin_deg",
        "radius_mm",
        "phi_deg",
        "length_mm",
    ]
    assert row.split()[3:5] == ["50.0000", "90.0000"]


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["kinematics", "inverse", "--target", "nan,0,5"], "--target"),
        (["kinematics", "inverse", "--target", "1,2"], "--target"),
        (["kinematics", "inverse", "--target", "1,2,3", "--r-min-mm", "0"], "--r-min-mm"),
        (["kinematics", "inverse", "--target", "1,2,3", "--r-min-mm", "-3"], "--r-min-mm"),
        (["kinematics", "inverse", "--target", "30,0,5", "--r-min-mm", "30"], "below --r-min-mm 30"),
        (["kinematics", "inverse", "--target", "0,0,-5"], "behind"),
        (
            ["kinematics", "inverse", "--target", "1,2,3", "--start-pose", "/no/such/file.txt"],
            "file.txt",
        ),
        (["kinematics", "forward", "--kappa-per-mm", "-1", "--segment", "1,0,1"], "--kappa-per-mm"),
        (["kinematics", "forward", "--kappa-per-mm", "0.1", "--segment", "1,0,-1"], "duration"),
        (["kinematics", "forward", "--kappa-per-mm", "0.1"], "--segment"),
        (["bench", "kinematics", "--samples", "1"], "--samples"),
        (["no-such-command"], "invalid choice"),
    ],
)
def test_errors_are_one_line_with_exit_2(capsys, argv, needle):
    with pytest.raises(SystemExit) as info:
        code = main(argv)
        raise SystemExit(code)
    assert info.value.code == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("error: ") and needle in lines[0]


def test_bench_kinematics_writes_record(capsys, tmp_path):
    out = tmp_path / "bench.json"
    code, text, _ = run(
        capsys,
        "bench",
        "kinematics",
        "--arcs",
        "2000",
        "--samples",
        "8",
        "--repeat",
        "1",
        "--out",
        str(out),
    )
    assert code == 0 and "M arcs/s" in text
    rec = json.loads(out.read_text())
    assert rec["benchmark"] == "kinematics"
    assert rec["inputs"]["n_arcs"] == 2000
    assert {"versions", "cpu", "python"} <= set(rec["machine"])
    for row in rec["results"]:
        assert row["arcs_per_s"] > 0 and row["max_abs_diff_mm"] < 1e-9


EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[1] / "examples"


def test_schema_prints_the_json_schema(capsys):
    from needlekit.io.scenario_schema import SCENARIO_SCHEMA

    code, out, _ = run(capsys, "schema")
    assert code == 0 and json.loads(out) == SCENARIO_SCHEMA


def test_scene_info_table_and_json(capsys):
    code, out, _ = run(capsys, "scene", "info", str(EXAMPLES / "toy.yaml"))
    assert code == 0
    lines = out.splitlines()
    assert lines[0].startswith("scene: toy lung")
    assert lines[1].split()[:3] == ["name", "role", "field"]
    row = next(line for line in lines if line.startswith("nodule"))
    assert row.split()[1] == "target" and row.split()[-2] == "1.44"  # 4/3 pi 7^3 mm^3
    code, out, _ = run(capsys, "scene", "info", str(EXAMPLES / "toy.yaml"), "--json")
    data = json.loads(out)
    lung = next(s for s in data["structures"] if s["name"] == "lung")
    assert lung["volume_ml"] == pytest.approx(4 / 3 * np.pi * 80 * 60 * 100 / 1000, rel=0.01)


def test_scene_render_writes_self_contained_html(capsys, tmp_path):
    out = tmp_path / "toy.html"
    code, text, _ = run(
        capsys,
        "scene",
        "render",
        str(EXAMPLES / "toy.yaml"),
        "--out",
        str(out),
        "--max-cells",
        "40",
    )
    assert code == 0 and text.strip() == str(out)
    html = out.read_text()
    assert "plotly" in html and "<script src=" not in html  # plotly.js is inlined: opens offline
    for name in ("lung", "vessel", "airway", "nodule"):
        assert name in html


def test_scene_errors_are_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "version: 1\nstructures: [{name: a, role: wall, sphere: {center_mm: [0,0,0], radius_mm: 1}}]\n"
    )
    code, _, err = run(capsys, "scene", "info", str(bad))
    assert code == 2
    assert (
        err.strip()
        == "error: bad.yaml: structures[0].role: expected one of obstacle, target, entry_surface, allowed_region, context, got 'wall'"
    )


@pytest.mark.slow
def test_demo_writes_figures_and_phantom_views(capsys, tmp_path, exact_clearance):
    code, _out, _ = run(capsys, "demo", "--out", str(tmp_path))
    assert code == 0
    # exactly the files the command line checks before it starts (and no temporary file)
    written = {p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file()}
    assert written == set(DEMO_FILES)
    names = {p.name for p in tmp_path.iterdir()}
    assert {"demo.json", "phantoms.html", "phantoms.json", "reachability.png"} <= names
    summary = json.loads((tmp_path / "phantoms.json").read_text())
    assert set(summary) == {"lung", "liver", "neck"}
    assert all(len(v["start_poses"]) >= 1 for v in summary.values())
    # the main job: the lung phantom's effective-region sweep, its best plan and report
    lung = tmp_path / "lung"
    assert {"scenario.yaml", "sweep.json", "plan.json", "report.html"} <= {
        p.name for p in lung.iterdir()
    }
    sweep = json.loads((lung / "sweep.json").read_text())
    assert sweep["planners"] == ["rcs_star", "rcs", "rrt"]
    st = sweep["summary"]
    assert st["rcs_star"]["n_effective"] == pytest.approx(
        544 * (1 - np.sin(np.radians(20))) / 2, abs=3
    )
    # iteration budgets end every search: the same numbers on any machine
    solved = {p: (st[p]["n_effective"], st[p]["n_solved"]) for p in ("rcs_star", "rcs", "rrt")}
    assert solved == {"rcs_star": (178, 5), "rcs": (178, 6), "rrt": (178, 2)}
    mean = [st[p]["mean_cost_mm"] for p in ("rcs_star", "rcs", "rrt")]
    # the crossing vessel makes the best path bend around it (a case where planning
    # matters): RCS*'s best has a detour beyond the turn-then-straight connection, and the
    # mean costs order as Feng's Table 4, RCS* < RRT < RCS
    assert mean == pytest.approx([32.448558, 33.545845, 33.047463], abs=1e-5)
    assert mean[0] < mean[2] < mean[1]
    assert len(sweep["best_plans"]["rcs_star"]["primitives"]) == 3
    plan = json.loads((lung / "plan.json").read_text())
    assert plan["cost_mm"] == pytest.approx(st["rcs_star"]["best_cost_mm"]) and plan["check"]["ok"]
    assert np.linalg.norm(np.diff(plan["points_mm"], axis=0), axis=1).max() <= 0.5 + 1e-9
    # the exact oracle: every plan written clears the phantom's exact anatomy, by at least
    # the clearance it certifies
    from needlekit.planning.steerable.plan import SteerablePlan
    from needlekit.scenario.loading import load_scenario
    from needlekit.scenario.problems import problem_from_scenario
    from needlekit.scenario.results import read_plan_json

    sc = load_scenario(lung / "scenario.yaml")
    problem = problem_from_scenario(sc)
    best, _, _ = read_plan_json(lung / "plan.json")
    # both the planner's figure and the check's (at the check's own sample spacing)
    for claimed in (plan["stats"], plan["check"]):
        exact_clearance(sc.base, problem, best, claimed["certified_clearance_mm"])
    for p, bp in sweep["best_plans"].items():
        rows = [
            [q["rotation_rad"], q["curvature_per_mm"], q["length_mm"]] for q in bp["primitives"]
        ]
        assert bp["status"] == "solved" and bp["cost_mm"] == st[p]["best_cost_mm"]
        path = SteerablePlan(np.array(bp["start_pose"]), rows)
        exact_clearance(sc.base, problem, path, bp["stats"]["certified_clearance_mm"])
    # the sweep chose the plan's direction: held to the scenario's own direction it fails,
    # saying so; held to the start point (the sweep's problem) it passes
    code, text, err = run(capsys, "verify", str(lung / "scenario.yaml"), str(lung / "plan.json"))
    assert code == 1 and text.startswith("VIOLATED:")
    assert "  - start: the plan's insertion direction is " in text
    # the start is the only violation; the path's clearance is said, as for a plan that passes
    lines = text.splitlines()[1:]
    assert [v for v in lines if not v.startswith(("  - start:", "clearance: certified "))] == []
    assert sum(v.startswith("clearance: certified ") for v in lines) == 1
    assert "--any-start-direction" in err
    code, text, _ = run(
        capsys,
        "verify",
        str(lung / "scenario.yaml"),
        str(lung / "plan.json"),
        "--any-start-direction",
    )
    assert code == 0 and text.startswith("ok:")
    html = (lung / "report.html").read_text()
    assert html.count("plotly.js v") == 1 and "Fig. 8" in html and "Fig. 9" in html


def test_plan_then_verify_round_trip(capsys, tmp_path):
    out = tmp_path / "plan.json"
    code, text, _ = run(capsys, "plan", str(EXAMPLES / "toy.yaml"), "--out", str(out))
    assert code == 0 and text.startswith("rcs_star: solved")
    data = json.loads(out.read_text())
    for key in (
        "status",
        "planner",
        "cost_mm",
        "length_mm",
        "time_s",
        "primitives",
        "points_mm",
        "start_pose",
        "goal_mm",
    ):
        assert key in data
    assert data["goal_mm"] == [20.0, 30.0, 40.0]
    code, text, _ = run(capsys, "verify", str(EXAMPLES / "toy.yaml"), str(out))
    assert code == 0 and text.startswith("ok:")
    # the same plan breaks a tighter curvature limit: exit 1 with the violation named
    code, text, _ = run(
        capsys, "verify", str(EXAMPLES / "toy.yaml"), str(out), "--r-min-mm", "500", "--json"
    )
    report = json.loads(text)
    assert code == 1 and not report["ok"] and report["violations"][0].startswith("curvature")


def test_plan_overrides_start_pose_and_goal(capsys, tmp_path):
    pose = tmp_path / "start.txt"
    g = np.eye(4)
    g[:3, 3] = [0.0, -12.0, 0.0]
    g[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # z axis along +y (toward the nodule)
    np.savetxt(pose, g)
    out = tmp_path / "plan.json"
    # RCS* ends when it has certified the optimum (a few ms here): the budget only bounds it
    code, _, _ = run(
        capsys, "plan", str(EXAMPLES / "toy.yaml"), "--start-pose", str(pose), "--goal", "10,40,20",
        "--r-min-mm", "60", "--needle-diameter-mm", "1.5", "--out", str(out), "--time-limit-s", "30",
    )  # fmt: skip
    data = json.loads(out.read_text())
    assert code == 0 and data["status"] == "solved" and data["stats"]["certified"]
    assert np.allclose(data["start_pose"], g) and data["goal_mm"] == [10.0, 40.0, 20.0]
    # nothing in the way: the shortest turn-then-straight path at r_min = 60 mm, ending on
    # the 1 mm goal tolerance
    free = shortest_arc_line(g, [10.0, 40.0, 20.0], 60.0).length_mm[0] - 1.0
    assert data["cost_mm"] == pytest.approx(free, abs=1e-6)
    assert data["cost_mm"] == pytest.approx(56.66881713834231, abs=1e-6)
    assert [p["curvature_per_mm"] for p in data["primitives"]] == pytest.approx([1 / 60, 0.0])


def test_plan_and_verify_errors(capsys, tmp_path):
    code, _, err = run(capsys, "plan", str(tmp_path / "missing.yaml"))
    assert code == 2 and err.startswith("error: ") and "not found" in err
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    code, _, err = run(capsys, "verify", str(EXAMPLES / "toy.yaml"), str(bad))
    assert code == 2 and "bad.json" in err and len(err.strip().splitlines()) == 1


def test_sweep_writes_the_direction_table(capsys, tmp_path):
    out = tmp_path / "sweep.json"
    code, text, _ = run(
        capsys,
        "sweep",
        str(EXAMPLES / "toy.yaml"),
        "--directions",
        "60",
        "--max-iterations",
        "200",
        "--time-limit-s",
        "10",
        "--out",
        str(out),
        "--plan",
        str(tmp_path / "best.json"),
        "--report",
        str(tmp_path / "report.html"),
    )
    data = json.loads(out.read_text())
    assert len(data["directions"]) == 60 and data["planners"] == ["rcs_star"]
    assert "Fig. 8" in (tmp_path / "report.html").read_text()
    summary = data["summary"]["rcs_star"]
    # the start lies on the airway wall: its outward normal halves the sphere (alpha = 0)
    assert summary["n_effective"] == 29
    # an iteration budget, not the clock, ends each search: the same outcome on any machine
    # (8 solved before clearance was certified: half the 0.5 mm sample gap is now kept too)
    assert code == 0 and summary["n_solved"] == 7 and summary["best_index"] == 13
    assert summary["best_cost_mm"] == pytest.approx(60.39820756787659, abs=1e-6)
    assert summary["mean_cost_mm"] == pytest.approx(63.379010229738455, abs=1e-6)
    assert "29 of 60 directions effective, 7 solved" in text
    rows = data["directions"]
    costs = [r["cost_mm"]["rcs_star"] for r in rows if r["status"]["rcs_star"] == "solved"]
    assert len(costs) == 7
    # one direction ends approximate: its nearest valid path, with the cost of that path
    assert [r["status"]["rcs_star"] for r in rows].count("approximate") == 1
    best = data["best_plans"]["rcs_star"]
    assert best["cost_mm"] == summary["best_cost_mm"] == min(costs)
    plan = json.loads((tmp_path / "best.json").read_text())
    assert plan["check"]["ok"] and plan["cost_mm"] == best["cost_mm"]


@pytest.mark.slow
def test_sweep_compares_planners_on_a_process_pool(capsys, tmp_path):
    out = tmp_path / "sweep.json"
    args = ["sweep", str(EXAMPLES / "toy.yaml"), "--healpix", "2", "--max-iterations", "50"]
    args += ["--planner", "rcs_star", "rrt", "--time-limit-s", "10", "--out", str(out)]
    code, text, _ = run(capsys, *args, "--executor", "process", "--workers", "2")
    data = json.loads(out.read_text())
    assert code == 0
    for planner in ("rcs_star", "rrt"):  # the iteration budget ends each search
        st = data["summary"][planner]
        assert (st["n_effective"], st["n_solved"], st["best_index"]) == (26, 6, 5)
        assert st["best_cost_mm"] == pytest.approx(60.3521519536678, abs=1e-6)
    assert data["planners"] == ["rcs_star", "rrt"] and len(data["directions"]) == 48
    assert text.count("directions effective") == 2
    serial_out = tmp_path / "serial.json"
    run(capsys, *args[:-1], str(serial_out))
    serial = json.loads(serial_out.read_text())
    assert [r["cost_mm"] for r in serial["directions"]] == [
        r["cost_mm"] for r in data["directions"]
    ]


def test_clearance_cost_from_the_scenario_plans_and_verifies(capsys, tmp_path):
    text = (
        (EXAMPLES / "toy.yaml")
        .read_text()
        .replace(
            "planner: {name: rcs_star, time_limit_s: 1.0, seed: 0}",
            # an iteration budget ends RRT's anytime search, never the 60 s clock
            "planner: {name: rrt, time_limit_s: 60.0, max_iterations: 100, seed: 0,"
            " cost: {kind: clearance, weight: 2.0, reach_mm: 3.0}}",
        )
    )
    assert "clearance" in text
    scenario = tmp_path / "toy_clearance.yaml"
    scenario.write_text(text)
    out = tmp_path / "plan.json"
    code, _, _ = run(capsys, "plan", str(scenario), "--out", str(out))
    data = json.loads(out.read_text())
    assert code == 0 and data["cost_mm"] > data["length_mm"]  # every mm costs at least 1
    assert data["status"] == "solved" and data["stats"]["iterations"] == 100
    assert data["stats"]["reason"] == "iteration limit"
    assert data["cost_mm"] == pytest.approx(67.08006203546118, abs=1e-6)
    code, text, _ = run(capsys, "verify", str(scenario), str(out))
    assert code == 0 and text.startswith("ok: cost")
    # a plan file whose cost was tampered with fails the check
    data["cost_mm"] = data["length_mm"]
    out.write_text(json.dumps(data))
    code, text, _ = run(capsys, "verify", str(scenario), str(out))
    assert code == 1 and "cost: the plan claims" in text


def test_points_with_a_negative_first_coordinate_are_values_not_options():
    from needlekit.cli._parser import _build_parser

    args = _build_parser().parse_args(
        ["plan", "x.yaml", "--goals", "-10,10,70", "1,2,3", "-1.5e1,0,2", "--out", "p.json"]
    )
    assert args.goals == [[-10.0, 10.0, 70.0], [1.0, 2.0, 3.0], [-15.0, 0.0, 2.0]]
    args = _build_parser().parse_args(["kinematics", "inverse", "--target", "-5,0,40"])
    assert args.target == [[-5.0, 0.0, 40.0]]
