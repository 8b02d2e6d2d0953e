"""The README's lung-nodule walkthrough, run as written: every ``$ needlekit ...`` line of
its section, in order, in a fresh folder, prints what the README shows (timings masked)
and exits as the README says. A newcomer who follows only the README meets what it
promises; a change to a command's output that the README does not follow fails here.

The prepared-anatomy cache is shared with the other real-data tests (the ``cache`` lines,
whose entries and ages depend on the machine, are parsed, not run)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.cli._parser import _build_parser

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
SECTION = "## A lung nodule, end to end"


def _steps() -> list[tuple[str, list[str]]]:
    """(command line, expected stdout lines) of every console block of the section."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    body = text.split(SECTION, 1)[1].split("\n## ", 1)[0]
    steps, inside, current = [], False, None
    for line in body.splitlines():
        if line.startswith("```"):
            inside = line.strip() == "```console"
            current = None
            continue
        if not inside:
            continue
        if line.startswith("$ needlekit "):
            current = (line[2:], [])
            steps.append(current)
        elif current is not None and not line.startswith("WARNING "):  # stderr's
            current[1].append(line)
    return steps


#: What changes from run to run: search and set-up times, the export's time, the
#: re-plans' latency (the last column of the execute table), the cache's ages.
_TIMES = [
    (re.compile(r"\(\d+\.\d ms search, \d+\.\d ms set-up\)"), "(T ms search, T ms set-up)"),
    (re.compile(r"\(\d+\.\d s\)$"), "(T s)"),
    (re.compile(r"^(closed loop .*\s)\d+\.\d{4}$"), r"\1T"),
]


def _masked(lines: list[str]) -> list[str]:
    out = []
    for line in lines:
        line = line.rstrip()
        for pattern, repl in _TIMES:
            line = pattern.sub(repl, line)
        out.append(line)
    return out


def test_the_section_holds_the_steps_a_newcomer_needs():
    commands = [shlex.split(c)[1] for c, _ in _steps()]
    for step in ("plan", "verify", "execute", "slicer", "report", "cache"):
        assert step in commands, step
    assert (ROOT / "docs" / "img" / "plan-lung1.png").is_file()
    assert "plan-lung1.png" in (ROOT / "README.md").read_text(encoding="utf-8")


def test_every_step_prints_what_the_readme_shows(medrad_dir, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("NEEDLEKIT_MEDRAD", str(medrad_dir))
    monkeypatch.chdir(tmp_path)
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    ran = 0
    for line, expected in _steps():
        argv = shlex.split(line)[1:]
        if argv[0] == "cache":  # the machine's own entries: the line must parse
            _build_parser().parse_args(argv)
            continue
        margin = "--safety-margin-mm" in argv
        capsys.readouterr()
        status = main(argv)
        out = capsys.readouterr().out.splitlines()
        assert status == (1 if margin else 0), line
        assert _masked(out) == _masked(expected), line
        ran += 1
    assert ran == 6
    # the walkthrough's files, where the README says they are
    for name in ("plan.json", "plan.html", "execute/execute.json", "execute.html",
                 "lung1.mrb", "case.html", "plan.failed.json"):  # fmt: skip
        assert (tmp_path / "case" / name).is_file(), name
