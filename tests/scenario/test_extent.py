"""A start, goal or target outside the anatomy is refused before any search, naming its
field, with a unit hint when x10, x100 or x1000 brings it inside (a goal in metres)."""

from __future__ import annotations

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.scenario.extent import EXTENT_SLACK_MM, check_inside_anatomy

#: The anatomy of the newcomer's lung: z 1050-1400 mm.
BOX = np.array([[0.0, 100.0, 1050.0], [150.0, 300.0, 1400.0]])
SPAN = "(x 0 to 150, y 100 to 300, z 1050 to 1400 mm)"

FAR = """\
version: 1
name: far from the origin
structures:
  - {name: body,   role: allowed_region, sphere: {center_mm: [60, 200, 1200], radius_mm: 150}}
  - {name: vessel, role: obstacle, sphere: {center_mm: [60, 230, 1200], radius_mm: 5}}
  - {name: nodule, role: target,   sphere: {center_mm: [60, 200, 1210], radius_mm: 7}}
needle: {diameter_mm: 1.0, r_min_mm: 50}
start: {point_mm: START, direction: [0, 1, 0.1]}
goal: {point_mm: GOAL, tolerance_mm: 1.0}
straight:
  entry_surface: body
  targets: [TARGET]
"""
#: The body sphere's box, as the messages write it.
FAR_SPAN = "(x -90 to 210, y 50 to 350, z 1050 to 1350 mm)"
GOOD = {"START": "[60, 140, 1200]", "GOAL": "[60, 200, 1210]", "TARGET": "[60, 200, 1210]"}


def _far(tmp_path, **points):
    text = FAR
    for key, value in {**GOOD, **points}.items():
        text = text.replace(key, value)
    path = tmp_path / "far.yaml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    ("point", "hint"),
    [
        ([0.06, 0.2, 1.21], "; it looks like metres: x1000 gives [60, 200, 1210] mm, inside"),
        ([6, 20, 121], "; it looks like centimetres: x10 gives [60, 200, 1210] mm, inside"),
        ([0.6, 2, 12.1], "; it looks like decimetres: x100 gives [60, 200, 1210] mm, inside"),
        ([-500, 200, 1210], ""),  # no factor helps: no hint
    ],
)
def test_a_point_outside_names_its_field_and_the_unit_it_looks_written_in(point, hint):
    with pytest.raises(InvalidInputError) as exc:
        check_inside_anatomy(point, BOX, "goal.point_mm")
    shown = "[" + ", ".join(f"{v:.4g}" for v in point) + "]"
    assert str(exc.value) == f"goal.point_mm: {shown} mm lies outside the anatomy {SPAN}{hint}"


def test_a_point_inside_or_within_the_slack_passes():
    check_inside_anatomy([60, 200, 1210], BOX, "goal")
    check_inside_anatomy([-EXTENT_SLACK_MM, 100, 1050], BOX, "goal")  # on the slack's edge
    with pytest.raises(InvalidInputError):
        check_inside_anatomy([-EXTENT_SLACK_MM - 1e-6, 100, 1050], BOX, "goal")
    check_inside_anatomy([1e9, 0, 0], None, "goal")  # no bounded structure: nothing to check


def _error(argv, capsys) -> list[str]:
    assert main(argv) == 2
    return capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize(
    ("where", "value", "field"),
    [
        ("GOAL", "[0.06, 0.2, 1.21]", "goal.point_mm"),
        ("START", "[0.06, 0.14, 1.2]", "start.point_mm"),
        ("TARGET", "[0.06, 0.2, 1.21]", "straight.targets[0]"),
    ],
)
def test_a_scenario_in_metres_is_refused_before_any_search(where, value, field, tmp_path,
                                                           capsys, monkeypatch):  # fmt: skip
    import needlekit.planning.steerable.solve as solve_module

    def no_search(*_a, **_k):  # the check comes first: no search may start
        raise AssertionError("a search started")

    monkeypatch.setattr(solve_module, "solve", no_search)
    path = _far(tmp_path, **{where: value})
    x1000 = "[" + ", ".join(f"{1000 * float(v):.4g}" for v in value.strip("[]").split(",")) + "]"
    assert _error(["plan", str(path), "--out", str(tmp_path / "p.json")], capsys) == [
        f"error: far.yaml: {field}: {value} mm lies outside the anatomy {FAR_SPAN}; it looks "
        f"like metres: x1000 gives {x1000} mm, inside"
    ]


@pytest.mark.parametrize(
    ("flags", "flag"),
    [(["--goal", "0.06,0.2,1.21"], "--goal"), (["--goals", "60,200,1210", "0.06,0.2,1.21"],
                                                "--goals")],
)
def test_a_goal_flag_in_metres_is_refused_naming_the_flag(flags, flag, tmp_path, capsys):
    path = _far(tmp_path)
    assert _error(["plan", str(path), *flags, "--out", str(tmp_path / "p.json")], capsys) == [
        f"error: {flag}: [0.06, 0.2, 1.21] mm lies outside the anatomy {FAR_SPAN}; it looks "
        "like metres: x1000 gives [60, 200, 1210] mm, inside"
    ]


def test_the_same_scenario_in_millimetres_plans(tmp_path, capsys):
    path = _far(tmp_path)
    assert main(["plan", str(path), "--out", str(tmp_path / "p.json")]) == 0
