"""``needlekit reproduce``: Feng et al. 2023's page, quick."""

from __future__ import annotations

import pytest

from needlekit.cli import main


@pytest.mark.slow
@pytest.mark.realdata
def test_feng2023_quick(tmp_path, read_page):
    assert main(["reproduce", "feng2023", "--quick", "--out", str(tmp_path)]) == 0
    html, doc = read_page(tmp_path, "feng2023")
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
