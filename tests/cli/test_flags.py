"""The command line declared per command: every flag several commands
share is made by its one definition in :mod:`needlekit.cli._flags`, and planner options
pass as ``--option NAME=VALUE``, typed as the planner declares them."""

from __future__ import annotations

import ast
import dataclasses
from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.cli._flags import SHARED_FLAGS, TIME_LIMIT_S, Flag
from needlekit.cli._options import planner_flag_options
from needlekit.cli._parser import _build_parser, walk_commands
from needlekit.cli.puncture import ADAPTATION_DELAY_MS
from needlekit.errors import InvalidInputError
from needlekit.planning.registry import (
    BUILTIN_PLANNERS,
    _dataclass_types,
    option_types,
    register_planner,
    unregister_planner,
)
from needlekit.scenario.problems import planner_settings

CLI = Path(__file__).resolve().parents[2] / "src" / "needlekit" / "cli"
TOY = str(Path(__file__).resolve().parents[2] / "examples" / "toy.yaml")

#: Every shared flag: those of :mod:`needlekit.cli._flags` and puncture's (with bench control).
SHARED = {**SHARED_FLAGS, ADAPTATION_DELAY_MS.name: ADAPTATION_DELAY_MS}

#: Arguments that share a shared flag's name but are another flag, and why.
NOT_THE_SHARED_FLAG = {
    ("bench", "scale", "--directions"): "the sweep sizes of the series (a list)",
    ("bench", "scale", "--workers"): "the pool sizes of the series (a list)",
    ("bench", "scale", "--dask-workers"): "the Dask cluster sizes of the series (a list)",
}


def _arguments():
    """``(command words, option string, action)`` of every flag of every command."""
    for words, parser, group in walk_commands(_build_parser()):
        if group is None:
            for action in parser._actions:
                for opt in action.option_strings:
                    yield words, opt, action


def test_every_shared_flag_comes_from_its_one_definition():
    seen: dict[str, int] = {}
    for words, opt, action in _arguments():
        if opt not in SHARED or (*words, opt) in NOT_THE_SHARED_FLAG:
            continue
        assert getattr(action, "flag", None) is SHARED[opt], (words, opt)
        for key, value in SHARED[opt].kwargs.items():
            if key not in ("folder", "dest", "action"):
                assert getattr(action, key) == value, (words, opt, key)
        seen[opt] = seen.get(opt, 0) + 1
    assert set(seen) == set(SHARED)  # every definition is used
    assert all(n >= 2 for n in seen.values()), seen  # and shared
    assert seen["--time-limit-s"] == 6  # plan, sweep, multi, study feng-lungs, bench x2


def test_the_exceptions_are_other_flags_not_copies():
    found = {(*w, o): a for w, o, a in _arguments() if (*w, o) in NOT_THE_SHARED_FLAG}
    assert set(found) == set(NOT_THE_SHARED_FLAG)
    for action in found.values():
        assert action.nargs == "+" and not hasattr(action, "flag")


def _literal_flag_definitions():
    """Every call in cli/ that defines an argument or a Flag by a literal option string."""
    for path in sorted(CLI.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.Call) and node.args):
                continue
            first = node.args[0]
            if not (isinstance(first, ast.Constant) and isinstance(first.value, str)):
                continue
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("add_argument", "add_input", "add_output", "Flag"):
                yield path.name, name, first.value


def test_no_module_adds_a_shared_flag_by_hand():
    defs = list(_literal_flag_definitions())
    for opt in SHARED:
        made = [(f, n) for f, n, o in defs if o == opt]
        by_hand = [(f, n) for f, n in made if n != "Flag"]
        assert [n for _, n in made].count("Flag") == 1, (opt, made)
        assert all(("bench.py", "add_argument") == m for m in by_hand), (opt, by_hand)


