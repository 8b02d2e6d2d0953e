"""Plan files (``plan.json``): writing planner results and reading plans back to verify."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.files import read_json_object, write_json

__all__ = ["plan_from_dict", "read_plan_json", "write_plan_json"]


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


def read_plan_json(path: str | os.PathLike):
    """Read a plan file back: the plan and the goal it was made for.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    plan : needlekit.planning.steerable.plan.SteerablePlan or None
        None when the file holds no plan (e.g. status ``timeout``).
    goal_mm : ndarray, shape (3,)
    data : dict
        The whole document.

    Raises
    ------
    InvalidInputError
        Missing file, bad JSON or a field not as the format says (named).
    """
    p = Path(path)
    data = read_json_object(p, "plan")
    plan, goal = plan_from_dict(data, p.name)
    return plan, goal, data


def plan_from_dict(data: dict, where: str):
    """The plan and goal of a ``plan.json`` document (or of one plan inside another file,
    such as a sweep's best plans).

    Parameters
    ----------
    data : dict
        ``goal_mm``, ``cost_mm``, ``start_pose`` and ``primitives`` as
        :func:`write_plan_json` writes them.
    where : str
        Names the document in messages (``"plan.json"``, ``"sweep.json: best_plans.rrt"``).

    Returns
    -------
    plan : needlekit.planning.steerable.plan.SteerablePlan or None
        None when the document holds no plan (e.g. status ``timeout``).
    goal_mm : ndarray, shape (3,)

    Raises
    ------
    InvalidInputError
        A field not as the format says (named after ``where``).
    """
    from needlekit.planning.steerable.plan import SteerablePlan

    if not isinstance(data, dict):
        raise InvalidInputError(where, "expected a JSON object (a plan)")
    try:
        goal = np.asarray(data["goal_mm"], dtype=float).reshape(3)
    except (KeyError, TypeError, ValueError):
        raise InvalidInputError(f"{where}: goal_mm", "expected three numbers") from None
    cost = data.get("cost_mm")
    if cost is not None and (
        isinstance(cost, bool) or not isinstance(cost, (int, float)) or not np.isfinite(cost)
    ):
        raise InvalidInputError(f"{where}: cost_mm", f"expected a number or null, got {cost!r}")
    prims = data.get("primitives") or []
    if data.get("start_pose") is None or not prims:
        return None, goal
    try:
        rows = [
            [float(q["rotation_rad"]), float(q["curvature_per_mm"]), float(q["length_mm"])]
            for q in prims
        ]
    except (KeyError, TypeError, ValueError):
        raise InvalidInputError(
            f"{where}: primitives",
            "expected objects with rotation_rad, curvature_per_mm, length_mm",
        ) from None
    try:
        plan = SteerablePlan(np.asarray(data["start_pose"], dtype=float), np.array(rows))
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc.field}", exc.reason) from None
    except (TypeError, ValueError):
        raise InvalidInputError(f"{where}: start_pose", "expected a 4x4 matrix") from None
    return plan, goal
