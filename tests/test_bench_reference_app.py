"""``needlekit bench steerable --reference-app``: the UNC reference app beside needlekit.

Most tests run a fake app (a Python script written into tmp_path that reads the case
folder's input files as the real app does and prints what the real app prints for a known
case). The tests with the real app and Med-RAD take the app's path from
``$NEEDLEKIT_REFERENCE_APP`` and skip when it is unset. The last part is the screening of
sampled targets (``--sample-targets``): the sampling on a synthetic case and on lung 1,
the summary on fabricated rows, the flags.
"""

import math
import os
import stat
import sys
import types
from pathlib import Path

import numpy as np
import pytest

import needlekit.io.medrad as medrad
from needlekit.anatomy.occupancy import VoxelObstacles
from needlekit.benchmarks import reference_app as ra
from needlekit.benchmarks import reference_comparison as rc
from needlekit.benchmarks import target_screening as ts
from needlekit.benchmarks.steerable import BENCH_NEEDLE, _row, _summary, run_steerable_benchmark
from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.result import PlanResult

REFERENCE_APP_ENV = "NEEDLEKIT_REFERENCE_APP"

#: What the real app prints (test_rcs_star.cc, test_utils.h, needle_validator.h) for lung 1
#: start 1, r_min 50 (certified), the same start at r_min 100 (refused) and start 2 at 50
#: (budget), with the progress stream shortened.
CERTIFIED_LOG = (
    "Needle parameters:\n\tradius of curvature 50\n"
    + "".join(f"\rLoaded obstacle points: {i}" for i in range(1, 6))
    + "\nUsing cost: PATH_LENGTH\n"
    "11:33:27.907 INFO  [0000] (needle_prcs_star_impl.h:117) found solution with cost 58.2573\n"
    "11:33:27.908 INFO  [0000] (test_utils.h:245) solve time 0.0223788 seconds\n"
    "11:33:27.910 INFO  [0000] (prcs_base.hpp:94) iterations: 6\n"
    "11:33:27.915 INFO  [0000] (test_utils.h:251) exact solution\n"
    "0.0121523, 60.5\n0.0221523, 58.2573\n"
)
REFUSED_LOG = (
    "\rLoaded obstacle points: 1\rLoaded obstacle points: 2\n"
    "Goal point not in FRS, need rad to be 80.1965\n"
    "terminate called after throwing an instance of 'std::runtime_error'\n"
)
BUDGET_LOG = (
    "\rLoaded obstacle points: 7\n"
    "11:33:45.244 INFO  [0000] (test_utils.h:245) solve time 1.00047 seconds\n"
    "11:33:45.244 INFO  [0000] (prcs_base.hpp:94) iterations: 8667\n"
    "11:33:45.245 INFO  [0000] (test_utils.h:266) no solution found\n"
)


def _parse(text):
    return ra.parse_app_log(text.replace("\r", "\n").split("\n"))


def test_the_app_log_is_read_for_cost_times_iterations_and_refusals():
    c = _parse(CERTIFIED_LOG)
    assert c["status"] == "certified" and c["verdict"] == "certified" and c["exhausted"]
    assert c["solve_s"] == pytest.approx(0.0223788) and c["iterations"] == 6
    assert c["solutions"] == [[0.0121523, 60.5], [0.0221523, 58.2573]]
    assert c["cost_mm"] == 58.2573 and c["first_solution_s"] == 0.0121523
    assert c["found_costs_mm"] == [58.2573] and c["obstacle_points"] == 5
    assert not any(line.startswith("Loaded obstacle") for line in c["kept"])

    r = _parse(REFUSED_LOG)
    assert (r["status"], r["verdict"], r["reason"]) == (
        "refused",
        "infeasible",
        "Goal point not in FRS",
    )
    assert r["needs_r_min_mm"] == pytest.approx(80.1965) and r["solve_s"] is None

    b = _parse(BUDGET_LOG)
    assert (b["status"], b["verdict"], b["exhausted"]) == ("no plan (budget)", "no plan", False)
    assert b["iterations"] == 8667 and b["cost_mm"] is None

    f = _parse("Segmentation fault\n")
    assert (f["status"], f["verdict"]) == ("failed", "failed")
    w = _parse("\rLoaded obstacle points: 3\nReachable workspace is not connected to the goal!\n")
    assert (w["status"], w["verdict"]) == ("refused", "infeasible")


