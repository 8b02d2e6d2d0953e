"""Shared by the tests of ``needlekit reproduce``: each paper's page, read and checked for
the parts every page has."""

import json

import pytest

PAGE_PARTS = (
    "needlekit beside the paper",
    "The setup, side by side",
    "Deviations from the paper&#x27;s setup",
    "Re-run each part",
    "This run",
)


@pytest.fixture
def read_page():
    """``read_page(folder, paper) -> (html, record)``: the page and its JSON record, after
    checking the parts every page has."""

    def read(tmp_path, paper):
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

    return read
