"""``needlekit reproduce``: each paper's page beside the paper's numbers (issue 12, point 4)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.cli._parser import REPRODUCE_PAPERS
from needlekit.reproduce import PAPERS
from needlekit.reproduce.tang import ROWS, statistic_comparisons

PAGE_PARTS = (
    "needlekit beside the paper",
    "The setup, side by side",
    "Deviations from the paper&#x27;s setup",
    "Re-run each part",
    "This run",
)


def test_the_command_and_the_library_list_the_same_papers():
    assert tuple(PAPERS) == REPRODUCE_PAPERS == ("feng2023", "liu2016", "tang", "lecture")


def test_bad_arguments_fail_at_once_with_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:  # argparse's own usage error
        main(["reproduce", "nope", "--out", str(tmp_path / "o")])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "invalid choice: 'nope'" in err[0]
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["reproduce", "lecture", "--quick", "--out", str(blocker)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: --out: {blocker}: is a file, expected a folder"]


def test_statistics_are_each_judged_on_their_own():
    # Welch's t by hand: (1.63 - 1.55) / sqrt(0.69^2/100 + 0.40^2/100) = 1.0025
    ours = {"n": 100, "mean": 1.63, "sd": 0.69, "min": 0.21, "max": 3.10}
    paper = {"mean": 1.55, "sd": 0.40, "min": 0.64, "max": 2.34}
    rows = statistic_comparisons(ours, paper, "position error", "mm")
    mean, sd, span = rows
    assert mean["agrees"] == "yes" and "p = 0.317" in mean["note"]  # two-sided, df ~158
    assert sd["agrees"] == "no"  # variance ratio 2.98 on 99 and 99 degrees of freedom
    assert span["agrees"] == "no" and span["needlekit"] == "[0.210, 3.100]"
    same = statistic_comparisons(dict(paper, n=100), paper, "x", "mm")
    assert [r["agrees"] for r in same] == ["yes", "yes", "yes"]
    assert statistic_comparisons({"n": 1}, paper, "x", "mm")[0]["agrees"] == "no"


def test_tang_rows_are_eq3_then_each_change_alone_then_together():
    assert [r.key for r in ROWS] == [
        "eq3", "history", "ball", "clamp", "redraw", "offtick", "defaults", "guide100",
        "guidemean",
    ]  # fmt: skip
    eq3 = ROWS[0]
    assert eq3.flags == (
        "--history 0 --stability-radius-mm 0 --no-vfi-clamp --no-redraw --adaptation-delay-ms 0"
    )
    bare = "--adaptation-delay-ms 0"
    alone = {r.key: r.flags for r in ROWS[1:6]}
    assert alone == {
        "history": f"--stability-radius-mm 0 --no-vfi-clamp --no-redraw {bare}",
        "ball": f"--history 0 --no-vfi-clamp --no-redraw {bare}",
        "clamp": f"--history 0 --stability-radius-mm 0 --no-redraw {bare}",
        "redraw": f"--history 0 --stability-radius-mm 0 --no-vfi-clamp {bare}",
        "offtick": "--history 0 --stability-radius-mm 0 --no-vfi-clamp --no-redraw",
    }
    assert ROWS[6].flags == "" and ROWS[7].flags == "--guide-samples 100"


def _page(tmp_path, paper):
    html = (tmp_path / f"{paper}.html").read_text(encoding="utf-8")
    doc = json.loads((tmp_path / f"{paper}.json").read_text(encoding="utf-8"))
    for part in PAGE_PARTS:
        assert part in html, part
    assert "quick (reduced) run" in html and doc["quick"] is True
    assert "load average at the end" in html and doc["machine"]["load_average"]
    assert doc["wall_s"] > 0 and doc["deviations"] and doc["setup"]
    for row in doc["comparisons"]:
        assert row["agrees"] in ("yes", "no", "partly", "-")
    return html, doc


@pytest.mark.slow
def test_lecture_quick(tmp_path, capsys):
    assert main(["reproduce", "lecture", "--quick", "--out", str(tmp_path)]) == 0
    html, doc = _page(tmp_path, "lecture")
    rows = {r["quantity"]: r for r in doc["comparisons"]}
    assert rows["the slide's waypoint W1 with its printed radius"]["agrees"] == "no"
    assert (
        "misses W1 by 5.13 mm"
        in rows["the slide's waypoint W1 with its printed radius"]["needlekit"]
    )
    multi = doc["record"]["multi_target"]["rows"]
    assert len(multi) == 4 and all(r["per target: status"] == "solved" for r in multi)
    assert all(r["per target: check"] == "ok" for r in multi)
    # the lecture's procedure: its own tree per target, each from the start node
    assert len({r["per target: nodes"] for r in multi}) > 1
    assert html.count("<img alt=") == 4  # the kinematics figures, inlined as PNG
    out = capsys.readouterr().out
    assert "lecture: 6 of 7 comparisons agree with the paper (1 do not" in out
    dyn = doc["record"]["dynamic"]
    assert dyn["status"] == "reached" and dyn["check"]["ok"] is True
    assert dyn["static"]["check"]["ok"] is False  # the plan made at t = 0 meets the vessel
    assert rows["dynamic environment: RRT re-planning among moving obstacles"]["agrees"] == "yes"
    assert (tmp_path / "lecture" / "dynamic.json").is_file()


@pytest.mark.slow
def test_liu2016_quick(tmp_path):
    assert main(["reproduce", "liu2016", "--quick", "--out", str(tmp_path)]) == 0
    _, doc = _page(tmp_path, "liu2016")
    rec = doc["record"]
    assert rec["checks_ok"] is True
    f12 = rec["fig12"]
    assert f12["vessel_bound"] >= 20
    assert abs(f12["min_mm"] - 1.5) <= 0.05 and abs(f12["max_mm"] - 1.5) <= 0.05
    rigid = rec["rigid"]["needles"]
    assert [r["target"] for r in rigid] == [1, 2, 3]
    assert [r["target (Sigma, mm)"] for r in rigid] == ["0, 0, 0", "0, -15, 0", "0, -30, 0"]
    assert all(r["clearance_mm"] >= 1.5 for r in rigid)
    moved = rec["deformed"]["needles"]
    assert moved[0]["target moved_mm"] == 0.0 and moved[1]["target moved_mm"] > 0.1
    for name in ("multi.json", "multi_deformed.json", "scenario.yaml"):
        assert (tmp_path / "liu2016" / name).is_file()
    # the results written are what `needlekit verify` reads
    case = tmp_path / "liu2016"
    assert main(["verify", str(case / "scenario.yaml"), str(case / "multi.json")]) == 0


@pytest.mark.slow
def test_tang_quick_rows(tmp_path, monkeypatch):
    import needlekit.reproduce.tang as tang

    monkeypatch.setattr(tang, "QUICK_ROWS", {"eq3": 1, "defaults": 2})
    assert main(["reproduce", "tang", "--quick", "--out", str(tmp_path)]) == 0
    html, doc = _page(tmp_path, "tang")
    rows = doc["record"]["rows"]
    assert list(rows) == ["eq3", "defaults"]
    assert rows["eq3"]["summary"]["trials"] == 1 and rows["defaults"]["summary"]["trials"] == 2
    quantities = [c["quantity"] for c in doc["comparisons"]]
    for q in ("position error: mean (mm)", "position error: SD (mm)",
              "position error: range (mm)", "angle to the guide line: SD (deg)"):  # fmt: skip
        assert q in quantities
    sd = next(
        c for c in doc["comparisons"] if c["quantity"].startswith("angle to the guide line: SD")
    )
    assert "0.045 deg" in sd["note"]  # the paper's SD cannot go with its range
    assert "Tang et al., Section III-B" in html
    assert (tmp_path / "tang" / "defaults" / "puncture.html").is_file()
    d = rows["defaults"]["summary"]["position_error_mm"]
    assert d["n"] == 2 and math.isfinite(d["mean"]) and np.isfinite(d["sd"])


@pytest.mark.slow
@pytest.mark.realdata
def test_feng2023_quick(tmp_path):
    assert main(["reproduce", "feng2023", "--quick", "--out", str(tmp_path)]) == 0
    html, doc = _page(tmp_path, "feng2023")
    rows = {r["quantity"]: r for r in doc["comparisons"]}
    assert rows["goal 1: order of the mean costs"]["paper"] == (
        "RCS* 61.146 < RRT 62.666 < RCS 62.796"
    )
    for g in ("goal 1", "goal 2"):
        assert rows[f"{g}: RCS* has the lowest mean cost"]["agrees"] == "yes"
        assert rows[f"{g}: paths bend around obstacles"]["agrees"] == "yes"
    study = doc["record"]["study"]
    assert doc["record"]["checks_ok"] is True
    assert study["settings"]["directions"] == 136 and study["settings"]["max_iterations"] == 300
    assert "not published" in html and "Table 4 beside Feng" in html
    for name in ("goal1/sweep.json", "goal2/sweep.json", "feng_lungs.json"):
        assert (tmp_path / "feng2023" / name).is_file()
    assert not (tmp_path / "feng2023" / "report.html").exists()  # the paper's page is the page
