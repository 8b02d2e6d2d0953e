"""One line, naming the culprit (issue "Fail safe", point 6).

Bad files and values swept over the commands: stderr is exactly one line starting
``error: ``, it names the flag or the file at fault, and it holds no internal name of
needlekit (a module path, a function or class name that is not part of a file format) and
no library's words about itself (``No module named``, a traceback); a library's own log
lines (nibabel's header notes) and Python warnings never precede it.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import struct
from functools import cache
from pathlib import Path

import pytest

from needlekit.cli import main

ROOT = Path(__file__).resolve().parents[2]
SRC = ROOT / "src" / "needlekit"
EXAMPLES = ROOT / "examples"
TOY = str(EXAMPLES / "toy.yaml")
MULTI = str(EXAMPLES / "liver_phantom_multi.yaml")


@cache
def internal_names() -> frozenset[str]:
    """needlekit's function and class names that no file format or message uses as a word:
    every ``def`` and ``class`` name with an underscore or a capital inside, less the
    identifiers the code writes as strings (field names, keys, kinds), except in
    ``__all__``."""
    defs, words = set(), set()
    for path in SRC.rglob("*.py"):
        tree = ast.parse(path.read_text())
        exported = {
            id(c)
            for node in ast.walk(tree)
            if isinstance(node, ast.Assign)
            and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)
            for c in ast.walk(node.value)
        }
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                defs.add(node.name)
            elif (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and id(node) not in exported
                and node.value.isidentifier()
            ):
                words.add(node.value)
    return frozenset(
        d for d in defs - words if "_" in d.strip("_") or re.search(r"[a-z][A-Z]", d)
    )


def leaks(line: str) -> set[str]:
    """The internal names, module paths and library self-talk in an error line."""
    tokens = set(re.findall(r"[A-Za-z_][A-Za-z0-9_.]*[A-Za-z0-9_]", line))
    found = {t for t in tokens if t in internal_names() or t.startswith("needlekit.")}
    found |= {p for p in ("No module named", "Traceback", "Error:", "object has no") if p in line}
    return found


def test_the_leak_check_sees_internal_names():
    assert "samples_for_spacing" in internal_names()
    assert leaks("error: x: overflow in samples_for_spacing") == {"samples_for_spacing"}
    assert leaks("error: a.stl: cannot read mesh: No module named '...'") == {"No module named"}
    assert leaks("error: plan.json: goal_mm: expected three finite numbers") == set()


def test_no_line_of_the_bad_input_table_leaks_an_internal_name():
    spec = importlib.util.spec_from_file_location(
        "bad_input_table", Path(__file__).with_name("test_bad_input_table.py")
    )
    table = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(table)
    leaked = {line: leaks(line) for _, line in table.ROWS if leaks(line)}
    assert leaked == {}


# -- the sweep ---------------------------------------------------------------------------------


def _nifti_without_orientation() -> bytes:
    """A NIfTI-1 header nibabel reads with a log line (pixdim 0) and no sform or qform."""
    h = bytearray(348)
    struct.pack_into("<i", h, 0, 348)
    struct.pack_into("<8h", h, 40, 3, 2, 2, 2, 1, 1, 1, 1)
    struct.pack_into("<hh", h, 70, 2, 8)  # uint8
    struct.pack_into("<f", h, 108, 352.0)
    h[344:348] = b"n+1\x00"
    return bytes(h) + b"\x00" * 4 + b"\x01" * 8


def _files(d: Path) -> dict[str, Path]:
    """Bad files by name; each scenario's culprit is the file it names."""
    texts = {
        "empty.yaml": "",
        "garbage.yaml": "\x00\x01binary: [",
        "nan.json": '{"goal_mm": [NaN, 0, 0], "primitives": []}',
        "huge.json": '{"goal_mm": [1, 2, 3], "primitives": [{"rotation_rad": 0, '
        '"curvature_per_mm": 1e308, "length_mm": 5}], "start_pose": '
        "[[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}",
        "list.json": "[1, 2]",
        "pose.txt": "1 0 0 inf\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
        "open.stl": "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
        "vertex 0 1 0\nendloop\nendfacet\nendsolid x\n",
        "huge.obj": "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1e308\nf 1 2 3\nf 1 2 4\nf 1 3 4\nf 2 3 4\n",
    }
    out = {}
    for name, text in texts.items():
        out[name] = d / name
        out[name].write_text(text)
    for name, data in (
        ("garbage.stl", bytes(range(256)) * 2),
        ("garbage.nii", b"\x13\x37" * 300),
        ("weird.nii", _nifti_without_orientation()),
    ):
        out[name] = d / name
        out[name].write_bytes(data)
    for name in ("garbage.stl", "open.stl", "huge.obj", "garbage.nii", "weird.nii"):
        kind = "mask" if name.endswith(".nii") else "mesh"
        doc = d / f"with-{name}.yaml"
        doc.write_text(
            f"version: 1\nstructures:\n  - {{name: a, role: obstacle, {kind}: {{path: {name}}}}}\n"
        )
        out[doc.name] = doc
    return out