def test_a_huge_progress_stream_is_read_in_bounded_pieces(tmp_path):
    log = tmp_path / "run.log"
    n = 200_000  # ~5 MB on one line, as the real app's
    with open(log, "w") as fh:
        fh.write("".join(f"\rLoaded obstacle points: {i}" for i in range(1, n + 1)))
        fh.write("\n" + CERTIFIED_LOG.split("\nUsing cost", 1)[1])
    lines = list(ra._lines(log))
    assert max(map(len, lines)) <= ra._MAX_LINE
    parsed = ra.parse_app_log(lines)
    assert parsed["obstacle_points"] == n and parsed["cost_mm"] == 58.2573


# -- input files --------------------------------------------------------------------------


def _block_case():
    """A 40^3 grid (1 mm voxels): a free box [10, 30)^3 with a 6 mm obstacle cube in it;
    two starts and a target inside the box."""
    occ = np.ones((40, 40, 40), bool)
    occ[10:30, 10:30, 10:30] = False
    occ[16:22, 16:22, 16:22] = True  # a vessel: its centre voxels are > 2 mm from free space
    affine = np.diag([1.0, 1.0, 1.0, 1.0])
    affine[:3, 3] = (-20.0, -20.0, 80.0)
    starts = []
    for x in (-7.0, -6.0):
        pose = np.eye(4)
        pose[:3, :3] = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]  # z along +x
        pose[:3, 3] = (x, -5.0, 95.0)
        starts.append(types.SimpleNamespace(name=f"start{len(starts) + 1}", world_T_tip=pose))
    case = types.SimpleNamespace(
        voxel_obstacles=lambda needle_diameter_mm: VoxelObstacles(
            occ, affine, needle_diameter_mm=needle_diameter_mm
        ),
        starts=starts,
        targets_mm={"target": np.array([6.0, 5.0, 103.0])},
    )
    return case, occ, affine


def test_the_obstacle_file_is_the_crop_and_the_shell_of_the_obstacles(tmp_path):
    case, occ, affine = _block_case()
    points = np.array([s.world_T_tip[:3, 3] for s in case.starts] + [case.targets_mm["target"]])
    path = tmp_path / "P1_obstacles.txt"
    info = ra.write_obstacle_file(path, occ, affine, points, margin_mm=5.0, shell_mm=1.0)
    lines = path.read_text().splitlines()
    crop_affine = np.array([[float(v) for v in line.split()] for line in lines[:4]])
    size = [int(v) for v in lines[4].split()]
    ijk = np.array([[int(v) for v in line.split()] for line in lines[5:]])
    # bounding box x -7..6, y -5..5, z 95..103 (+-5 mm) -> voxel indices 8..31, 10..30, 10..28
    assert info["crop_lo"] == [8, 10, 10] and info["crop_hi"] == [32, 31, 29]
    assert size == info["crop_size"] == [24, 21, 19]
    np.testing.assert_allclose(crop_affine[:3, 3], affine[:3, :3] @ [8, 10, 10] + affine[:3, 3])
    np.testing.assert_allclose(crop_affine[:3, :3], affine[:3, :3])
    assert len(ijk) == info["written_voxels"] and np.all(ijk >= 0) and np.all(ijk < size)
    world = ijk + info["crop_lo"]
    assert occ[tuple(world.T)].all()  # only obstacle voxels
    # every obstacle voxel within 1 mm of free space is there, none deeper
    kept = {tuple(v) for v in world}
    assert (9, 15, 15) in kept and (8, 15, 15) not in kept  # 1 and 2 mm outside the box
    assert (16, 18, 18) in kept and (17, 18, 18) not in kept  # the cube's skin, 2 mm into it
    assert (18, 18, 18) not in kept
    assert info["obstacle_voxels"] == int(occ[8:32, 10:31, 10:29].sum()) > len(ijk)


