"""Per-call time statistics shared by the control benchmark and its TRO 2022 yardstick
(:mod:`needlekit.benchmarks.control`, :mod:`needlekit.benchmarks.tro2022`), and the
budget a 1 kHz control tick is held against."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["TICK_TARGET_US", "step_statistics", "tick_verdict"]

#: A control tick's targets (us). Franka's 1 kHz loop leaves about 300 us to user code:
#: p99 <= 300 us for every kind of tick on its own, p99.9 <= 1 ms (a tick past
#: the whole period is a missed cycle); the median (the control loop's budget) leaves room for the tail.
TICK_TARGET_US = {"median": 100.0, "p99": 300.0, "p99.9": 1000.0}


def step_statistics(seconds) -> dict[str, Any]:
    """``n``, ``median``, ``mean``, ``p90``, ``p99``, ``p99.9`` and ``max`` in microseconds.

    Parameters
    ----------
    seconds : array_like, shape (n,)
        Per-call times (s).

    Returns
    -------
    dict

    Examples
    --------
    >>> step_statistics([1e-6, 3e-6])["median"]
    2.0
    """
    us = np.asarray(seconds, dtype=float) * 1e6
    if not len(us):
        return {"n": 0}
    return {
        "n": len(us),
        "median": float(np.median(us)),
        "mean": float(us.mean()),
        "p90": float(np.percentile(us, 90)),
        "p99": float(np.percentile(us, 99)),
        "p99.9": float(np.percentile(us, 99.9)),
        "max": float(us.max()),
    }


def tick_verdict(stats: dict) -> dict[str, Any]:
    """Whether a tick kind's median, p99 and p99.9 are within :data:`TICK_TARGET_US`
    (``pass``: all three).

    Parameters
    ----------
    stats : dict
        :func:`step_statistics` of one kind of tick.

    Returns
    -------
    dict
        ``median_ok``, ``p99_ok``, ``p999_ok``, ``pass`` (None for no ticks).

    Examples
    --------
    >>> tick_verdict({"n": 3, "median": 90.0, "p99": 310.0, "p99.9": 400.0})["pass"]
    False
    """
    if not stats.get("n"):
        return {"median_ok": None, "p99_ok": None, "p999_ok": None, "pass": None}
    median_ok = stats["median"] <= TICK_TARGET_US["median"]
    p99_ok = stats["p99"] <= TICK_TARGET_US["p99"]
    p999_ok = stats["p99.9"] <= TICK_TARGET_US["p99.9"]
    ok = median_ok and p99_ok and p999_ok
    return {"median_ok": median_ok, "p99_ok": p99_ok, "p999_ok": p999_ok, "pass": ok}
