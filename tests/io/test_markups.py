"""3D Slicer Markups export: the documents follow the rules of Slicer's markups schema
1.0.x (checked here with our own assertions), RAS <-> LPS signs, round trips, one-line
errors for malformed files, and the ``needlekit markups`` command."""

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.io.markups import (
    DEFAULT_CURVE_SPACING_MM,
    MARKUPS_SCHEMA,
    markups_curve,
    markups_document,
    markups_line,
    read_markups,
    write_markups_curve,
    write_markups_line,
    write_markups_lines,
    write_plan_curve,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.scenario.results import read_plan_json

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

# ------------------------------------------------------------ the schema's rules
# From Slicer's markups-schema-v1.0.3.json (read, not vendored): the top level requires
# "@schema" and "markups"; a markup requires "type"; the enumerations and array sizes below.
TYPES = {"Fiducial", "Line", "Angle", "Curve", "ClosedCurve", "Plane", "ROI"}
SYSTEMS = {"LPS", "RAS"}
UNITS = {"mm", "um"}
POSITION_STATUS = {"undefined", "preview", "defined"}
SLICER_ACCEPTS = re.compile(r".*markups-schema-v1\.[0-9]+\.[0-9]+\.json#*$")


def _numbers(v, n):
    return (
        isinstance(v, list)
        and len(v) == n
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        and all(math.isfinite(x) for x in v)
    )


def assert_follows_schema(doc):
    assert isinstance(doc, dict)
    assert {"@schema", "markups"} <= set(doc)
    assert isinstance(doc["@schema"], str) and SLICER_ACCEPTS.match(doc["@schema"].lower())
    assert isinstance(doc["markups"], list) and doc["markups"]
    for m in doc["markups"]:
        assert isinstance(m, dict) and "type" in m
        assert m["type"] in TYPES
        assert isinstance(m.get("name", ""), str)
        assert m.get("coordinateSystem", "LPS") in SYSTEMS
        assert m.get("coordinateUnits", "mm") in UNITS
        for key in ("locked", "fixedNumberOfControlPoints"):
            assert isinstance(m.get(key, False), bool)
        assert isinstance(m.get("labelFormat", ""), str)
        assert isinstance(m["controlPoints"], list)
        ids = []
        for cp in m["controlPoints"]:
            assert isinstance(cp, dict)
            for key in ("id", "label", "description", "associatedNodeID"):
                assert isinstance(cp.get(key, ""), str)
            ids.append(cp["id"])
            assert _numbers(cp["position"], 3)
            assert _numbers(cp["orientation"], 9)
            for key in ("selected", "locked", "visibility"):
                assert isinstance(cp[key], bool)
            assert cp["positionStatus"] in POSITION_STATUS
        assert len(set(ids)) == len(ids)
        display = m.get("display", {})
        assert isinstance(display, dict)
        for key in ("visibility", "propertiesLabelVisibility", "pointLabelsVisibility"):
            assert isinstance(display.get(key, True), bool)
        assert 0.0 <= display.get("opacity", 1.0) <= 1.0
        for key in ("color", "selectedColor", "activeColor"):
            if key in display:
                assert _numbers(display[key], 3) and all(0 <= c <= 1 for c in display[key])
        for meas in m.get("measurements", []):
            assert isinstance(meas, dict) and isinstance(meas["name"], str)
            assert isinstance(meas.get("enabled", True), bool)
            assert isinstance(meas.get("value", 0.0), (int, float))
            assert isinstance(meas.get("units", ""), str)


def _load(path):
    return json.loads(Path(path).read_text())


# ------------------------------------------------------------------- writing


def test_line_follows_the_schema_in_lps():
    entry, target = [10.0, -20.0, 30.0], [-5.0, 25.0, 80.0]
    item = markups_line(entry, target, name="needle 1", color=(1, 0.5, 0))
    doc = markups_document([item])
    assert_follows_schema(doc)
    assert doc["@schema"] == MARKUPS_SCHEMA
    assert item["type"] == "Line" and item["name"] == "needle 1"
    assert item["coordinateSystem"] == "LPS" and item["coordinateUnits"] == "mm"
    cps = item["controlPoints"]
    assert [c["label"] for c in cps] == ["entry", "target"]
    # RAS -> LPS: x and y change sign, z stays
    assert cps[0]["position"] == [-10.0, 20.0, 30.0]
    assert cps[1]["position"] == [5.0, -25.0, 80.0]
    # identity orientation in RAS, written in LPS as Slicer does (first two rows negated)
    assert cps[0]["orientation"] == [-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]
    assert all(c["positionStatus"] == "defined" for c in cps)
    assert item["display"]["color"] == item["display"]["selectedColor"] == [1.0, 0.5, 0.0]
    (length,) = item["measurements"]
    assert length["name"] == "length" and length["units"] == "mm"
    assert length["value"] == pytest.approx(np.linalg.norm(np.subtract(target, entry)))


def test_no_negative_zero_is_written(tmp_path):
    p = write_markups_line(tmp_path / "a.mrk.json", [0.0, 0.0, 0.0], [0.0, 0.0, 5.0])
    assert "-0.0" not in p.read_text()


def test_line_round_trip_and_default_name(tmp_path):
    entry, target = np.array([1.5, -2.25, 3.0]), np.array([40.0, 50.0, -60.125])
    p = write_markups_line(tmp_path / "needle7.mrk.json", entry, target)
    assert_follows_schema(_load(p))
    (m,) = read_markups(p)
    assert m.type == "Line" and m.name == "needle7"
    np.testing.assert_array_equal(m.points_ras, [entry, target])
    kind, name, pts = m  # a plain (type, name, points) tuple too
    assert (kind, name, pts.shape) == ("Line", "needle7", (2, 3))


def test_curve_round_trip(tmp_path):
    t = np.linspace(0.0, np.pi / 2, 20)
    pts = np.c_[50 * np.cos(t) - 10, 50 * np.sin(t) + 5, 3 * t]
    p = write_markups_curve(tmp_path / "path.mrk.json", pts, name="tip path", color=[0, 1, 0])
    doc = _load(p)
    assert_follows_schema(doc)
    item = doc["markups"][0]
    assert item["type"] == "Curve" and len(item["controlPoints"]) == 20
    assert item["controlPoints"][3]["label"] == "tip path-4"
    np.testing.assert_array_equal([c["position"] for c in item["controlPoints"]], pts * [-1, -1, 1])
    (m,) = read_markups(p)
    assert (m.type, m.name) == ("Curve", "tip path")
    np.testing.assert_array_equal(m.points_ras, pts)


def test_plan_curve_samples_the_tip_path(tmp_path):
    plan = SteerablePlan(np.eye(4), [[0.0, 0.02, 25 * np.pi], [0.0, 0.0, 10.0]])
    p = write_plan_curve(tmp_path / "plan.mrk.json", plan, spacing_mm=1.5)
    (m,) = read_markups(p)
    np.testing.assert_allclose(m.points_ras, plan.points_mm(1.5), atol=1e-12)
    np.testing.assert_allclose(m.points_ras[-1], plan.end_pose()[:3, 3], atol=1e-9)
    steps = np.linalg.norm(np.diff(m.points_ras, axis=0), axis=1)
    assert steps.max() <= 1.5 + 1e-9
    with pytest.raises(InvalidInputError, match=r"^spacing_mm: must be a finite number > 0"):
        write_plan_curve(tmp_path / "x.mrk.json", plan, spacing_mm=0.0)
    with pytest.raises(InvalidInputError, match=r"^plan: has zero length"):
        write_plan_curve(tmp_path / "x.mrk.json", SteerablePlan(np.eye(4), []))


def test_several_lines_one_file_each_and_combined(tmp_path):
    pairs = [
        ([0.0, 0.0, 0.0], [10.0, 0.0, 50.0]),
        ([5.0, 5.0, 0.0], [10.0, 20.0, 60.0]),
        ([-5.0, 3.0, 1.0], [-10.0, 20.0, 70.0]),
    ]
    out = tmp_path / "lines"
    paths = write_markups_lines(out, pairs, combined="needles.mrk.json")
    assert [p.name for p in paths] == [
        "needle1.mrk.json",
        "needle2.mrk.json",
        "needle3.mrk.json",
        "needles.mrk.json",
    ]
    for i, p in enumerate(paths[:3]):
        assert_follows_schema(_load(p))
        (m,) = read_markups(p)
        assert (m.type, m.name) == ("Line", f"needle{i + 1}")
        np.testing.assert_array_equal(m.points_ras, pairs[i])
    assert_follows_schema(_load(paths[3]))
    every = read_markups(paths[3])
    assert [m.name for m in every] == ["needle1", "needle2", "needle3"]
    np.testing.assert_array_equal([m.points_ras for m in every], pairs)
    # a pair unpacks straight into the one-file writer
    (m,) = read_markups(write_markups_line(tmp_path / "one.mrk.json", *pairs[1]))
    np.testing.assert_array_equal(m.points_ras, pairs[1])


def test_several_lines_checks_every_input_before_writing(tmp_path):
    out = tmp_path / "lines"
    good = [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]
    with pytest.raises(InvalidInputError, match=r"^target_mm: coincides with entry_mm"):
        write_markups_lines(out, [good, [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]])
    with pytest.raises(InvalidInputError, match=r"^names: must be unique .*'a' repeats"):
        write_markups_lines(out, [good, good], names=["a", "a"])
    with pytest.raises(InvalidInputError, match=r"^names\[0\]: must be a plain file name"):
        write_markups_lines(out, [good], names=["../escape"])
    with pytest.raises(InvalidInputError, match=r"^names: expected a list of names"):
        write_markups_lines(out, [good], names="a")
    with pytest.raises(InvalidInputError, match=r"^names: expected 2 names"):
        write_markups_lines(out, [good, good], names=["a"])
    with pytest.raises(InvalidInputError, match=r"^combined: 'a.mrk.json' is also"):
        write_markups_lines(out, [good], names=["a"], combined="a.mrk.json")
    with pytest.raises(InvalidInputError, match=r"^trajectories_mm: expected shape \(2x3\)"):
        write_markups_lines(out, [[0.0, 0.0, 0.0]])
    assert not out.exists()


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: markups_line([0, 0, np.nan], [1, 2, 3], name="a"), r"^entry_mm: must be finite"),
        (lambda: markups_line([0, 0], [1, 2, 3], name="a"), r"^entry_mm: expected shape"),
        (lambda: markups_line([0, 0, 0], [1, 2, 3], name=""), r"^name: expected a non-empty"),
        (
            lambda: markups_line([0, 0, 0], [1, 2, 3], name="a", color=[1, 2, 0]),
            r"^color: expected three numbers in \[0, 1\]",
        ),
        (lambda: markups_curve([[0, 0, 0]], name="a"), r"^points_mm: a curve needs at least 2"),
        (lambda: markups_curve([[0, 0, 0], [1, np.inf, 0]], name="a"), r"^points_mm: must be"),
        (lambda: markups_document([]), r"^markups: expected at least one markup"),
    ],
)
def test_writer_input_errors(call, message):
    with pytest.raises(InvalidInputError, match=message):
        call()