def test_a_case_folder_holds_what_the_app_reads(tmp_path):
    case, _, _ = _block_case()
    obst = tmp_path / "P1_obstacles.txt"
    obst.write_text("x\n")
    needle = {**BENCH_NEEDLE, "r_min_mm": 50.0}
    folder = ra.write_case_folder(tmp_path / "P1_s1_r50", obst, case.starts[0].world_T_tip,
                                  case.targets_mm["target"], needle)  # fmt: skip
    inp = folder / "data" / "input"
    assert (inp / "obstacles.txt").read_text() == "x\n" and (inp / "obstacles.txt").is_symlink()
    start, goal = (np.array(line.split(), float) for line in
                   (inp / "start_and_goal_poses.txt").read_text().splitlines())  # fmt: skip
    np.testing.assert_allclose(start[:3], (-7.0, -5.0, 95.0))
    w, x, y, z = start[3:]  # this rotation: (w, x, y, z) = (1/2, 1/2, 1/2, 1/2) up to sign
    np.testing.assert_allclose(np.abs([w, x, y, z]), 0.5, atol=1e-12)
    np.testing.assert_allclose(goal, (6.0, 5.0, 103.0, 1, 0, 0, 0))
    assert (inp / "needle_parameters.txt").read_text() == "50 1 150 90\n"
    assert (inp / "costs.txt").read_text() == ""
    assert (folder / "bin").is_dir() and (folder / "data" / "output").is_dir()


# -- a fake app ---------------------------------------------------------------------------

FAKE_APP = """\
#!{python}
# Reads the case's input files as UNC's rcs_star does (from bin/: ../data/input/...) and
# prints what the real app prints. r_min 100 -> refused ("Goal point not in FRS"); start
# x < -6.5 mm -> certified (58.2573 mm in 22.4 ms, 6 iterations); else the budget runs out
# without a plan (1.00047 s, 8667 iterations).
import os, sys
assert sys.argv[1:] == ["0", "0", "1"], sys.argv
inp = "../data/input/"
r, d, l, a = map(float, open(inp + "needle_parameters.txt").read().split())
start, goal = (list(map(float, line.split())) for line in open(inp + "start_and_goal_poses.txt"))
assert len(start) == 7 and len(goal) == 7 and os.path.exists(inp + "costs.txt")
lines = open(inp + "obstacles.txt").read().splitlines()
assert all(len(line.split()) == 4 for line in lines[:4]) and len(lines[4].split()) == 3
with open(os.environ["FAKE_TRACE"], "a") as fh:
    fh.write("app\\n")
print("Needle parameters:\\n\\tradius of curvature %g" % r)
for i in range(1, len(lines) - 4):
    sys.stdout.write("\\rLoaded obstacle points: %d" % i)
print()
if r > 99:
    print("Goal point not in FRS, need rad to be 80.1965")
    sys.stdout.flush()
    sys.stderr.write("terminate called after throwing an instance of 'std::runtime_error'\\n")
    os.abort()
if start[0] < -6.5:
    print("12:00:00.000 INFO  [0000] (x.h:1) found solution with cost 58.2573")
    print("12:00:00.000 INFO  [0000] (x.h:1) solve time 0.0224 seconds")
    print("12:00:00.000 INFO  [0000] (x.h:1) iterations: 6")
    print("0.0112, 60.5")
    print("0.0224, 58.2573")
else:
    print("12:00:00.000 INFO  [0000] (x.h:1) solve time 1.00047 seconds")
    print("12:00:00.000 INFO  [0000] (x.h:1) iterations: 8667")
open("../data/output/plan_org.txt", "w").write("1 2 3\\n")
"""


def _fake_app(tmp_path, monkeypatch):
    app = tmp_path / "rcs_star"
    app.write_text(FAKE_APP.format(python=sys.executable))
    app.chmod(app.stat().st_mode | stat.S_IXUSR)
    trace = tmp_path / "trace.txt"
    monkeypatch.setenv("FAKE_TRACE", str(trace))
    return app, trace


def _fake_solve(trace, start, r):
    """needlekit's side of the fake case: the same verdicts, known times."""

    def solve(budget_s):
        if budget_s < ra.REFERENCE_BUDGET_S:
            return None  # the warm-up
        with open(trace, "a") as fh:
            fh.write("nk\n")
        if r > 99:
            status, cost, t, stats = PlanStatus.INFEASIBLE, np.inf, 0.0002, {"iterations": 0}
        elif start == 1:
            status, cost, t = PlanStatus.SOLVED, 58.25735, 0.0112
            stats = {"iterations": 5, "certified": True, "first_solution_s": 0.0056}
        else:
            status, cost, t, stats = PlanStatus.APPROXIMATE, 70.0, 1.0, {"iterations": 2000}
        stats |= {"planner_wall_s": t}
        return PlanResult(status, "rcs_star", None, cost, t, np.zeros(3), stats)

    return solve