def test_a_command_cannot_redefine_what_the_definition_holds():
    import argparse

    with pytest.raises(TypeError, match="shared definition"):
        TIME_LIMIT_S.add(argparse.ArgumentParser(), type=int)
    assert isinstance(TIME_LIMIT_S, Flag)


# -- --option NAME=VALUE ----------------------------------------------------------------------


@pytest.mark.parametrize("entry", BUILTIN_PLANNERS, ids=lambda e: e.name)
def test_the_declared_option_types_are_the_classes(entry):
    cls = entry.load()
    assert option_types(entry.name) == _dataclass_types(cls.options_type)
    assert tuple(option_types(entry.name)) == entry.option_names


def test_options_are_typed_as_declared():
    got = planner_flag_options(
        [
            ("resolution.max_length_mm", "8"),
            ("resolution.spin_levels", "3"),
            ("connection", "arc"),
            ("seed", "7"),
        ],
        ["rcs_star", "rrt"],
    )
    assert got == {
        "rcs_star": {"resolution": {"max_length_mm": 8.0, "spin_levels": 3}},
        "rrt": {"connection": "arc", "seed": 7},
    }
    assert isinstance(got["rcs_star"]["resolution"]["spin_levels"], int)
    assert planner_flag_options(None, ["rcs"]) == {"rcs": {}}
    assert planner_flag_options([("order", "3, 1,2")], ["liu_cfrw"]) == {
        "liu_cfrw": {"order": (3, 1, 2)}
    }


def test_a_field_replaces_only_that_field_of_the_scenario_s():
    block = {"resolution": {"max_length_mm": 16.0, "length_levels": 5}}
    flags = {"resolution": {"max_length_mm": 8.0}}
    got = planner_settings({"name": "rcs_star", "options": block}, options={"rcs_star": flags})
    assert got.options["rcs_star"] == {"resolution": {"max_length_mm": 8.0, "length_levels": 5}}
    assert block == {"resolution": {"max_length_mm": 16.0, "length_levels": 5}}


@pytest.mark.parametrize(
    ("pairs", "planners", "message"),
    [
        (
            [("bogus", "1")],
            ["rcs_star"],
            "--option bogus: unknown option (rcs_star takes resolution)",
        ),
        ([("seed", "1.5")], ["rrt"], "--option seed: rrt: expected a whole number, got '1.5'"),
        (
            [("resolution.max_length_mm", "x")],
            ["rcs"],
            "--option resolution.max_length_mm: rcs: expected a number, got 'x'",
        ),
        (
            [("resolution.max_length_mm", "inf")],
            ["rcs"],
            "expected a number in [-1e+06, 1e+06] mm, got 'inf'",
        ),
        ([("seed", "1" + "0" * 30)], ["rrt"], "expected a whole number in ["),
        ([("resolution", "8")], ["rcs"], "give resolution.FIELD=VALUE"),
        ([("resolution.nope", "1")], ["rcs"], "unknown: nope"),
        ([("connection.x", "1")], ["rrt"], "rrt's connection has no fields"),
        ([("order", "1,x")], ["liu_cfrw"], "whole numbers separated by commas"),
        ([("seed", "2")], ["rcs_star", "rcs"], "rcs_star takes resolution; rcs takes resolution"),
    ],
)
def test_an_unknown_name_or_a_wrong_type_is_one_error_naming_the_flag(pairs, planners, message):
    with pytest.raises(InvalidInputError, match=r"^--option ") as exc:
        planner_flag_options(pairs, planners)
    assert message in str(exc.value)


@dataclasses.dataclass(frozen=True)
class _PlugOptions:
    depth: int = 1
    gain: float = 0.5
    greedy: bool = False
    label: str = "a"
    cap: int | None = None


class _PlugPlanner:
    name = "plug_opts"
    family = "steerable"
    options_type = _PlugOptions

    def __init__(self, options=None):
        self.options = options

    def solve(self, problem, termination):  # pragma: no cover - never run here
        raise NotImplementedError