@pytest.fixture(scope="module")
def bad(tmp_path_factory) -> tuple[dict[str, Path], Path, str]:
    d = tmp_path_factory.mktemp("bad")
    plan = d / "plan.json"
    assert main(["plan", TOY, "--out", str(plan)]) == 0
    return _files(d), d, str(plan)


#: Per command, where a bad file goes: X is the file.
SLOTS = [
    ["plan", "X"],
    ["sweep", "X", "--directions", "2"],
    ["verify", "X", "PLAN"],
    ["verify", TOY, "X"],
    ["cfrw", "X"],
    ["multi", "X"],
    ["approach", "X"],
    ["markups", "X", "--out", "OUT/m.mrk.json"],
    ["execute", "--truth", "kinematic", TOY, "X", "--trials", "1"],
    ["report", "X", "--out", "OUT/r.html"],
    ["scene", "info", "X"],
    ["scene", "render", "X", "--out", "OUT/s.html"],
    ["kinematics", "forward", "--kappa-per-mm", "0.01", "--segment", "1,0,1", "--start-pose", "X"],
    ["plan", TOY, "--start-pose", "X"],
]

#: Which bad files each slot takes (a scenario, a plan or record, a pose).
_SCENARIOS = ("empty.yaml", "garbage.yaml", "missing.yaml", "with-garbage.stl.yaml",
              "with-open.stl.yaml", "with-huge.obj.yaml", "with-garbage.nii.yaml",
              "with-weird.nii.yaml")  # fmt: skip
_RECORDS = ("nan.json", "huge.json", "list.json", "garbage.yaml", "missing.json")
_POSES = ("pose.txt", "garbage.yaml", "missing.txt")


def _kinds(slot: list[str]) -> tuple[str, ...]:
    if "--start-pose" in slot:
        return _POSES
    if slot[0] in ("markups", "report") or (slot[-1] == "X" and slot[0] == "verify"):
        return _RECORDS
    if slot[0] == "execute":
        return _RECORDS
    return _SCENARIOS


def _culprits(slot: list[str], name: str) -> tuple[str, ...]:
    """What the line may name: the file a scenario points at, else the file; for the
    straight commands the scenario too (a scenario without a straight block is refused
    before its anatomy is read)."""
    if not name.startswith("with-"):
        return (name,)
    inner = name.removeprefix("with-").removesuffix(".yaml")
    return (inner, name) if slot[0] in ("cfrw", "multi", "approach") else (inner,)


CASES = [(slot, name) for slot in SLOTS for name in _kinds(slot)]


@pytest.mark.parametrize(
    ("slot", "name"), CASES, ids=[f"{' '.join(s[:2])}-{n}" for s, n in CASES]
)
def test_a_bad_file_is_one_line_naming_it(slot, name, bad, capsys):
    files, d, plan = bad
    path = files.get(name, d / name)
    argv = [
        str(path) if a == "X" else plan if a == "PLAN" else a.replace("OUT", str(d))
        for a in slot
    ]
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (argv, err)
    assert any(c in lines[0] for c in _culprits(slot, name)), (argv, err)
    assert leaks(lines[0]) == set(), (argv, lines[0])


def test_a_library_log_line_never_precedes_the_error(bad, capsys):
    files, _, _ = bad
    code = main(["scene", "info", str(files["with-weird.nii.yaml"])])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "pixdim" not in err
    assert err.startswith("error: ")
    assert "weird.nii: NIfTI header has neither sform nor qform" in err
