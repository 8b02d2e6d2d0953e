"""``needlekit study livers``: the Med-RAD liver study.

Fixed outcomes on livers 2 and 3 at gamma 1.5 mm (docs/straight.md's study table): each
planned plan passes the independent check, and a case that is not covered says why.
"""

import json

import pytest

from needlekit.cli import main
from needlekit.studies.liver_study import LIVER_SETTINGS, liver_cases, liver_scenario


@pytest.mark.realdata
def test_every_start_pose_names_its_nodule(medrad_dir):
    cases = liver_cases(medrad_dir)
    got = [(c["patient"], c["nodule"], c["start"]) for c in cases]
    assert got == [
        (1, "nodule", "start1"),
        (2, "nodule1", "target1_start1"),
        (2, "nodule1", "target1_start2"),
        (2, "nodule2", "target2_start1"),
        (3, "nodule1", "nodule1_start1"),
        (3, "nodule2", "nodule2_start1"),
        (4, "nodule", "start1"),
        (5, "nodule1", "target1_start1"),
        (5, "nodule2", "target2_start1"),
    ]


def test_the_case_scenario_is_the_liver_4_example_with_four_changes(tmp_path):
    from pathlib import Path

    import yaml

    example = yaml.safe_load(
        (Path(__file__).parents[1] / "examples" / "medrad_liver4.yaml").read_text()
    )
    case = {"patient": 4, "nodule": "nodule", "start": "start1"}
    doc = liver_scenario(case, 1.5)
    for key in ("needle", "base", "start", "version"):
        assert doc[key] == example[key], key
    assert doc["straight"] == example["straight"]
    assert LIVER_SETTINGS["straight"]["coverage"].get("structure") is None  # not touched
    other = liver_scenario({"patient": 2, "nodule": "nodule2", "start": "target2_start1"}, 3.0)
    assert other["base"]["medrad"]["patient"] == 2
    assert other["start"] == {"case_start": "target2_start1"}
    assert other["straight"]["coverage"]["structure"] == "nodule2"
    assert other["straight"]["gamma_mm"] == 3.0


@pytest.mark.realdata
@pytest.mark.slow
def test_livers_2_and_3_are_planned_checked_and_explained(medrad_dir, tmp_path, capsys):
    out = tmp_path / "livers.json"
    args = ["study", "livers", "--livers", "2", "3", "--gamma", "1.5"]
    code = main([*args, "--medrad", str(medrad_dir), "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    rec = json.loads(out.read_text())
    rows = {(r["patient"], r["start"]): r for r in rec["rows"]}
    assert len(rows) == 5
    assert rec["summary"] == {
        "cases": 5, "covered": 3, "not_covered": 1, "blocked": 1, "verified": 5, "violations": 0,
    }  # fmt: skip
    for key in ((2, "target1_start1"), (2, "target1_start2"), (3, "nodule1_start1")):
        r = rows[key]
        assert r["status"] == "covered" and r["coverage"] == 1.0 and r["reason"] == ""
        assert r["min_clearance_mm"] >= 1.5 and r["verified"] is True
    assert [rows[k]["needles_planned"] for k in ((2, "target1_start1"), (3, "nodule1_start1"))] == [
        2,
        1,
    ]
    # nodule 2 of liver 2: the second needle's cone is closed by the vessels alone
    b = rows[(2, "target2_start1")]
    assert b["status"] == "blocked" and (b["needles_planned"], b["needles_chosen"]) == (1, 3)
    assert b["blocked"]["free"] == 0 and b["blocked"]["placed_needle"] == 0
    assert b["blocked"]["clearance"] == 16560
    assert "most blocked: closer than gamma to the anatomy" in b["reason"]
    assert b["verified"] is True  # the one needle placed passes the check
    # nodule 2 of liver 3: the tumour is covered, the margin's last voxels are not
    n = rows[(3, "nodule2_start1")]
    assert n["status"] == "not_covered" and n["tumour_coverage"] == 1.0
    assert n["reason"].startswith("coverage: 0.9995 with the planned directions")
    assert "blocked" in text and "not_covered" in text and "5 cases: 3 covered" in text


def test_a_folder_without_livers_is_one_line_naming_the_flag(tmp_path, capsys):
    code = main(["study", "livers", "--medrad", str(tmp_path), "--out", str(tmp_path / "x.json")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: --medrad: no Med-RAD liver patients under")


@pytest.mark.realdata
def test_a_missing_patient_is_one_line_naming_the_flag(medrad_dir, tmp_path, capsys):
    out = tmp_path / "x.json"
    code = main(
        ["study", "livers", "--livers", "9", "--medrad", str(medrad_dir), "--out", str(out)]
    )
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: --livers: no patient [9] under") and not out.exists()


@pytest.mark.realdata
def test_an_interrupted_study_keeps_its_rows_and_resume_plans_only_the_rest(
    medrad_dir, tmp_path, monkeypatch, capsys
):
    """The bookkeeping without the planning: each case is a row made
    from its key, and Ctrl-C arrives in the third case."""
    import needlekit.studies.liver_study as ls

    ran = []

    def fake(case, gamma_mm, **_):
        ran.append((case["start"], gamma_mm))
        if len(ran) == 3:
            raise KeyboardInterrupt
        return {**case, "gamma_mm": gamma_mm, "status": "covered", "reason": "",
                "needles_chosen": 1, "needles_planned": 1, "coverage": 1.0,
                "tumour_coverage": 1.0, "min_clearance_mm": 2.0, "healthy_ablated_ml": 1.0,
                "plan_s": 0.1, "verified": True, "violations": []}  # fmt: skip

    monkeypatch.setattr(ls, "run_liver_case", fake)
    out = tmp_path / "livers.json"
    args = ["study", "livers", "--livers", "2", "--gamma", "1.5", "3", "--medrad", str(medrad_dir)]
    assert main([*args, "--out", str(out)]) == 130
    (line,) = capsys.readouterr().err.strip().splitlines()
    beside = tmp_path / "livers.partial.json"  # never over livers.json
    assert line == (
        f"interrupted: 2 of 6 cases done; written to {beside} marked partial; the same "
        "command with --resume carries on"
    )
    assert [r["gamma_mm"] for r in json.loads(beside.read_text())["rows"]] == [1.5, 3.0]
    assert main([*args, "--gamma", "3", "--out", str(out), "--resume"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"error: --resume: {beside} was written with other settings than this run's"
    )
    assert main([*args, "--out", str(out), "--resume"]) == 0
    first = ("target1_start1", 1.5)
    assert ran[:3] == [first, ("target1_start1", 3.0), ("target1_start2", 1.5)]
    assert ran[3:] == [("target1_start2", 1.5), ("target1_start2", 3.0),
                       ("target2_start1", 1.5), ("target2_start1", 3.0)]  # fmt: skip
    rec = json.loads(out.read_text())
    assert "partial" not in rec and rec["summary"]["cases"] == 6 and not beside.exists()
