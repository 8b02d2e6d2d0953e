"""``needlekit bench straight``: the record's structure and the plan's fixed outcome.

Speed is measured by the benchmark, never asserted here: no test looks at a time's value.
"""

import json
from pathlib import Path

import pytest

import needlekit.cli
from needlekit.benchmarks.straight import TARGETS_S, run_straight_benchmark
from needlekit.cli import main

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
STAGES = ("prepare", "cfrw_map", "layer", "multi_plan", "verify")
#: examples/liver_phantom_multi.yaml's three needles (docs/straight.md), at its 2-degree
#: grid, and the same plan on the benchmark's 1-degree grid.
LENGTHS_2DEG_MM = (77.74, 68.89, 86.56)
LENGTHS_1DEG_MM = (77.73, 68.89, 86.55)


def _timing(stage):
    assert set(stage) >= {"median_s", "min_s", "runs_s"}
    assert 0 < stage["min_s"] <= stage["median_s"]
    assert all(t > 0 for t in stage["runs_s"])


@pytest.mark.slow
def test_bench_straight_on_the_phantom_writes_the_record(capsys, tmp_path):
    out = tmp_path / "bench.json"
    code = main(["bench", "straight", "--repeat", "1", "--livers", "0", "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    assert "liver_phantom cfrw map 1 deg" in text and "multi plan 1 deg" in text
    rec = json.loads(out.read_text())
    assert rec["benchmark"] == "straight"
    assert {"versions", "cpu", "python", "cpu_count"} <= set(rec["machine"])
    assert len(rec["load_average"]["before"]) == 3
    assert rec["inputs"]["repeat"] == 1 and rec["inputs"]["resolution_deg"] == 1.0
    assert rec["inputs"]["livers"] == []
    assert rec["inputs"]["scenarios"] == [str(EXAMPLES / "liver_phantom_multi.yaml")]
    assert rec["targets_s"] == TARGETS_S == {"cfrw_map_1deg_s": 1.0, "multi_plan_s": 10.0}
    (case,) = rec["cases"]
    assert case["name"] == "liver_phantom"
    for stage in STAGES:
        _timing(case[stage])
        assert len(case[stage]["runs_s"]) == 1
    assert case["prepare"]["excluded"] is True
    assert case["prepare"]["first_s"] == case["prepare"]["runs_s"][0]
    # met is the median against the target, whatever the median is
    assert case["met"] == {
        "cfrw_map_1deg_s": case["cfrw_map"]["median_s"] <= 1.0,
        "multi_plan_s": case["multi_plan"]["median_s"] <= 10.0,
    }

    m = case["cfrw_map"]
    assert m["grid"] == [61, 360] and m["directions"] == 61 * 360  # theta 0-60, phi 0-359
    assert sum(m["counts"].values()) == m["directions"]
    assert m["counts"]["free"] > 0 and m["counts"]["clearance"] > 0
    split = m["split"]
    for part in ("entry_search", "normal_angle", "clearance"):
        _timing(split[part])
    assert split["clearance"]["directions"] <= split["entry_search"]["directions"]
    assert split["clearance_max_abs_diff_vs_map_mm"] == 0.0  # the same calls as the map's

    layer = case["layer"]
    assert layer["h_mm"] == 150.0 and layer["polylines"] >= 1 and layer["vertices"] > 3

    plan = case["multi_plan"]
    assert plan["solved"] and plan["needles"] == plan["needles_placed"] == plan["targets"] == 3
    assert plan["orders_tried"] == 6  # 3! orders, all tried
    assert plan["targets_from"] == "scenario" and plan["coverage"] is None
    assert plan["steps_s"]["rounds"] == 1 and plan["steps_s"]["trajectories_s"] > 0
    assert plan["lengths_mm"] == pytest.approx(LENGTHS_1DEG_MM, abs=0.01)
    own = case["multi_plan_scenario_resolution"]
    assert own["resolution_deg"] == 2.0 and own["solved"] and own["needles_placed"] == 3
    assert own["lengths_mm"] == pytest.approx(LENGTHS_2DEG_MM, abs=0.01)
    assert case["verify"]["ok"] and case["verify"]["violations"] == []


def test_missing_cases_are_skipped_saying_why(tmp_path):
    rec = run_straight_benchmark(
        repeat=1, livers=(4,), medrad_dir=tmp_path / "none", examples_dir=tmp_path
    )
    assert [c["name"] for c in rec["cases"]] == ["liver_phantom", "medrad_liver4"]
    phantom, liver = rec["cases"]
    assert "liver_phantom_multi.yaml not found" in phantom["skipped"]
    assert liver["skipped"].startswith("Med-RAD data not found")
    assert rec["inputs"]["scenarios"] == []
    assert [r["summary"].split(":")[0] for r in rec["results"]] == ["skipped", "skipped"]


def test_missing_liver_scenario_is_skipped_saying_why(tmp_path):
    # the data has liver 9, the examples have no scenario for it
    (tmp_path / "medrad" / "Liver" / "Patient9").mkdir(parents=True)
    rec = run_straight_benchmark(
        repeat=1, livers=(9,), medrad_dir=tmp_path / "medrad", examples_dir=tmp_path
    )
    assert "medrad_liver9.yaml not found" in rec["cases"][1]["skipped"]


def test_bad_flags_are_one_error_line_before_any_work(capsys, tmp_path, monkeypatch):
    def started(command, args):
        raise AssertionError(f"{command} started before its flags were checked")

    monkeypatch.setattr(needlekit.cli, "_run", started)
    (tmp_path / "file.txt").write_text("a file\n")
    bad = tmp_path / "file.txt" / "bench.json"
    for argv, start in (
        (["--out", str(bad)], "error: --out"),
        (["--repeat", "0"], "error: argument --repeat"),
        (["--medrad", str(tmp_path / "none")], "error: --medrad"),
    ):
        try:
            code = main(["bench", "straight", *argv])
        except SystemExit as exc:
            code = exc.code
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith(start), lines


@pytest.mark.realdata  # with the data, a liver it does not have is refused up front
def test_a_liver_the_data_does_not_have_is_refused_before_any_work(capsys, tmp_path):
    out = tmp_path / "bench.json"
    code = main(["bench", "straight", "--livers", "4", "9", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and not out.exists()
    assert (
        err.startswith("error: --livers: no Med-RAD liver patient 9 at ") and err.count("\n") == 1
    )
