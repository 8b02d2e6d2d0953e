"""The one gate every number from outside passes: finite, within a stated range, named.

A number needlekit reads, from a command-line flag or a field of a file (scenario, plan,
sweep, multi, execute and partial records), is checked here before anything is computed
from it:

- a flag's type is a :class:`Bounds` turned into an argparse type
  (:func:`needlekit.cli._common.number`): the parser refuses it, naming the flag, before
  any heavy module loads;
- a file's every number is checked by :func:`check_document` when the file is read
  (:func:`needlekit.io.files.read_json_object`, the scenario reader), against the bound of
  its field's unit (:func:`field_bounds`), named by its place in the file.

The bounds are wide: they exclude only what no needle insertion means and what would make
later arithmetic overflow (a length squared, a count of samples, an angle times a
curvature). Past them the answer is one line, ``<field>: expected <range>, got <value>``.

- Lengths and coordinates (``*_mm``): :data:`MAX_ABS_MM`, a kilometre.
- Curvatures (``*_per_mm``): :data:`MAX_CURVATURE_PER_MM`, a radius of a micrometre.
- Any other real number: :data:`MAX_ABS_NUMBER`; whole numbers: :data:`MAX_ABS_INT`.
- A quantity that must be positive (a size, a time, a step): at least
  :data:`MIN_POSITIVE` of its unit.

This module is light (no numpy): the command line imports it to build its parser.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from needlekit.errors import InvalidInputError

__all__ = [
    "ANY_INT",
    "ANY_MM",
    "ANY_PER_MM",
    "ANY_REAL",
    "MAX_ABS_INT",
    "MAX_ABS_MM",
    "MAX_ABS_NUMBER",
    "MAX_CURVATURE_PER_MM",
    "MIN_POSITIVE",
    "MIN_SPEED_MM_S",
    "MIN_STEP_MM",
    "Bounds",
    "check_document",
    "check_number",
    "field_bounds",
    "magnitude",
]

#: Largest length or coordinate (mm): a kilometre, far past any anatomy or robot, and far
#: enough from the float range that distances, squares and sample counts stay finite.
MAX_ABS_MM: float = 1e6
#: Largest curvature (1/mm): a radius of curvature of one micrometre.
MAX_CURVATURE_PER_MM: float = 1e3
#: Largest magnitude of any other real number (a time, an angle, a speed, a ratio): a
#: product of two such numbers is still far inside the float range.
MAX_ABS_NUMBER: float = 1e12
#: Smallest value of a quantity that must be positive (a size, a time, a speed, a step), in
#: its own unit: a nanometre, a microsecond. Below it, quotients made from it (a curvature
#: 1/r, a sample count length/step) overflow or lose all precision.
MIN_POSITIVE: float = 1e-6
#: Smallest sampling step along a path (mm): a micrometre; finer gives tens of millions of
#: samples on a needle's length (a curve's control points, a re-planning cycle).
MIN_STEP_MM: float = 1e-3
#: Slowest insertion speed (mm/s): a simulated insertion of 100 mm at it already takes
#: hours of simulated time, each control period a step.
MIN_SPEED_MM_S: float = 1e-2
#: Largest magnitude of a whole number (a count, an index, a seed): what a signed 64-bit
#: integer holds, as numpy stores it.
MAX_ABS_INT: int = 2**63 - 1


def magnitude(value: float | int) -> str:
    """A number in a few characters (``1e+308``; an int past the float range as ``10^400``).

    Parameters
    ----------
    value : float or int

    Returns
    -------
    str
    """
    try:
        return f"{float(value):g}"
    except OverflowError:
        return f"{'-' if value < 0 else ''}10^{int(abs(value).bit_length() * math.log10(2))}"


@dataclass(frozen=True)
class Bounds:
    """A range a number must lie in: finite, ``low`` to ``high``.

    Parameters
    ----------
    low, high : float
        The range's ends (finite).
    low_open : bool
        ``low`` itself is refused (``> low`` rather than ``>= low``).
    integer : bool
        A whole number is expected.
    unit : str
        Shown after the range (``"mm"``, ``"s"``); empty for none.

    Examples
    --------
    >>> Bounds(0.0, 1e6, low_open=True, unit="mm").check(2.5, "--step-mm")
    2.5
    >>> str(Bounds(0.0, 1e6, low_open=True, unit="mm"))
    'a number in (0, 1e+06] mm'
    """

    low: float
    high: float
    low_open: bool = False
    integer: bool = False
    unit: str = ""

    def __str__(self) -> str:
        what = "a whole number" if self.integer else "a number"
        lo, hi = (
            f"{v:g}" if not self.integer else f"{int(v)}" if abs(v) < 1e12 else f"{v:.3g}"
            for v in (self.low, self.high)
        )
        text = f"{what} in {'(' if self.low_open else '['}{lo}, {hi}]"
        return f"{text} {self.unit}" if self.unit else text

    def contains(self, value: float | int) -> bool:
        """Whether ``value`` (a number) is finite and in the range.

        Parameters
        ----------
        value : float or int

        Returns
        -------
        bool
        """
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.integer and not isinstance(value, int):
            return False
        above = value > self.low if self.low_open else value >= self.low
        return above and value <= self.high

    def check(self, value: Any, name: str) -> float | int:
        """``value`` if it is a number in the range, else an error naming ``name``.

        Parameters
        ----------
        value : object
            A number as read (bool is not a number).
        name : str
            The flag or field, shown first in the message.

        Returns
        -------
        float or int
            The value (an int for ``integer``).

        Raises
        ------
        InvalidInputError
            ``"<name>: expected <range>, got <value>"``.
        """
        numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not (numeric and self.contains(value)):
            got = magnitude(value) if numeric else repr(value)
            raise InvalidInputError(name, f"expected {self}, got {got}")
        return value


def check_number(value: Any, name: str, bounds: Bounds) -> float | int:
    """The gate as a function: ``bounds.check(value, name)``.

    Parameters
    ----------
    value : object
    name : str
        The flag or field.
    bounds : Bounds

    Returns
    -------
    float or int

    Raises
    ------
    InvalidInputError
        Named by ``name``.
    """
    return bounds.check(value, name)


#: Any length or coordinate (mm).
ANY_MM = Bounds(-MAX_ABS_MM, MAX_ABS_MM, unit="mm")
#: Any curvature (1/mm).
ANY_PER_MM = Bounds(-MAX_CURVATURE_PER_MM, MAX_CURVATURE_PER_MM, unit="1/mm")
#: Any other real number.
ANY_REAL = Bounds(-MAX_ABS_NUMBER, MAX_ABS_NUMBER)
#: Any whole number.
ANY_INT = Bounds(-MAX_ABS_INT, MAX_ABS_INT, integer=True)

#: The bound of a field by how its name ends (its unit), longest ending first.
_BY_SUFFIX: tuple[tuple[str, Bounds], ...] = (("_per_mm", ANY_PER_MM), ("_mm", ANY_MM))


def field_bounds(key: str) -> Bounds | None:
    """The bound a file's field keeps by its unit (the end of its name), or None when its
    name says no unit (then its numbers keep the general bound, or the one of the field
    they sit in).

    Parameters
    ----------
    key : str
        The field's name (``length_mm``, ``curvature_per_mm``, ``seed``).

    Returns
    -------
    Bounds or None
    """
    for suffix, bounds in _BY_SUFFIX:
        if key.endswith(suffix):
            return bounds
    return None


def _printable(key: Any) -> str:
    text = str(key)
    return text if text.isprintable() else repr(text)


def check_document(data: Any, source: str) -> None:
    """Every number in a parsed document finite and within its field's bound.

    A number's bound is that of the nearest enclosing field whose name ends in a unit
    (:func:`field_bounds`: ``[12, 5e6]`` under ``point_mm`` is a length), else the
    general one of its kind (:data:`MAX_ABS_NUMBER`, :data:`MAX_ABS_INT`).

    Parameters
    ----------
    data : object
        The parsed JSON or YAML document.
    source : str
        Names the document in messages (the file name).

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"<source>: <field path>: expected <range>, got <value>"`` for the first number
        outside its bound (NaN, an infinity, ``1e999``, a length past a kilometre).
    """
    stack: list[tuple[Any, str, Bounds | None]] = [(data, "", None)]
    while stack:
        value, where, bounds = stack.pop()
        if isinstance(value, dict):
            for k, v in value.items():
                key = _printable(k)
                stack.append((v, f"{where}.{key}" if where else key, field_bounds(key) or bounds))
        elif isinstance(value, list):
            stack.extend((v, f"{where}[{i}]", bounds) for i, v in enumerate(value))
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            kind = bounds or (ANY_INT if isinstance(value, int) else ANY_REAL)
            kind.check(value, f"{source}: {where or '(top level)'}")
