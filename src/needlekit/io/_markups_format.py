"""The Slicer Markups format pieces shared by writing and reading ``.mrk.json`` files.

The ``@schema`` string and how a reader recognises it, the markup types and position
statuses of schema 1.0.x, the :class:`Markup` a file's item is read into, the RAS <-> LPS
flip done at the file boundary, and the node name Slicer gives a file. The writers live in
:mod:`needlekit.io.markups` (which re-exports these public names), the reader in
:mod:`needlekit.io.markups_read`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["MARKUPS_SCHEMA", "Markup"]

#: The ``@schema`` Slicer writes (5.x). Its URL points at the "master" branch, which no
#: longer resolves; Slicer keeps it for compatibility with Slicer < 5.1 and accepts any
#: ``markups-schema-v1.<minor>.<patch>.json`` when reading.
MARKUPS_SCHEMA = (
    "https://raw.githubusercontent.com/slicer/slicer/master/Modules/Loadable/Markups/"
    "Resources/Schema/markups-schema-v1.0.3.json#"
)

#: How Slicer's reader recognises a markups file (compared without regard to case).
_SCHEMA_PATTERN = re.compile(r"markups-schema-v1\.[0-9]+\.[0-9]+\.json#*$", re.IGNORECASE)

#: The markup types of schema 1.0.x.
_TYPES = ("Fiducial", "Line", "Angle", "Curve", "ClosedCurve", "Plane", "ROI")
_POSITION_STATUS = ("undefined", "preview", "defined")


class Markup(NamedTuple):
    """One markup read from a file.

    Attributes
    ----------
    type : str
        ``"Line"``, ``"Curve"``, ``"Fiducial"``, ...
    name : str
        The markup's ``name``, else the file's name without ``.mrk.json`` (as Slicer
        names the node).
    points_ras : ndarray, shape (n, 3)
        Control point positions in RAS mm, in file order (points without a position,
        ``positionStatus: "undefined"``, are left out).
    """

    type: str
    name: str
    points_ras: np.ndarray


def _flip_xy(points: np.ndarray) -> np.ndarray:
    """RAS <-> LPS (self-inverse): negate x and y; ``0.0 - v`` writes no ``-0.0``."""
    out = np.array(points, dtype=np.float64)
    out[..., :2] = 0.0 - out[..., :2]
    return out


def _stem(path: str | os.PathLike) -> str:
    """A file's name without ``.mrk.json`` (or its last suffix), as Slicer names nodes."""
    name = Path(path).name
    for suffix in (".mrk.json", ".json"):
        if name.lower().endswith(suffix) and len(name) > len(suffix):
            return name[: -len(suffix)]
    return Path(path).stem or name
