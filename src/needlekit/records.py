"""The result contract every layer shares: one status vocabulary and the field readers
that each result's ``from_dict`` checks its record with.

Every result needlekit writes (a steerable plan, a sweep, a straight multi-needle plan, its
ablation coverage, a run among moving obstacles) is a frozen dataclass with ``to_dict()``
for JSON and ``from_dict(data, where)`` beside it that rebuilds it, checking each field as
it is read: a record that does not hold what its writer writes raises
:class:`~needlekit.errors.InvalidInputError` naming the record and the field. This module
knows no planner: planning, control, the scenario layer and the applications all import
it.
"""

from __future__ import annotations

import enum

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = ["Status", "enum_of", "field_of", "is_number", "number_or_inf", "trial_solved"]


class Status(enum.Enum):
    """How a planning run (or a trial) ended: one vocabulary for every planner family.

    SOLVED
        A plan that reaches the goal and passed the independent check; for
        resolution-optimal planners that finished their search, certified optimal at the
        resolution searched (see the result's statistics).
    APPROXIMATE
        A valid path that ends near, but not within tolerance of, the goal; or, for a
        sequence of needles cut short by its budget, the needles placed so far.
    INFEASIBLE
        No plan exists at the resolution searched (the search space was exhausted), or the
        goal is provably out of reach; the result's ``reason`` says why. Never a budget
        stop.
    TIMEOUT
        The budget ran out before a plan was found (or, for anytime planners, before the
        search finished; a best plan so far is then reported as SOLVED).
    INVALID_INPUT
        The problem itself is malformed (start in collision beyond the start exclusion,
        goal outside the allowed region, ...). Records written before 2026-12-03 carry
        ``"invalid_problem"``, which still reads as this; ``INVALID_PROBLEM`` is the same
        member under its old name.
    """

    SOLVED = "solved"
    APPROXIMATE = "approximate"
    INFEASIBLE = "infeasible"
    TIMEOUT = "timeout"
    INVALID_INPUT = "invalid_input"
    INVALID_PROBLEM = "invalid_input"  # the old name: an alias of INVALID_INPUT

    @classmethod
    def _missing_(cls, value):
        return cls.INVALID_INPUT if value == "invalid_problem" else None

    @property
    def has_plan(self) -> bool:
        """Whether a path comes with this status."""
        return self in (Status.SOLVED, Status.APPROXIMATE)


def is_number(value) -> bool:
    """A JSON number (an int or a float, numpy's too), not a bool and not text.

    Parameters
    ----------
    value : object

    Returns
    -------
    bool

    Examples
    --------
    >>> is_number(1.5), is_number("1.5"), is_number(True)
    (True, False, False)
    """
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


def _number_array(value) -> np.ndarray | None:
    """``value`` as a float array when every leaf is a number (lists of lists, or a numeric
    array); None when any leaf is text, a bool, null or an object: ``"1.5"`` is not a
    number in a record, whatever ``float()`` makes of it."""
    if isinstance(value, np.ndarray):
        ok = value.dtype.kind in "iuf"
    else:
        stack, ok = [value], True
        while stack and ok:
            v = stack.pop()
            if isinstance(v, (list, tuple)):
                stack.extend(v)
            else:
                ok = is_number(v)
    if not ok:
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):  # ragged
        return None


def field_of(data: dict, key: str, where: str, kind: str = "number", *, optional: bool = False):
    """One field of a record, checked.

    Parameters
    ----------
    data : dict
        The record (anything else is refused, naming ``where``).
    key : str
    where : str
        Names the record in messages (``"plan.json"``, ``"sweep.json: directions[3]"``).
    kind : str
        ``number`` (finite), ``int``, ``str``, ``bool``, ``list``, ``dict``, ``point``
        (three finite numbers) or ``pose`` (a 4x4 matrix of finite numbers).
    optional : bool
        A missing or null field gives None instead of an error.

    Returns
    -------
    object
        The value; an ndarray of shape (3,) or (4, 4) for ``point`` and ``pose``.

    Raises
    ------
    InvalidInputError
        ``"<where>: <key>: ..."``: missing, null, or not of ``kind``.

    Examples
    --------
    >>> field_of({"cost_mm": 12.5}, "cost_mm", "plan.json")
    12.5
    >>> field_of({}, "seed", "plan.json", "int", optional=True) is None
    True
    """
    name = f"{where}: {key}"
    if not isinstance(data, dict):
        raise InvalidInputError(where, "expected a JSON object")
    value = data.get(key)
    if value is None:
        if optional:
            return None
        raise InvalidInputError(
            name, "missing" if key not in data else "expected a value, got null"
        )
    if kind in ("point", "pose"):
        shape = (3,) if kind == "point" else (4, 4)
        arr = _number_array(value)
        if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
            what = "three finite numbers" if kind == "point" else "a 4x4 matrix of finite numbers"
            raise InvalidInputError(name, f"expected {what}")
        return arr
    numeric = is_number(value)
    ok = {
        "number": numeric and np.isfinite(value),
        "int": isinstance(value, int) and not isinstance(value, bool),
        "str": isinstance(value, str),
        "bool": isinstance(value, bool),
        "list": isinstance(value, list),
        "dict": isinstance(value, dict),
    }[kind]
    if not ok:
        what = {"number": "a finite number", "int": "a whole number", "str": "text"}
        what |= {"bool": "true or false", "list": "a list", "dict": "an object"}
        raise InvalidInputError(name, f"expected {what[kind]}, got {value!r:.60}")
    return value


def number_or_inf(data: dict, key: str, where: str) -> float:
    """A finite number, or ``inf`` where the record holds null (an unsolved cost).

    Parameters
    ----------
    data : dict
    key, where : str
        As :func:`field_of`.

    Returns
    -------
    float
    """
    value = field_of(data, key, where, optional=True)
    return float("inf") if value is None else float(value)


def enum_of(kind: type[enum.Enum], value, where: str):
    """A member of ``kind`` from its recorded value.

    Parameters
    ----------
    kind : Enum subclass
    value : object
        The recorded value (usually text).
    where : str
        Names the field in messages.

    Returns
    -------
    enum member

    Raises
    ------
    InvalidInputError
        ``"<where>: expected one of ..."``.

    Examples
    --------
    >>> enum_of(Status, "invalid_problem", "plan.json: status")
    <Status.INVALID_INPUT: 'invalid_input'>
    """
    try:
        return kind(value)
    except ValueError:
        known = ", ".join(dict.fromkeys(s.value for s in kind))
        raise InvalidInputError(where, f"expected one of {known}, got {value!r:.40}") from None


def trial_solved(status: str) -> bool:
    """Whether a controller trial's written status says it reached its target:
    ``"solved"``, or ``"completed"`` in records written before the one status vocabulary
    (2026-12-03).

    Parameters
    ----------
    status : str

    Returns
    -------
    bool
    """
    return status in (Status.SOLVED.value, "completed")