def test_a_plug_in_s_options_are_typed_from_its_class():
    register_planner("plug_opts", _PlugPlanner)
    try:
        assert option_types("plug_opts") == {
            "depth": int, "gain": float, "greedy": bool, "label": str, "cap": int,
        }  # fmt: skip
        pairs = [("depth", "3"), ("gain", "2"), ("greedy", "yes"), ("label", "x=y"), ("cap", "4")]
        assert planner_flag_options(pairs, ["plug_opts"]) == {
            "plug_opts": {"depth": 3, "gain": 2.0, "greedy": True, "label": "x=y", "cap": 4}
        }
        assert planner_flag_options([("greedy", "off")], ["plug_opts"])["plug_opts"] == {
            "greedy": False
        }
        with pytest.raises(InvalidInputError, match="expected true or false"):
            planner_flag_options([("greedy", "maybe")], ["plug_opts"])
    finally:
        unregister_planner("plug_opts")


def test_the_parser_reads_name_equals_value():
    args = _build_parser().parse_args(
        ["plan", "x.yaml", "--option", "a=1", "--option", "resolution.max_length_mm = 8"]
    )
    assert args.option == [("a", "1"), ("resolution.max_length_mm", "8")]
    args = _build_parser().parse_args(["sweep", "x.yaml", "--option", "label=x=y"])
    assert args.option == [("label", "x=y")]
    assert _build_parser().parse_args(["plan", "x.yaml"]).option is None


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["plan", TOY, "--option", "bogus=1"], "error: --option bogus: unknown option"),
        (["plan", TOY, "--option", "resolution.spin_levels=two"], "expected a whole number"),
        (["plan", TOY, "--option", "=1"], "error: argument --option: expected NAME=VALUE"),
        (["plan", TOY, "--planner", "rrt", "--option", "seed=1", "--seed", "2"], "--seed"),
        (["plan", TOY, "--planner", "rrt", "--option", "connection=arc", "--rrt-connection", "arc"],
         "also given as --rrt-connection"),
        (["sweep", TOY, "--planner", "rcs_star", "rcs", "--option", "connection=arc"],
         "error: --option connection: unknown option"),
    ],
)  # fmt: skip
def test_option_errors_exit_2_on_one_line(capsys, tmp_path, argv, message):
    try:
        code = main([*argv, "--out", str(tmp_path / "out.json")])
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert message in err[0]


def test_the_options_reach_the_planner_settings():
    from needlekit.cli.planning import _settings

    doc = {"planner": {"name": "rcs_star", "options": {"resolution": {"length_levels": 5}}}}
    argv = ["plan", "x.yaml", "--option", "resolution.max_length_mm=8"]
    args = _build_parser().parse_args(argv)
    settings = _settings(args, doc)
    assert settings.names == ("rcs_star",)
    assert settings.options["rcs_star"]["resolution"] == {"length_levels": 5, "max_length_mm": 8.0}
    argv = ["sweep", "x.yaml", "--planner", "rcs", "rrt", "--option", "seed=4"]
    args = _build_parser().parse_args(argv)
    settings = _settings(args, {})
    assert settings.options["rrt"]["seed"] == 4 and "seed" not in settings.options["rcs"]


def test_main_builds_the_parser_once_and_hands_each_call_its_own_defaults(monkeypatch):
    import needlekit.cli as cli
    from needlekit.cli._parser import _build_parser as build

    built = []

    def counting():
        built.append(1)
        return build()

    monkeypatch.setattr(cli, "_build_parser", counting)
    argv = ["study", "execute-lungs", "--out", "o"]
    _, first = cli._parse(argv)
    first.patients.append(99)  # a command that changes its arguments
    _, second = cli._parse(argv)
    assert len(built) == 1
    assert first.patients == [1, 2, 3, 4, 5, 99] and second.patients == [1, 2, 3, 4, 5]
    assert build().parse_args(argv).patients == [1, 2, 3, 4, 5]
