"""Every console table carries the unit of each numeric column in its header and never
prints ``nan`` or ``inf``: a value that is not there is a dash, and a footnote line under
the table says why.

The commands that print tables are run on small inputs (the toy scenario, one trial); the
studies' tables, which need the Med-RAD data and hours, are printed from records of known
content through their real handlers."""

from __future__ import annotations

import io
import math
import re
from contextlib import redirect_stdout
from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.cli._common import NO_VALUE, _fmt_table
from needlekit.cli._verdicts import sensing_table
from needlekit.cli.execute_multi import multi_table

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"

#: A header that names its unit: mm, mm/s, deg, rad, s, ms, mL, %, /mm, or x_mm-style.
UNIT = re.compile(r"(\bmm\b|_mm\b|\bdeg\b|_deg\b|\brad\b|\bs\b|_s\b|\bms\b|\bml\b|_ml\b|%|/mm)",
                  re.IGNORECASE)  # fmt: skip
#: Numeric columns without a unit: counts, indices, unit-vector components, ratios.
UNITLESS = {"crossed", "stopped", "re-plans", "target", "dir_x", "dir_y", "dir_z", "feng", "not direct",
            "needles", "solved", "scans"}  # fmt: skip


def _tables(text: str) -> list[tuple[list[str], list[list[str]], list[str]]]:
    """The tables in a command's output: (headers, rows, footnotes), read from the ruler
    line of dashes under each header."""
    lines = text.splitlines()
    out = []
    for i, line in enumerate(lines):
        if i == 0 or not re.fullmatch(r"-+( +-+)*", line):
            continue
        starts = [m.start() for m in re.finditer(r"-+", line)]
        bounds = list(zip(starts, [*starts[1:], None], strict=True))

        def cut(text: str, bounds=bounds) -> list[str]:
            return [text[a:b].strip() for a, b in bounds]

        headers = cut(lines[i - 1])
        rows, notes = [], []
        for row in lines[i + 1:]:
            if row.startswith("- in "):
                notes.append(row)
            elif row.strip() and not notes:
                rows.append(cut(row))
            else:
                break
        out.append((headers, rows, notes))
    return out


def _number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def check_tables(text: str, expected: int) -> list:
    tables = _tables(text)
    assert len(tables) == expected, text
    assert not re.search(r"\b(nan|inf|NaN|Infinity)\b", text), text
    for headers, rows, notes in tables:
        for k, h in enumerate(headers):
            cells = [r[k] for r in rows]
            if cells and all(_number(c) or c == "-" for c in cells) and any(map(_number, cells)):
                assert UNIT.search(h) or h.lower() in UNITLESS or "unit" in headers, (h, text)
            if "-" in cells:  # every dash is explained under the table
                assert any(n.startswith(f"- in {h}: ") for n in notes), (h, text)
    return tables


def _run(argv) -> tuple[int, str]:
    out = io.StringIO()
    with redirect_stdout(out):
        code = main([str(a) for a in argv])
    return code, out.getvalue()


def test_a_missing_value_is_a_dash_and_its_reason_a_footnote():
    text = _fmt_table(
        ["run", "error mm", "p95 ms"],
        [["a", 1.0, None], ["b", math.nan, math.inf], ["c", 2, "-"]],
        why={"p95 ms": "no re-plan ran"},
    )
    assert text.splitlines() == [
        "run  error mm  p95 ms",
        "---  --------  ------",
        "a      1.0000       -",
        "b           -       -",
        "c           2       -",
        f"- in error mm: {NO_VALUE}",
        "- in p95 ms: no re-plan ran",
    ]


def test_scene_info_and_kinematics():
    code, text = _run(["scene", "info", TOY])
    assert code == 0
    check_tables(text, 1)
    # a target on the needle's axis: a straight line, its radius infinite
    code, text = _run(["kinematics", "inverse", "--target", "0,0,30", "--target", "10,0,30"])
    assert code == 0
    ((headers, rows, notes),) = check_tables(text, 1)
    assert rows[0][headers.index("radius_mm")] == "-"
    assert rows[1][headers.index("radius_mm")] == "50.0000"  # (10^2 + 30^2) / (2 * 10)
    assert notes == ["- in radius_mm: the target lies on the needle's axis: a straight line "
                     "(infinite radius)"]  # fmt: skip
    code, text = _run(["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment",
                       "5,0,2", "--dt-s", "1"])  # fmt: skip
    assert code == 0
    check_tables(text, 1)


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("tables") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(path)]) == 0
    return path


def test_execute_with_breathing(toy_plan, tmp_path):
    code, text = _run(["execute", "--truth", "kinematic", TOY, toy_plan, "--trials", "1", "--breathing", "lung",
                       "--replan-delay-ms", "5", "--replan-iterations", "500", "--seed", "3",
                       "--out", tmp_path / "e"])  # fmt: skip
    run, breathing = check_tables(text, 2)
    headers, rows, notes = run
    assert headers == ["run", "error mean mm", "sd mm", "max mm", "% <= 1 mm",
                       "min clearance mm", "crossed", "re-plans", "re-plan p95 ms"]  # fmt: skip
    assert rows[0][0] == "open loop" and rows[0][-1] == "-"  # the open loop never re-plans
    assert notes == ["- in re-plan p95 ms: no re-plan ran, so there is no latency to measure "
                     "(the open loop never re-plans)"]  # fmt: skip
    assert breathing[0] == ["policy", "error mean mm", "sd mm", "max mm", "% <= 1 mm",
                            "crossed", "procedure s"]  # fmt: skip
    assert code == (1 if "exit 1: " in text else 0)


