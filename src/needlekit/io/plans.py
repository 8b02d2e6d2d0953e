"""Plan files (``plan.json``): a planner result written atomically.

Reading one back builds planning objects, so it lives above planning:
:func:`needlekit.scenario.results.read_plan_json` (and
:func:`needlekit.planning.steerable.plan.plan_from_dict` for a record already parsed).
"""

from __future__ import annotations

import os
from pathlib import Path

from needlekit.io.files import write_json

__all__ = ["write_plan_json"]


def write_plan_json(path: str | os.PathLike, result, **extra) -> Path:
    """Write a planner result as ``plan.json`` (atomically).

    Parameters
    ----------
    path : path-like
    result : needlekit.planning.steerable.result.PlanResult
    **extra
        More top-level fields (e.g. ``scenario``).

    Returns
    -------
    Path
    """
    return write_json(path, {**result.to_dict(), **extra})
