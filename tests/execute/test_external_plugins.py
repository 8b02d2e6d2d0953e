"""A truth and a sensor written outside needlekit, registered only by an entry-point file
(``*.dist-info/entry_points.txt`` on PYTHONPATH), run by ``needlekit execute`` with no edit
to needlekit: their names are in execute.json, and their effects are the ones they must
have."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.scenario.results import read_plan_json

ROOT = Path(__file__).resolve().parents[2]
TOY = ROOT / "examples" / "toy.yaml"
SRC = Path(__import__("needlekit").__file__).resolve().parents[1]

#: The plug-in: a needle that never bends (it spins, but inserts straight along its axis),
#: and a sensor that reads the true tip exactly, 8 times a second, with no latency.
PLUGIN = '''
import numpy as np
from needlekit.control.em import EMSample


class RigidNeedle:
    def __init__(self, start_pose):
        self.pose = np.array(start_pose, dtype=float)
        self.inserted_mm = 0.0

    def step(self, spin_rad, kappa_per_mm, ds_mm, dt_s):
        c, s = np.cos(spin_rad), np.sin(spin_rad)
        self.pose[:3, :3] = self.pose[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        self.pose[:3, 3] += ds_mm * self.pose[:3, 2]
        self.inserted_mm += ds_mm
        return self.pose


def rigid_truth(setup):
    return RigidNeedle(setup.start_pose)


rigid_truth.parameters = lambda settings: {"bends": False}


class ExactSensor:
    rate_hz = 8.0

    def __init__(self):
        self.next_s = 0.0

    def update(self, t, true_pose):
        out = None
        while self.next_s <= t + 1e-12:
            out = EMSample(self.next_s, self.next_s, np.array(true_pose(), dtype=float))
            self.next_s += 1.0 / self.rate_hz
        return out


def exact_sensor(setup):
    return ExactSensor()
'''

ENTRY_POINTS = """\
[needlekit.execute.truths]
rigid = outsideplug:rigid_truth

[needlekit.execute.sensors]
exact = outsideplug:exact_sensor
"""


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("outside")
    (root / "outsideplug.py").write_text(textwrap.dedent(PLUGIN))
    info = root / "outsideplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: outsideplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(ENTRY_POINTS)
    return root


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory):
    path = tmp_path_factory.mktemp("outside-plan") / "plan.json"
    assert main(["plan", str(TOY), "--out", str(path)]) == 0
    return path


def _execute(plugin_path, toy_plan, out, *flags):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), str(plugin_path)])}
    argv = [sys.executable, "-m", "needlekit.cli", "execute", "--truth", "kinematic", str(TOY), str(toy_plan),
            "--trials", "1", "--replan-delay-ms", "5", "--replan-iterations", "200",
            "--out", str(out), *flags]  # fmt: skip
    return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600)


def test_a_truth_and_a_sensor_from_outside_run_and_are_recorded(plugin_path, toy_plan, tmp_path):
    done = _execute(plugin_path, toy_plan, tmp_path, "--truth", "rigid", "--sensor", "exact")
    assert done.returncode in (0, 1), done.stderr  # 1: the rigid needle may miss or cross
    doc = json.loads((tmp_path / "execute.json").read_text())
    assert doc["truth"] == {"name": "rigid", "factory": "outsideplug:rigid_truth",
                            "parameters": {"bends": False}}  # fmt: skip
    assert doc["sensor"]["name"] == "exact"
    assert doc["sensor"]["factory"] == "outsideplug:exact_sensor"
    assert doc["options"]["settings"]["models"]["truth"] == "rigid"
    trial = doc["trials"][0]
    # the truth's effect: open loop, the plan's whole length inserted straight along the
    # start direction, whatever the plan's curvature
    plan, goal, _ = read_plan_json(toy_plan)
    start = plan.start_pose
    end = start[:3, 3] + plan.length_mm * start[:3, 2]
    assert trial["open_loop"]["final_error_mm"] == pytest.approx(
        float(np.linalg.norm(end - goal)), abs=1e-6
    )
    assert trial["open_loop"]["points_mm"][-1] == pytest.approx(end.tolist(), abs=1e-4)
    # the sensor's effect: one exact sample every 1/8 s from t = 0, each admitted by the
    # guard (the loop's last sensor reading is at procedure_s, where the goal fell behind)
    closed = trial["closed_loop"]
    assert closed["rejected"] == {}
    assert closed["samples"] == math.floor(closed["procedure_s"] * 8.0 + 1e-9) + 1


def test_an_unknown_plug_in_name_is_one_line_with_the_outside_names_offered(
    plugin_path, toy_plan, tmp_path
):
    done = _execute(plugin_path, toy_plan, tmp_path, "--truth", "rigdi")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in done.stderr
    assert lines[0].startswith("error: --truth: unknown truth 'rigdi'")
    assert "kinematic, layered, mechanics, physical, rigid" in lines[0] and lines[0].endswith("did you mean rigid?")
    assert not (tmp_path / "execute.json").exists()