def test_the_comparison_interleaves_the_app_and_needlekit_and_sums_up(tmp_path, monkeypatch):
    app, trace = _fake_app(tmp_path, monkeypatch)
    case, _, _ = _block_case()
    cmp = rc.ReferenceComparison(app, tmp_path / "work", BENCH_NEEDLE)
    cmp.add_patient(1, case)
    results = []
    for i, s in enumerate(case.starts, start=1):
        for r in (50.0, 100.0):
            res = cmp.compare(1, i, s.world_T_tip, case.targets_mm["target"], r,
                              _fake_solve(trace, i, r))  # fmt: skip
            results.append(res)
    assert trace.read_text().split() == ["app", "nk", "nk", "app", "app", "nk", "nk", "app"]
    rec = cmp.record()
    rows = rec["rows"]
    assert [r["order"] for r in rows] == ["app+needlekit", "needlekit+app"] * 2
    assert [r["app"]["status"] for r in rows] == [
        "certified", "refused", "no plan (budget)", "refused"]  # fmt: skip
    assert [r["needlekit"]["verdict"] for r in rows] == [
        "certified", "infeasible", "no plan", "infeasible"]  # fmt: skip
    assert all(r["verdicts_agree"] for r in rows)
    first = rows[0]
    assert first["app"]["obstacle_points"] == rec["patients"][0]["written_voxels"]
    assert first["app"]["returncode"] == 0 and rows[1]["app"]["returncode"] != 0
    assert first["ratio_time_to_certified"] == pytest.approx(0.0112 / 0.0224)
    assert first["ratio_first_solution"] == pytest.approx(0.0056 / 0.0112)
    assert first["ratio_us_per_iteration"] == pytest.approx((0.0112 / 5) / (0.0224 / 6))
    assert first["needlekit"]["us_per_iteration"] == pytest.approx(1e6 * 0.0112 / 5)
    assert first["cost_difference_mm"] == pytest.approx(0.00005)
    assert rows[2]["ratio_time"] == pytest.approx(1.0 / 1.00047)
    assert rows[2]["ratio_time_to_certified"] is None
    for r in rows:
        assert len(r["app"]["loadavg"]) == 3 and len(r["needlekit"]["loadavg"]) == 3
        log = Path(r["app"]["log"]).read_text()
        assert "Loaded obstacle points" not in log and "radius of curvature" in log
    assert rec["warm_up"] is not None and results[0].status is PlanStatus.SOLVED
    s = rec["summary"]
    assert s["cases"] == 4 and s["verdicts_agree"] == "4/4" and s["costs_agree"] == "1/1"
    assert s["ratio_time_to_certified"]["median"] == pytest.approx(0.5)
    assert s["ratio_time_to_certified"]["n"] == 1
    assert s["ratio_first_solution"]["median"] == pytest.approx(0.5)
    assert s["max_abs_cost_difference_mm"] == pytest.approx(0.00005)
    assert s["median_us_per_iteration"]["app"] == pytest.approx(
        np.median([1e6 * 0.0224 / 6, 1e6 * 1.00047 / 8667]))  # fmt: skip
    table = rc.format_comparison(rec)
    assert table.splitlines()[0] == rc.TABLE_HEADER and "P1 s1 r50" in table
    assert "time to certified (both certified): 0.50 (n=1" in table


def test_disagreeing_verdicts_and_costs_are_counted():
    def row(app_v, nk_v, app_cost, nk_cost):
        a = {"verdict": app_v, "cost_mm": app_cost, "time_to_certified_s": 0.01,
             "first_solution_s": 0.01, "solve_s": 0.01, "us_per_iteration": 1.0,
             "loadavg": [1.0, 1.0, 1.0]}  # fmt: skip
        n = {"verdict": nk_v, "cost_mm": nk_cost, "time_to_certified_s": 0.03,
             "first_solution_s": 0.02, "time_s": 0.03, "us_per_iteration": 2.0,
             "loadavg": [2.0, 2.0, 2.0]}  # fmt: skip
        return rc._compared({"patient": 1, "start": 1, "r_min_mm": 50.0, "app": a, "needlekit": n})

    rows = [row("certified", "certified", 58.0, 58.0005), row("certified", "certified", 58.0, 58.01),
            row("infeasible", "no plan", None, None)]  # fmt: skip
    s = rc.comparison_summary(rows)
    assert s["verdicts_agree"] == "2/3" and s["verdict_disagreements"] == ["P1 s1 r50"]
    assert s["costs_agree"] == "1/2" and s["max_abs_cost_difference_mm"] == pytest.approx(0.01)
    assert s["ratio_time_to_certified"] == {"median": pytest.approx(3.0), "n": 2,
                                            "min": pytest.approx(3.0), "max": pytest.approx(3.0)}  # fmt: skip
    assert s["loadavg_1min"] == [1.0, 2.0]


