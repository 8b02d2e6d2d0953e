"""The static list of needlekit's own planners (names, families, option names checked
without importing the planners) against the planner classes themselves."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

import needlekit.planning.registry as registry
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import (
    BUILTIN_PLANNERS,
    BuiltinPlanner,
    check_planner_options,
    planner_class,
    planner_names,
    register_planner,
)
from needlekit.scenario.problems import planner_settings


@pytest.mark.parametrize("entry", BUILTIN_PLANNERS, ids=lambda e: e.name)
def test_each_entry_says_what_its_class_is(entry):
    cls = entry.load()
    assert cls.name == entry.name and cls.family == entry.family
    assert entry.option_names == tuple(f.name for f in dataclasses.fields(cls.options_type))
    assert entry.names(cls)
    # a declared capability is the class's, and "warm_start" is a keyword its solve takes
    assert entry.capabilities == tuple(getattr(cls, "capabilities", ()))
    takes = "warm_start" in inspect.signature(cls.solve).parameters
    assert ("warm_start" in entry.capabilities) == takes


def test_the_builtins_are_the_registry_s_first_planners_in_order():
    assert planner_names()[: len(BUILTIN_PLANNERS)] == [e.name for e in BUILTIN_PLANNERS]
    for entry in BUILTIN_PLANNERS:
        assert planner_class(entry.name) is entry.load()


@pytest.mark.parametrize(
    ("name", "options", "family"),
    [
        ("nope", {}, "steerable"),
        ("liu_cfrw", {}, "steerable"),
        ("rrt", {}, "straight"),
        ("rrt", {"bogus": 1, "also": 2}, "steerable"),
        ("rcs_star", {"seed": 3}, "steerable"),
        ("liu_cfrw", {"connection": "arc"}, "straight"),
    ],
)
def test_the_light_check_says_what_planner_settings_says(name, options, family):
    block = {"name": name, "options": options}
    with pytest.raises(InvalidInputError) as heavy:
        planner_settings(block, family=family)
    with pytest.raises(InvalidInputError) as light:
        check_planner_options(name, options, family=family)
    assert str(light.value) == str(heavy.value)


def test_a_planner_the_light_check_passes_is_built():
    for entry in BUILTIN_PLANNERS:
        check_planner_options(entry.name, {}, family=entry.family)
        planner_settings({"name": entry.name}, family=entry.family).build()


def test_the_registry_imports_a_builtin_only_when_it_is_needed(monkeypatch):
    monkeypatch.setattr(registry, "_REGISTRY", {})
    monkeypatch.setattr(registry, "_BUILTINS_LOADED", False)
    assert planner_names("steerable") == ["rcs_star", "rcs", "rrt"]
    assert all(isinstance(v, BuiltinPlanner) for v in registry._REGISTRY.values())
    cls = BUILTIN_PLANNERS[2].load()
    register_planner("rrt", cls)  # the class an entry stands for is the same planner
    assert registry._REGISTRY["rrt"] is cls
    with pytest.raises(InvalidInputError, match="already registered"):
        register_planner("rcs", cls)
    assert planner_class("rcs") is BUILTIN_PLANNERS[1].load()
    assert registry._REGISTRY["rcs"] is BUILTIN_PLANNERS[1].load()  # resolved once
