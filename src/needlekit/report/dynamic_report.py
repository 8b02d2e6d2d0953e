"""Planning among moving obstacles drawn on a page (``needlekit plan --dynamic --report``).

:func:`dynamic_figure` draws what the lecture's dynamic-environment figure shows, in 3D:
the path the needle took, the plan of every cycle (older plans fainter), the moving
obstacles at each cycle's time (earlier places fainter), and the plan made once at
``t = 0`` with the point where it meets an obstacle, and the obstacle there, when it does.
:func:`dynamic_sections` adds the run's verdicts and a table of the cycles;
:func:`write_dynamic_report` writes the self-contained page.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit.report.html_page import FigureSection, ListSection, TableSection, write_report_html

__all__ = ["dynamic_figure", "dynamic_sections", "write_dynamic_report"]

#: Colours of the paths: executed, cycle plans, the plan made once at t = 0.
_EXECUTED, _CYCLE, _STATIC = "#1b7837", "#2166ac", "#b2182b"
#: Most obstacle places drawn (evenly chosen among the cycles' times).
MAX_OBSTACLE_PLACES: int = 6
#: Space (mm) around the paths in the zoomed view, and the figure's height (px).
ZOOM_MARGIN_MM, FIGURE_HEIGHT_PX = 4.0, 760


def _fade(i: int, n: int, low: float = 0.15, high: float = 0.8) -> float:
    """Opacity of the i-th of n items, oldest faintest."""
    return high if n <= 1 else low + (high - low) * i / (n - 1)


def _line(go, points, name, colour, width, opacity=1.0, dash=None, group=None, legend=True):
    p = np.asarray(points, dtype=float)
    return go.Scatter3d(
        x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", name=name, opacity=opacity,
        line={"width": width, "color": colour, "dash": dash}, legendgroup=group,
        showlegend=legend,
    )  # fmt: skip


def _mesh(go, field, name, colour, opacity, group, legend, max_cells):
    from needlekit.anatomy.summary import surface_mesh

    verts, faces = surface_mesh(field, max_cells=max_cells)
    if len(faces) == 0:
        return None
    v = np.round(verts, 2)
    return go.Mesh3d(
        x=v[:, 0], y=v[:, 1], z=v[:, 2], i=faces[:, 0], j=faces[:, 1], k=faces[:, 2],
        color=colour, opacity=opacity, name=name, legendgroup=group, showlegend=legend,
        hovertemplate=f"{name}<extra></extra>",
    )  # fmt: skip


def _places(result) -> list[float]:
    """The times at which the moving obstacles are drawn: cycle times, at most
    :data:`MAX_OBSTACLE_PLACES`, the first and last always."""
    times = [c.t_s for c in result.cycles]
    end = result.executed.length_mm / result.settings["insertion_speed_mm_s"]
    times = sorted({*times, end})
    if len(times) > MAX_OBSTACLE_PLACES:
        idx = np.round(np.linspace(0, len(times) - 1, MAX_OBSTACLE_PLACES)).astype(int)
        times = [times[i] for i in sorted(set(idx.tolist()))]
    return times


def dynamic_figure(problem, result, *, title: str = "", max_cells: int = 96):
    """The scene, the executed path, every cycle's plan, the moving obstacles at several
    times, and the plan made at ``t = 0`` with its first contact.

    Parameters
    ----------
    problem : SteerableProblem
        The static anatomy, start pose and goal.
    result : DynamicResult
    title : str
    max_cells : int
        Resolution limit of the static anatomy's surfaces (samples per axis).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go

    from needlekit.report.scene3d import scene_figure

    focus = [problem.start_pose[None, :3, 3], problem.goal_mm[None], result.executed.points_mm(0.5)]
    focus += [c.result.plan.points_mm(0.5) for c in result.cycles if c.result.plan is not None]
    if result.static is not None and result.static[0].plan is not None:
        focus.append(result.static[0].plan.points_mm(0.5))
    fig = scene_figure(
        problem.scene,
        start_poses=np.asarray(problem.start_pose)[None],
        targets_mm=problem.goal_mm[None],
        max_cells=max_cells,
        title=title,
        focus_mm=np.vstack(focus),
        focus_margin_mm=ZOOM_MARGIN_MM,
    )
    shown = [problem.start_pose[None, :3, 3], problem.goal_mm[None]]
    n = len(result.cycles)
    for i, c in enumerate(result.cycles):
        plan = c.result.plan
        if plan is None:
            continue
        pts = plan.points_mm(0.5)
        shown.append(pts)
        name = f"cycle {c.index + 1} plan (t = {c.t_s:.1f} s, {c.source})"
        fig.add_trace(_line(go, pts, name, _CYCLE, 3, _fade(i, n), "dot", "plans", True))
    times = _places(result)
    for m in result.moving:
        colour = m.color or "#d1495b"
        for i, t in enumerate(times):
            mesh = _mesh(go, m.at(t), f"{m.name} at t = {t:.1f} s", colour,
                         _fade(i, len(times), 0.1, 0.6), m.name, True, 48)  # fmt: skip
            if mesh is not None:
                fig.add_trace(mesh)
    executed = result.executed.points_mm(0.5)
    shown.append(executed)
    fig.add_trace(_line(go, executed, f"executed path ({result.status.value})", _EXECUTED, 8))
    if result.static is not None and result.static[0].plan is not None:
        _add_static(go, fig, result, shown)
    fig.update_layout(height=FIGURE_HEIGHT_PX, scene_camera={"eye": _eye(problem, result)})
    return fig


