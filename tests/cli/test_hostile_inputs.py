"""Hostile and careless inputs: deep nesting, alias bombs, numbers at
the edge of the float range, sizes that would exhaust memory, more workers than cores. Each
is one clear error line (exit 2) or a clear answer, never a traceback."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import pytest

from needlekit.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = EXAMPLES / "toy.yaml"
MULTI = EXAMPLES / "liver_phantom_multi.yaml"
TOY_BODY = "\n".join(
    line for line in TOY.read_text().splitlines() if not line.startswith(("needle:", "goal:"))
)


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def _one_error(capsys, *argv) -> str:
    code, _, err = _run(capsys, *argv)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (code, err)
    return lines[0]


def _toy(tmp_path, needle="{diameter_mm: 1.0, r_min_mm: 50}", goal="{point_mm: [20, 30, 40]}",
         name="case.yaml"):  # fmt: skip
    path = tmp_path / name
    path.write_text(f"{TOY_BODY}\nneedle: {needle}\ngoal: {goal}\n")
    return path


def test_a_scenario_nested_900_deep_is_refused(tmp_path, capsys):
    path = tmp_path / "deep.yaml"
    path.write_text("version: 1\nname: " + "[" * 900 + "]" * 900 + "\n")
    line = _one_error(capsys, "plan", path)
    assert line == f"error: {path}: refused at line 2: the document is nested deeper than 64 levels"


def test_a_plan_nested_100000_deep_is_refused(tmp_path, capsys):
    path = tmp_path / "deep.json"
    path.write_text('{"goal_mm": ' + "[" * 100_000 + "]" * 100_000 + "}")
    for argv in (["verify", TOY, path], ["markups", path, "--out", tmp_path / "x.mrk.json"]):
        assert (
            _one_error(capsys, *argv) == f"error: {path}: nested too deeply to be a needlekit file"
        )


def test_a_yaml_alias_bomb_is_refused_at_parse(tmp_path, capsys):
    lines = ["version: 1", 'a0: &a0 ["x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    path = tmp_path / "bomb.yaml"
    # in a free-form field the schema would walk: 9^9 = 387 million values
    path.write_text("\n".join(lines) + "\ncollision_options: {x: *a8}\n")
    line = _one_error(capsys, "plan", path)
    assert line.startswith(f"error: {path}: refused at line ")
    assert line.endswith("stands for more than 1,000,000 values once its aliases are expanded")


def test_exponent_numbers_are_numbers(tmp_path, capsys):
    # YAML 1.1 reads 5e1 as text; a scenario reads it as JSON and YAML 1.2 do
    plain = _toy(tmp_path)
    exp = _toy(tmp_path, "{diameter_mm: 1e0, r_min_mm: 5e1}", name="exp.yaml")
    codes = [_run(capsys, "plan", s, "--out", tmp_path / f"{s.stem}.json")[0] for s in (plain, exp)]
    a, b = (json.loads((tmp_path / f"{s.stem}.json").read_text()) for s in (plain, exp))
    assert codes == [0, 0] and a["cost_mm"] == b["cost_mm"] and a["primitives"] == b["primitives"]


@pytest.mark.parametrize(
    ("needle", "goal", "field", "says"),
    [
        (
            "{r_min_mm: 50}",
            "{point_mm: [1e308, 0, 0]}",
            "goal.point_mm[0]",
            "expected a number in [-1e+06, 1e+06] mm, got 1e+308",
        ),
        (
            "{r_min_mm: 1e308}",
            "{point_mm: [20, 30, 40]}",
            "needle.r_min_mm",
            "expected a number in [-1e+06, 1e+06] mm, got 1e+308",
        ),
        (
            "{r_min_mm: 50, max_length_mm: 1e999}",
            "{point_mm: [20, 30, 40]}",
            "needle.max_length_mm",
            "expected a number in [-1e+06, 1e+06] mm, got inf",
        ),
        (
            "{r_min_mm: 50}",
            "{point_mm: [20, 30, .nan]}",
            "goal.point_mm[2]",
            "expected a number in [-1e+06, 1e+06] mm, got nan",
        ),
        (
            "{r_min_mm: 50}",
            "{point_mm: [20, 30, 40], tolerance_mm: .inf}",
            "goal.tolerance_mm",
            "expected a number in [-1e+06, 1e+06] mm, got inf",
        ),
        (
            "{r_min_mm: -.inf}",
            "{point_mm: [20, 30, 40]}",
            "needle.r_min_mm",
            "expected a number in [-1e+06, 1e+06] mm, got -inf",
        ),
    ],
    ids=["goal-1e308", "rmin-1e308", "length-1e999", "goal-nan", "tolerance-inf", "rmin-minus-inf"],
)
def test_numbers_past_the_range_are_named(tmp_path, capsys, needle, goal, field, says):
    path = _toy(tmp_path, needle, goal)
    line = _one_error(capsys, "plan", path, "--out", tmp_path / "p.json")
    assert line.startswith(f"error: {path.name}: {field}: ") and says in line
    assert not (tmp_path / "p.json").exists()


def test_a_goal_at_the_start_is_a_clear_answer_in_valid_json(tmp_path, capsys):
    path = _toy(tmp_path, goal="{point_mm: [0, -12, 0]}")
    out = tmp_path / "p.json"
    code, text, _ = _run(capsys, "plan", path, "--out", out)
    assert code == 1 and "invalid_input" in text
    assert (
        "the goal is 0.000 mm from the start, within the goal tolerance 1 mm: there is nothing to insert"
        in text
    )

    def no_constants(name):
        raise AssertionError(f"{name} in a JSON output")

    data = json.loads(out.read_text(), parse_constant=no_constants)
    assert data["status"] == "invalid_input" and data["cost_mm"] is None


@pytest.mark.parametrize(
    ("argv", "flag", "what"),
    [
        (
            ["sweep", TOY, "--directions", "1000000000"],
            "--directions",
            "1000000000 directions",
        ),
        (["sweep", TOY, "--healpix", "10000000"], "--healpix", "1200000000000000 directions"),
        (
            ["cfrw", MULTI, "--resolution-deg", "1e-5"],
            "--resolution-deg",
            "a 1e-05-degree grid (2.16e+14 cells)",
        ),
        (
            ["multi", MULTI, "--resolution-deg", "1e-5"],
            "--resolution-deg",
            "a 1e-05-degree grid (2.16e+14 cells)",
        ),
        (["bench", "fields", "--grid", "1000000"], "--grid", "a 1000000^3 grid"),
    ],
    ids=["directions", "healpix", "cfrw", "multi", "grid"],
)
def test_a_size_that_would_exhaust_memory_is_refused_with_the_estimate(
    tmp_path, capsys, argv, flag, what
):
    out = tmp_path / ("out.json" if argv[0] != "multi" else "multi.json")
    line = _one_error(capsys, *argv, "--out", out)
    assert line.startswith(f"error: {flag}: {what} would need at least ")
    assert line.endswith(" available") and any(u in line for u in ("PiB", "TiB", "GiB"))
    assert not out.exists()


def test_a_curve_spacing_finer_than_a_micrometre_is_refused(tmp_path, capsys):
    plan = tmp_path / "plan.json"
    assert main(["plan", str(TOY), "--out", str(plan)]) == 0
    capsys.readouterr()
    with pytest.raises(SystemExit) as stop:  # the parser's own refusal
        main(["markups", str(plan), "--spacing-mm", "1e-12", "--out", str(tmp_path / "c.json")])
    assert stop.value.code == 2
    assert capsys.readouterr().err == (
        "error: argument --spacing-mm: expected a number in [0.001, 1e+06] mm, got '1e-12'\n"
    )


def test_more_workers_than_cores_are_capped_with_a_warning(caplog):
    from needlekit.batch import open_executor

    cores = os.cpu_count() or 1
    with caplog.at_level(logging.WARNING, logger="needlekit.batch"):
        with open_executor("process", workers=cores + 5) as pool:
            assert pool._max_workers == cores
            assert pool.submit(sum, [1, 2]).result() == 3
    assert caplog.messages == [
        f"{cores + 5} workers asked for, this machine has {cores} cores: using {cores}"
    ]


@pytest.mark.parametrize(
    "doc",
    [
        {"version": 1, "collision_options": {"a\nb": float("inf")}},
        {"version": 1, "goal": {"point\n_mm": [1e308, 0, 0]}},
        {"version": 1, "needle": {"r_min_mm": 50, "x\r": float("nan")}},
    ],
    ids=["inf-under-a-broken-key", "mm-key-with-a-line-break", "nan-under-a-carriage-return"],
)
def test_a_key_with_line_breaks_keeps_the_error_on_one_line(doc):
    from needlekit.errors import InvalidInputError
    from needlekit.io.scenario_schema import validate_scenario_document

    with pytest.raises(InvalidInputError) as err:
        validate_scenario_document(doc, "fuzz.yaml")
    assert "\n" not in str(err.value) and "\r" not in str(err.value)
    assert str(err.value).startswith("fuzz.yaml: ")


@pytest.mark.parametrize("value", [10**400, -(10**5000)], ids=["1e400", "minus-1e5000"])
def test_a_whole_number_past_the_float_range_is_named(value):
    from needlekit.errors import InvalidInputError
    from needlekit.io.scenario_schema import validate_scenario_document

    with pytest.raises(InvalidInputError) as err:
        validate_scenario_document({"version": 1, "goal": {"point_mm": [value, 0, 0]}}, "f.yaml")
    power = 400 if value > 0 else 5000
    sign = "" if value > 0 else "-"
    assert str(err.value) == (
        f"f.yaml: goal.point_mm[0]: expected a number in [-1e+06, 1e+06] mm, got {sign}10^{power}"
    )


# ---------------------------------------------------------------------------------------
# point 7: an error never echoes what the file holds


def _secret_files(tmp_path: Path) -> dict[str, Path]:
    """Files that are not what a command expects, each holding the word SECRET where a
    parser would quote it."""
    files = {
        "shadow": "root:SECRET1:19000:0:99999:7:::\nuser:*SECRET2\n",
        "alias.yaml": "a: *SECRET3\n",
        "tag.yaml": "a: !SECRET4 x\n",
        "pose.txt": "SECRET5 1 2 3\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
        "bad.json": '{"a": SECRET6}',
        "header.nrrd": "NRRD0004\ntype: SECRET7\ndimension: 3\nsizes: 2 2 2\nencoding: raw\n\n",
        "mesh.vtk": "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n"
        "SECRET8 0 0\n",
    }
    out = {}
    for name, text in files.items():
        out[name] = tmp_path / name
        out[name].write_text(text)
    gz = tmp_path / "mask.nii.gz"
    gz.write_bytes(b"SECRET9 not gzip")
    out["mask.nii.gz"] = gz
    return out


def test_errors_never_echo_the_file(tmp_path, capsys):
    f = _secret_files(tmp_path)
    cases = [
        ["plan", f["shadow"]],
        ["plan", f["alias.yaml"]],
        ["plan", f["tag.yaml"]],
        ["plan", TOY, "--start-pose", f["pose.txt"]],
        ["plan", TOY, "--start-pose", f["shadow"]],
        ["verify", TOY, f["bad.json"]],
        ["verify", TOY, f["shadow"]],
        ["report", f["shadow"], "--out", tmp_path / "r.html"],
        ["markups", f["bad.json"], "--out", tmp_path / "m.mrk.json"],
    ]
    for name, kind in (("header.nrrd", "mask"), ("mask.nii.gz", "mask"), ("mesh.vtk", "mesh")):
        scenario = tmp_path / f"with-{name}.yaml"
        scenario.write_text(
            f"version: 1\nstructures:\n  - {{name: a, role: obstacle, {kind}: {{path: {name}}}}}\n"
        )
        cases.append(["scene", "info", scenario])
    for argv in cases:
        line = _one_error(capsys, *argv)
        assert "SECRET" not in line, (argv, line)
