"""Shared pieces of the command line: the parser class, argument types, tables."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager

from needlekit._numbers import (
    ANY_MM,
    ANY_REAL,
    MAX_ABS_INT,
    MAX_ABS_MM,
    MAX_ABS_NUMBER,
    MIN_POSITIVE,
    MIN_SPEED_MM_S,
    MIN_STEP_MM,
    Bounds,
)
from needlekit.errors import did_you_mean

EXIT_OK = 0
EXIT_USAGE = 2
#: The work ran but did not produce a result that passes its checks.
EXIT_FAILED = 1
#: A run stopped by Ctrl-C or SIGINT (128 + the signal's number, as shells report it).
EXIT_INTERRUPTED = 130


#: A value that starts with a minus sign and is a number or a comma-separated list of them
#: (``-10,10,70``): argparse's own test takes only a single number, so a point with a
#: negative first coordinate was read as an unknown option.
_NEGATIVE_VALUE = re.compile(
    r"^-\d*\.?\d+(?:[eE][-+]?\d+)?(?:,\s*[-+]?\d*\.?\d+(?:[eE][-+]?\d+)?)*$"
)


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``error: ...``, exit 2), reading ``-10,10,70`` as a
    value (no option of needlekit looks like a negative number).

    No flag may be abbreviated (``allow_abbrev=False``): ``--trial`` never stands for
    another flag. A flag, command or choice that is not one of the parser's is answered
    with the nearest ones (:func:`needlekit.errors.did_you_mean`); ``mistaken_flags``
    (flag -> what to say) names what a flag that is not one was likely meant as.
    """

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_VALUE
        self.mistaken_flags: dict[str, str] = {}

    def error(self, message: str):  # type: ignore[override]
        self.exit(EXIT_USAGE, f"error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        namespace, extras = super().parse_known_args(args, namespace)
        for word in extras:  # an unknown flag near one of ours: say which, in one line
            if not word.startswith("--"):
                continue
            flag = word.split("=", 1)[0]
            hint = self.mistaken_flags.get(flag)
            if hint is None:
                flags = [o for o in self._option_string_actions if o.startswith("--")]
                hint = did_you_mean(flag, flags)
            if hint:
                self.error(f"{flag}: not a flag of {self.prog}{hint}")
        return namespace, extras

    def _check_value(self, action, value) -> None:
        if action.choices is not None and isinstance(value, str) and value not in action.choices:
            hint = did_you_mean(value, action.choices)
            if hint:
                choices = ", ".join(map(repr, action.choices))
                raise argparse.ArgumentError(
                    action, f"invalid choice: {value!r} (choose from {choices}){hint}"
                )
        super()._check_value(action, value)


class _Formatter(argparse.HelpFormatter):
    """argparse's help layout, except that a text of several lines (an epilog of examples)
    is printed as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


class _Number:
    """The argparse type of a numeric flag: the text read as one number (or ``count``
    comma-separated ones) and passed through the gate (:class:`needlekit._numbers.Bounds`),
    so that the parser refuses a value out of range, naming the flag, before any work.

    Parameters
    ----------
    bounds : Bounds or sequence of Bounds
        The range of the value, or of each of ``count`` values.
    what : str
        What the flag takes, for several values (``"three numbers x,y,z"``).
    container : type
        What several values are returned as (``list`` or ``tuple``).
    """

    def __init__(self, bounds, what: str = "", container: type = list) -> None:
        self.each = tuple(bounds) if isinstance(bounds, (tuple, list)) else (bounds,)
        self.what = what
        self.container = container
        self.__name__ = "number"

    @property
    def bounds(self):
        """The first (or only) value's :class:`~needlekit._numbers.Bounds`."""
        return self.each[0]

    def _expected(self) -> str:
        if len(self.each) == 1:
            return f"expected {self.each[0]}"
        if len(set(self.each)) == 1:
            return f"expected {self.what}, each {self.each[0]}"
        return f"expected {self.what} ({'; '.join(str(b) for b in self.each)})"

    def __call__(self, text: str):
        parts = [p for p in text.replace(",", " ").split() if p] if len(self.each) > 1 else [text]
        values = []
        if len(parts) == len(self.each):
            for part, b in zip(parts, self.each, strict=True):
                try:
                    v = int(part) if b.integer else float(part)
                except ValueError:
                    break
                if not b.contains(v):
                    break
                values.append(v)
        if len(values) != len(self.each):
            raise argparse.ArgumentTypeError(f"{self._expected()}, got {text!r}")
        return self.container(values) if len(self.each) > 1 else values[0]

    def __repr__(self) -> str:
        return f"number({self._expected()[9:]})"


def number(low: float, high: float, *, low_open: bool = False, integer: bool = False,
           unit: str = "") -> _Number:  # fmt: skip
    """The argparse type of a flag of one number in ``[low, high]`` (``(low, high]`` with
    ``low_open``): see :class:`_Number`.

    Parameters
    ----------
    low, high : float
    low_open : bool
    integer : bool
        A whole number.
    unit : str
        Shown in the message.

    Returns
    -------
    _Number
    """
    return _Number(Bounds(low, high, low_open=low_open, integer=integer, unit=unit))


def _numbers(count: int, what: str, bounds=None, container: type = list) -> _Number:
    """The type of a flag of ``count`` numbers (each within ``bounds``, one or one per
    number); by default a point in millimetres (``what`` says "(mm)") keeps each coordinate
    within :data:`~needlekit._numbers.MAX_ABS_MM`, other numbers the general bound."""
    if bounds is None:
        bounds = ANY_MM if "(mm)" in what else ANY_REAL
    each = bounds if isinstance(bounds, (tuple, list)) else (bounds,) * count
    return _Number(each, what, container)


#: Largest count a flag takes (trials, iterations, cells...): a billion; past it no run
#: ends on this kind of machine.
MAX_COUNT = 10**9

#: A real number > 0 (a time, a speed, a factor): at least MIN_POSITIVE.
_positive = number(MIN_POSITIVE, MAX_ABS_NUMBER)
#: A real number >= 0.
_non_negative = number(0.0, MAX_ABS_NUMBER)
#: A length > 0 (mm): at least MIN_POSITIVE (a nanometre).
_positive_mm = number(MIN_POSITIVE, MAX_ABS_MM, unit="mm")
#: A sampling step along a path (mm).
_step_mm = number(MIN_STEP_MM, MAX_ABS_MM, unit="mm")
#: An insertion speed (mm/s).
_speed_mm_s = number(MIN_SPEED_MM_S, MAX_ABS_MM, unit="mm/s")
#: A length >= 0 (mm).
_non_negative_mm = number(0.0, MAX_ABS_MM, unit="mm")
#: A count > 0.
_positive_int = number(1, MAX_COUNT, integer=True)
#: A count that may be 0.
_count = number(0, MAX_COUNT, integer=True)
#: A seed (what numpy's generators take: a whole number >= 0), or an index that may be 0.
_seed = number(0, MAX_ABS_INT, integer=True)


def _start_pose(path):
    """The 4x4 pose in the text file at ``path``, or the identity when None."""
    if path is None:
        import numpy as np

        return np.eye(4)
    from needlekit.io.poses import read_pose_txt

    return read_pose_txt(path)


#: What a dash stands for when the table's caller gave no reason of its own.
NO_VALUE = "no value to show"


def _fmt_table(
    headers: Sequence[str], rows: Sequence[Sequence[object]], why: Mapping[str, str] | None = None
) -> str:
    """A console table: text columns aligned left, numbers right, floats to 4 decimals.

    A cell with no value (None, a NaN or an infinity, or the text ``-``) is a dash, never
    ``nan`` or ``inf``; under the table, one footnote line per column that has a dash says
    why (``why[header]``, else :data:`NO_VALUE`). Headers of numbers carry their unit
    (``error mean mm``, ``procedure s``); ``tests/cli/test_tables.py`` runs every command
    that prints a table and checks both.

    Parameters
    ----------
    headers : sequence of str
    rows : sequence of sequences
    why : mapping, optional
        Header -> why a cell of that column has no value.

    Returns
    -------
    str
    """

    def missing(v: object) -> bool:
        return v is None or v == "-" or (isinstance(v, float) and not math.isfinite(v))

    def cell(v: object) -> str:
        if missing(v):
            return "-"
        if isinstance(v, float):
            return f"{v:.4f}"
        return str(v)

    def numeric(text: str) -> bool:
        try:
            float(text)
        except ValueError:
            return text == "-"
        return True

    text = [[cell(v) for v in row] for row in rows]
    widths = [
        max(len(h), *(len(r[i]) for r in text)) if text else len(h) for i, h in enumerate(headers)
    ]
    # text columns align left, numbers right
    left = [bool(text) and not all(numeric(r[i]) for r in text) for i in range(len(headers))]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            c.ljust(w) if lft else c.rjust(w) for c, w, lft in zip(cells, widths, left, strict=True)
        ).rstrip()

    lines = [line(headers), "  ".join("-" * w for w in widths)]
    lines.extend(line(r) for r in text)
    for i, h in enumerate(headers):
        if any(missing(row[i]) for row in rows):
            lines.append(f"- in {h or 'column ' + str(i + 1)}: {(why or {}).get(h, NO_VALUE)}")
    return "\n".join(lines)


@contextmanager
def sweep_progress() -> Iterator:
    """Progress bars for a sweep study: ``progress(planner)`` opens one bar per planner and
    returns its per-direction update; every bar is closed on leaving the block.

    Yields
    ------
    callable
        ``progress(planner) -> update`` (see
        :func:`needlekit.studies.sweep_study.run_sweep_study`).
    """
    from tqdm import tqdm

    bars: list = []

    class _Update:
        """One direction done; the total (the effective directions) set before the first,
        so that the bar shows the share done and an estimate of the time left."""

        def __init__(self, bar) -> None:
            self.bar = bar

        def __call__(self, _result) -> None:
            self.bar.update(1)

        def set_total(self, n: int) -> None:
            self.bar.total = n
            self.bar.refresh()

    def progress(planner: str):
        bar = tqdm(desc=f"sweep {planner:8s}", unit="dir", disable=None)
        bars.append(bar)
        return _Update(bar)

    try:
        yield progress
    finally:
        for bar in bars:
            bar.close()