# ------------------------------------------------------------------- reading


def _slicer_document(system="LPS"):
    """A curve as Slicer 5 writes it (every key it writes, an unplaced point included)."""
    return {
        "@schema": MARKUPS_SCHEMA,
        "markups": [
            {
                "type": "Curve",
                "coordinateSystem": system,
                "coordinateUnits": "mm",
                "locked": False,
                "fixedNumberOfControlPoints": False,
                "labelFormat": "%N-%d",
                "lastUsedControlPointNumber": 3,
                "controlPoints": [
                    {
                        "id": str(i + 1),
                        "label": f"OC-{i + 1}",
                        "description": "",
                        "associatedNodeID": "vtkMRMLScalarVolumeNode1",
                        "position": pos,
                        "orientation": [-1.0, -0.0, -0.0, -0.0, -1.0, -0.0, 0.0, 0.0, 1.0],
                        "selected": True,
                        "locked": False,
                        "visibility": True,
                        "positionStatus": status,
                    }
                    for i, (pos, status) in enumerate(
                        [
                            ([-12.5, 30.25, 7.0], "defined"),
                            ([1.0, -2.0, 3.0], "defined"),
                            ("", "undefined"),
                        ]
                    )
                ],
                "measurements": [
                    {
                        "name": "length",
                        "enabled": True,
                        "value": 45.3,
                        "units": "mm",
                        "printFormat": "%-#4.4g%s",
                    }
                ],
                "display": {
                    "visibility": True,
                    "opacity": 1.0,
                    "color": [0.4, 1.0, 1.0],
                    "selectedColor": [1.0, 0.5, 0.5],
                    "activeColor": [0.4, 1.0, 0.0],
                    "propertiesLabelVisibility": True,
                    "pointLabelsVisibility": True,
                    "textScale": 3.0,
                    "glyphType": "Sphere3D",
                    "glyphScale": 1.0,
                    "glyphSize": 5.0,
                    "useGlyphScale": True,
                    "sliceProjection": False,
                    "snapMode": "toVisibleSurface",
                },
            }
        ],
    }