def _eye(problem, result) -> dict:
    """A camera looking across both the insertion and the first obstacle's motion (so that
    a detour around it shows), a little from above."""
    d = problem.goal_mm - problem.start_pose[:3, 3]
    motion = result.moving[0].motion if result.moving else None
    v = None if motion is None else motion.velocity_mm_s + motion.amplitude_mm
    n = np.cross(d, v) if v is not None else np.zeros(3)
    if np.linalg.norm(n) < 1e-9 * max(1.0, float(np.linalg.norm(d))):
        n = np.array([1.25, 1.25, 0.0])  # plotly's default side
    eye = 1.9 * n / np.linalg.norm(n) + np.array([0.0, 0.0, 0.35])
    return dict(zip("xyz", eye.tolist(), strict=True))


def _add_static(go, fig, result, shown) -> None:
    """The plan made at t = 0, its first contact with a moving obstacle and that obstacle
    at the contact's time."""
    plan, check = result.static
    pts = plan.plan.points_mm(0.5)
    shown.append(pts)
    verdict = "" if check is None else (" passes" if check.ok else " fails the check")
    fig.add_trace(_line(go, pts, f"plan made at t = 0, open-loop{verdict}", _STATIC, 5,
                        dash="dash"))  # fmt: skip
    per = {} if check is None else check.metrics.get("per_obstacle", {})
    for m in result.moving:
        contact = per.get(m.name, {}).get("first_contact")
        if contact is None:
            continue
        t, p = contact
        fig.add_trace(
            go.Scatter3d(
                x=[p[0]], y=[p[1]], z=[p[2]], mode="markers", name=f"contact with {m.name}, "
                f"t = {t:.2f} s", marker={"size": 7, "color": _STATIC, "symbol": "x"},
            )
        )  # fmt: skip
        mesh = _mesh(go, m.at(t), f"{m.name} at the contact, t = {t:.1f} s", "#67001f", 0.45,
                     f"{m.name} contact", True, 48)  # fmt: skip
        if mesh is not None:
            fig.add_trace(mesh)


