"""``needlekit reproduce``: the lecture's page, quick."""

from __future__ import annotations

import contextlib
import io

import pytest

from needlekit.cli import main


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """``(folder, stdout)`` of one quick run, shared by the page checks and the browser."""
    out = tmp_path_factory.mktemp("lecture")
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert main(["reproduce", "lecture", "--quick", "--out", str(out)]) == 0
    return out, text.getvalue()


@pytest.mark.slow
def test_lecture_quick(quick, read_page):
    tmp_path, out = quick
    html, doc = read_page(tmp_path, "lecture")
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
    assert "lecture: 6 of 7 comparisons agree with the paper (1 do not" in out
    dyn = doc["record"]["dynamic"]
    assert dyn["status"] == "reached" and dyn["check"]["ok"] is True
    assert dyn["static"]["check"]["ok"] is False  # the plan made at t = 0 meets the vessel
    assert rows["dynamic environment: RRT re-planning among moving obstacles"]["agrees"] == "yes"
    assert (tmp_path / "lecture" / "dynamic.json").is_file()


@pytest.mark.slow
@pytest.mark.browser
def test_the_lecture_page_renders_in_a_browser(quick, rendered):
    """The quick run's page in headless Chromium: its 3D views drawn, no console warning
    (``rendered``, tests/conftest.py)."""
    plots, pngs = rendered(quick[0] / "lecture.html")
    assert plots >= 1 and pngs
