"""Going on from inside the tissue: the problem of a needle already inserted.

A needle that has gone in part of the way plans the rest from where its tip is: no entry
surface and no puncture angle any more, no start exclusion, and what is left of the
length and heading budgets, so that the whole path keeps the original limits. The
moving-obstacle re-planner (:mod:`needlekit.planning.steerable.dynamic`) goes on from the
end of the path it executed; the execution simulator (:mod:`needlekit.execute`) from the
tracked tip.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from needlekit.anatomy.scene import Scene
from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem

__all__ = ["HEADING_SLACK_DEG", "continuation_from_pose", "continuation_problem"]

#: Angle (deg) kept back from the heading limit of a continuation: rounding only.
HEADING_SLACK_DEG: float = 1e-6


def continuation_problem(
    problem: SteerableProblem, executed: SteerablePlan, scene: Scene | None = None
) -> SteerableProblem:
    """The problem of going on from the end of an executed path, inside the tissue.

    Parameters
    ----------
    problem : SteerableProblem
        The original problem (start pose, limits, goal).
    executed : SteerablePlan
        What has been inserted, from the problem's start pose (no primitives: the start).
    scene : Scene, optional
        The anatomy to plan in (default the problem's).

    Returns
    -------
    SteerableProblem
        With nothing inserted, the original problem (on ``scene``). Otherwise from the
        executed path's end pose, a start inside the tissue (``start_inside``: no entry
        surface, no puncture angle) without start exclusion, ``max_length_mm`` less the
        inserted length, and ``max_heading_change_deg`` less the angle between the start
        direction and the current one: a continuation within it keeps the whole path
        within the original limit.

    Raises
    ------
    InvalidInputError
        Nothing left of the length or the heading budget (``executed``).
    """
    scene = problem.scene if scene is None else scene
    if executed.length_mm <= 0.0:
        return replace(problem, scene=scene, metadata=dict(problem.metadata))
    return continuation_from_pose(problem, executed.end_pose(), executed.length_mm, scene)


def continuation_from_pose(
    problem: SteerableProblem, tip_pose, inserted_mm: float, scene: Scene | None = None
) -> SteerableProblem:
    """The problem of going on from a tip inside the tissue, ``inserted_mm`` in: where an
    executed path ends (:func:`continuation_problem`) or where a tracked needle is.

    Parameters
    ----------
    problem : SteerableProblem
        The original problem (start pose, limits, goal).
    tip_pose : array_like, shape (4, 4)
        The tip now (RAS mm).
    inserted_mm : float
        The length inserted so far, > 0.
    scene : Scene, optional
        The anatomy to plan in (default the problem's).

    Returns
    -------
    SteerableProblem
        From ``tip_pose``, a start inside the tissue (``start_inside``: no entry surface,
        no puncture angle) without start exclusion, ``max_length_mm`` less the inserted
        length, and ``max_heading_change_deg`` less the angle between the start direction
        and the tip's: a continuation within it keeps the whole path within the original
        limit.

    Raises
    ------
    InvalidInputError
        Nothing left of the length or the heading budget (``executed``).
    """
    scene = problem.scene if scene is None else scene
    tip = np.asarray(tip_pose, dtype=np.float64)
    cos_turn = float(np.clip(tip[:3, 2] @ problem.start_pose[:3, 2], -1.0, 1.0))
    heading = problem.max_heading_change_deg - math.degrees(math.acos(cos_turn))
    heading -= HEADING_SLACK_DEG
    length = problem.max_length_mm - float(inserted_mm)
    if heading <= 0.0 or length <= 0.0:
        raise InvalidInputError(
            "executed",
            f"nothing left to plan with: {length:.3f} mm of length and {heading:.3f} deg of "
            "heading change remain",
        )
    meta = {k: v for k, v in problem.metadata.items() if k != "puncture_normal_source"}
    return replace(
        problem,
        scene=scene,
        start_pose=tip,
        start_point_mm=None,
        min_puncture_angle_deg=0.0,
        start_exclusion_mm=0.0,
        max_length_mm=length,
        max_heading_change_deg=heading,
        entry_surface=None,
        entry_normal=None,
        start_inside=True,
        metadata={**meta, "continued_after_mm": float(inserted_mm)},
    )