def _verdicts(result) -> list[str]:
    m = result.check.metrics
    s = result.settings

    def mm(v):
        return "-" if v is None else f"{v:.3f} mm"

    lines = [
        f"Re-planning ({s['planner']}, every {s['step_mm']:g} mm at {s['insertion_speed_mm_s']:g}"
        f" mm/s, {s['predict']} prediction): {result.status.value}; {result.reason}.",
        f"Executed path: {result.executed.length_mm:.2f} mm in {m['duration_s']:.2f} s; "
        f"certified clearance to the static anatomy {mm(m['certified_clearance_mm'])}, to the "
        f"moving obstacles as the tip passed {mm(m['certified_moving_clearance_mm'])}; the "
        f"inserted needle to the moving obstacles until the end {mm(m['shaft_clearance_mm'])} "
        "(information).",
    ]
    lines += [f"Violation: {v}" for v in result.check.violations]
    if result.static is not None:
        plan, check = result.static
        if check is None:
            lines.append(f"Plan made once at t = 0: {plan.status.value}, no plan.")
        else:
            cm = check.metrics
            lines.append(
                f"Plan made once at t = 0 ({plan.length_mm:.2f} mm), executed open-loop: "
                f"{'passes' if check.ok else 'fails'} the check; certified clearance to the "
                f"moving obstacles as the tip passed {mm(cm['certified_moving_clearance_mm'])}."
            )
            lines += [f"Violation: {v}" for v in check.violations]
    return lines


def _cycle_rows(result) -> list[dict]:
    rows = []
    for c in result.cycles:
        r = c.result
        offsets = list(c.obstacle_offsets_mm.values())
        rows.append(
            {
                "cycle": c.index + 1,
                "t_s": c.t_s,
                "inserted_mm": c.inserted_mm,
                "plan": c.source,
                "status": r.status.value,
                "cost_mm": r.cost_mm if r.status.has_plan else None,
                "advanced_mm": c.advanced_mm,
                "obstacle_offset_mm": offsets[0] if len(offsets) == 1 else None,
                "window_from_s": c.window_s[0],
                "window_to_s": c.window_s[1],
            }
        )
    return rows


def dynamic_sections(problem, result, *, title: str = "") -> list:
    """The page's sections: verdicts, the figure, the cycles.

    Parameters
    ----------
    problem : SteerableProblem
        The static anatomy, start pose and goal.
    result : DynamicResult
    title : str
        The figure's title.

    Returns
    -------
    list
        Sections for :func:`needlekit.report.html_page.write_report_html`.
    """
    motions = [
        f"{m.name}: drift {np.round(m.motion.velocity_mm_s, 3).tolist()} mm/s"
        + (
            ""
            if m.motion.period_s is None
            else f", sinusoid {np.round(m.motion.amplitude_mm, 3).tolist()} mm every "
            f"{m.motion.period_s:g} s (phase {m.motion.phase_deg:g} deg)"
        )
        for m in result.moving
    ]
    caption = (
        "Green: the path the needle took. Dotted blue: the plan of each cycle, from the tip "
        "where that cycle planned (older plans fainter; 'kept': the rest of the previous "
        "plan, re-checked). The moving obstacles at the cycles' times, earlier places "
        "fainter. Dashed red: the plan made once at t = 0 and executed open-loop, with its "
        "first contact (x) and the obstacle then. Time = inserted length / insertion speed."
    )
    return [
        ListSection(_verdicts(result), "Verdicts"),
        ListSection(motions, "Moving obstacles", "Displacement from the place at t = 0."),
        FigureSection("Paths and obstacles", dynamic_figure(problem, result, title=title), caption),
        TableSection(
            "Cycles",
            _cycle_rows(result),
            "Each cycle plans from the tip at t; the window is the span of times the "
            "obstacles were planned against (for the arrival prediction: when the tip may "
            "reach the goal); the offset is the obstacle's displacement at t.",
        ),
    ]


def write_dynamic_report(path: str | os.PathLike, problem, result, *, title: str = "") -> Path:
    """Write a run among moving obstacles as one self-contained HTML page, atomically.

    Parameters
    ----------
    path : path-like
    problem : SteerableProblem
        The static anatomy, start pose and goal.
    result : DynamicResult
    title : str

    Returns
    -------
    Path
    """
    heading = f"Re-planning among moving obstacles{': ' + title if title else ''}"
    return write_report_html(
        path, title=heading, sections=dynamic_sections(problem, result, title=title)
    )
