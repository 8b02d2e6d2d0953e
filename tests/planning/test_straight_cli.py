"""needlekit cfrw, multi and verify on a scenario's straight block."""

import json

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.io.markups import read_markups
from needlekit.scenario.problems import multi_problem_from_scenario

SCENARIO = """\
version: 1
name: two needles in a sphere
structures:
  - {name: skin, role: entry_surface, sphere: {center_mm: [0, 0, 0], radius_mm: 100}}
  - {name: vessel, role: obstacle, capsule: {p0_mm: [-60, 5, 35], p1_mm: [60, 5, 35], radius_mm: 4}}
  - {name: vessel2, role: obstacle, capsule: {p0_mm: [25, -60, 60], p1_mm: [25, 60, 60], radius_mm: 3}}
  - {name: tumour, role: target, sphere: {center_mm: [0, -7.5, 0], radius_mm: 12}}
needle: {diameter_mm: 2.0, max_length_mm: 150}
goal: {point_mm: [0, 0, 0]}
straight:
  entry_surface: skin
  targets: [[0, 0, 0], [0, -15, 0]]
  gamma_mm: 1.5
  up: [0, 0, 1]
  theta_range_deg: [0, 80]
  resolution_deg: 4
"""


@pytest.fixture
def scenario(tmp_path):
    path = tmp_path / "two.yaml"
    path.write_text(SCENARIO)
    return path


def test_the_scenario_block_builds_the_problem(scenario):
    multi, options = multi_problem_from_scenario(scenario)
    assert multi.targets_mm.tolist() == [[0.0, 0.0, 0.0], [0.0, -15.0, 0.0]]
    p = multi.problem
    assert (p.gamma_mm, p.needle.radius_mm, p.needle.max_length_mm) == (1.5, 1.0, 150.0)
    assert p.theta_range_deg == (0.0, 80.0) and options == {"resolution_deg": 4}


def test_cfrw_writes_the_map_layers_and_best_entries(scenario, tmp_path, capsys):
    out = tmp_path / "cfrw.json"
    assert main(["cfrw", str(scenario), "--out", str(out), "--target", "2", "--layers", "50"]) == 0
    data = json.loads(out.read_text())
    assert data["target_mm"] == [0.0, -15.0, 0.0] and data["gamma_mm"] == 1.5
    assert data["counts"]["free"] == int(np.sum(data["feasible"])) > 0
    assert list(data["layers"]) == ["50"] and data["layers"]["50"]
    best = data["best"]["min_length"]
    assert best["clearance_mm"] >= 1.5 and best["length_mm"] <= 150.0
    fronts = data["pareto_front"]
    assert fronts[0]["length_mm"] == pytest.approx(best["length_mm"])
    assert "CFRW of target 2" in capsys.readouterr().out
    assert main(["cfrw", str(scenario), "--out", str(out), "--target", "3"]) == 2


def test_directions_without_a_value_are_null_in_the_map(scenario, tmp_path):
    # a needle too short for part of the sphere: those directions are not evaluated
    short = tmp_path / "short.yaml"
    short.write_text(scenario.read_text().replace("max_length_mm: 150", "max_length_mm: 100.5"))
    out = tmp_path / "cfrw.json"
    assert main(["cfrw", str(short), "--out", str(out), "--target", "2", "--layers", "50"]) == 0
    data = json.loads(out.read_text())
    clearance = np.array(data["clearance_mm"], dtype=object)
    missing = np.vectorize(lambda v: v is None)(clearance)
    assert data["counts"]["too_long"] == int(missing.sum()) > 0
    assert all(isinstance(v, float) for v in clearance[~missing])


def test_multi_plans_exports_and_verifies(scenario, tmp_path, capsys):
    out, marks = tmp_path / "multi.json", tmp_path / "marks"
    assert main(["multi", str(scenario), "--out", str(out), "--markups", str(marks)]) == 0
    data = json.loads(out.read_text())
    assert data["status"] == "solved" and data["gamma_mm"] == 1.5
    assert data["needle_radius_mm"] == 1.0 and "coverage" in data
    needles = data["needles"]
    assert [n["order"] for n in needles] == [1, 2]
    for n in needles:
        assert {"target_mm", "entry_mm", "length_mm", "clearance_mm", "needle_clearance_mm"} <= set(
            n
        )
        assert n["clearance_mm"] >= 1.5
        assert np.linalg.norm(n["entry_mm"]) == pytest.approx(100.0, abs=1e-3)
    assert needles[0]["needle_clearance_mm"] is None and needles[1]["needle_clearance_mm"] >= 1.5
    for n in needles:  # Slicer lines: entry then target, back in RAS
        ((kind, _, pts),) = read_markups(marks / f"needle{n['order']}.mrk.json")
        assert kind == "Line"
        assert np.allclose(pts, [n["entry_mm"], n["target_mm"]], atol=1e-6)
    capsys.readouterr()
    assert main(["verify", str(scenario), str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] and len(report["needles"]) == 2


def test_verify_refuses_a_needle_moved_onto_a_vessel(scenario, tmp_path, capsys):
    out = tmp_path / "multi.json"
    assert main(["multi", str(scenario), "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    # aim the first needle straight up through the vessel at z = 35
    data["needles"][0]["entry_mm"] = [0.0, 0.0, 100.0]
    data["needles"][0]["target_mm"] = [0.0, 0.0, 0.0]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    capsys.readouterr()
    assert main(["verify", str(scenario), str(bad)]) == 1
    text = capsys.readouterr().out
    assert "VIOLATED" in text and "needle 1: certified clearance" in text
    data["needles"][1]["entry_mm"] = [0.0, -15.0, 90.0]  # inside the skin, not on it
    bad.write_text(json.dumps(data))
    assert main(["verify", str(scenario), str(bad)]) == 1
    assert "needle 2: entry" in capsys.readouterr().out


def test_a_scenario_without_a_straight_block_is_an_input_error(tmp_path, capsys):
    path = tmp_path / "plain.yaml"
    path.write_text(SCENARIO.split("straight:")[0])
    assert main(["multi", str(path), "--out", str(tmp_path / "m.json")]) == 2
    assert (
        capsys.readouterr().err.strip()
        == "error: plain.yaml: straight: the scenario has no straight block"
    )


@pytest.mark.slow
def test_multi_writes_its_report(scenario, tmp_path):
    out, page = tmp_path / "multi.json", tmp_path / "multi.html"
    assert main(["multi", str(scenario), "--out", str(out), "--report", str(page)]) == 0
    html = page.read_text()
    assert html.count("<script") >= 1 and "Fig. 11" in html and 'src="http' not in html
