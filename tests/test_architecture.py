"""The layers of docs/architecture.md hold for every import in src/needlekit.

Every module's imports are read from its syntax tree, those inside functions (and under
``if TYPE_CHECKING``) too; each module is mapped to its layer by :data:`LAYERS`. The test
fails on any import cycle between modules, and on any import that points up or sideways
(between two blocks of one floor), listing each.
"""

from __future__ import annotations

import ast
from pathlib import Path

import needlekit

SRC = Path(needlekit.__file__).resolve().parent

#: The floor of each block, low to high (docs/architecture.md). Blocks on one floor share
#: only what sits below them. A module's block is the longest key that prefixes its name
#: (``needlekit.planning.steerable.rcs`` -> ``planning.steerable``).
LAYERS: dict[str, int] = {
    "base": 0,
    "geometry": 1,
    "anatomy": 2,
    "needle": 2,
    "planning": 3,  # the shared interface: interface, registry, options, result
    "planning.steerable": 4,
    "planning.straight": 4,
    "control": 4,
    "io": 4,
    "execute": 5,
    "report": 6,
    "scenario": 6,
    "studies": 7,
    "reproduce": 8,
    "benchmarks": 8,
    "cli": 9,
    "_warmup": 9,
    "__main__": 9,
}

#: The base floor, one block (its modules import one another): errors, constants,
#: conventions, validation, the result contract, provenance, the batch executor.
BASE = {
    "errors",
    "constants",
    "conventions",
    "_validation",
    "_validation_kernels",
    "records",
    "provenance",
    "batch",
}

#: Cycles tolerated for now (none: the test fails on any cycle, and on an entry here that
#: no longer cycles, so the expectation stays exact).
KNOWN_CYCLES: set[frozenset[str]] = set()


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(SRC.rglob("*.py"))}


def _resolve(name: str, known: dict[str, Path]) -> str | None:
    """The needlekit module (or package) a dotted name refers to."""
    parts = name.split(".")
    while parts:
        if ".".join(parts) in known:
            return ".".join(parts)
        parts.pop()
    return None


def _imports(mod: str, path: Path, known: dict[str, Path]) -> list[tuple[str, int]]:
    """(module imported, line) for every needlekit import of a module, at any depth."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".") if is_pkg else mod.split(".")[:-1]
                base = base[: len(base) - (node.level - 1)]
                prefix = ".".join(base + ([node.module] if node.module else []))
            else:
                prefix = node.module or ""
            names = [f"{prefix}.{a.name}" if a.name != "*" else prefix for a in node.names]
        else:
            continue
        for name in names:
            if name.split(".")[0] == "needlekit":
                target = _resolve(name, known)
                if target is not None and target not in (mod, "needlekit"):
                    out.append((target, node.lineno))
    return out


def _block(mod: str) -> str:
    rest = mod.split(".")[1:]
    if rest and rest[0] in BASE:
        return "base"
    for n in range(len(rest), 0, -1):
        key = ".".join(rest[:n])
        if key in LAYERS:
            return key
    raise AssertionError(f"{mod}: not in the layer table (tests/test_architecture.py LAYERS)")


def _graph() -> tuple[dict[str, set[str]], list[tuple[str, int, str]]]:
    known = _modules()
    graph: dict[str, set[str]] = {m: set() for m in known}
    edges = []
    for mod, path in known.items():
        for target, line in _imports(mod, path, known):
            graph[mod].add(target)
            edges.append((mod, line, target))
    return graph, edges


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(frozenset(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_every_module_has_a_layer():
    for mod in _modules():
        if mod != "needlekit":
            _block(mod)


def test_no_import_cycle():
    graph, _ = _graph()
    cycles = set(_cycles(graph))
    new = [" <-> ".join(sorted(c)) for c in cycles - KNOWN_CYCLES]
    assert not new, "import cycles:\n" + "\n".join(new)
    # a known cycle that is gone must leave the list (the expectation stays exact)
    gone = [" <-> ".join(sorted(c)) for c in KNOWN_CYCLES - cycles]
    assert not gone, "no longer cycles; remove from KNOWN_CYCLES:\n" + "\n".join(gone)


def test_imports_point_down():
    _, edges = _graph()
    bad = []
    for mod, line, target in edges:
        if mod == "needlekit":
            continue  # the package's own __init__ (version only)
        src, dst = _block(mod), _block(target)
        if src == dst:
            continue
        if LAYERS[dst] > LAYERS[src]:
            bad.append(f"upward: {mod}:{line} -> {target} ({src} -> {dst})")
        elif LAYERS[dst] == LAYERS[src]:
            bad.append(f"sideways: {mod}:{line} -> {target} ({src} -> {dst})")
    assert not bad, "imports against the layers:\n" + "\n".join(bad)


def test_the_walk_sees_imports_inside_functions(tmp_path):
    """The checker itself: a function-level import counts as an edge."""
    mod = tmp_path / "m.py"
    mod.write_text("def f():\n    from needlekit.errors import InvalidInputError\n")
    known = {"needlekit.errors": SRC / "errors.py"}
    assert _imports("needlekit.m", mod, known) == [("needlekit.errors", 2)]