@pytest.mark.parametrize(
    ("system", "expected"),
    [
        ("LPS", [[12.5, -30.25, 7.0], [-1.0, 2.0, 3.0]]),
        ("RAS", [[-12.5, 30.25, 7.0], [1.0, -2.0, 3.0]]),
    ],
)
def test_reads_what_slicer_writes_in_lps_and_ras(tmp_path, system, expected):
    p = tmp_path / "OC.mrk.json"
    p.write_text(json.dumps(_slicer_document(system), indent=4))
    (m,) = read_markups(p)
    assert (m.type, m.name) == ("Curve", "OC")  # no "name": the file's, as Slicer does
    np.testing.assert_array_equal(m.points_ras, expected)


def test_a_file_without_coordinate_system_is_lps(tmp_path):
    doc = _slicer_document()
    del doc["markups"][0]["coordinateSystem"]
    p = tmp_path / "x.json"
    p.write_text(json.dumps(doc))
    np.testing.assert_array_equal(read_markups(p)[0].points_ras[0], [12.5, -30.25, 7.0])


def _malformed(doc_change):
    doc = _slicer_document()
    doc_change(doc)
    return json.dumps(doc)


def _set(path, value):
    def change(doc):
        *parents, last = path
        node = doc
        for key in parents:
            node = node[key]
        if value is KeyError:
            del node[last]
        else:
            node[last] = value

    return change


