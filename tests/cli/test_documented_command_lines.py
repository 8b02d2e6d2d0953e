"""Every ``needlekit ...`` command line in the code blocks of README.md and docs/*.md still
parses, as do the examples of ``needlekit plan --help``. Parsed only,
never run. A line CHANGELOG.md lists as changed (``- `OLD` -> `NEW` `` under "### Command
line") is exempt, and its new form is parsed instead."""

from __future__ import annotations

import contextlib
import io
import re
import shlex
from pathlib import Path

import pytest

from needlekit.cli._parser import _build_parser

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
#: Where a command line ends: the rest is the shell's.
_SHELL = {"|", "||", "&&", ";", ">", ">>", "2>", "&"}


def _blocks(text: str):
    """The lines of every fenced code block."""
    inside = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            inside = not inside
        elif inside:
            yield line


def _command_lines(path: Path) -> list[str]:
    out, pending = [], ""
    for line in _blocks(path.read_text(encoding="utf-8")):
        line = pending + line.strip()
        pending = ""
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        line = line.removeprefix("$ ")
        if line.startswith("needlekit "):
            out.append(line)
    return out


def _argv(line: str) -> list[str]:
    words = shlex.split(line, comments=True)[1:]
    for i, w in enumerate(words):
        if w in _SHELL:
            return words[:i]
    return words


def _changed() -> dict[str, str]:
    """Old command line -> new, as CHANGELOG.md's "### Command line" sections list them."""
    path = ROOT / "CHANGELOG.md"
    if not path.exists():
        return {}
    changed, inside = {}, False
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("#"):
            inside = line.strip() == "### Command line"
        elif inside:
            m = re.match(r"^\s*- `(needlekit [^`]+)` -> `(needlekit [^`]+)`", line)
            if m:
                changed[m.group(1)] = m.group(2)
    return changed


def _parses(argv: list[str]) -> str | None:
    """None when ``argv`` parses (``--help`` included), else what argparse said."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            _build_parser().parse_args(argv)
        except SystemExit as exc:
            if exc.code not in (0, None):
                return err.getvalue().strip() or f"exit {exc.code}"
    return None


DOCUMENTED = [(p.relative_to(ROOT).as_posix(), line) for p in DOCS for line in _command_lines(p)]


def test_the_documents_hold_command_lines():
    files = {f for f, _ in DOCUMENTED}
    assert len(DOCUMENTED) >= 80 and {"README.md", "docs/steerable.md"} <= files


@pytest.mark.parametrize(
    ("doc", "line"), DOCUMENTED, ids=[f"{f}:{i}" for i, (f, _) in enumerate(DOCUMENTED)]
)
def test_every_documented_command_line_parses(doc, line):
    changed = _changed()
    cleaned = " ".join(_argv(line))
    for old, new in changed.items():
        if cleaned == " ".join(_argv(old)):
            line = new  # listed as changed: the new form must parse
    assert _parses(_argv(line)) is None, (doc, line, _parses(_argv(line)))


def test_the_changed_lines_new_forms_parse():
    for old, new in _changed().items():
        assert _parses(_argv(new)) is None, (old, new)


def test_the_examples_of_plan_help_parse():
    epilog = _build_parser()._subparsers._group_actions[0].choices["plan"].epilog
    lines = [ln.strip() for ln in epilog.splitlines() if "needlekit " in ln]
    assert len(lines) >= 4
    for ln in lines:
        assert _parses(_argv(ln[ln.index("needlekit ") :])) is None, ln


def test_the_line_reader_knows_the_shell():
    assert _argv("needlekit plan a.yaml --out p.json   # note") == [
        "plan",
        "a.yaml",
        "--out",
        "p.json",
    ]
    assert _argv("needlekit schema | head") == ["schema"]
    assert _parses(["plan", "a.yaml", "--bogus"]) is not None
