"""Every public function documents its parameters and return value (numpydoc)."""

import inspect

import pytest

import needlekit.geometry
import needlekit.needle

PUBLIC = [
    (mod.__name__, name, getattr(mod, name))
    for mod in (needlekit.geometry, needlekit.needle)
    for name in mod.__all__
    if inspect.isfunction(getattr(mod, name))
]


@pytest.mark.parametrize(("module", "name", "fn"), PUBLIC, ids=[f"{m}.{n}" for m, n, _ in PUBLIC])
def test_public_function_has_numpydoc_sections(module, name, fn):
    doc = inspect.getdoc(fn) or ""
    assert "Returns\n-------" in doc, f"{module}.{name}: no Returns section"
    if inspect.signature(fn).parameters:
        assert "Parameters\n----------" in doc, f"{module}.{name}: no Parameters section"
    # every documented batch shape states its dimensions
    assert "shape" in doc or "bool" in doc or "int" in doc, f"{module}.{name}: no shapes given"
