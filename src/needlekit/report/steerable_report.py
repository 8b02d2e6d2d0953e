"""Plans to several targets drawn on one page (the lecture's multi-target RRT figure).

:func:`write_goals_report` writes one self-contained HTML page (``needlekit plan --goals
... --report``): a table of the targets (status, cost, iterations, tree nodes) and the
scene with every plan from the common start pose to its target, as the lecture draws its
multi-target RRT results.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["goals_figure", "write_goals_report"]


def goals_figure(problem, results, *, title: str = "", max_cells: int = 96):
    """The scene with every plan's tip path, its start pose and its target.

    Parameters
    ----------
    problem : SteerableProblem
        The scene and start pose.
    results : sequence of PlanResult
        One per target (a target without a plan is drawn without a path).
    title : str
    max_cells : int
        Resolution limit of the surfaces (samples per axis).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    from needlekit.report.scene3d import scene_figure, zoom_onto

    drawn = [(i, r) for i, r in enumerate(results, start=1) if r.plan is not None]
    paths = [r.plan.points_mm(0.5) for _, r in drawn]
    goals = np.array([r.goal_mm for r in results], dtype=float)
    fig = scene_figure(
        problem.scene,
        start_poses=np.asarray(problem.start_pose)[None],
        targets_mm=goals,
        paths_mm=paths,
        path_names=[f"target {i}: {r.cost_mm:.2f} mm ({r.status.value})" for i, r in drawn],
        max_cells=max_cells,
        title=title,
    )
    zoom_onto(fig, np.vstack([*paths, goals, np.asarray(problem.start_pose)[None, :3, 3]]))
    return fig


def write_goals_report(
    path: str | os.PathLike, problem, results, *, planner: str, mode: str
) -> Path:
    """Write the plans to several targets as one self-contained HTML page, atomically.

    Parameters
    ----------
    path : path-like
    problem : SteerableProblem
    results : sequence of PlanResult
    planner : str
    mode : {"per-target", "one-tree"}

    Returns
    -------
    Path
    """
    from needlekit.report.html_page import FigureSection, TableSection, write_report_html

    rows = []
    for i, r in enumerate(results, start=1):
        rows.append(
            {
                "target": i,
                "goal (RAS mm)": ", ".join(f"{c:.2f}" for c in r.goal_mm),
                "status": r.status.value,
                "cost (mm)": "-" if not r.status.has_plan else f"{r.cost_mm:.3f}",
                "iterations": r.stats.get("iterations", "-"),
                "tree nodes": r.stats.get("nodes", "-"),
            }
        )
    how = (
        "a new search from the start node for each target (the lecture's procedure)"
        if mode == "per-target"
        else "one RRT tree grown for every target"
    )
    sections = [
        TableSection("Targets", rows, f"{planner}, {how}."),
        FigureSection(
            "Plans",
            goals_figure(problem, results),
            "Every plan's tip path from the start pose (cone) to its target (cross).",
        ),
    ]
    return write_report_html(path, title=f"Plans to {len(results)} targets", sections=sections)
