"""Reading 3D Slicer Markups files (``.mrk.json``), written by Slicer or by needlekit.

:func:`read_markups` checks the schema, each markup's type, coordinate system and units,
and each control point, and returns the control points in RAS mm whether the file is in
LPS or RAS. The format is described in :mod:`needlekit.io.markups` (which re-exports
:func:`read_markups`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io._markups_format import (
    _POSITION_STATUS,
    _SCHEMA_PATTERN,
    _TYPES,
    MARKUPS_SCHEMA,
    Markup,
    _flip_xy,
    _stem,
)
from needlekit.io.files import read_json_object

__all__ = ["read_markups"]


def _position(value: Any, field: str, count: int = 3) -> np.ndarray:
    ok = (
        isinstance(value, list)
        and len(value) == count
        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)
    )
    if not ok:
        raise InvalidInputError(field, f"expected {count} numbers, got {value!r}")
    arr = np.asarray(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        bad = "NaN" if np.any(np.isnan(arr)) else "infinity"
        raise InvalidInputError(field, f"must be finite, got {bad}")
    return arr


def _units_ok(units: Any) -> bool:
    if isinstance(units, list) and units:
        units = units[0]
    return units == "mm"


def _read_markup(m: Any, where: str, default_name: str) -> Markup:
    if not isinstance(m, dict):
        raise InvalidInputError(where, f"expected an object, got {type(m).__name__}")
    kind = m.get("type")
    if kind not in _TYPES:
        raise InvalidInputError(
            f"{where}.type", f"expected one of {', '.join(_TYPES)}, got {kind!r}"
        )
    system = m.get("coordinateSystem", "LPS")
    if system not in ("LPS", "RAS"):
        raise InvalidInputError(f"{where}.coordinateSystem", f"expected LPS or RAS, got {system!r}")
    if "coordinateUnits" in m and not _units_ok(m["coordinateUnits"]):
        raise InvalidInputError(
            f"{where}.coordinateUnits", f"only mm is supported, got {m['coordinateUnits']!r}"
        )
    name = m.get("name") or default_name
    if not isinstance(name, str):
        raise InvalidInputError(f"{where}.name", f"expected a string, got {name!r}")
    cps = m.get("controlPoints", [])
    if not isinstance(cps, list):
        raise InvalidInputError(f"{where}.controlPoints", "expected a list of control points")
    points = []
    for j, cp in enumerate(cps):
        at = f"{where}.controlPoints[{j}]"
        if not isinstance(cp, dict):
            raise InvalidInputError(at, f"expected an object, got {type(cp).__name__}")
        status = cp.get("positionStatus", "defined")
        if status not in _POSITION_STATUS:
            raise InvalidInputError(
                f"{at}.positionStatus",
                f"expected one of {', '.join(_POSITION_STATUS)}, got {status!r}",
            )
        if "orientation" in cp:
            _position(cp["orientation"], f"{at}.orientation", 9)
        if status == "undefined" or "position" not in cp:
            continue  # a point not placed yet (Slicer writes "position": "")
        points.append(_position(cp["position"], f"{at}.position"))
    pts = np.array(points, dtype=np.float64).reshape(-1, 3)
    if system == "LPS":
        pts = _flip_xy(pts)
    return Markup(kind, name, pts)


def read_markups(path: str | os.PathLike) -> list[Markup]:
    """Read a Slicer Markups file (``.mrk.json``), written by Slicer or by needlekit.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    list of Markup
        One per item of the file's ``markups`` list, in order: ``(type, name,
        points_ras)`` with ``points_ras`` of shape (n, 3) in RAS mm, whether the file is
        in LPS (the default) or RAS.

    Raises
    ------
    InvalidInputError
        One line naming the file and the field: not JSON, no ``@schema`` or not a markups
        schema 1.x, no ``markups`` list (or an empty one), an unknown ``type`` or
        ``coordinateSystem``, units other than mm, a position that is not 3 finite
        numbers (NaN included), an orientation that is not 9 numbers.
    """
    p = Path(path)
    data = read_json_object(p, "markups")
    schema = data.get("@schema")
    if schema is None:
        raise InvalidInputError(f"{p.name}: @schema", f"missing; expected {MARKUPS_SCHEMA}")
    if not isinstance(schema, str) or not _SCHEMA_PATTERN.search(schema):
        raise InvalidInputError(
            f"{p.name}: @schema",
            f"expected a Slicer markups schema (...markups-schema-v1.x.y.json), got {schema!r}",
        )
    markups = data.get("markups")
    if markups is None:
        raise InvalidInputError(f"{p.name}: markups", "missing; expected a list of markups")
    if not isinstance(markups, list) or not markups:
        raise InvalidInputError(f"{p.name}: markups", "expected a non-empty list of markups")
    stem = _stem(p)
    try:
        return [_read_markup(m, f"markups[{i}]", stem) for i, m in enumerate(markups)]
    except InvalidInputError as exc:
        raise InvalidInputError(f"{p.name}: {exc.field}", exc.reason) from None
