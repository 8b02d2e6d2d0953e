"""Steerable-needle plans drawn on a page: one plan, or plans to several targets.

- :func:`plans_figure`: the scene with plans from their start poses to their targets
  (:func:`goals_figure`: the lecture's multi-target RRT figure);
- :func:`plan_rows`, :func:`check_rows`, :func:`check_text`: a plan's motions and its
  independent check (:func:`needlekit.planning.steerable.verify.verify_plan`) as rows and
  words;
- :func:`plan_sections`: one plan with its check and scene (``needlekit report``); the
  sweep report's best plan uses the same rows and words;
- :func:`goals_sections`, :func:`write_goals_report`: one self-contained HTML page of plans
  to several targets (``needlekit plan --goals ... --report``, ``needlekit report``): a
  table of the targets (status, cost, iterations, tree nodes) and the scene with every
  plan from the common start pose to its target.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit.planning.result import PlanStatus
from needlekit.report.html_page import FigureSection, TableSection, TextSection, write_report_html

__all__ = [
    "check_rows",
    "check_text",
    "goals_figure",
    "goals_sections",
    "plan_rows",
    "plan_check",
    "plan_sections",
    "plans_figure",
    "write_goals_report",
    "write_plan_report",
]


def plans_figure(problem, results, names, *, title: str = "", max_cells: int = 96):
    """The scene with every plan's tip path, its start pose and its target, zoomed onto
    them.

    Parameters
    ----------
    problem : SteerableProblem
        The scene (its start pose is drawn when a result has none).
    results : sequence of PlanResult
        A result without a plan is drawn as its start pose and target only.
    names : sequence of str
        Legend entry of each result's path.
    title : str
    max_cells : int
        Resolution limit of the surfaces (samples per axis).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    from needlekit.report.scene3d import scene_figure

    poses = [r.start_pose if r.start_pose is not None else problem.start_pose for r in results]
    starts = np.array([p for p in poses if p is not None], dtype=float).reshape(-1, 4, 4)
    starts = np.unique(starts, axis=0)
    drawn = [(r, n) for r, n in zip(results, names, strict=True) if r.plan is not None]
    paths = [r.plan.points_mm(0.5) for r, _ in drawn]
    goals = np.array([r.goal_mm for r in results], dtype=float).reshape(-1, 3)
    fig = scene_figure(
        problem.scene,
        start_poses=starts if len(starts) else None,
        targets_mm=goals,
        paths_mm=paths,
        path_names=[n for _, n in drawn],
        max_cells=max_cells,
        title=title,
        focus_mm=np.vstack([*paths, goals, starts[:, :3, 3].reshape(-1, 3)]),
    )
    return fig


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
    names = [f"target {i}: {r.cost_mm:.2f} mm ({r.status.value})" for i, r in enumerate(results, 1)]
    return plans_figure(problem, results, names, title=title, max_cells=max_cells)


def plan_check(problem, result, *, free_direction: bool = False):
    """The independent check of a result's plan (None without one), as ``needlekit verify``
    makes it: from the problem's start (its point; its direction too unless a sweep chose
    the plan's, ``free_direction``), to the goal the plan was made for. A plan edited to
    start elsewhere fails. A path that stops short of the goal is checked as such.

    Parameters
    ----------
    problem : SteerableProblem
    result : PlanResult
    free_direction : bool

    Returns
    -------
    VerificationReport or None
    """
    from needlekit.planning.steerable.verify import verify_approximate, verify_plan

    if result.plan is None:
        return None
    p = problem.with_goal(result.goal_mm)
    if free_direction:
        p = p.with_free_start_direction()
    if result.status is PlanStatus.APPROXIMATE:
        return verify_approximate(p, result.plan)
    cost = None if not np.isfinite(result.cost_mm) else result.cost_mm
    return verify_plan(p, result.plan, expected_cost_mm=cost)


def write_plan_report(
    path: str | os.PathLike, problem, result, *, title: str | None = None
) -> Path:
    """The page of one plan (``needlekit plan SCENARIO --report plan.html``), as
    ``needlekit report plan.json`` draws it: the summary, the path in the anatomy, the
    independent check run on it, the motions.

    Parameters
    ----------
    path : path-like
    problem : SteerableProblem
        The problem the plan was made for.
    result : PlanResult
    title : str, optional
        Default: "Steerable-needle plan: " and the scene's name.

    Returns
    -------
    Path
    """
    check = plan_check(problem, result)
    sections = plan_sections(problem.with_goal(result.goal_mm), result, check)
    title = title or f"Steerable-needle plan: {problem.scene.name or 'scenario'}"
    return write_report_html(path, title=title, sections=sections)


def plan_rows(plan) -> list[dict]:
    """A plan's motions, one row each: spin, curvature and length.

    Parameters
    ----------
    plan : SteerablePlan

    Returns
    -------
    list of dict
        ``step`` (1-based), ``rotation_deg`` (spin about the tip's z before the arc),
        ``curvature (1/mm)`` and ``length_mm`` (keys the page turns into headers; a
        ``*_per_mm`` key would read as a length in mm).
    """
    return [
        {
            "step": i + 1,
            "rotation_deg": float(np.degrees(spin)),
            "curvature (1/mm)": float(kappa),
            "length_mm": float(length),
        }
        for i, (spin, kappa, length) in enumerate(plan.primitives)
    ]


