"""The common record every benchmark writes: when, where, with what, on which inputs."""

from __future__ import annotations

import datetime as _dt
import os
import platform
import sys
import time
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from typing import Any

__all__ = ["best_time", "format_record", "machine_info"]

_PACKAGES = ("needlekit", "numpy", "scipy", "numba", "llvmlite", "dqrobotics", "daqp")


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_info() -> dict[str, Any]:
    """Machine, OS, Python and package versions, and the time of the run (UTC).

    Returns
    -------
    dict
        ``time_utc``, ``platform``, ``cpu``, ``cpu_count``, ``python``, ``versions`` (package
        name to version, None when not installed) and ``load_average`` (1, 5, 15 min).
    """
    versions = {}
    for name in _PACKAGES:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            versions[name] = None
    return {
        "time_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "platform": platform.platform(),
        "cpu": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
        "versions": versions,
        # the 1, 5 and 15 min load averages when the record was made (timings on a shared
        # machine depend on it)
        "load_average": list(os.getloadavg()),
    }


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
        with ``name`` and ``summary``).

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
    return "\n".join(lines)
