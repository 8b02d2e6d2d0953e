"""A misspelt command, flag, choice, planner, planner option or scenario key is answered
in one line naming it and the nearest right one (difflib), exit 2, before any work; no
flag may be abbreviated, so execute's ``--trial`` (the old name of ``--replay-trial``)
is refused with both meanings it may have had."""

from __future__ import annotations

from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.cli._parser import _build_parser, walk_commands

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = EXAMPLES / "toy.yaml"

CASES = [
    (["plna", "x"], "error: argument COMMAND: invalid choice: 'plna' (choose from 'kinematics', "
     "'schema', 'scene', 'plan', 'sweep', 'verify', 'cfrw', 'multi', 'approach', 'markups', "
     "'slicer', 'puncture', 'execute', 'report', 'demo', 'reproduce', 'study', 'bench', "
     "'cache'); did you mean "
     "plan?"),
    (["study", "feng-lung"], "error: argument STUDY: invalid choice: 'feng-lung' (choose from "
     "'livers', 'feng-lungs', 'execute-lungs'); did you mean feng-lungs?"),
    (["execute", "--truth", "kinematic", "{TOY}", "{TOY}", "--trails", "3"],
     "error: --trails: not a flag of needlekit execute; did you mean --trials?"),
    (["execute", "--truth", "kinematic", "{TOY}", "{TOY}", "--trial", "3"],
     "error: --trial: not a flag of needlekit execute; did you mean --trials N (how many "
     "trials) or --replay-trial K (run trial K alone)?"),
    (["execute", "--truth", "kinematic", "{TOY}", "{TOY}", "--trial=3"],
     "error: --trial: not a flag of needlekit execute; did you mean --trials N (how many "
     "trials) or --replay-trial K (run trial K alone)?"),
    (["plan", "{TOY}", "--plnner", "rcs"],
     "error: --plnner: not a flag of needlekit plan; did you mean --planner?"),
    # a prefix of a flag is not that flag (argparse's abbreviations are off)
    (["plan", "{TOY}", "--time-limit", "1"],
     "error: --time-limit: not a flag of needlekit plan; did you mean --time-limit-s?"),
    (["plan", "{TOY}", "--safety-margin", "1"],
     "error: --safety-margin: not a flag of needlekit plan; did you mean --safety-margin-mm?"),
    (["execute", "--truth", "kinematic", "{TOY}", "{TOY}", "--breathing", "lnug"],
     "error: argument --breathing: invalid choice: 'lnug' (choose from 'lung', 'liver'); did "
     "you mean lung?"),
    (["plan", "{TOY}", "--planner", "rcs_str"],
     "error: --planner: unknown planner 'rcs_str'; available: rcs_star, rcs, rrt, liu_cfrw; "
     "did you mean rcs_star?"),
    (["plan", "{TOY}", "--option", "resolutio.max_length_mm=8"],
     "error: --option resolutio.max_length_mm: unknown option (rcs_star takes resolution); "
     "did you mean resolution?"),
    # nothing near: argparse's own line, unchanged
    (["plan", "{TOY}", "--bogus"], "error: unrecognized arguments: --bogus"),
]


@pytest.mark.parametrize(("argv", "line"), CASES)
def test_a_misspelling_is_one_line_with_the_nearest_name(argv, line, capsys):
    argv = [a.replace("{TOY}", str(TOY)) for a in argv]
    assert _status(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [line]


def _status(argv) -> int:
    """The exit status, from the parser (SystemExit) or the command."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


def _with(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new)


@pytest.mark.parametrize(
    ("old", "new", "line"),
    [
        ("planner: {", "planer: {",
         "error: s.yaml: (top level): unknown field 'planer' (allowed: version, name, "
         "description, frame, base, structures, needle, start, goal, planner, straight, "
         "dynamic, collision_model, collision_options); did you mean planner?"),
        ("needle: {diameter_mm: 1.0,", "needle: {diameter_mm: 1.0, safety_margn_mm: 1,",
         "error: s.yaml: needle: unknown field 'safety_margn_mm' (allowed: diameter_mm, "
         "r_min_mm, max_length_mm, safety_margin_mm, max_heading_change_deg, "
         "min_puncture_angle_deg, start_exclusion_mm); did you mean safety_margin_mm?"),
    ],
)
def test_a_misspelt_scenario_key_names_the_right_one(old, new, line, tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text(_with(TOY.read_text(), old, new))
    assert main(["plan", str(path), "--out", str(tmp_path / "p.json")]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [line]
    assert not (tmp_path / "p.json").exists()


def test_no_parser_takes_abbreviations():
    parsers = [_build_parser()] + [p for _, p, _ in walk_commands(_build_parser())]
    assert len(parsers) > 20
    assert all(p.allow_abbrev is False for p in parsers)


def test_replay_trial_is_the_one_name_of_the_single_trial_flag():
    execute = dict((w, p) for w, p, _ in walk_commands(_build_parser()))[("execute",)]
    flags = set(execute._option_string_actions)
    assert {"--trials", "--replay-trial"} <= flags and "--trial" not in flags