def check_text(check) -> str:
    """The verdict of an independent check in words: ``passed`` or ``FAILED: <rules>``.

    Parameters
    ----------
    check : Verification

    Returns
    -------
    str
    """
    return "passed" if check.ok else "FAILED: " + "; ".join(check.violations)


def check_rows(check) -> list[dict]:
    """The measurements of :func:`~needlekit.planning.steerable.verify.verify_plan`, one
    row each, with the verdict first.

    Parameters
    ----------
    check : Verification

    Returns
    -------
    list of dict
        ``quantity`` and ``value`` (text).
    """
    m = check.metrics

    def mm(key: str) -> str:
        return f"{m[key]:.3f} mm"

    angle = m.get("puncture_angle_deg")
    rows = [
        ("verdict", check_text(check)),
        ("cost (recomputed from the motions)", f"{m['cost']:.4f}"),
        ("length", mm("length_mm")),
        ("end to goal", mm("goal_distance_mm")),
        ("largest curvature", f"{m['max_curvature_per_mm']:.5f} /mm"),
        ("largest heading change", f"{m['max_heading_change_deg']:.2f} deg"),
        ("puncture angle", "-" if angle is None else f"{angle:.2f} deg"),
        ("smallest sampled clearance", mm("min_clearance_mm")),
        ("certified clearance (whole path)", mm("certified_clearance_mm")),
        ("collision model", str(m["collision_model"])),
    ]
    return [{"quantity": q, "value": v} for q, v in rows]


def plan_sections(problem, result, check, *, max_cells: int = 96) -> list:
    """One plan on a page: summary, independent check, motions and the 3D scene.

    Parameters
    ----------
    problem : SteerableProblem
        The problem the plan was checked against (scene, limits, goal).
    result : PlanResult
    check : Verification or None
        Its independent check (None: the result holds no plan).
    max_cells : int
        Resolution limit of the surfaces (samples per axis).

    Returns
    -------
    list of FigureSection, TableSection and TextSection
        For :func:`~needlekit.report.html_page.write_report_html`.
    """
    goal = ", ".join(f"{c:.2f}" for c in result.goal_mm)
    text = f"{result.planner}: {result.status.value}"
    if result.plan is None:
        reason = result.stats.get("reason")
        text += f", no plan to the goal ({goal}) RAS mm" + (f": {reason}." if reason else ".")
        return [TextSection(text, "Summary")]
    cert = ", certified optimal at the finest resolution" if result.stats.get("certified") else ""
    text += (
        f"{cert}; cost {result.cost_mm:.3f}, {len(result.plan.primitives)} motions, "
        f"{1000 * result.time_s:.1f} ms of search; goal ({goal}) RAS mm, tolerance "
        f"{problem.goal_tolerance_mm:g} mm; r_min {problem.r_min_mm:g} mm, needle diameter "
        f"{problem.needle_diameter_mm:g} mm. Independent check: {check_text(check)}."
    )
    label = f"{result.planner}: {result.cost_mm:.2f}"
    fig = plans_figure(problem, [result], [label], max_cells=max_cells)
    return [
        TextSection(text, "Summary"),
        FigureSection(
            "Path in the anatomy",
            fig,
            "The tip path (magenta) from the start pose (cone) to the goal (diamond), RAS mm, "
            "framed on the path and looked at from where the fewest of its points are behind "
            "an obstacle. Surfaces that enclose the workspace (pleura, fissures, skin) are "
            "see-through, the obstacles the path passes solid; click a legend entry to hide "
            "or show a structure, drag to turn the view.",
        ),
        TableSection(
            "Independent check",
            check_rows(check),
            "Re-derived from the motions alone against the scenario: curvature, length, goal, "
            "heading, puncture angle, cost, and the clearance certified for the whole path.",
        ),
        TableSection(
            "Motions",
            plan_rows(result.plan),
            "Each motion: spin the tip about its axis, then insert along an arc of that "
            "curvature (0: straight).",
        ),
    ]


def goals_sections(problem, results, *, planner: str, mode: str, checks=None) -> list:
    """The sections of plans to several targets: a table of the targets and the scene.

    Parameters
    ----------
    problem : SteerableProblem
    results : sequence of PlanResult
    planner : str
    mode : {"per-target", "one-tree"}
    checks : sequence of Verification or None, optional
        Each target's independent check (None where it has no plan): a column of the
        table when given.

    Returns
    -------
    list of FigureSection and TableSection
    """
    rows = []
    for i, r in enumerate(results, start=1):
        row = {
            "target": i,
            "goal (RAS mm)": ", ".join(f"{c:.2f}" for c in r.goal_mm),
            "status": r.status.value,
            "cost (mm)": "-" if not r.status.has_plan else f"{r.cost_mm:.3f}",
            "iterations": r.stats.get("iterations", "-"),
            "tree nodes": r.stats.get("nodes", "-"),
        }
        if checks is not None:
            c = checks[i - 1]
            row["independent check"] = "-" if c is None else check_text(c)
        rows.append(row)
    how = (
        "a new search from the start node for each target (the lecture's procedure)"
        if mode == "per-target"
        else "one RRT tree grown for every target"
    )
    return [
        TableSection("Targets", rows, f"{planner}, {how}."),
        FigureSection(
            "Plans",
            goals_figure(problem, results),
            "Every plan's tip path from the start pose (cone) to its target (diamond).",
        ),
    ]


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
    sections = goals_sections(problem, results, planner=planner, mode=mode)
    return write_report_html(path, title=f"Plans to {len(results)} targets", sections=sections)