CP = ("markups", 0, "controlPoints", 0)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("{not json", r"bad\.mrk\.json: not a JSON markups file"),
        ("[1, 2]", r"bad\.mrk\.json: expected a JSON object at the top level"),
        (_malformed(_set(["@schema"], KeyError)), r"^bad\.mrk\.json: @schema: missing"),
        (
            _malformed(_set(["@schema"], "https://example.org/markups-schema-v2.0.0.json#")),
            r"^bad\.mrk\.json: @schema: expected a Slicer markups schema",
        ),
        (_malformed(_set(["markups"], KeyError)), r"^bad\.mrk\.json: markups: missing"),
        (_malformed(_set(["markups"], [])), r"^bad\.mrk\.json: markups: expected a non-empty"),
        (
            _malformed(_set(["markups", 0, "type"], "Spline")),
            r"^bad\.mrk\.json: markups\[0\]\.type: expected one of Fiducial, Line",
        ),
        (
            _malformed(_set(["markups", 0, "coordinateSystem"], "XYZ")),
            r"^bad\.mrk\.json: markups\[0\]\.coordinateSystem: expected LPS or RAS, got 'XYZ'",
        ),
        (
            _malformed(_set(["markups", 0, "coordinateUnits"], "um")),
            r"^bad\.mrk\.json: markups\[0\]\.coordinateUnits: only mm is supported",
        ),
        (
            _malformed(_set(["markups", 0, "controlPoints"], {})),
            r"markups\[0\]\.controlPoints: expected a list",
        ),
        (
            _malformed(_set([*CP, "position"], [1.0, float("nan"), 2.0])),
            r"^bad\.mrk\.json: markups\[0\]\.controlPoints\[0\]\.position\[1\]: expected a number "
            r"in \[-1e\+12, 1e\+12\], got nan$",
        ),
        (
            _malformed(_set([*CP, "position"], [1.0, 2.0])),
            r"markups\[0\]\.controlPoints\[0\]\.position: expected 3 numbers",
        ),
        (
            _malformed(_set([*CP, "position"], [1.0, True, 2.0])),
            r"markups\[0\]\.controlPoints\[0\]\.position: expected 3 numbers",
        ),
        (
            _malformed(_set([*CP, "orientation"], [1.0] * 8)),
            r"markups\[0\]\.controlPoints\[0\]\.orientation: expected 9 numbers",
        ),
        (
            _malformed(_set([*CP, "positionStatus"], "placed")),
            r"markups\[0\]\.controlPoints\[0\]\.positionStatus: expected one of undefined",
        ),
    ],
)
def test_malformed_files_are_one_line_errors_naming_the_field(tmp_path, text, message):
    p = tmp_path / "bad.mrk.json"
    p.write_text(text)
    with pytest.raises(InvalidInputError, match=message) as info:
        read_markups(p)
    assert "\n" not in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(InvalidInputError, match=r"nope\.mrk\.json: markups file not found"):
        read_markups(tmp_path / "nope.mrk.json")


