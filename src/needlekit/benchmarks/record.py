"""The common record every benchmark writes: when, where, with what, on which inputs."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from needlekit.provenance import machine_info  # the records' machine block

__all__ = ["best_time", "format_record", "machine_info"]


def best_time(fn: Callable[[], Any], repeat: int) -> float:
    """Best wall-clock time (s) of ``repeat`` calls; the minimum is the least noisy.

    Parameters
    ----------
    fn : callable
        Called with no argument.
    repeat : int
        Number of calls.

    Returns
    -------
    float
        Seconds (inf when ``repeat`` is 0).
    """
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def format_record(record: dict[str, Any]) -> str:
    """A short human-readable summary of a benchmark record.

    Parameters
    ----------
    record : dict
        ``benchmark``, ``machine`` (:func:`machine_info`), ``inputs`` and ``results`` (rows
        with ``name`` and ``summary``), and optionally ``verdict`` (one line).

    Returns
    -------
    str
        Lines joined by newlines.
    """
    lines = [f"benchmark: {record['benchmark']}"]
    m = record["machine"]
    lines.append(f"machine:   {m['cpu']} ({m['cpu_count']} cpus), Python {m['python']}")
    lines.append("versions:  " + ", ".join(f"{k} {v}" for k, v in m["versions"].items() if v))
    lines.append("inputs:    " + ", ".join(f"{k}={v}" for k, v in record["inputs"].items()))
    for row in record["results"]:
        lines.append(f"  {row['name']:<28} {row['summary']}")
    if record.get("verdict"):  # a suite's judgement of its pooled figures
        lines.append(f"verdict:   {record['verdict']}")
    return "\n".join(lines)