def test_every_row_records_the_time_per_iteration_and_the_summary_its_median():
    def res(wall, iterations):
        stats = {"planner_wall_s": wall, "iterations": iterations}
        return PlanResult(PlanStatus.SOLVED, "rcs", None, 50.0, wall, np.zeros(3), stats)

    rows = [_row(res(0.01, 10), start=1) | {"reference_cost_mm": "n/a"},
            _row(res(0.03, 10), start=2) | {"reference_cost_mm": "n/a"},
            _row(res(0.0, 0), start=3) | {"reference_cost_mm": "n/a"}]  # fmt: skip
    assert [r["us_per_iteration"] for r in rows] == [pytest.approx(1000.0),
                                                     pytest.approx(3000.0), None]  # fmt: skip
    assert _summary(rows)["rcs"]["median_us_per_iteration"] == pytest.approx(2000.0)


# -- the command line ---------------------------------------------------------------------


@pytest.fixture
def no_loading(monkeypatch):
    def load(*args, **kwargs):
        raise AssertionError("a Med-RAD case was loaded before the flags were checked")

    monkeypatch.setattr(medrad, "load_medrad", load)


def _one_error_line(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    return err[0]


def test_a_missing_or_unusable_app_is_one_error_line_before_any_work(capsys, tmp_path, no_loading):
    bench = ["bench", "steerable", "--patients", "1", "--reference-app"]
    missing = tmp_path / "nope"
    assert _one_error_line(capsys, [*bench, str(missing)]) == (
        f"error: --reference-app: {missing}: not found"
    )
    plain = tmp_path / "rcs_star"
    plain.write_text("#!/bin/sh\n")
    plain.chmod(0o644)
    assert _one_error_line(capsys, [*bench, str(plain)]) == (
        f"error: --reference-app: {plain}: is not executable"
    )
    assert _one_error_line(capsys, [*bench, str(tmp_path)]).startswith(
        f"error: --reference-app: {tmp_path}: is a folder"
    )


def test_the_comparison_needs_rcs_star_and_the_apps_budget(
    capsys, tmp_path, monkeypatch, no_loading
):
    app, _ = _fake_app(tmp_path, monkeypatch)
    bench = ["bench", "steerable", "--patients", "1", "--reference-app", str(app)]
    assert _one_error_line(capsys, [*bench, "--planners", "rcs", "rrt"]) == (
        "error: --reference-app: compares needlekit's rcs_star with the app: add rcs_star "
        "to --planners"
    )
    assert _one_error_line(capsys, [*bench, "--time-limit-s", "2"]) == (
        "error: --time-limit-s: the reference app's budget is its stock 1 s; use 1 with "
        "--reference-app, got 2"
    )
    work = tmp_path / "file"
    work.write_text("")
    assert _one_error_line(capsys, [*bench, "--reference-work", str(work)]) == (
        f"error: --reference-work: {work}: is not a folder"
    )


# -- the real app -------------------------------------------------------------------------


@pytest.mark.realdata
@pytest.mark.slow
def test_the_real_app_and_needlekit_agree_on_lung_1(tmp_path, medrad_dir):
    app = os.environ.get(REFERENCE_APP_ENV)
    if not app:
        pytest.skip(f"set {REFERENCE_APP_ENV} to a built UNC rcs_star to compare with it")
    from needlekit.benchmarks.steerable import run_steerable_benchmark

    record = run_steerable_benchmark(
        patients=(1,), radii_mm=(50.0,), planners=("rcs_star",), medrad_dir=medrad_dir,
        reference_app=app, reference_work=tmp_path,
    )  # fmt: skip
    cmp = record["reference_app"]
    by_start = {r["start"]: r for r in cmp["rows"]}
    # lung 1, r_min 50: starts 1, 3, 4, 5 certified by both at the same cost, start 2 no plan
    for s in (1, 3, 4, 5):
        assert by_start[s]["app"]["status"] == "certified", by_start[s]["app"]
        assert by_start[s]["verdicts_agree"], by_start[s]
        assert abs(by_start[s]["cost_difference_mm"]) <= ra.COST_AGREEMENT_MM
    assert by_start[2]["app"]["cost_mm"] is None and by_start[2]["needlekit"]["cost_mm"] is None
    assert cmp["summary"]["ratio_time_to_certified"]["n"] == 4


# -- sampled targets (--sample-targets) ---------------------------------------------------


def _pose(position, direction):
    """A start pose at ``position`` whose z axis (insertion direction) is ``direction``."""
    z = np.asarray(direction, float) / np.linalg.norm(direction)
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    pose[:3, 3] = position
    return pose


def _synthetic_lung():
    """A 100^3 grid of 2 mm voxels (origin -100 mm): a free box 160 mm wide with an
    obstacle slab across it at x = 30-40 mm and two starts at the box's centre, one
    pointing +x, one +y."""
    free = np.zeros((100, 100, 100), bool)
    free[10:90, 10:90, 10:90] = True
    free[65:70, :, :] = False  # the slab: x = 30..38 mm (voxel centres)
    affine = np.diag([2.0, 2.0, 2.0, 1.0])
    affine[:3, 3] = -100.0
    starts = (
        types.SimpleNamespace(name="start1", world_T_tip=_pose([0.0, 0.0, 0.0], [1, 0, 0])),
        types.SimpleNamespace(name="start2", world_T_tip=_pose([0.0, 0.0, 0.0], [0, 1, 0])),
    )
    case = types.SimpleNamespace(
        free_space=types.SimpleNamespace(data=free, affine=affine),
        voxel_obstacles=lambda needle_diameter_mm: VoxelObstacles(
            ~free, affine, needle_diameter_mm=needle_diameter_mm
        ),
        starts=starts,
    )
    return case


def _check_drawn(case, drawn, needle_diameter_mm=1.0):
    free, affine = np.asarray(case.free_space.data), np.asarray(case.free_space.affine)
    obstacles = case.voxel_obstacles(needle_diameter_mm=needle_diameter_mm)
    by_name = {s.name: np.asarray(s.world_T_tip) for s in case.starts}
    for k, d in enumerate(drawn):
        assert d["sample"] == k
        pose = by_name[d["start_name"]]
        assert d["start"] == int(d["start_name"].removeprefix("start"))
        np.testing.assert_allclose(d["start_mm"], pose[:3, 3])
        t = np.asarray(d["target_mm"])
        ijk = np.linalg.solve(affine[:3, :3], t - affine[:3, 3])
        np.testing.assert_allclose(ijk, np.round(ijk), atol=1e-6)  # a voxel centre
        assert free[tuple(np.round(ijk).astype(int))]  # a free voxel
        v = t - pose[:3, 3]
        dist = np.linalg.norm(v)
        assert 35.0 <= dist <= 90.0 and d["distance_mm"] == pytest.approx(dist)
        angle = math.degrees(math.acos(np.clip(v @ pose[:3, 2] / dist, -1, 1)))
        assert angle <= 90.0 + 1e-9 and d["angle_deg"] == pytest.approx(angle, abs=1e-6)
        assert not obstacles.collides(t)  # clear for the needle


def test_sampled_targets_are_reproducible_and_meet_every_condition():
    case = _synthetic_lung()
    drawn = ts.sample_targets(case, 40, seed=3)
    assert drawn == ts.sample_targets(case, 40, seed=3)  # same seed, same targets
    assert drawn[:10] == ts.sample_targets(case, 10, seed=3)  # a prefix of a longer draw
    assert drawn != ts.sample_targets(case, 40, seed=4)
    _check_drawn(case, drawn)
    assert {d["start"] for d in drawn} == {1, 2}  # both starts drawn
    # nothing in the slab or within the needle's clearance of it (x 30-38 mm +- 1.2 mm)
    assert not any(28.8 < d["target_mm"][0] < 39.2 for d in drawn)


def test_a_start_without_room_ahead_is_one_error_naming_the_flag():
    case = _synthetic_lung()
    free = np.zeros_like(case.free_space.data)
    free[45:56, 45:56, 45:56] = True  # a 22 mm box around the starts: nothing 35 mm away
    case.free_space.data = free
    with pytest.raises(InvalidInputError, match=r"^--sample-targets: start\d: no free voxel"):
        ts.sample_targets(case, 1)
    with pytest.raises(InvalidInputError, match="--sample-targets"):
        ts.sample_targets(_synthetic_lung(), 0)


@pytest.mark.realdata
def test_targets_sampled_in_lung_1_are_free_and_ahead_of_their_start(medrad_lung1):
    drawn = ts.sample_targets(medrad_lung1, 12, seed=0)
    assert drawn == ts.sample_targets(medrad_lung1, 12, seed=0)
    _check_drawn(medrad_lung1, drawn)
    pleura = next(s for s in medrad_lung1.scene.structures if s.name == "pleuralBoundary")
    assert np.all(pleura.field.signed_distance(np.array([d["target_mm"] for d in drawn])) <= 0.0)


# -- the comparison with sampled targets --------------------------------------------------


def test_the_crop_covers_the_sampled_targets_and_each_case_is_named_by_its_sample(
    tmp_path, monkeypatch
):
    app, trace = _fake_app(tmp_path, monkeypatch)
    # a 2 mm margin: the stock 30 mm already covers the whole 40 mm grid
    monkeypatch.setattr(
        rc, "write_obstacle_file",
        lambda *a, **k: ra.write_obstacle_file(*a, **k, margin_mm=2.0),
    )  # fmt: skip
    case, _, _ = _block_case()
    plain = rc.ReferenceComparison(app, tmp_path / "plain", BENCH_NEEDLE)
    plain.add_patient(1, case)
    cmp = rc.ReferenceComparison(app, tmp_path / "work", BENCH_NEEDLE)
    far = np.array([[-15.0, 15.0, 115.0]])  # beyond the starts' and target's crop
    cmp.add_patient(1, case, far)
    # starts and target: x -7..6, y -5..5, z 95..103 (+-2 mm) -> i 11..28, j 13..27, k 13..25
    assert plain.patients[0]["crop_lo"] == [11, 13, 13]
    assert plain.patients[0]["crop_hi"] == [29, 28, 26]
    # with (-15, 15, 115), voxel (5, 35, 35): the crop reaches it, +- 2 mm
    assert cmp.patients[0]["crop_lo"] == [3, 13, 13]
    assert cmp.patients[0]["crop_hi"] == [29, 38, 38]
    s = case.starts[0]
    cmp.compare(1, 1, s.world_T_tip, far[0], 50.0, _fake_solve(trace, 1, 50.0), sample=7)
    row = cmp.rows[0]
    assert row["sample"] == 7 and row["target_mm"] == far[0].tolist()
    assert (tmp_path / "work" / "P1_s1_t7_r50" / "data" / "input").is_dir()
    assert rc._case_name(row) == "P1 s1 t7 r50"
    assert cmp.record()["summary"]["cases"] == 1


def _screen_row(sample, app_status, app_verdict, nk_verdict, nk_time_s, app_reason=None):
    return {
        "patient": 1, "start": 2, "sample": sample, "r_min_mm": 50.0,
        "target_mm": [1.0, 2.0, float(sample)],
        "app": {"status": app_status, "verdict": app_verdict, "reason": app_reason},
        "needlekit": {"verdict": nk_verdict, "time_s": nk_time_s,
                      "reason": "goal not connected" if nk_verdict == "infeasible" else None},
    }  # fmt: skip


def test_the_screening_summary_counts_not_connected_cases_and_unsound_answers():
    nc = ts.NOT_CONNECTED
    rows = [
        _screen_row(0, "refused", "infeasible", "infeasible", 0.002, nc),
        _screen_row(1, "refused", "infeasible", "infeasible", 0.15, nc),  # too slow
        _screen_row(2, "refused", "infeasible", "no plan", 1.0, nc),  # missed
        _screen_row(3, "refused", "infeasible", "infeasible", 0.0003, "Goal point not in FRS"),
        _screen_row(4, "certified", "certified", "infeasible", 0.01),  # unsound
        _screen_row(5, "no plan (budget)", "no plan", "infeasible", 0.01),  # stronger, not unsound
        _screen_row(6, "certified", "certified", "certified", 0.02),
    ]
    s = ts.screening_summary(rows)
    assert s["cases"] == 7 and s["app_not_connected"] == 3
    assert s["needlekit_infeasible_of_those"] == 2
    assert s["needlekit_infeasible_within_0_1_s_of_those"] == 1
    assert s["max_needlekit_time_s_of_those"] == 1.0
    assert [c["case"] for c in s["not_connected_cases"]] == [
        "P1 s2 t0 r50", "P1 s2 t1 r50", "P1 s2 t2 r50"]  # fmt: skip
    first = s["not_connected_cases"][0]
    assert first["target_mm"] == [1.0, 2.0, 0.0] and first["needlekit_time_s"] == 0.002
    assert first["needlekit_reason"] == "goal not connected"
    assert [c["case"] for c in s["unsound"]] == ["P1 s2 t4 r50"]
    assert [c["case"] for c in s["disagreements"]] == ["P1 s2 t2 r50", "P1 s2 t5 r50"]
    assert s["app_statuses"]["refused"] == 4 and s["needlekit_verdicts"]["infeasible"] == 5
    text = ts.format_screening(s).splitlines()
    assert text[0].startswith("SOUNDNESS BUG: needlekit says infeasible, the app finds a plan: "
                              "P1 s2 t4 r50")  # fmt: skip
    assert text[1].startswith("screening: 7 cases; the app says not connected in 3, needlekit "
                              "infeasible in 2 of them (1 within 0.1 s), largest needlekit "
                              "time 1000.0 ms")  # fmt: skip
    empty = ts.screening_summary([])
    assert empty["app_not_connected"] == 0 and empty["max_needlekit_time_s_of_those"] is None
    assert not ts.format_screening(empty).startswith("SOUNDNESS")


def test_sampled_targets_need_the_reference_app(capsys, tmp_path, monkeypatch, no_loading):
    bench = ["bench", "steerable", "--patients", "1", "--planners", "rcs_star"]
    assert _one_error_line(capsys, [*bench, "--sample-targets", "5"]) == (
        "error: --sample-targets: screens sampled targets beside the reference app: give "
        "--reference-app too"
    )
    assert _one_error_line(capsys, [*bench, "--target-seed", "3"]) == (
        "error: --target-seed: seeds --sample-targets: give that too"
    )
    assert _one_error_line(capsys, [*bench, "--sample-targets", "0"]).startswith(
        "error: argument --sample-targets: expected a whole number in [1, "
    )
    with pytest.raises(InvalidInputError, match=r"^--sample-targets: screens sampled"):
        run_steerable_benchmark(patients=(1,), planners=("rcs_star",), sample_targets=3)
    with pytest.raises(InvalidInputError, match=r"^--sample-targets: expected a whole number"):
        run_steerable_benchmark(patients=(1,), planners=("rcs_star",), sample_targets=-1)


@pytest.mark.realdata
@pytest.mark.slow
def test_the_real_app_screens_sampled_targets_in_lung_1(tmp_path, medrad_dir):
    app = os.environ.get(REFERENCE_APP_ENV)
    if not app:
        pytest.skip(f"set {REFERENCE_APP_ENV} to a built UNC rcs_star to compare with it")
    record = run_steerable_benchmark(
        patients=(1,), radii_mm=(50.0,), planners=("rcs_star",), medrad_dir=medrad_dir,
        reference_app=app, reference_work=tmp_path, sample_targets=2, target_seed=0,
    )  # fmt: skip
    cmp = record["reference_app"]
    drawn = cmp["samples"]["1"]["targets"]
    assert [r["target_mm"] for r in cmp["rows"]] == [d["target_mm"] for d in drawn]
    assert [r["sample"] for r in record["results"]] == [0, 1]
    assert all(r["reference_cost_mm"] == "n/a" for r in record["results"])
    # no sampled target lies outside the app's crop: the app never calls a goal out of range
    assert all(r["app"]["reason"] != "Goal point is outside image range" for r in cmp["rows"])
    assert cmp["screening"]["cases"] == 2 and cmp["screening"]["unsound"] == []
