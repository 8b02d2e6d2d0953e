"""``needlekit plan --goals``: a plan to each of several targets, by the lecture's procedure
(a new search from the start for each) or from one RRT tree."""

import json
from pathlib import Path

import pytest

from needlekit.cli import main

TOY = str(Path(__file__).parents[2] / "examples" / "toy.yaml")
GOALS = ["20,30,40", "10,35,45", "28,28,36"]


@pytest.mark.parametrize("mode", ["per-target", "one-tree"])
def test_plans_to_several_targets_are_written_together(tmp_path, capsys, mode):
    out, report = tmp_path / "goals.json", tmp_path / "goals.html"
    argv = ["plan", TOY, "--planner", "rrt", "--goals", *GOALS, "--max-iterations", "600"]
    assert main([*argv, "--multi", mode, "--out", str(out), "--report", str(report)]) == 0
    rec = json.loads(out.read_text())
    assert rec["planner"] == "rrt" and rec["mode"] == mode and len(rec["targets"]) == 3
    assert [t["goal_mm"] for t in rec["targets"]] == [[20, 30, 40], [10, 35, 45], [28, 28, 36]]
    assert all(t["status"] == "solved" for t in rec["targets"])
    nodes = [t["stats"]["nodes"] for t in rec["targets"]]
    # a tree per target, or one tree for all (the same node count on every target)
    assert (len(set(nodes)) == 1) == (mode == "one-tree")
    # measured (iteration budgets: the same on any machine)
    costs = [t["cost_mm"] for t in rec["targets"]]
    assert costs == pytest.approx([62.8618, 66.2789, 63.8052], abs=1e-4)
    assert "3 of 3 targets solved" in capsys.readouterr().out
    html = report.read_text()
    assert "Plans to 3 targets" in html and "target 3: 63.81 mm (solved)" in html


def test_any_planner_goes_target_by_target(tmp_path):
    out = tmp_path / "goals.json"
    assert (
        main(["plan", TOY, "--planner", "rcs_star", "--goals", *GOALS[:2], "--out", str(out)]) == 0
    )
    rec = json.loads(out.read_text())
    assert [t["planner"] for t in rec["targets"]] == ["rcs_star", "rcs_star"]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--goals", *GOALS, "--multi", "one-tree"], "error: --multi: one-tree grows an RRT tree"),
        (["--goals", *GOALS, "--goal", "1,2,3"], "error: --goals: give the targets with"),
    ],
)
def test_bad_combinations_are_one_line_errors(tmp_path, capsys, extra, message):
    extra = [str(tmp_path / a) if a.endswith(".html") else a for a in extra]
    code = main(["plan", TOY, "--out", str(tmp_path / "p.json"), *extra])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(message) and err.count("\n") == 1