# ---------------------------------------------------------------- the command


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    out = tmp_path_factory.mktemp("plan") / "plan.json"
    code = main(
        [
            "plan",
            str(EXAMPLES / "toy.yaml"),
            "--out",
            str(out),
            "--max-iterations",
            "2000",
            "--time-limit-s",
            "60",
        ]
    )
    assert code == 0
    return out


def _run(capsys, *argv):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_markups_writes_the_tip_path_as_a_curve(capsys, tmp_path, toy_plan):
    capsys.readouterr()
    out = tmp_path / "out" / "toy.mrk.json"
    code, text, err = _run(capsys, "markups", toy_plan, "--out", out, "--spacing-mm", "1.5")
    assert code == 0 and err == "", err
    assert text.startswith("curve: ") and text.strip().endswith(f"-> {out}")
    doc = _load(out)
    assert_follows_schema(doc)
    assert doc["markups"][0]["type"] == "Curve"
    plan, goal, _ = read_plan_json(toy_plan)
    (m,) = read_markups(out)
    assert (m.type, m.name) == ("Curve", "toy")
    np.testing.assert_allclose(m.points_ras, plan.points_mm(1.5), atol=1e-12)
    np.testing.assert_allclose(m.points_ras[0], [0.0, -12.0, 0.0], atol=1e-12)  # the start
    np.testing.assert_allclose(m.points_ras[-1], plan.end_pose()[:3, 3], atol=1e-9)
    assert np.linalg.norm(m.points_ras[-1] - goal) <= 1.0 + 1e-9  # within the goal tolerance
    np.testing.assert_array_equal(  # in the file: LPS
        doc["markups"][0]["controlPoints"][0]["position"], [0.0, 12.0, 0.0]
    )
    # the default spacing is the documented one
    code, _, _ = _run(capsys, "markups", toy_plan, "--out", tmp_path / "d.mrk.json")
    assert code == 0
    (m,) = read_markups(tmp_path / "d.mrk.json")
    np.testing.assert_allclose(m.points_ras, plan.points_mm(DEFAULT_CURVE_SPACING_MM))
    code, text, _ = _run(capsys, "markups", "--help")
    assert f"default {DEFAULT_CURVE_SPACING_MM:g} mm" in " ".join(text.split())


def test_cli_markups_errors_are_one_line(capsys, tmp_path, toy_plan):
    capsys.readouterr()
    data = _load(toy_plan)
    data.update(status="timeout", primitives=[], points_mm=[], cost_mm=None, length_mm=None)
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps(data))
    (tmp_path / "adir").mkdir()
    cases = [
        ([empty, "--out", tmp_path / "a.mrk.json"], "holds no path (status 'timeout')"),
        ([toy_plan, "--out", tmp_path / "a.txt"], "--out: "),
        ([toy_plan, "--out", tmp_path / "adir"], "--out: "),
        ([tmp_path / "missing.json", "--out", tmp_path / "a.mrk.json"], "plan: "),
        ([toy_plan, "--out", tmp_path / "a.mrk.json", "--spacing-mm", "0"], "--spacing-mm"),
        ([toy_plan], "--out"),
    ]
    for argv, needle in cases:
        code, text, err = _run(capsys, "markups", *argv)
        lines = err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), err
        assert needle in lines[0], (needle, err)
        assert text == ""
    assert not (tmp_path / "a.mrk.json").exists() and not (tmp_path / "a.txt").exists()
