"""``straight.targets: coverage``: targets chosen to cover a tumour plus margin, planned
with liu_cfrw, coverage re-evaluated along the planned needles (needlekit multi)."""

import json

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.ablation import planned_coverage, voxelise
from needlekit.planning.straight.coverage import AblationZone, evaluate_coverage
from needlekit.scenario.loading import load_scenario
from needlekit.scenario.problems import coverage_region, multi_problem_from_scenario

SCENARIO = """\
version: 1
name: a sphere tumour to ablate
structures:
  - {name: skin, role: entry_surface, sphere: {center_mm: [0, 0, 0], radius_mm: 100}}
  - {name: vessel, role: obstacle, capsule: {p0_mm: [-60, 5, 35], p1_mm: [60, 5, 35], radius_mm: 4}}
  - {name: vessel2, role: obstacle, capsule: {p0_mm: [25, -60, 60], p1_mm: [25, 60, 60], radius_mm: 3}}
  - {name: tumour, role: target, sphere: {center_mm: [0, -5, 0], radius_mm: 8}}
needle: {diameter_mm: 2.0, max_length_mm: 150}
straight:
  entry_surface: skin
  targets: coverage
  coverage:
    zone: {kind: ellipsoid, length_mm: 30, diameter_mm: 24}
    margin_mm: 3
    max_needles: 4
    voxel_mm: 1.5
  gamma_mm: 1.5
  up: [0, 0, 1]
  theta_range_deg: [0, 70]
  resolution_deg: 5
"""


