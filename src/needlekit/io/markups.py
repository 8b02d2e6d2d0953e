"""3D Slicer Markups files (``.mrk.json``): needle trajectories as Line and Curve nodes.

A straight trajectory becomes a Markups **Line** (two control points: entry, then
target); a steerable plan's tip path becomes a Markups **Curve** (control points along the
path). The files follow Slicer's Markups JSON schema 1.0.x:

- the top level holds ``@schema`` (:data:`MARKUPS_SCHEMA`, the string Slicer itself writes)
  and ``markups``, a list of markup objects;
- each markup names its ``type`` (``"Line"``, ``"Curve"``, ...), ``coordinateSystem``
  (``"LPS"`` or ``"RAS"``; LPS when absent), ``coordinateUnits`` (``"mm"``) and its
  ``controlPoints``: each with ``id``, ``label``, ``position`` (3 numbers),
  ``orientation`` (a 3x3 matrix as 9 numbers, row by row), ``selected``, ``locked``,
  ``visibility`` and ``positionStatus`` (``"undefined"``, ``"preview"`` or ``"defined"``);
- ``display`` (colour, opacity, labels) and ``measurements`` are optional.

Frames: needlekit works in patient RAS; the files are written in **LPS**, the default of
the format and what Slicer writes, by negating x and y at this boundary (positions, and
the first two rows of each control point's orientation matrix). :func:`read_markups` reads
both LPS and RAS files and always returns RAS.

One file per trajectory: Slicer writes one markup per file, and names the node after
the file, so a trajectory per file keeps each needle a node of its own that Slicer saves
back in place. :func:`write_markups_lines` can also write one combined file holding every
trajectory in its ``markups`` list; Slicer loads each entry of the list as a node of its
own (all named after that one file).

This module writes the files; the format's shared pieces (:data:`MARKUPS_SCHEMA`,
:class:`Markup`, the LPS flip) are in :mod:`needlekit.io._markups_format` and the reader
in :mod:`needlekit.io.markups_read`, whose public names this module re-exports.

Examples
--------
>>> import json, tempfile
>>> from pathlib import Path
>>> d = Path(tempfile.mkdtemp())
>>> p = write_markups_line(d / "needle.mrk.json", [10.0, 20.0, 30.0], [15.0, 25.0, 80.0])
>>> json.loads(p.read_text())["markups"][0]["controlPoints"][0]["position"]
[-10.0, -20.0, 30.0]
>>> [(m.type, m.name, m.points_ras.tolist()) for m in read_markups(p)]
[('Line', 'needle', [[10.0, 20.0, 30.0], [15.0, 25.0, 80.0]])]
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from needlekit._validation import as_batch, as_points
from needlekit.errors import InvalidInputError
from needlekit.io._markups_format import MARKUPS_SCHEMA, Markup, _flip_xy, _stem
from needlekit.io.files import staged_outputs, write_json
from needlekit.io.markups_read import read_markups  # re-exported (it lived here)

__all__ = [
    "DEFAULT_CURVE_SPACING_MM",
    "MARKUPS_SCHEMA",
    "Markup",
    "markups_curve",
    "markups_document",
    "markups_line",
    "read_markups",
    "write_markups_curve",
    "write_markups_line",
    "write_markups_lines",
    "write_plan_curve",
]

#: Spacing of a curve's control points along a tip path. Slicer draws a spline through
#: them; a polyline through points 2 mm apart on an arc of radius 50 mm (a tight needle)
#: already stays within s^2 / (8 r) = 0.01 mm of the arc, and a 100 mm path needs ~50
#: points, few enough for Slicer's control point table.
DEFAULT_CURVE_SPACING_MM = 2.0

#: A control point's orientation: the identity in RAS, written in LPS (first two rows
#: negated, as Slicer does).
_IDENTITY_LPS = [-1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 1.0]


def _color(color: Any, field: str) -> list[float] | None:
    if color is None:
        return None
    try:
        c = np.asarray(color, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidInputError(field, f"expected three numbers in [0, 1], got {color!r}") from None
    if c.shape != (3,) or not np.all(np.isfinite(c)) or np.any((c < 0) | (c > 1)):
        raise InvalidInputError(field, f"expected three numbers in [0, 1] (RGB), got {color!r}")
    return c.tolist()


def _name(name: Any, field: str = "name") -> str:
    if not isinstance(name, str) or not name.strip():
        raise InvalidInputError(field, f"expected a non-empty string, got {name!r}")
    return name


def _control_points(points_ras: np.ndarray, labels: Sequence[str], description: str) -> list[dict]:
    lps = _flip_xy(points_ras)
    return [
        {
            "id": str(i + 1),
            "label": label,
            "description": description,
            "associatedNodeID": "",
            "position": p.tolist(),
            "orientation": list(_IDENTITY_LPS),
            "selected": True,
            "locked": True,
            "visibility": True,
            "positionStatus": "defined",
        }
        for i, (p, label) in enumerate(zip(lps, labels, strict=True))
    ]


def _markup(
    kind: str,
    name: str,
    points_ras: np.ndarray,
    labels: Sequence[str],
    *,
    color: list[float] | None,
    description: str,
    point_labels: bool,
) -> dict:
    display: dict[str, Any] = {
        "visibility": True,
        "opacity": 1.0,
        "propertiesLabelVisibility": True,
        "pointLabelsVisibility": point_labels,
    }
    if color is not None:
        # Control points are written selected, and Slicer draws selected points (and the
        # line between them) in selectedColor: set both.
        display["color"] = color
        display["selectedColor"] = color
    return {
        "type": kind,
        "name": name,
        "coordinateSystem": "LPS",
        "coordinateUnits": "mm",
        "locked": True,
        "fixedNumberOfControlPoints": True,
        "labelFormat": "%N-%d",
        "controlPoints": _control_points(points_ras, labels, description),
        "measurements": [
            {
                "name": "length",
                "enabled": True,
                "value": float(np.linalg.norm(np.diff(points_ras, axis=0), axis=1).sum()),
                "units": "mm",
                "printFormat": "%-#4.4g%s",
            }
        ],
        "display": display,
    }


def markups_line(entry_mm, target_mm, *, name: str, color=None, description: str = "") -> dict:
    """One straight needle trajectory as a Slicer Markups Line (a ``markups`` item).

    Parameters
    ----------
    entry_mm : array_like, shape (3,)
        Entry point (skin), RAS mm.
    target_mm : array_like, shape (3,)
        Target point, RAS mm; must differ from the entry.
    name : str
        The markup's name.
    color : array_like, shape (3,), optional
        RGB in [0, 1]; Slicer's default colour when None.
    description : str
        Text stored with both control points (Slicer's control point table shows it).

    Returns
    -------
    dict
        One item of a document's ``markups`` list (see :func:`markups_document`): type
        ``"Line"``, control points ``entry`` and ``target`` in LPS mm, its length as a
        measurement.

    Raises
    ------
    InvalidInputError
        A point that is not 3 finite numbers, entry equal to target, a bad colour or name.
    """
    entry, _ = as_batch(entry_mm, "entry_mm", (3,))
    target, _ = as_batch(target_mm, "target_mm", (3,))
    if len(entry) != 1 or len(target) != 1:
        raise InvalidInputError("entry_mm", "expected one entry and one target point")
    if np.array_equal(entry, target):
        raise InvalidInputError("target_mm", "coincides with entry_mm: a line needs two points")
    return _markup(
        "Line",
        _name(name),
        np.concatenate([entry, target]),
        ("entry", "target"),
        color=_color(color, "color"),
        description=description,
        point_labels=True,
    )


def markups_curve(points_mm, *, name: str, color=None, description: str = "") -> dict:
    """A tip path as a Slicer Markups Curve (a ``markups`` item).

    Parameters
    ----------
    points_mm : array_like, shape (n, 3)
        Points along the path, RAS mm, from the start (entry) to the tip; n >= 2.
        Slicer draws a spline through them, so give them densely (e.g.
        ``plan.points_mm(DEFAULT_CURVE_SPACING_MM)``).
    name : str
        The markup's name; control points are labelled ``name-1``, ``name-2``, ...
    color : array_like, shape (3,), optional
        RGB in [0, 1].
    description : str
        Text stored with every control point.

    Returns
    -------
    dict
        One item of a document's ``markups`` list: type ``"Curve"``, LPS mm, with the
        polyline length through the points as a measurement (Slicer recomputes it along
        its spline).

    Raises
    ------
    InvalidInputError
        Fewer than two points, a point not finite, a bad colour or name.
    """
    pts, _ = as_points(points_mm, "points_mm")
    if len(pts) < 2:
        raise InvalidInputError("points_mm", f"a curve needs at least 2 points, got {len(pts)}")
    name = _name(name)
    return _markup(
        "Curve",
        name,
        pts,
        [f"{name}-{i + 1}" for i in range(len(pts))],
        color=_color(color, "color"),
        description=description,
        point_labels=False,
    )


def markups_document(markups: Sequence[dict]) -> dict:
    """A whole ``.mrk.json`` document holding the given markups.

    Parameters
    ----------
    markups : sequence of dict
        Items made by :func:`markups_line` or :func:`markups_curve` (at least one).

    Returns
    -------
    dict
        ``{"@schema": MARKUPS_SCHEMA, "markups": [...]}``.
    """
    items = list(markups)
    if not items or not all(isinstance(m, dict) for m in items):
        raise InvalidInputError("markups", "expected at least one markup (a dict)")
    return {"@schema": MARKUPS_SCHEMA, "markups": items}


def write_markups_line(
    path: str | os.PathLike,
    entry_mm,
    target_mm,
    *,
    name: str | None = None,
    color=None,
    description: str = "",
) -> Path:
    """Write one straight trajectory as a Slicer Line file (atomically).

    Parameters
    ----------
    path : path-like
        Destination, e.g. ``needle1.mrk.json``.
    entry_mm, target_mm : array_like, shape (3,)
        Entry and target, RAS mm (``write_markups_line(path, *pair)`` for a pair).
    name : str, optional
        The markup's name (default: the file's name without ``.mrk.json``).
    color : array_like, shape (3,), optional
        RGB in [0, 1].
    description : str
        Stored with the control points.

    Returns
    -------
    Path
        The file written.
    """
    item = markups_line(
        entry_mm,
        target_mm,
        name=_stem(path) if name is None else name,
        color=color,
        description=description,
    )
    return write_json(path, markups_document([item]))


def write_markups_lines(
    folder: str | os.PathLike,
    trajectories_mm,
    *,
    names: Sequence[str] | None = None,
    color=None,
    combined: str | None = None,
) -> list[Path]:
    """Write several straight trajectories: one Line file each, optionally also one
    file holding them all.

    All files are written as one unit (:func:`needlekit.io.files.staged_outputs`):
    every input is checked first, and a failure leaves no file changed.

    Parameters
    ----------
    folder : path-like
        Where the files go (created if missing).
    trajectories_mm : array_like, shape (n, 2, 3)
        ``(entry, target)`` pairs, RAS mm; n >= 1.
    names : sequence of str, optional
        One name per trajectory (default ``needle1``, ``needle2``, ...); each file is
        ``<name>.mrk.json``, so names must be unique and hold no path separator.
    color : array_like, shape (3,), optional
        RGB in [0, 1], for every line.
    combined : str, optional
        Also write ``folder/<combined>`` (e.g. ``"needles.mrk.json"``) with every line in
        its ``markups`` list.

    Returns
    -------
    list of Path
        The per-trajectory files in order, then the combined file if asked for.
    """
    pairs, _ = as_batch(trajectories_mm, "trajectories_mm", (2, 3))
    if names is None:
        names = [f"needle{i + 1}" for i in range(len(pairs))]
    elif isinstance(names, str):
        raise InvalidInputError("names", f"expected a list of names, got the string {names!r}")
    names = list(names)
    if len(names) != len(pairs):
        raise InvalidInputError(
            "names", f"expected {len(pairs)} names (one per trajectory), got {len(names)}"
        )
    for i, n in enumerate(names):
        _name(n, f"names[{i}]")
        if "/" in n or "\\" in n or n in (".", ".."):
            raise InvalidInputError(f"names[{i}]", f"must be a plain file name, got {n!r}")
    if len(set(names)) != len(names):
        dup = next(n for n in names if names.count(n) > 1)
        raise InvalidInputError("names", f"must be unique (file names), {dup!r} repeats")
    if combined is not None and (
        not isinstance(combined, str) or not combined.strip() or "/" in combined
    ):
        raise InvalidInputError("combined", f"expected a plain file name, got {combined!r}")
    if combined is not None and combined in {f"{n}.mrk.json" for n in names}:
        raise InvalidInputError("combined", f"{combined!r} is also a trajectory's file")
    items = [
        markups_line(entry, target, name=n, color=color, description=f"trajectory {i + 1}")
        for i, ((entry, target), n) in enumerate(zip(pairs, names, strict=True))
    ]
    out = Path(folder)
    written: list[Path] = []
    with staged_outputs():
        for item, n in zip(items, names, strict=True):
            written.append(write_json(out / f"{n}.mrk.json", markups_document([item])))
        if combined is not None:
            written.append(write_json(out / combined, markups_document(items)))
    return written


def write_markups_curve(
    path: str | os.PathLike,
    points_mm,
    *,
    name: str | None = None,
    color=None,
    description: str = "",
) -> Path:
    """Write a tip path as a Slicer Curve file (atomically).

    Parameters
    ----------
    path : path-like
        Destination, e.g. ``plan.mrk.json``.
    points_mm : array_like, shape (n, 3)
        Points along the path, RAS mm; n >= 2.
    name : str, optional
        The markup's name (default: the file's name without ``.mrk.json``).
    color : array_like, shape (3,), optional
        RGB in [0, 1].
    description : str
        Stored with the control points.

    Returns
    -------
    Path
        The file written.
    """
    item = markups_curve(
        points_mm,
        name=_stem(path) if name is None else name,
        color=color,
        description=description,
    )
    return write_json(path, markups_document([item]))


def write_plan_curve(
    path: str | os.PathLike,
    plan,
    *,
    spacing_mm: float = DEFAULT_CURVE_SPACING_MM,
    name: str | None = None,
    color=None,
    description: str = "",
) -> Path:
    """Write a steerable plan's tip path as a Slicer Curve file.

    Parameters
    ----------
    path : path-like
        Destination.
    plan : needlekit.planning.steerable.plan.SteerablePlan
        The plan (e.g. ``PlanResult.plan`` or the first value of
        :func:`needlekit.scenario.results.read_plan_json`).
    spacing_mm : float
        Largest spacing of the control points along the path (mm, > 0); the ends of
        every primitive are control points too.
    name : str, optional
        The markup's name (default: the file's name without ``.mrk.json``).
    color : array_like, shape (3,), optional
        RGB in [0, 1].
    description : str
        Stored with the control points.

    Returns
    -------
    Path
        The file written.
    """
    if not (isinstance(spacing_mm, (int, float)) and math.isfinite(spacing_mm) and spacing_mm > 0):
        raise InvalidInputError("spacing_mm", f"must be a finite number > 0, got {spacing_mm!r}")
    points = plan.points_mm(float(spacing_mm))
    if len(points) < 2:
        raise InvalidInputError("plan", "has zero length: no path to export")
    return write_markups_curve(path, points, name=name, color=color, description=description)
