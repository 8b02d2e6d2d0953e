"""Shared pieces of the command line: the parser class, argument types, tables."""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

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
    value (no option of needlekit looks like a negative number)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = _NEGATIVE_VALUE

    def error(self, message: str):  # type: ignore[override]
        self.exit(EXIT_USAGE, f"error: {message}\n")


class _Formatter(argparse.HelpFormatter):
    """argparse's help layout, except that a text of several lines (an epilog of examples)
    is printed as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


def _numbers(count: int, what: str):
    """The type of a flag of ``count`` numbers; a point in millimetres (``what`` says
    "(mm)") keeps each coordinate within the scenario files' bound (a kilometre)."""
    from needlekit.io.scenario_schema import MAX_ABS_MM

    bound = MAX_ABS_MM if "(mm)" in what else math.inf

    def parse(text: str) -> list[float]:
        parts = [p for p in text.replace(",", " ").split() if p]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        if not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"must be finite numbers, got {text!r}")
        if any(abs(v) > bound for v in values):
            raise argparse.ArgumentTypeError(
                f"{text!r} is past {bound:g} mm (a kilometre): not a position in a body"
            )
        return values

    return parse


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return v


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number > 0, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a whole number > 0, got {text!r}")
    return v


def _seed(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if v < 0:  # numpy's SeedSequence takes only non-negative entropy
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}")
    return v


def _start_pose(path):
    """The 4x4 pose in the text file at ``path``, or the identity when None."""
    if path is None:
        import numpy as np

        return np.eye(4)
    from needlekit.io.poses import read_pose_txt

    return read_pose_txt(path)


def _fmt_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    def cell(v: object) -> str:
        if isinstance(v, float):
            return "inf" if math.isinf(v) else f"{v:.4f}"
        return str(v)

    def numeric(text: str) -> bool:
        try:
            float(text)
        except ValueError:
            return text in ("-", "inf")
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
