"""Lengths that look written in other units: one table for scenario fields and flags.

Every length in needlekit is in millimetres. A needle diameter of ``0.002`` or a curvature
radius of ``0.03`` is valid input (a positive number) but almost surely metres; a goal
tolerance of ``1000`` mm accepts any path that gets within a metre of the target. Each
quantity below has the range that needle insertions use (from the lecture's and the papers'
set-ups, with generous slack); a value outside it draws one warning line naming the field
or flag, the same whether it came from a scenario file (:func:`document_warnings`) or from
the command line (:func:`flag_warnings`). Warnings, not errors: a phantom or a test may use
odd sizes on purpose. A zero is never warned about where zero is allowed (no margin).

Ranges (mm unless said): needle diameter 0.1-10 (33 G to 4 G needles and ablation
antennas), minimum radius of curvature at least 1 (needlekit's default is 50; the
reference planner's Med-RAD set-ups use 50 and 100), insertion length 5-2000, safety
margin and start exclusion at most 50 and 100, goal tolerance 0.01-50, Liu et al.'s safe
distance gamma 0.01-50 (the paper sets 1.5; `study livers` also runs 3), ablation margin
at most 50 and zone sizes 1-300, voxel sizes 0.01-20, a moving obstacle's step 0.01-200
and speed 0.01-1000 mm/s, the puncture controller's stability radius 0.01-50 (needlekit's
default 1.5), a markup curve's spacing 0.01-100 and a curvature at most 1/mm.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

from needlekit.constants import MM_WARNING_MIN_R_MIN_MM

__all__ = [
    "QUANTITIES",
    "Quantity",
    "document_warnings",
    "flag_values",
    "flag_warnings",
    "implausible",
]

_log = logging.getLogger("needlekit.units")


@dataclass(frozen=True)
class Quantity:
    """A length with the range insertions use.

    Parameters
    ----------
    field : str
        Its place in a scenario document, dotted; ``*`` stands for any key (a structure's
        name, a list index); empty for a flag alone.
    flags : tuple of str
        Command-line flags that give it.
    low, high : float or None
        The range; None leaves that side open.
    unit : str
    """

    field: str
    flags: tuple[str, ...] = ()
    low: float | None = None
    high: float | None = None
    unit: str = "mm"


#: The table (module notes for where the ranges come from).
QUANTITIES: tuple[Quantity, ...] = (
    Quantity("needle.diameter_mm", ("--needle-diameter-mm",), 0.1, 10.0),
    Quantity("needle.r_min_mm", ("--r-min-mm",), MM_WARNING_MIN_R_MIN_MM, None),
    Quantity("needle.max_length_mm", (), 5.0, 2000.0),
    Quantity("needle.safety_margin_mm", (), None, 50.0),
    Quantity("needle.start_exclusion_mm", (), None, 100.0),
    Quantity("goal.tolerance_mm", (), 0.01, 50.0),
    Quantity("straight.gamma_mm", ("--gamma",), 0.01, 50.0),
    Quantity("straight.coverage.margin_mm", (), None, 50.0),
    Quantity("straight.coverage.zone.length_mm", (), 1.0, 300.0),
    Quantity("straight.coverage.zone.diameter_mm", (), 1.0, 300.0),
    Quantity("straight.coverage.zone.radius_mm", (), 0.5, 150.0),
    Quantity("planner.cost.reach_mm", (), 0.01, 500.0),
    Quantity("dynamic.step_mm", ("--step-mm",), 0.01, 200.0),
    Quantity("dynamic.insertion_speed_mm_s", ("--insertion-speed-mm-s",), 0.01, 1000.0, "mm/s"),
    Quantity("base.phantom.voxel_size_mm", (), 0.01, 20.0),
    Quantity("structures.*.mesh.voxel_size_mm", (), 0.01, 20.0),
    Quantity("", ("--stability-radius-mm",), 0.01, 50.0),
    Quantity("", ("--spacing-mm",), 0.01, 100.0),
    Quantity("", ("--kappa-per-mm",), None, 1.0, "1/mm"),
)


def implausible(name: str, value: Any, quantity: Quantity) -> str | None:
    """The warning for one value, or None when it is in range (or not a number, or a zero
    the field allows).

    Parameters
    ----------
    name : str
        How the message names it (a field or a flag).
    value : object
    quantity : Quantity

    Returns
    -------
    str or None
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return None
    v = float(value)
    if not math.isfinite(v) or v == 0.0:
        return None  # non-finite values are errors elsewhere; zero is a choice
    u = quantity.unit
    if quantity.low is not None and abs(v) < quantity.low:
        return (
            f"{name} is {v:g} {u}, below the {quantity.low:g} {u} insertions use: lengths "
            "are millimetres (was it written in metres or centimetres?)"
        )
    if quantity.high is not None and abs(v) > quantity.high:
        return (
            f"{name} is {v:g} {u}, above the {quantity.high:g} {u} insertions use: lengths "
            "are millimetres (was it written in micrometres, or mistyped?)"
        )
    return None


def _at(data: Any, parts: list[str], where: str) -> Iterator[tuple[str, Any]]:
    """The values at a dotted pattern of a document, with their dotted places."""
    if not parts:
        yield where, data
        return
    head, rest = parts[0], parts[1:]
    if head == "*":
        if isinstance(data, Mapping):
            items: Iterable[tuple[Any, Any]] = data.items()
        elif isinstance(data, list):
            items = enumerate(data)
        else:
            return
        for k, v in items:
            name = v.get("name") if isinstance(v, Mapping) else None
            key = name if isinstance(name, str) else k
            yield from _at(v, rest, f"{where}.{key}" if where else str(key))
    elif isinstance(data, Mapping) and head in data:
        yield from _at(data[head], rest, f"{where}.{head}" if where else head)


def document_warnings(data: Any) -> list[str]:
    """The warnings for a scenario document's lengths.

    Parameters
    ----------
    data : object
        A parsed scenario document.

    Returns
    -------
    list of str
    """
    out = []
    for q in QUANTITIES:
        if not q.field:
            continue
        for where, value in _at(data, q.field.split("."), ""):
            msg = implausible(where, value, q)
            if msg is not None:
                out.append(msg)
    return out


def flag_warnings(values: Mapping[str, Any]) -> list[str]:
    """The warnings for the command line's values (argparse's ``dest`` names; a list
    value, as ``--gamma 1.5 3``, is checked item by item).

    Parameters
    ----------
    values : mapping
        ``vars(args)``.

    Returns
    -------
    list of str
    """
    out = []
    for q, flag, v in flag_values(values):
        msg = implausible(flag, v, q)
        if msg is not None:
            out.append(msg)
    return out


def flag_values(values: Mapping[str, Any]) -> Iterator[tuple[Quantity, str, Any]]:
    """Every value given to a flag of the table: ``(quantity, flag, value)``, a list
    value (``--gamma 1.5 3``) item by item; flags not given are skipped.

    Parameters
    ----------
    values : mapping
        ``vars(args)`` (argparse's ``dest`` names).

    Yields
    ------
    tuple of (Quantity, str, object)
    """
    for q in QUANTITIES:
        for flag in q.flags:
            value = values.get(flag.lstrip("-").replace("-", "_"))
            for v in value if isinstance(value, (list, tuple)) else [value]:
                if v is not None:
                    yield q, flag, v


def warn(messages: Iterable[str], source: str | None = None) -> None:
    """Log each message as one warning line (prefixed with ``source``, e.g. a file name)."""
    for m in messages:
        _log.warning("%s", f"{source}: {m}" if source else m)
