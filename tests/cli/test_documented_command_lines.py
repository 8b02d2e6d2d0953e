"""Every ``needlekit ...`` command line in the code blocks of README.md and docs/*.md still
parses, as do the examples of ``needlekit plan --help``. Parsed only,
never run. A line CHANGELOG.md lists as changed (``- `OLD` -> `NEW` `` under "### Command
line") is exempt, and its new form is parsed instead.

The prose's inline spans (`` `needlekit ...` ``, which may wrap over lines) are read too:
a span with two or more flags is a line a reader may copy and must parse in full, its
required arguments included; a shorter one names a command or a flag (`` `needlekit multi
--report` ``) and must parse but for what it leaves out: every flag it names exists and
every value it gives is valid. A synopsis (``...``, ``[optional]``, ``a|b``) is not
parsed, nor a value that is a placeholder the reader fills in (``--trials N``)."""

from __future__ import annotations

import argparse
import contextlib
import functools
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


#: Marks of a synopsis, not a line to run: an elision, an optional part, alternatives.
_SYNOPSIS = ("...", "[", "|")


def _inline_lines(path: Path) -> list[str]:
    """The inline ``needlekit ...`` spans of the prose (fenced blocks left out), each
    span's whitespace, line breaks included, made one space."""
    prose = re.sub(r"^\s*```.*?^\s*```", "", path.read_text(encoding="utf-8"), flags=re.S | re.M)
    return [" ".join(m.group(1).split()) for m in re.finditer(r"`(needlekit [^`]+)`", prose)]


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


def _parses(argv: list[str], parser=None) -> str | None:
    """None when ``argv`` parses (``--help`` included), else what argparse said."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            (parser or _strict_parser()).parse_args(argv)
        except SystemExit as exc:
            if exc.code not in (0, None):
                return err.getvalue().strip() or f"exit {exc.code}"
    return None


@functools.cache
def _strict_parser() -> argparse.ArgumentParser:
    """The command line's parser, built once (parsing leaves it as it was)."""
    return _build_parser()


@functools.cache
def _lenient_parser() -> argparse.ArgumentParser:
    """The command line's parser with nothing required (arguments, groups, subcommands):
    what a span leaves out is not an error, what it gives is checked as ever."""
    parser = _build_parser()
    todo = [parser]
    while todo:
        p = todo.pop()
        for group in p._mutually_exclusive_groups:
            group.required = False
        for action in p._actions:
            action.required = False
            if isinstance(action, argparse._SubParsersAction):
                todo.extend(action.choices.values())
    return parser


def _inline_error(line: str) -> str | None:
    """What is wrong with an inline span (module notes), or None."""
    if any(mark in line for mark in _SYNOPSIS):
        return None
    argv = _argv(line)
    full = sum(w.startswith("--") for w in argv) >= 2
    parser = None if full else _lenient_parser()
    err = _parses(argv, parser)
    if err and not full and argv[-1].startswith("--") and "expected one argument" in err:
        err = _parses([*argv, "X"], parser)  # a flag named, its value left out
    # a placeholder the reader fills in (N, DIR, X,Y,Z), refused for its type: a synopsis
    if err and any(f"'{w}'" in err for w in re.findall(r"\b[A-Z][A-Z0-9_,.]*\b", line + " X")):
        return None
    return err


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


INLINE = [(p.relative_to(ROOT).as_posix(), line) for p in DOCS for line in _inline_lines(p)]


def test_the_prose_holds_inline_command_lines():
    assert len(INLINE) >= 150
    assert any("\n" not in line and line.count("--") >= 2 for _, line in INLINE)


@pytest.mark.parametrize(
    ("doc", "line"), INLINE, ids=[f"{f}:inline{i}" for i, (f, _) in enumerate(INLINE)]
)
def test_every_inline_command_line_parses(doc, line):
    changed = _changed()
    cleaned = " ".join(_argv(line)) if not any(m in line for m in _SYNOPSIS) else None
    for old, new in changed.items():
        if cleaned == " ".join(_argv(old)):
            line = new
    assert _inline_error(line) is None, (doc, line, _inline_error(line))


def test_the_inline_reader_tells_a_line_from_a_reference(tmp_path):
    # a line to copy must be whole; a reference may leave out what it does not name
    assert "--out" in _inline_error("needlekit study execute-lungs --patients 1 --trials 100")
    assert _inline_error("needlekit study execute-lungs --patients 1 --trials 100 --out D") is None
    assert _inline_error("needlekit execute") is None
    assert _inline_error("needlekit multi --report") is None
    assert _inline_error("needlekit multi --bogus") is not None
    assert _inline_error("needlekit plan --max-iterations many") is not None
    # a placeholder is a synopsis; a real value of the wrong type is not
    assert _inline_error("needlekit puncture --trials N --out DIR") is None
    assert _inline_error("needlekit puncture --trials many --out DIR") is not None
    assert _inline_error("needlekit plan SCENARIO --goals X,Y,Z ... --report page.html") is None
    # a span wrapped over two lines of the source is read as one line
    doc = tmp_path / "wrapped.md"
    doc.write_text("Run `needlekit study execute-lungs --patients 1\n--trials 100` now.\n")
    assert _inline_lines(doc) == ["needlekit study execute-lungs --patients 1 --trials 100"]


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
