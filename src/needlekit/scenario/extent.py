"""A point given to a scenario (its start, goal, targets; ``--goal``, ``--goals``) lies
where the anatomy is, or it is an error naming its field, before any search.

The anatomy's extent is the box around its bounded structures (known without building a
lazy field: a Med-RAD volume's box comes from its header), grown by
:data:`EXTENT_SLACK_MM` so that a start on the skin of an anatomy whose outer structure is
not given still counts. A point outside it is almost always a unit mistake (a goal written
in metres, the anatomy in millimetres): when multiplying by 10, 100 or 1000 brings the point
inside, the message says so.
"""

from __future__ import annotations

import numpy as np

from needlekit.anatomy.fields import LazyField
from needlekit.errors import InvalidInputError

__all__ = ["EXTENT_SLACK_MM", "UNIT_FACTORS", "anatomy_box", "check_inside_anatomy"]

#: How far outside the box around the bounded structures (mm) a point may still lie: a
#: start on the skin, a few millimetres in air before the entry. A point in metres or
#: centimetres where the anatomy is in millimetres is off by far more.
EXTENT_SLACK_MM: float = 20.0

#: The factors tried for a unit hint, with the unit the point then looks written in.
UNIT_FACTORS: tuple[tuple[int, str], ...] = (
    (1000, "metres"),
    (10, "centimetres"),
    (100, "decimetres"),
)


def anatomy_box(scene) -> np.ndarray | None:
    """The box around the scene's bounded structures, from the bounds known without
    building a field (a lazy field that is not built and gives no bounds of its own is
    left out); None when no structure is bounded.

    Parameters
    ----------
    scene : needlekit.anatomy.scene.Scene

    Returns
    -------
    ndarray, shape (2, 3), or None
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm).
    """
    boxes = []
    for s in scene.structures:
        f = s.field
        if isinstance(f, LazyField) and not f.built and f._bounds is None:
            continue
        b = np.asarray(f.bounds(), dtype=float)
        if b.shape == (2, 3) and np.all(np.isfinite(b)):
            boxes.append(b)
    if not boxes:
        return None
    b = np.stack(boxes)
    return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])


def _inside(p: np.ndarray, box: np.ndarray) -> bool:
    return bool(np.all(p >= box[0] - EXTENT_SLACK_MM) and np.all(p <= box[1] + EXTENT_SLACK_MM))


def _fmt(p) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in np.asarray(p, dtype=float)) + "]"


def check_inside_anatomy(point_mm, box: np.ndarray | None, field: str) -> None:
    """Refuse a point outside the anatomy's box (grown by :data:`EXTENT_SLACK_MM`).

    Parameters
    ----------
    point_mm : array_like, shape (3,)
    box : ndarray, shape (2, 3), or None
        :func:`anatomy_box` (None: nothing to check against).
    field : str
        Names the point in the message (``goal.point_mm``, ``--goal``).

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"<field>: [x, y, z] mm lies outside the anatomy (x a to b, ...); it looks like
        metres: x1000 gives [...] mm, inside"``.

    Examples
    --------
    >>> box = np.array([[0.0, 100.0, 1050.0], [150.0, 300.0, 1400.0]])
    >>> check_inside_anatomy([60, 200, 1210], box, "goal")
    >>> check_inside_anatomy([0.06, 0.2, 1.21], box, "goal")
    Traceback (most recent call last):
    ...
    needlekit.errors.InvalidInputError: goal: [0.06, 0.2, 1.21] mm lies outside the anatomy (x 0 to 150, y 100 to 300, z 1050 to 1400 mm); it looks like metres: x1000 gives [60, 200, 1210] mm, inside
    """
    if box is None:
        return
    p = np.asarray(point_mm, dtype=float).reshape(3)
    if _inside(p, box):
        return
    span = ", ".join(
        f"{axis} {lo:.4g} to {hi:.4g}" for axis, lo, hi in zip("xyz", box[0], box[1], strict=True)
    )
    hint = ""
    for factor, unit in UNIT_FACTORS:
        if _inside(p * factor, box):
            hint = f"; it looks like {unit}: x{factor} gives {_fmt(p * factor)} mm, inside"
            break
    raise InvalidInputError(
        field, f"{_fmt(p)} mm lies outside the anatomy ({span} mm){hint}"
    )
