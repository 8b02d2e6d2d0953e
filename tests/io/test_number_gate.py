"""The one numeric gate (needlekit._numbers) on the files needlekit reads, and the one JSON
writer (needlekit.io.files.json_text) on what it writes: a number out of range is named by
its field, a computed NaN or infinity is named too (or written as null where the format
says it is unbounded), never a traceback."""

from __future__ import annotations

import ast
import json
import math
from pathlib import Path

import numpy as np
import pytest

from needlekit._numbers import MAX_ABS_MM, Bounds, check_document, field_bounds
from needlekit.errors import InvalidInputError, OutputError
from needlekit.io.files import json_text, read_json_object, write_json

SRC = Path(__file__).resolve().parents[2] / "src" / "needlekit"


def test_bounds_say_their_range_and_name_the_field():
    b = Bounds(0.0, 50.0, low_open=True, unit="mm")
    assert b.check(50.0, "x") == 50.0
    for bad in (0.0, -1.0, 50.5, math.nan, math.inf, -math.inf, True, "3"):
        with pytest.raises(InvalidInputError) as err:
            b.check(bad, "needle.diameter_mm")
        assert str(err.value).startswith("needle.diameter_mm: expected a number in (0, 50] mm, got ")
    whole = Bounds(1, 6, integer=True)
    assert whole.check(6, "n") == 6
    with pytest.raises(InvalidInputError, match=r"^n: expected a whole number in \[1, 6\], got 2.5$"):
        whole.check(2.5, "n")


def test_a_field_keeps_the_bound_of_its_unit():
    assert field_bounds("length_mm").high == MAX_ABS_MM
    assert field_bounds("curvature_per_mm").high == 1e3
    assert field_bounds("seed") is None


@pytest.mark.parametrize(
    ("doc", "line"),
    [
        ({"primitives": [{"length_mm": 1e308}]}, "f.json: primitives[0].length_mm: expected a number in [-1e+06, 1e+06] mm, got 1e+308"),
        ({"primitives": [{"curvature_per_mm": 1e308}]}, "f.json: primitives[0].curvature_per_mm: expected a number in [-1000, 1000] 1/mm, got 1e+308"),
        ({"goal_mm": [0, 0, math.nan]}, "f.json: goal_mm[2]: expected a number in [-1e+06, 1e+06] mm, got nan"),
        ({"stats": {"time_s": math.inf}}, "f.json: stats.time_s: expected a number in [-1e+12, 1e+12], got inf"),
        ({"seed": 10**30}, "f.json: seed: expected a whole number in [-9.22e+18, 9.22e+18], got 1e+30"),
    ],
    ids=["length", "curvature", "nan", "inf", "huge-int"],
)
def test_every_number_of_a_document_passes_the_gate(doc, line):
    with pytest.raises(InvalidInputError) as err:
        check_document(doc, "f.json")
    assert str(err.value) == line


@pytest.mark.parametrize(
    ("text", "field", "got"),
    [
        ('{"cost_mm": NaN}', "cost_mm", "nan"),
        ('{"cost_mm": Infinity}', "cost_mm", "inf"),
        ('{"goal_mm": [1e999, 0, 0]}', "goal_mm[0]", "inf"),
        ('{"primitives": [{"length_mm": 1e308}]}', "primitives[0].length_mm", "1e+308"),
    ],
)
def test_a_json_file_with_a_number_past_its_bound_is_named(tmp_path, text, field, got):
    path = tmp_path / "plan.json"
    path.write_text(text)
    with pytest.raises(InvalidInputError) as err:
        read_json_object(path, "plan")
    assert str(err.value).startswith(f"plan.json: {field}: expected a number in ")
    assert str(err.value).endswith(f", got {got}")


def test_the_writer_names_a_computed_non_finite_number_and_writes_nothing(tmp_path):
    path = tmp_path / "out.json"
    with pytest.raises(OutputError) as err:
        write_json(path, {"stats": {"cost_mm": np.float64("nan")}, "ok": True})
    assert str(err.value) == (
        "out.json: stats.cost_mm: computed value is nan, which JSON cannot hold; nothing was "
        "written"
    )
    assert not path.exists()
    with pytest.raises(OutputError, match=r"^--json: poses\[1\]\[0\]: computed value is -inf"):
        json_text({"poses": [[0.0], [np.float64(-np.inf)]]}, "--json")


def test_an_unbounded_clearance_is_written_as_null():
    data = {"stats": {"min_clearance_mm": math.inf, "certified_clearance_mm": np.inf}}
    assert json.loads(json_text(data, "plan.json")) == {
        "stats": {"min_clearance_mm": None, "certified_clearance_mm": None}
    }
    # only +inf is "no obstacle within reach": NaN and -inf are errors
    for bad in (math.nan, -math.inf):
        with pytest.raises(OutputError, match=r"^plan.json: min_clearance_mm: "):
            json_text({"min_clearance_mm": bad}, "plan.json")


def test_every_json_writer_goes_through_the_one_place():
    """No module but io/finite_json.py calls json.dump or json.dumps: the rule on non-finite
    numbers is written once."""
    callers = []
    for path in SRC.rglob("*.py"):
        if path == SRC / "io" / "finite_json.py":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if (
                isinstance(node, ast.Attribute)
                and node.attr in ("dump", "dumps")
                and isinstance(node.value, ast.Name)
                and node.value.id == "json"
            ):
                callers.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert callers == []
