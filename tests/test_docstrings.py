"""Every public function documents its parameters and return value (numpydoc).

Every module of the package is walked (:func:`pkgutil.walk_packages`), so a new module is
covered without being listed here. A module's public functions are the ones its
``__all__`` names, or without ``__all__`` every function and class it defines whose name
does not start with ``_``; a class's public methods count too.

The one rule for skipping: a module whose import fails because an optional extra of
``pyproject.toml`` is not installed (:data:`OPTIONAL_EXTRAS`) is skipped, naming the extra.
Any other import error fails. ``__main__`` modules run the command line on import, by
design, and are not imported.
"""

import importlib
import inspect
import pkgutil
from pathlib import Path

import pytest

import needlekit

#: Top-level modules of the optional extras (``pip install 'needlekit[EXTRA]'``) by extra.
OPTIONAL_EXTRAS = {
    "dask": "dask",
    "distributed": "dask",
    "vtk": "paa",
    "marinholab": "tro2022",
    "quadprog": "quadprog",
}


def _module_names():
    return sorted(
        ["needlekit"]
        + [
            info.name
            for info in pkgutil.walk_packages(needlekit.__path__, "needlekit.")
            if info.name.rsplit(".", 1)[-1] != "__main__"
        ]
    )


MODULE_NAMES = _module_names()


def _import(module_name):
    try:
        return importlib.import_module(module_name), None
    except ModuleNotFoundError as exc:
        top = (exc.name or "").split(".")[0]
        if top in OPTIONAL_EXTRAS:
            return None, f"needs the optional extra [{OPTIONAL_EXTRAS[top]}] ({top})"
        raise


def _public_names(mod):
    if hasattr(mod, "__all__"):
        return list(mod.__all__)
    return [
        name
        for name, obj in vars(mod).items()
        if not name.startswith("_")
        and (inspect.isfunction(obj) or inspect.isclass(obj))
        and obj.__module__ == mod.__name__
    ]


def _public(mod):
    for name in _public_names(mod):
        obj = getattr(mod, name)
        if inspect.isfunction(obj):
            yield name, obj
        elif inspect.isclass(obj) and obj.__module__ == mod.__name__:
            for meth_name, meth in vars(obj).items():
                if inspect.isfunction(meth) and not meth_name.startswith("_"):
                    yield f"{name}.{meth_name}", meth


def _cases():
    out = []
    for module_name in MODULE_NAMES:
        mod, skip = _import(module_name)
        if mod is None:
            out.append(pytest.param(module_name, "", None, marks=pytest.mark.skip(reason=skip)))
            continue
        out += [pytest.param(module_name, n, f, id=f"{module_name}.{n}") for n, f in _public(mod)]
    return out


PUBLIC = _cases()


def test_the_walk_finds_every_module_of_the_package():
    root = Path(needlekit.__file__).parent
    on_disk = set()
    for path in root.rglob("*.py"):
        parts = path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__main__":
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        on_disk.add(".".join(("needlekit", *parts)))
    assert on_disk == set(MODULE_NAMES)
    # the modules the hand-kept list of earlier named are all among them
    for name in ("needlekit.planning.registry", "needlekit.io.medrad_paths"):
        assert name in MODULE_NAMES


@pytest.mark.parametrize(("module", "name", "fn"), PUBLIC)
def test_public_function_has_numpydoc_sections(module, name, fn):
    doc = inspect.getdoc(fn) or ""
    assert "Returns\n-------" in doc or "Yields\n------" in doc, (
        f"{module}.{name}: no Returns section"
    )
    params = [p for p in inspect.signature(fn).parameters if p not in ("self", "cls")]
    if params:
        assert "Parameters\n----------" in doc, f"{module}.{name}: no Parameters section"
    # functions of arrays state the shapes of what they take and give
    if "ndarray" in doc or "array_like" in doc:
        assert "shape" in doc, f"{module}.{name}: arrays without shapes"
