"""``needlekit reproduce``: Tang et al.'s page, quick rows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from needlekit.cli import main


@pytest.mark.slow
def test_tang_quick_rows(tmp_path, monkeypatch, read_page):
    import needlekit.reproduce.tang as tang

    monkeypatch.setattr(tang, "QUICK_ROWS", {"eq3": 1, "defaults": 2})
    assert main(["reproduce", "tang", "--quick", "--out", str(tmp_path)]) == 0
    html, doc = read_page(tmp_path, "tang")
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
