"""``needlekit verify`` holds a plan file to the scenario's own start, goal and limits, and
refuses fields of the wrong type: a plan edited by hand cannot pass by moving its start."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.geometry.so3 import rot_z

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = EXAMPLES / "toy.yaml"


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    out = tmp_path_factory.mktemp("verify") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(out)]) == 0
    return json.loads(out.read_text())


def _write(tmp_path, doc, name="edited.json"):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return path


def _end(doc):
    return np.asarray(doc["points_mm"][-1])


def test_the_unedited_plan_passes(toy_plan, tmp_path, capsys):
    code, text, _ = _run(capsys, "verify", TOY, _write(tmp_path, toy_plan))
    assert code == 0 and text.startswith("ok:")


def test_a_plan_moved_to_start_elsewhere_fails_on_its_start(toy_plan, tmp_path, capsys):
    # the whole path shifted 0.5 mm toward the goal: it still ends within the 1 mm
    # tolerance (0.5 mm from the goal) and clears everything, so only the start tells
    doc = json.loads(json.dumps(toy_plan))
    step = np.asarray(doc["goal_mm"]) - _end(doc)
    step *= 0.5 / np.linalg.norm(step)
    pose = np.asarray(doc["start_pose"])
    pose[:3, 3] += step
    doc["start_pose"] = pose.tolist()
    code, text, _ = _run(capsys, "verify", TOY, _write(tmp_path, doc), "--json")
    report = json.loads(text)
    assert code == 1 and report["violations"] == [
        "start: the plan starts 0.5000 mm from the problem's start point"
    ]
    assert report["metrics"]["goal_distance_mm"] == pytest.approx(0.5, abs=1e-9)


def test_the_report_holds_a_moved_plan_to_the_scenarios_start(toy_plan, tmp_path, capsys):
    """``report`` checks a plan as ``verify`` does: the same moved start fails there too."""
    doc = json.loads(json.dumps(toy_plan))
    step = np.asarray(doc["goal_mm"]) - _end(doc)
    pose = np.asarray(doc["start_pose"])
    pose[:3, 3] += step * 0.5 / np.linalg.norm(step)
    doc["start_pose"] = pose.tolist()
    page = tmp_path / "page.html"
    for name, plan, want in (("same.json", toy_plan, 0), ("moved.json", doc, 1)):
        path = _write(tmp_path, plan, name)
        code, text, _ = _run(capsys, "report", path, "--scenario", TOY, "--out", page)
        assert code == want, text
    assert "check FAILED (1 of 1)" in text and "an independent check failed" in text


def test_the_roll_about_the_needle_is_free(toy_plan, tmp_path, capsys):
    # the same path from a start pose rolled 30 degrees about the needle, the first bend's
    # rotation taking the roll back: the start is the scenario's and the plan passes
    doc = json.loads(json.dumps(toy_plan))
    pose = np.asarray(doc["start_pose"])
    roll = np.radians(30.0)
    pose[:3, :3] = pose[:3, :3] @ rot_z(roll)
    doc["start_pose"] = pose.tolist()
    doc["primitives"][0]["rotation_rad"] -= roll
    code, text, _ = _run(capsys, "verify", TOY, _write(tmp_path, doc))
    assert code == 0 and text.startswith("ok:")


def test_a_turned_start_direction_is_named(toy_plan, tmp_path, capsys):
    doc = json.loads(json.dumps(toy_plan))
    pose = np.asarray(doc["start_pose"])
    c, s = np.cos(np.radians(2.0)), np.sin(np.radians(2.0))
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    pose[:3, :3] = pose[:3, :3] @ tilt
    doc["start_pose"] = pose.tolist()
    code, text, _ = _run(capsys, "verify", TOY, _write(tmp_path, doc), "--json")
    report = json.loads(text)
    assert code == 1
    assert report["violations"][0] == (
        "start: the plan's insertion direction is 2.0000 deg from the problem's start direction"
    )


def test_a_start_direction_a_rounding_short_of_unit_length_is_the_same_direction(toy_plan, tmp_path, capsys):
    # an estimated tip after thousands of filter updates: its axis 3e-13 short of unit
    # length, the plan started from it; arccos of the dot product read 1.05e-6 rad there
    doc = json.loads(json.dumps(toy_plan))
    pose = np.asarray(doc["start_pose"])
    pose[:3, :3] *= 1.0 - 3e-13
    doc["start_pose"] = pose.tolist()
    np.savetxt(tmp_path / "start.txt", pose, fmt="%.17g")
    code, text, _ = _run(capsys, "verify", TOY, _write(tmp_path, doc), "--start-pose", tmp_path / "start.txt")
    assert code == 0 and text.startswith("ok:"), text


def test_start_pose_flag_is_what_the_plan_is_held_to(toy_plan, tmp_path, capsys):
    plan = _write(tmp_path, toy_plan)
    g = np.asarray(toy_plan["start_pose"]).copy()
    np.savetxt(tmp_path / "same.txt", g)
    g[:3, 3] += [5.0, 0.0, 0.0]
    np.savetxt(tmp_path / "moved.txt", g)
    code, text, _ = _run(capsys, "verify", TOY, plan, "--start-pose", tmp_path / "same.txt")
    assert code == 0 and text.startswith("ok:")
    code, text, _ = _run(
        capsys, "verify", TOY, plan, "--start-pose", tmp_path / "moved.txt", "--json"
    )
    report = json.loads(text)
    assert code == 1
    assert (
        report["violations"][0] == "start: the plan starts 5.0000 mm from the problem's start point"
    )


def test_a_plan_for_another_goal_fails_on_the_goal(toy_plan, tmp_path, capsys):
    code, text, _ = _run(
        capsys, "verify", TOY, _write(tmp_path, toy_plan), "--goal", "25,30,40", "--json"
    )
    report = json.loads(text)
    end = _end(toy_plan)
    expected = np.linalg.norm(end - [25.0, 30.0, 40.0])
    assert code == 1 and report["violations"] == [
        f"goal: ends {expected:.4f} mm from the goal, tolerance 1 mm"
    ]


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d["primitives"][1].update(length_mm="20.5"), "plan.json: primitives"),
        (lambda d: d["primitives"][0].update(curvature_per_mm=True), "plan.json: primitives"),
        (lambda d: d.update(goal_mm=["20", "30", "40"]), "plan.json: goal_mm"),
        (lambda d: d.update(cost_mm="62.86"), "plan.json: cost_mm"),
        (lambda d: d["start_pose"][0].__setitem__(3, "0"), "plan.json: start_pose"),
        (lambda d: d.update(primitives="none"), "plan.json: primitives"),
    ],
    ids=["length-text", "curvature-bool", "goal-text", "cost-text", "pose-text", "primitives-text"],
)
def test_a_field_of_the_wrong_type_is_an_error_not_a_value(toy_plan, tmp_path, capsys, edit, field):
    doc = json.loads(json.dumps(toy_plan))
    edit(doc)
    path = _write(tmp_path, doc, "plan.json")
    code, text, err = _run(capsys, "verify", TOY, path)
    assert code == 2 and text == ""
    assert len(err.strip().splitlines()) == 1
    assert err.startswith(f"error: {field}: expected ")
