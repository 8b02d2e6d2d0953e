"""``needlekit reproduce``: Liu et al. 2016's page, quick."""

from __future__ import annotations

import pytest

from needlekit.cli import main


@pytest.mark.slow
def test_liu2016_quick(tmp_path, read_page):
    assert main(["reproduce", "liu2016", "--quick", "--out", str(tmp_path)]) == 0
    _, doc = read_page(tmp_path, "liu2016")
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
