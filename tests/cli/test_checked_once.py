"""Every request is checked once: one ``needlekit plan`` or ``sweep``
reads its scenario file once, checks it against the schema once, checks each planner's
name and options once and builds each planner once, however many directions or goals it
then plans; one ``needlekit execute`` reads its scenario and its plan once."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.io import safe_yaml, scenario_schema
from needlekit.planning import registry
from needlekit.planning.steerable.rcs import RCSStarPlanner
from needlekit.planning.steerable.rrt import RRTPlanner

TOY = str(Path(__file__).resolve().parents[2] / "examples" / "toy.yaml")


class _Counting:
    """Wraps the schema validator: counts the documents it checks."""

    def __init__(self, inner, counts):
        self.inner, self.counts = inner, counts

    def iter_errors(self, data):
        self.counts["schema"] += 1
        return self.inner.iter_errors(data)


@pytest.fixture
def counts(monkeypatch):
    n = {"schema": 0, "yaml": 0, "check": 0, "built": 0}
    validator = scenario_schema._validator()
    monkeypatch.setattr(scenario_schema, "_validator", lambda: _Counting(validator, n))
    load = safe_yaml.load_bounded

    def counting_load(text, **kw):
        n["yaml"] += 1
        return load(text, **kw)

    monkeypatch.setattr(safe_yaml, "load_bounded", counting_load)
    check = registry.check_planner_options

    def counting_check(*a, **k):
        n["check"] += 1
        return check(*a, **k)

    # every module that holds the function by name (the registry, the interface that
    # re-exports it, the scenario layer that calls it), each loaded before it is patched
    importlib.import_module("needlekit.planning.interface")
    importlib.import_module("needlekit.scenario.planners")
    for module in [m for name, m in list(sys.modules.items()) if name.startswith("needlekit")]:
        if getattr(module, "check_planner_options", None) is check:
            monkeypatch.setattr(module, "check_planner_options", counting_check)
    for cls in (RCSStarPlanner, RRTPlanner):  # RCS inherits RCS*'s __init__
        init = cls.__init__

        def counting_init(self, *a, _init=init, **k):
            n["built"] += 1
            _init(self, *a, **k)

        monkeypatch.setattr(cls, "__init__", counting_init)
    return n


def test_plan_reads_checks_and_builds_once(counts, tmp_path):
    out = tmp_path / "plan.json"
    argv = ["plan", TOY, "--goal", "10,40,20", "--max-iterations", "200", "--out", str(out)]
    assert main(argv) == 0
    assert json.loads(out.read_text())["status"] == "solved"
    assert counts == {"schema": 1, "yaml": 1, "check": 1, "built": 1}


def test_plan_to_several_goals_builds_its_planner_once(counts, tmp_path):
    out = tmp_path / "goals.json"
    goals = ["--goals", "10,40,20", "-5,35,25", "0,30,15"]
    argv = ["plan", TOY, *goals, "--max-iterations", "200", "--out", str(out)]
    assert main(argv) == 0
    assert len(json.loads(out.read_text())["targets"]) == 3
    assert counts == {"schema": 1, "yaml": 1, "check": 1, "built": 1}


def test_sweep_reads_checks_and_builds_once_for_every_direction(counts, tmp_path):
    out = tmp_path / "sweep.json"
    argv = ["sweep", TOY, "--directions", "12", "--max-iterations", "50", "--out", str(out)]
    assert main(argv) == 0
    record = json.loads(out.read_text())
    assert record["planners"] == ["rcs_star"] and len(record["directions"]) == 12
    assert counts == {"schema": 1, "yaml": 1, "check": 1, "built": 1}


def test_a_sweep_of_two_planners_builds_each_once(counts, tmp_path):
    out = tmp_path / "sweep.json"
    argv = ["sweep", TOY, "--planner", "rcs", "rrt", "--directions", "8",
            "--max-iterations", "30", "--seed", "3", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    assert counts == {"schema": 1, "yaml": 1, "check": 2, "built": 2}
    assert json.loads(out.read_text())["options"]["rrt"]["seed"] == 3


def _count_json_reads(monkeypatch) -> dict[str, int]:
    """Counts every read of a JSON document, by file name (wherever the reader is held)."""
    from needlekit.io import files

    reads: dict[str, int] = {}
    real = files.read_json_object

    def counting(path, *a, **k):
        name = Path(path).name
        reads[name] = reads.get(name, 0) + 1
        return real(path, *a, **k)

    importlib.import_module("needlekit.scenario.results")
    for module in [m for name, m in list(sys.modules.items()) if name.startswith("needlekit")]:
        if getattr(module, "read_json_object", None) is real:
            monkeypatch.setattr(module, "read_json_object", counting)
    return reads


def test_execute_reads_its_scenario_and_its_plan_once(tmp_path, monkeypatch):
    plan = tmp_path / "plan.json"
    assert main(["plan", TOY, "--max-iterations", "200", "--out", str(plan)]) == 0
    # counted from here: the execution only
    n = {"schema": 0, "yaml": 0}
    validator = scenario_schema._validator()
    monkeypatch.setattr(scenario_schema, "_validator", lambda: _Counting(validator, n))
    load = safe_yaml.load_bounded

    def counting_load(text, **kw):
        n["yaml"] += 1
        return load(text, **kw)

    monkeypatch.setattr(safe_yaml, "load_bounded", counting_load)
    reads = _count_json_reads(monkeypatch)
    out = tmp_path / "run"
    argv = ["execute", "--truth", "kinematic", TOY, str(plan), "--trials", "2", "--replan-iterations", "100",
            "--replan-delay-ms", "5", "--no-cache", "--out", str(out)]  # fmt: skip
    assert main(argv) in (0, 1)
    assert len(json.loads((out / "execute.json").read_text())["trials"]) == 2
    assert n == {"schema": 1, "yaml": 1}
    assert reads == {"plan.json": 1}
