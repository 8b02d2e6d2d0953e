"""Provenance: the machine, OS, Python and package versions a record was made with.

Benchmarks, studies and reproductions all stamp their records with :func:`machine_info`;
it lives in the base layer so that each of them imports it from here rather than from one
another.
"""

from __future__ import annotations

import datetime as _dt
import os
import platform
import sys
from importlib.metadata import PackageNotFoundError, version
from typing import Any

__all__ = ["machine_info"]

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
        ``time_utc``, ``platform``, ``cpu``, ``cpu_count``, ``python``, ``versions`` (per
        package, None when not installed) and ``load_average`` (1, 5 and 15 min).
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