def test_the_multi_table():
    e = {"mean": 0.5, "sd": 0.1, "max": 0.7}
    s = {
        "by_needle": {"1": {"error_mm": e, "target_shift_mm": {"mean": 0.2}}},
        "error_mm": e, "literature": [{"source": "Liu et al.", "mean_mm": 1.0, "sd_mm": 0.5}],
        "min_needle_gap_mm": None, "needles": 1, "trials": 2, "touched": [],
        "constraints": {"total": 0}, "crashed": [],
    }  # fmt: skip
    ((headers, rows, notes),) = check_tables(multi_table(s), 1)
    assert headers == ["", "error mean mm", "sd mm", "max mm", "target shift mm"]
    assert rows[-1] == ["Liu et al.", "1.0000", "0.5000", "-", "-"]
    assert len(notes) == 2


def test_the_execute_lungs_table(monkeypatch, tmp_path):
    import needlekit.studies.execute_lungs as study

    loop = {"mean_error_mm": 0.25, "sd_error_mm": 0.05, "within_1mm": 1.0, "violated": 0,
            "replans_mean": 1.5}  # fmt: skip
    record = {
        "cases": [
            {"patient": 1, "status": "done", "margin_wanted_mm": 0.2, "margin_mm": 0.1,
             "closed_loop": loop, "open_loop": {**loop, "mean_error_mm": 3.0}, "holds": True,
             "breathing": {"ignore": {**loop, "procedure_s": 30.0}}},
            {"patient": 2, "status": "no plan"},
        ],
        "holds": False, "wall_s": 1.0,
    }  # fmt: skip
    monkeypatch.setattr(study, "run_execute_lungs", lambda *a, **k: record)
    code, text = _run(["study", "execute-lungs", "--truth", "kinematic", "--trials", "1", "--out", tmp_path / "x"])
    assert code == 1
    cases, per_policy = check_tables(text, 2)
    assert cases[1][1][:3] == ["lung 2", "no plan", "-"]
    assert per_policy[0][2:4] == ["mean mm", "sd mm"]


def test_the_physical_execute_lungs_table(monkeypatch, tmp_path):
    import needlekit.studies.execute_lungs as study

    loop = {"mean_error_mm": 0.9, "sd_error_mm": 0.3, "p95_error_mm": 1.5, "max_error_mm": 1.8,
            "violated": 0}  # fmt: skip
    record = {
        "cases": [
            {"patient": 4, "status": "done", "start": 1, "margin_mm": 1.5, "holds": True,
             "open_loop": {**loop, "mean_error_mm": 2.6}, "closed_loop": loop,
             "sensing": {"em": {**loop, "scans": None, "target_moved_mm": 1.5},
                         "checkpoints": {**loop, "scans": 4.5, "target_moved_mm": 1.6,
                                         "stopped_near_obstacle": 1}}},
            {"patient": 2, "status": "infeasible"},
        ],
        "holds": False, "wall_s": 1.0,
    }  # fmt: skip
    monkeypatch.setattr(study, "run_execute_lungs", lambda *a, **k: record)
    code, text = _run(["study", "execute-lungs", "--sensing", "em,checkpoints", "--trials", "1",
                       "--out", tmp_path / "x"])  # fmt: skip
    assert code == 1
    ((headers, rows, _),) = check_tables(text, 1)
    assert headers[3:5] == ["sensing", "closed loop mm"]
    assert rows[0][:5] == ["lung 4", "start 1, 1.5 mm", "2.60 +- 0.30, 1.50, 1.80", "em",
                           "0.90 +- 0.30, 1.50, 1.80"]  # fmt: skip
    assert headers[5:7] == ["crossed", "stopped"]
    assert rows[0][5:7] == ["0", "0"]  # a record written before the stop counts none
    assert rows[1][3:8] == ["checkpoints", "0.90 +- 0.30, 1.50, 1.80", "0", "1", "4.5"]
    assert rows[2][:2] == ["lung 2", "infeasible"]


def test_the_sensing_table():
    e = {"mean": 0.5, "sd": 0.1, "max": 0.7}
    row = {"final_error_mm": e, "within_1mm": 1.0, "violated": 0, "procedure_s": {"mean": 32.0}}
    s = {
        "em": {**row, "target_displacement_max_mm": {"n": 0}, "target_error_mm": {"n": 0},
               "scans": {"n": 0}},
        "checkpoints": {**row, "target_displacement_max_mm": {"max": 4.0},
                        "target_error_mm": {"mean": 0.8}, "scans": {"mean": 3.0}},
    }  # fmt: skip
    ((headers, rows, notes),) = check_tables(sensing_table(s), 1)
    assert headers == ["policy", "error mean mm", "sd mm", "max mm", "% <= 1 mm", "crossed",
                       "target moved max mm", "target belief error mm", "scans",
                       "procedure s"]  # fmt: skip
    assert rows[0][0] == "sensing, em" and rows[0][6:9] == ["-", "-", "-"]
    assert rows[1][6:9] == ["4.0000", "0.8000", "3.0000"] and len(notes) == 3
