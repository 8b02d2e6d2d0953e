"""`study execute-lungs` interrupted and resumed (no data needed: the cases' own steps are
replaced): Ctrl-C keeps the lungs done and the one under way (its margin and plan, signed),
and --resume carries on without deciding that lung's margin again."""

from __future__ import annotations

import json

import pytest

from needlekit.errors import Interrupted
from needlekit.studies import execute_lungs


def test_ctrl_c_keeps_the_lungs_done_and_resume_goes_on_from_the_one_under_way(
    tmp_path, monkeypatch
):
    decided, ran = [], []

    def decide(st, patient):
        decided.append(patient)
        return {"patient": patient, "status": "planned", "margin_mm": 0.1 * patient,
                "plan_primitives": [[0.0, 0.0, 10.0 + patient]]}  # fmt: skip

    def run_case(st, d, resume):
        ran.append((d["patient"], resume))
        if d["patient"] == 2 and len(ran) == 2:
            raise KeyboardInterrupt
        return {**d, "status": "done", "holds": True}

    monkeypatch.setattr(execute_lungs, "_decide", decide)
    monkeypatch.setattr(execute_lungs, "_run_case", run_case)
    with pytest.raises(Interrupted, match="1 of 3 lungs done"):
        execute_lungs.run_execute_lungs(tmp_path, patients=(1, 2, 3), trials=4)
    partial = json.loads((tmp_path / "execute_lungs.partial.json").read_text())
    assert partial["partial"] is True and [c["patient"] for c in partial["cases"]] == [1]
    assert partial["current"]["patient"] == 2 and partial["current"]["margin_mm"] == 0.2
    with pytest.raises(Exception, match="--resume"):  # other trials: refused
        execute_lungs.run_execute_lungs(tmp_path, patients=(1, 2, 3), trials=5, resume=True)
    record = execute_lungs.run_execute_lungs(tmp_path, patients=(1, 2, 3), trials=4, resume=True)
    assert decided == [1, 2, 3]  # lung 2's margin and plan carried over, not decided again
    assert ran == [(1, False), (2, False), (2, True), (3, False)]
    assert [c["patient"] for c in record["cases"]] == [1, 2, 3] and record["holds"]
    assert record["resumed"] is True and "partial" not in record
    assert not (tmp_path / "execute_lungs.partial.json").exists()  # finished: now stale


def test_ctrl_c_before_the_first_lung_is_planned_writes_the_record_its_line_names(
    tmp_path, monkeypatch
):
    def decide(st, patient):  # Ctrl-C while the first lung's margin is measured
        raise KeyboardInterrupt

    monkeypatch.setattr(execute_lungs, "_decide", decide)
    with pytest.raises(Interrupted) as stopped:
        execute_lungs.run_execute_lungs(tmp_path, patients=(1, 2), trials=4)
    beside = tmp_path / "execute_lungs.partial.json"
    assert str(stopped.value) == (
        f"0 of 2 lungs done; written to {beside} marked partial; the same command with "
        "--resume carries on"
    )  # no lung under way: no trials are said to be kept
    partial = json.loads(beside.read_text())
    assert partial["partial"] is True and partial["cases"] == [] and "current" not in partial
