"""JSON text from data, finite numbers only: the one place needlekit turns data into JSON.

JSON holds finite numbers only (``NaN`` and ``Infinity`` are not JSON, and other tools
refuse them). Every file needlekit writes and every ``--json`` print goes through
:func:`json_text`, which refuses a non-finite number by naming its field, except a
clearance without bound (no obstacle within reach), written as null.
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

from needlekit.errors import OutputError

__all__ = ["UNBOUNDED_AS_NULL", "json_text"]


#: Fields whose +infinity means "no obstacle within reach" (every sample of the path lies
#: inside the start exclusion, or the scene has no obstacle): a clearance without bound,
#: written as null. Any other non-finite number is a result that cannot be written.
UNBOUNDED_AS_NULL = re.compile(r"clearances?_mm$")


def _finite_or_null(data: Any, key: str = "") -> Any:
    """``data`` with every +inf under an unbounded field (:data:`UNBOUNDED_AS_NULL`) as None;
    anything else as it is."""
    if isinstance(data, float) and data == math.inf and UNBOUNDED_AS_NULL.search(key):
        return None
    if isinstance(data, dict):
        return {k: _finite_or_null(v, str(k)) for k, v in data.items()}
    if isinstance(data, (list, tuple)):
        return [_finite_or_null(v, key) for v in data]
    if hasattr(data, "tolist") and hasattr(data, "dtype"):  # a numpy number or array
        return _finite_or_null(data.tolist(), key)
    return data


def _non_finite_at(data: Any) -> tuple[str, float] | None:
    """The place (``a.b[2]``) and value of the first NaN or infinity in ``data``, or None."""
    stack: list[tuple[Any, str]] = [(data, "")]
    while stack:
        value, where = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            return where or "(top level)", value
        if isinstance(value, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k)) for k, v in value.items())
        elif isinstance(value, (list, tuple)):
            stack.extend((v, f"{where}[{i}]") for i, v in enumerate(value))
        elif hasattr(value, "tolist") and hasattr(value, "dtype"):  # a numpy number or array
            stack.append((value.tolist(), where))
    return None


def json_text(data: Any, source: str, **dumps) -> str:
    """``data`` as JSON text, refusing NaN and infinity: the one place needlekit turns data
    into JSON (every file and every ``--json`` print goes through it).

    JSON holds finite numbers only (``NaN`` and ``Infinity`` are not JSON, and other tools
    refuse them). A clearance (a field ending ``clearance_mm`` or ``clearances_mm``) of +inf
    means no obstacle within reach and is written as null (:data:`UNBOUNDED_AS_NULL`; the
    formats say so in docs/scenarios.md); any other non-finite number is a result that
    cannot be written, and is named.

    Parameters
    ----------
    data : object
        JSON-serialisable.
    source : str
        Names the output in the message (the file name, ``"stdout"``).
    **dumps
        Passed to :func:`json.dumps` (``indent``, ``sort_keys``, ``separators``...).

    Returns
    -------
    str

    Raises
    ------
    OutputError
        ``"<source>: <field>: computed value is inf, ..."``; nothing is written.

    Examples
    --------
    >>> json_text({"cost_mm": 1.5}, "plan.json")
    '{"cost_mm": 1.5}'
    >>> json_text({"min_clearance_mm": float("inf")}, "plan.json")
    '{"min_clearance_mm": null}'
    """
    try:
        return json.dumps(data, allow_nan=False, **dumps)
    except ValueError:
        data = _finite_or_null(data)
        found = _non_finite_at(data)
        if found is None:
            return json.dumps(data, allow_nan=False, **dumps)
        where, value = found
        raise OutputError(
            f"{source}: {where}",
            f"computed value is {value}, which JSON cannot hold; nothing was written",
        ) from None
