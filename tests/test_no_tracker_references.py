"""The project's text names no tracker issue a reader cannot open: every file git tracks in
the source, the tests, the docs, the examples and the top-level files is read, so a new
file is covered without being listed here. What a test or a doc checks is said in words,
not by the number of the issue that asked for it."""

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: The word (spelt in two parts here, so that this file passes its own test).
WORD = "iss" + "ue"
#: The word, singular or plural, then a number: with a space, a "#" or a "-" between.
TRACKER = re.compile(r"\b" + WORD + r"s?[\s#-]*\d+", re.IGNORECASE)
#: Suffixes of binary or generated files that hold no prose.
BINARY = {".png", ".jpg", ".gz", ".nii", ".nrrd", ".stl", ".mrb", ".npz", ".npy", ".pyc"}


def _tracked() -> list[Path]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                             check=True).stdout  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout: the tracked files are unknown")
    return [ROOT / name for name in out.decode().split("\0") if name]


def test_no_file_names_a_tracker_issue():
    found = []
    for path in _tracked():
        if path.suffix in BINARY or not path.is_file():
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue
        for n, line in enumerate(text.splitlines(), 1):
            if TRACKER.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()}")
    assert found == [], "\n".join(found)


def test_the_pattern_finds_what_it_is_for():
    w = WORD
    for line in (f"({w} 21, point 5)", f"{w.title()} 4: costs", f"{w}s 11 and 12", f"see {w} #39",
                 f"{w}-22"):  # fmt: skip
        assert TRACKER.search(line), line
    for line in (f"an {w} with the mesh", f"the {w}'s point", "tissue 2 mm", f"{w}d 3 times"):
        assert not TRACKER.search(line), line
