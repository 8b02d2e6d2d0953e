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
LAYERS: dict[str, float] = {
    "base": 0,
    "geometry": 1,
    "anatomy": 2,
    "needle": 2,
    "planning": 3,  # the shared interface: interface, registry, options, result
    "planning.steerable": 4,
    "planning.straight": 4,
    "control": 4,
    "mechanics": 4,
    "io": 4,
    # the deforming organ: above io (its precomputation is cached there), below execute
    # (which runs it in the loop)
    "tissue": 4.5,
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
#: conventions, validation (and its numeric gate), the result contract, provenance, the
#: batch executor, the memory estimate, the units' plausible ranges.
BASE = {
    "errors",
    "constants",
    "conventions",
    "_numbers",
    "_validation",
    "_validation_kernels",
    "records",
    "provenance",
    "batch",
    "memory",
    "plausibility",
    "registry",
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


def _from_module(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    """The absolute module a ``from ... import`` of module ``mod`` names (relative ones
    resolved)."""
    if not node.level:
        return node.module or ""
    base = mod.split(".") if is_pkg else mod.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _imports(mod: str, path: Path, known: dict[str, Path]) -> list[tuple[str, int]]:
    """(module imported, line) for every needlekit import of a module, at any depth."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            prefix = _from_module(mod, is_pkg, node)
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


# -- function-level imports: only to defer something heavy or optional --------------------

#: Third-party packages whose loading a function-level import may defer: slow to import
#: (numba compiles or loads its kernels; scipy, plotly, matplotlib, trimesh ...) or an
#: optional extra (dask, vtk, quadprog, the TRO 2022 wheel, selenium, pyigtl). numpy is
#: loaded by every module. From the standard library, ``importlib.metadata`` (the package's
#: version and the registries' entry points): 25-80 ms with the email parser it loads,
#: read by few commands.
DEFERRABLE = {
    "importlib.metadata",
    "numba", "scipy", "plotly", "matplotlib", "nibabel", "nrrd", "isal", "edt", "trimesh",
    "rtree", "skimage", "yaml", "jsonschema", "tqdm", "dqrobotics", "daqp", "dask",
    "distributed", "vtk", "marinholab", "quadprog", "selenium", "pyigtl", "pypardiso",
}  # fmt: skip

#: The command line and its start-up helpers defer what they like (a command loads only
#: what it runs).
DEFERRING_FREELY = ("needlekit.cli", "needlekit._warmup", "needlekit.__main__")


def _split_imports(mod: str, path: Path, known: dict[str, Path]):
    """(module-level names, [(line, names)] of function-level imports) of one module:
    needlekit modules resolved, other packages by their top name; imports under ``if
    TYPE_CHECKING`` left out."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_pkg = path.name == "__init__.py"
    top: set[str] = set()
    inner: list[tuple[int, set[str]]] = []

    def names_of(node) -> set[str]:
        if isinstance(node, ast.Import):
            raw = [a.name for a in node.names]
        else:
            prefix = _from_module(mod, is_pkg, node)
            raw = [prefix] + [f"{prefix}.{a.name}" for a in node.names if a.name != "*"]
        out = set()
        for name in raw:
            if name.split(".")[0] == "needlekit":
                target = _resolve(name, known)
                if target is not None and target != mod:
                    out.add(target)
            elif name.startswith("importlib.metadata"):  # the one standard module of note
                out.add("importlib.metadata")
            else:
                out.add(name.split(".")[0])
        return out

    def visit(node, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            if isinstance(child, ast.Import | ast.ImportFrom):
                if in_function:
                    inner.append((child.lineno, names_of(child)))
                else:
                    top.update(names_of(child))
            inner_fn = in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            visit(child, inner_fn)

    visit(tree, False)
    parts = mod.split(".")
    top.update(".".join(parts[:i]) for i in range(1, len(parts)) if ".".join(parts[:i]) in known)
    return top, inner


def _third_party_loaded(start: set[str], top: dict[str, set[str]]) -> set[str]:
    """The third-party packages that importing ``start`` loads, through module-level imports."""
    seen: set[str] = set()
    loaded: set[str] = set()
    stack = list(start)
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        if name in top:
            stack.extend(top[name])
            parts = name.split(".")
            stack.extend(".".join(parts[:i]) for i in range(1, len(parts)))
        elif not name.startswith("needlekit"):
            loaded.add(name)
    return loaded


def _needless_function_imports(known: dict[str, Path]) -> list[str]:
    split = {mod: _split_imports(mod, path, known) for mod, path in known.items()}
    top = {mod: names for mod, (names, _) in split.items()}
    bad = []
    for mod, (_, inner) in split.items():
        if mod.startswith(DEFERRING_FREELY):
            continue
        already = _third_party_loaded({mod}, top)
        for line, names in inner:
            deferred = (_third_party_loaded(names, top) - already) & DEFERRABLE
            if not deferred:
                bad.append(f"{mod}:{line} imports {', '.join(sorted(names))} inside a function")
    return bad


def test_function_level_imports_only_defer_heavy_or_optional_packages():
    """Outside the command line, an import inside a function must put off loading a heavy
    or optional package (:data:`DEFERRABLE`) that the module itself does not load; any
    other belongs at the top of the module (the layers keep that free of cycles)."""
    bad = _needless_function_imports(_modules())
    assert not bad, "move these to the top of their modules:\n" + "\n".join(bad)


def test_the_function_import_rule_tells_deferring_from_needless(tmp_path):
    """The checker itself, on a small package: deferring plotly passes, a light module or
    the standard library inside a function fails, the command line may defer anything."""
    pkg = tmp_path / "needlekit"
    (pkg / "cli").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "light.py").write_text("import json\n")
    (pkg / "figures.py").write_text("import plotly\n")
    (pkg / "cli" / "__init__.py").write_text("def main():\n    import needlekit.light\n")
    (pkg / "user.py").write_text(
        "def draw():\n    import needlekit.figures\n"
        "def parse():\n    import needlekit.light\n"
        "def now():\n    import time\n"
    )
    known = {
        "needlekit": pkg / "__init__.py",
        "needlekit.light": pkg / "light.py",
        "needlekit.figures": pkg / "figures.py",
        "needlekit.cli": pkg / "cli" / "__init__.py",
        "needlekit.user": pkg / "user.py",
    }
    bad = _needless_function_imports(known)
    assert bad == [
        "needlekit.user:4 imports needlekit.light inside a function",
        "needlekit.user:6 imports time inside a function",
    ]