def _write(tmp_path, text, name="cov.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_the_block_parses_with_its_defaults(tmp_path):
    sc = load_scenario(_write(tmp_path, SCENARIO))
    c = sc.straight["coverage"]
    assert sc.straight["targets"] == "coverage"
    assert c["zone"] == AblationZone("ellipsoid", 30.0, 24.0, 0.0)
    assert (c["margin_mm"], c["max_needles"], c["coverage_goal"]) == (3.0, 4, 1.0)
    assert c["structure"] == "tumour" and c["clip_to_body"] is True
    text = SCENARIO.replace("    margin_mm: 3\n    max_needles: 4\n", "")
    c = load_scenario(_write(tmp_path, text, "d.yaml")).straight["coverage"]
    assert (c["margin_mm"], c["max_needles"]) == (5.0, 6)


def test_the_region_is_the_voxelised_sphere_plus_margin(tmp_path):
    sc = load_scenario(_write(tmp_path, SCENARIO))
    multi, _ = multi_problem_from_scenario(sc)
    region, settings = coverage_region(sc, multi.problem)
    h = 1.5
    # voxel centres within R (+ margin) of the centre, up to one voxel diagonal either way
    for r, n in ((8.0, region.tumour.sum()), (11.0, region.mask.sum())):
        v = n * h**3
        d = np.sqrt(3) * h / 2
        assert 4 / 3 * np.pi * (r - d) ** 3 <= v <= 4 / 3 * np.pi * (r + d) ** 3
    assert settings["zone"].length_mm == 30.0


def test_plan_coverage_is_the_pipeline_the_command_study_and_benchmark_share(tmp_path):
    from dataclasses import replace

    from needlekit.planning.interface import Termination, get_planner
    from needlekit.planning.straight.ablation import plan_coverage, plan_with_coverage

    sc = load_scenario(_write(tmp_path, SCENARIO))
    multi, options = multi_problem_from_scenario(sc)
    region, settings = coverage_region(sc, multi.problem)
    planner = get_planner("liu_cfrw", options)
    steps: dict = {}
    plan, outcome = plan_coverage(
        multi, planner, region, settings, time_limit_s=60.0, timings=steps
    )
    by_hand = plan_with_coverage(
        multi.problem,
        region,
        settings["zone"],
        lambda t: planner.solve(replace(multi, targets_mm=t), Termination(60.0)),
        max_needles=settings["max_needles"],
        coverage_goal=settings["coverage_goal"],
    )
    assert plan.to_dict() == by_hand[0].to_dict()
    assert outcome.to_dict() == by_hand[1].to_dict()
    assert outcome.ok and steps["rounds"] >= 1 and steps["trajectories_s"] > 0


def test_voxelise_counts_a_ball():
    from needlekit.anatomy.primitives import Sphere

    mask, affine = voxelise(Sphere([1.0, 2.0, 3.0], 5.0), 1.0)
    centres = np.argwhere(mask) @ affine[:3, :3].T + affine[:3, 3]
    assert np.all(np.linalg.norm(centres - [1, 2, 3], axis=1) <= 5.0 + 1e-9)
    assert int(mask.sum()) == 515


def test_multi_chooses_plans_and_rechecks_the_coverage(tmp_path, capsys):
    path = _write(tmp_path, SCENARIO)
    out = tmp_path / "multi.json"
    report = tmp_path / "multi.html"
    assert main(["multi", str(path), "--out", str(out), "--report", str(report)]) == 0
    assert "coverage: 1.0000" in capsys.readouterr().out
    rec = json.loads(out.read_text())
    c = rec["coverage"]
    # the report shows the coverage table and draws one ablation zone per needle
    html = report.read_text()
    assert "Ablation coverage" in html and "healthy tissue ablated (mL)" in html
    assert "ellipsoid 30 x 24 mm along the needle" in html
    assert html.count('"legendgroup":"zones"') == len(rec["needles"])
    assert rec["status"] == "solved" and c["status"] == "covered" and c["reason"] == ""
    assert c["coverage"] == 1.0 and c["needles"] == len(rec["needles"]) <= 4
    assert c["zone"] == {"kind": "ellipsoid", "length_mm": 30.0, "diameter_mm": 24.0,
                         "tip_offset_mm": 0.0}  # fmt: skip
    for key in ("healthy_ablated_ml", "tumour_volume_ml", "region_volume_ml"):
        assert c[key] > 0
    assert c["planned"]["coverage"] == c["coverage"]
    # the targets planned are the ones chosen, each zone along its real needle
    chosen = np.array(c["chosen"]["targets_mm"])
    planned = np.array([n["planned_target_mm"] for n in rec["needles"]])
    assert {tuple(np.round(p, 4)) for p in planned} == {tuple(np.round(p, 4)) for p in chosen}
    sc = load_scenario(path)
    multi, _ = multi_problem_from_scenario(sc)
    region, settings = coverage_region(sc, multi.problem)
    dirs = [np.subtract(n["target_mm"], n["entry_mm"]) for n in rec["needles"]]
    again = evaluate_coverage(region, settings["zone"], planned, dirs)
    assert again.coverage == c["coverage"]
    assert again.healthy_ablated_ml == pytest.approx(c["healthy_ablated_ml"])
    # every target is inside the body and clear of the vessels by radius + gamma
    obstacles = multi.problem.obstacle_field()
    assert np.all(obstacles.signed_distance(planned) >= 1.0 + 1.5)
    assert main(["verify", str(path), str(out)]) == 0


def test_too_few_needles_say_so_and_exit_1(tmp_path, capsys):
    text = SCENARIO.replace("max_needles: 4", "max_needles: 1").replace(
        "length_mm: 30, diameter_mm: 24", "length_mm: 16, diameter_mm: 12"
    )
    out = tmp_path / "multi.json"
    assert main(["multi", str(_write(tmp_path, text)), "--out", str(out)]) == 1
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "not covered: coverage: 1 needles reach" in line and "goal 1" in line
    rec = json.loads(out.read_text())
    assert rec["status"] == "infeasible" and rec["coverage"]["status"] == "not_covered"
    assert rec["reason"].startswith("coverage: 1 needles reach")
    assert rec["coverage"]["needles"] == 1 and rec["coverage"]["coverage"] < 1.0


def test_planned_coverage_of_no_needle_is_zero(tmp_path):
    from needlekit.planning.straight.sequence import MultiNeedlePlan

    sc = load_scenario(_write(tmp_path, SCENARIO))
    multi, _ = multi_problem_from_scenario(sc)
    region, settings = coverage_region(sc, multi.problem)
    rep = planned_coverage(region, settings["zone"], MultiNeedlePlan((), (), False, 0, 1.5, 1.0))
    assert rep.coverage == 0.0 and rep.needles == 0


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        ("targets: coverage\n", "targets: [[0, 0, 0]]\n", "straight.coverage: only goes with"),
        ("structure: x\n", None, None),
        ("kind: ellipsoid, length_mm: 30, diameter_mm: 24", "kind: sphere, length_mm: 30",
         "straight.coverage.zone: a sphere takes radius_mm"),
        ("kind: ellipsoid, length_mm: 30, diameter_mm: 24", "kind: ellipsoid, radius_mm: 3",
         "straight.coverage.zone.radius_mm: only for kind: sphere"),
        ("length_mm: 30, diameter_mm: 24", "length_mm: 20, diameter_mm: 24",
         "straight.coverage.zone.length_mm: the zone is longest along the needle"),
        ("max_needles: 4", "max_needles: 0", r"straight.coverage.max_needles: expected a number >= 1"),
        ("max_needles: 4", "coverage_goal: 1.5", r"straight.coverage.coverage_goal: expected a number <= 1"),
        ("voxel_mm: 1.5", "voxels: 1", "straight.coverage: unknown field 'voxels'"),
        ("targets: coverage", "targets: cover", "straight.targets"),
    ],
)  # fmt: skip
def test_bad_coverage_blocks_are_one_line_errors(tmp_path, old, new, match):
    if new is None:  # an unknown tumour structure
        text = SCENARIO.replace("    voxel_mm: 1.5\n", "    voxel_mm: 1.5\n    structure: liver\n")
        match = "straight.coverage.structure: no structure named 'liver' .targets: tumour"
    else:
        text = SCENARIO.replace(old, new)
    with pytest.raises(InvalidInputError, match=match) as err:
        load_scenario(_write(tmp_path, text))
    assert "\n" not in str(err.value)


def test_a_sphere_zone_takes_its_radius(tmp_path):
    text = SCENARIO.replace(
        "kind: ellipsoid, length_mm: 30, diameter_mm: 24", "kind: sphere, radius_mm: 13"
    )
    zone = load_scenario(_write(tmp_path, text)).straight["coverage"]["zone"]
    assert zone == AblationZone.sphere(13.0)


@pytest.mark.realdata
@pytest.mark.slow
def test_medrad_liver4_example_is_covered_and_verified(medrad_dir, medrad_liver4_multi_plan,
                                                       monkeypatch):  # fmt: skip
    from pathlib import Path

    monkeypatch.setenv("NEEDLEKIT_MEDRAD", str(medrad_dir))
    example = Path(__file__).parents[2] / "examples" / "medrad_liver4.yaml"
    out = medrad_liver4_multi_plan  # `multi` on the example, exit 0 (tests/conftest.py)
    rec = json.loads(out.read_text())
    c = rec["coverage"]
    assert c["status"] == "covered" and c["coverage"] == 1.0 and 1 <= c["needles"] <= 6
    assert c["tumour_volume_ml"] == pytest.approx(51.0, abs=0.1)
    assert all(n["clearance_mm"] >= 1.5 for n in rec["needles"])
    assert main(["verify", str(example), str(out)]) == 0
