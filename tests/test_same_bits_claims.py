"""A scalar path that claims numpy's bits must not take its transcendentals from libm.

numpy's float64 loops for ``arctan2``, ``arccos``, ``exp``, ``log`` and most other
transcendentals are SIMD code on AVX-512 machines, rounding differently from libm (and so
from ``math``) in up to a third of the results; called on one number they run the same loop,
so a one-pair twin that wants the batch's bits calls numpy's ufunc. ``sqrt`` is exact in
both, and ``sin`` and ``cos`` agree (numpy takes libm's there). This test walks every Python
function of ``src`` that says it gives "the same bits" (in its docstring or comments) and
is not compiled by numba (whose calls are libm's on both sides of any comparison), and
fails on a ``math`` call from the list below. The behaviour itself is checked by each
twin's own bit test (e.g. ``tests/geometry/test_so3_se3.py``).
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np

SRC = Path(__file__).resolve().parents[1] / "src" / "needlekit"

#: math's functions whose results numpy's SIMD loops round differently on some machines
#: (measured on an AVX-512 Xeon, numpy 2.4: 0.1-49 % of 100,000 random arguments).
LIBM_NOT_NUMPY = {
    "atan2", "acos", "asin", "atan", "tan", "exp", "exp2", "expm1", "log", "log1p",
    "log2", "log10", "hypot", "sinh", "cosh", "tanh", "asinh", "acosh", "atanh", "cbrt",
    "pow",
}  # fmt: skip


def _is_numba(fn: ast.AST) -> bool:
    for dec in fn.decorator_list:
        text = ast.unparse(dec)
        if "njit" in text or "jit" in text.split("(")[0] or "vectorize" in text:
            return True
    return False


def _claims() -> list[tuple[str, str, list[str]]]:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        text = path.read_text()
        if "same bits" not in text and "batch's bits" not in text:
            continue
        tree = ast.parse(text)
        for fn in ast.walk(tree):
            if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef) or _is_numba(fn):
                continue
            body = ast.get_source_segment(text, fn) or ""
            if "same bits" not in body and "batch's bits" not in body:
                continue
            calls = sorted(
                node.func.attr
                for node in ast.walk(fn)
                if isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and isinstance(node.func.value, ast.Name)
                and node.func.value.id == "math"
                and node.func.attr in LIBM_NOT_NUMPY
            )
            found.append((str(path.relative_to(SRC)), fn.name, calls))
    return found


def test_no_scalar_twin_claiming_numpys_bits_calls_a_libm_transcendental():
    claims = _claims()
    # the walk finds the twins it is about (so a renamed phrase cannot empty it)
    names = {name for _, name, _ in claims}
    assert {"angle_between", "so3_log_unchecked"} <= names, names
    bad = [(p, n, c) for p, n, c in claims if c]
    assert not bad, f"libm transcendentals in paths that claim numpy's bits: {bad}"


def test_numpys_arctan2_on_one_number_is_its_loop_on_many():
    # the premise of the fix: the ufunc on one pair gives the array loop's bits
    rng = np.random.default_rng(3)
    y, x = rng.normal(size=(2, 4000)) * 10.0 ** rng.uniform(-6, 3, (2, 4000))
    batch = np.arctan2(y, x)
    assert all(np.arctan2(float(a), float(b)) == c for a, b, c in zip(y, x, batch, strict=True))
    # and math's is that function to within an ulp (so a logged angle may use either)
    one = np.array([math.atan2(a, b) for a, b in zip(y, x, strict=True)])
    assert np.all(np.abs(one - batch) <= np.spacing(np.abs(batch)))
