"""``needlekit reproduce``: each paper's page beside the paper's numbers."""

from __future__ import annotations

import pytest

from needlekit.cli import main
from needlekit.cli._parser import REPRODUCE_PAPERS
from needlekit.reproduce import PAPERS
from needlekit.reproduce.tang import ROWS, statistic_comparisons


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
