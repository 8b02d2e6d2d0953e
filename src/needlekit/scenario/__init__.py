"""Scenario documents turned into problems: the layer above planning.

A scenario file (``docs/scenarios.md``) is read and schema-checked by
:mod:`needlekit.io.scenario_schema` (file handling: no planner involved); here it becomes a
:class:`~needlekit.scenario.loading.Scenario` (:mod:`needlekit.scenario.loading`: the
anatomy, needle, start, goal and planner settings built), then problems
(:mod:`needlekit.scenario.problems`: steerable, and the picklable
:class:`~needlekit.scenario.problems.ScenarioSource` of batch workers;
:mod:`needlekit.scenario.straight`: straight multi-needle and coverage;
:mod:`needlekit.scenario.dynamic`: moving obstacles), the planner settings
(:mod:`needlekit.scenario.planners`), and result files are read back against their scenarios
(:mod:`needlekit.scenario.results`).

The main names are importable from the package itself; each is loaded on first use, so
``import needlekit.scenario`` stays light (no numba) for the command line.
"""

from __future__ import annotations

import importlib

__all__ = [
    "PlannerSettings",
    "Scenario",
    "ScenarioSource",
    "load_problem",
    "load_scenario",
    "multi_problem_from_scenario",
    "parse_scenario",
    "planner_settings",
    "problem_from_scenario",
]

_WHERE = {
    "Scenario": "loading",
    "load_scenario": "loading",
    "parse_scenario": "loading",
    "PlannerSettings": "planners",
    "ScenarioSource": "problems",
    "load_problem": "problems",
    "multi_problem_from_scenario": "straight",
    "planner_settings": "planners",
    "problem_from_scenario": "problems",
}


def __getattr__(name: str):
    if name in _WHERE:
        return getattr(importlib.import_module(f"needlekit.scenario.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'needlekit.scenario' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
