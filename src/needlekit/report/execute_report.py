"""The page of ``needlekit execute --report``: one trial animated in 3D (the plan, the
open-loop path, the closed-loop tip going in with the plan it follows, re-plans as they
apply), the final errors open beside closed loop, the re-plan latency, the summary and the
published closed-loop figures beside it."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit.report.html_page import FigureSection, TableSection, TextSection, write_report_html

__all__ = [
    "TITLE",
    "animated_trial_figure",
    "execute_sections",
    "shown_trial",
    "write_execute_report",
]

#: The page's title.
TITLE = "Plan execution: open beside closed loop"

#: Colours: the plan, open loop, closed loop (in 2D figures; the 3D view draws the
#: closed-loop path in :data:`needlekit.report.scene3d.PATH_COLOUR`), the plan followed.
_PLAN, _OPEN, _CLOSED, _FOLLOWED = "#2a9d8f", "#e76f51", "#264653", "#e9c46a"
#: Insertion between two frames of the animation (mm).
FRAME_STEP_MM: float = 2.0
#: The anatomy's surfaces: samples per axis at most (a lung's vessels stay readable).
MAX_CELLS: int = 96


def shown_trial(trials: list[dict]) -> dict | None:
    """The trial the page animates: the one that re-planned most (the first of those),
    among those that ran.

    Parameters
    ----------
    trials : list of dict

    Returns
    -------
    dict or None
    """
    ran = [t for t in trials if "closed_loop" in t]
    if not ran:
        return None
    return max(ran, key=lambda t: (t["closed_loop"]["replans"], -t["trial"]))


def _line(go, pts, name, colour, width, dash=None, visible=True):
    pts = np.asarray(pts, dtype=float).reshape(-1, 3)
    return go.Scatter3d(
        x=pts[:, 0], y=pts[:, 1], z=pts[:, 2], mode="lines", name=name, visible=visible,
        line={"color": colour, "width": width, "dash": dash},
    )  # fmt: skip


def _followed(plan_pts, events: list[dict], inserted: float) -> np.ndarray:
    """The plan the needle follows once ``inserted`` mm are in."""
    pts = plan_pts
    for e in events:
        if e["applied_at_mm"] <= inserted:
            pts = np.asarray(e["points_mm"])
    return pts


def animated_trial_figure(problem, plan, trial: dict, *, title: str = ""):
    """The anatomy, the plan, the open-loop path and the closed-loop tip going in (a frame
    every :data:`FRAME_STEP_MM`), with the plan it follows at each moment.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan
    trial : dict
        A trial of ``execute.json``.
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go

    from needlekit.report.scene3d import PATH_COLOUR, scene_figure

    plan_pts = plan.points_mm(1.0)
    closed, opened = trial["closed_loop"], trial["open_loop"]
    path = np.asarray(closed["points_mm"])
    focus = np.vstack([plan_pts, path, np.asarray(opened["points_mm"]), problem.goal_mm[None]])
    fig = scene_figure(problem.scene, start_poses=np.asarray(problem.start_pose)[None],
                       targets_mm=problem.goal_mm[None], max_cells=MAX_CELLS, title=title,
                       focus_mm=focus)  # fmt: skip
    spacing = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(spacing)])
    events = closed.get("replan_events", [])
    fig.add_trace(_line(go, plan_pts, "plan", _PLAN, 4, "dash"))
    fig.add_trace(_line(go, opened["points_mm"], f"open loop ({opened['final_error_mm']:.2f} mm off)",
                        _OPEN, 4))  # fmt: skip
    first = len(fig.data)
    fig.add_trace(_line(go, path[:1], f"closed loop ({closed['final_error_mm']:.2f} mm off)",
                        PATH_COLOUR, 8))  # fmt: skip
    fig.add_trace(_line(go, plan_pts, "plan followed (re-plans as they apply)", _FOLLOWED, 5))
    stops = [*np.arange(0.0, arc[-1], FRAME_STEP_MM), arc[-1]]
    frames = []
    for s in stops:
        k = int(np.searchsorted(arc, s, "right"))
        followed = _followed(plan_pts, events, s)
        frames.append(go.Frame(
            name=f"{s:.0f}",
            data=[_line(go, path[: max(k, 1)], None, PATH_COLOUR, 8), _line(go, followed, None, _FOLLOWED, 5)],
            traces=[first, first + 1],
        ))  # fmt: skip
    fig.frames = frames
    fig.data[first].x, fig.data[first].y, fig.data[first].z = path[:, 0], path[:, 1], path[:, 2]
    last = _followed(plan_pts, events, arc[-1])
    fig.data[first + 1].x, fig.data[first + 1].y, fig.data[first + 1].z = last.T
    steps = [{"label": f.name, "method": "animate",
              "args": [[f.name], {"mode": "immediate", "frame": {"duration": 0, "redraw": True}}]}
             for f in frames]  # fmt: skip
    fig.update_layout(
        sliders=[{"steps": steps, "active": len(steps) - 1,
                  "currentvalue": {"prefix": "inserted (mm): "}}],
        updatemenus=[{"type": "buttons", "showactive": False, "buttons": [{
            "label": "play", "method": "animate",
            "args": [None, {"frame": {"duration": 80, "redraw": True}, "fromcurrent": False}],
        }]}],
    )  # fmt: skip
    return fig


def _histograms(trials: list[dict]):
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    ran = [t for t in trials if "closed_loop" in t]
    lat = [1e3 * v for t in ran for v in t["closed_loop"]["replan_latency_s"]]
    fig = make_subplots(rows=1, cols=2, subplot_titles=[
        "final tip-to-target error (mm)", "re-plan latency (ms)"])  # fmt: skip
    for loop, colour in (("open_loop", _OPEN), ("closed_loop", _CLOSED)):
        fig.add_trace(go.Histogram(x=[t[loop]["final_error_mm"] for t in ran], nbinsx=30,
                                   name=loop.replace("_", " "), marker={"color": colour},
                                   opacity=0.75), 1, 1)  # fmt: skip
    fig.add_trace(
        go.Histogram(x=lat, nbinsx=30, name="re-plans", marker={"color": _FOLLOWED}), 1, 2
    )
    fig.add_vline(x=1.0, line={"dash": "dot", "color": "#888"}, row=1, col=1)
    fig.add_vline(x=25.0, line={"dash": "dot", "color": "#888"}, row=1, col=2)
    fig.update_layout(barmode="overlay", height=420)
    fig.update_yaxes(title_text="trials", col=1)
    fig.update_yaxes(title_text="re-plans", col=2)
    return fig


def _summary_rows(summary: dict) -> list[dict]:
    rows = []
    for loop in ("open_loop", "closed_loop"):
        r = summary[loop]
        e, c, lat = r["final_error_mm"], r["min_clearance_mm"], r["replan_latency_ms"]
        rows.append({
            "run": loop.replace("_", " "), "error_mean_mm": e.get("mean"), "error_sd_mm": e.get("sd"),
            "error_p95_mm": e.get("p95"), "error_max_mm": e.get("max"),
            "within 1 mm": f"{100 * (r['within_1mm'] or 0):.0f} %", "crossed": r["violated"],
            "min_clearance_mm": c.get("min"), "re-plans per trial": r["replans"].get("mean"),
            "re-plan p95 (ms)": lat.get("p95"),
        })  # fmt: skip
    return rows


def _policy_rows(per_policy: dict) -> list[dict]:
    return [
        {"policy": name, "error_mean_mm": r["final_error_mm"].get("mean"),
         "error_sd_mm": r["final_error_mm"].get("sd"), "error_max_mm": r["final_error_mm"].get("max"),
         "within 1 mm": f"{100 * (r['within_1mm'] or 0):.0f} %", "crossed": r["violated"],
         "procedure_s": r["procedure_s"].get("mean")}
        for name, r in per_policy.items()
    ]  # fmt: skip


def execute_sections(doc: dict, problem, plan) -> list:
    """The page's sections for an ``execute.json`` document.

    Parameters
    ----------
    doc : dict
    problem : SteerableProblem
    plan : SteerablePlan

    Returns
    -------
    list
    """
    s = doc["summary"]
    sections = [TextSection(
        f"{s['trials']} trials of the plan on {doc['scenario'] or 'the scenario'}, each open loop "
        f"and closed loop on the same needle and tissue draws (seed {doc['seed']}); plans and "
        f"re-plans keep a {s['margin_mm']:g} mm margin. Errors and clearances are the true "
        "tip's; a crossing is the scenario's collision model's verdict on the executed path "
        "without the margin.")]  # fmt: skip
    sections.append(TableSection("Open loop beside closed loop", _summary_rows(s)))
    if "breathing" in s:
        b = doc["options"]["breathing"]
        sections.append(TableSection(
            "Breathing: the closed loop under each policy", _policy_rows(s["breathing"]),
            caption=f"The anatomy moving {b['amplitude_mm']:g} mm along "
            f"({', '.join(f'{v:g}' for v in b['direction'])}) every {b['period_s']:g} s "
            f"(sin^{2 * b['shape']}, each cycle's amplitude and period varying by "
            f"{100 * b['amplitude_jitter']:g} % and {100 * b['period_jitter']:g} %). Ignore: "
            "insert as if still; gate: advance only at end-exhale; track: follow the "
            "predicted motion. Errors and crossings in the tissue.",
        ))  # fmt: skip
    trial = shown_trial(doc["trials"])
    if trial is not None:
        sections.append(FigureSection(
            f"Trial {trial['trial']} going in", animated_trial_figure(problem, plan, trial),
            caption="Play, or drag the slider: the closed-loop tip as it goes in, and the plan "
            "it follows (the original, then each re-plan from where the tip was when its "
            "search returned). The open-loop path of the same needle beside it.",
        ))  # fmt: skip
        sections.append(FigureSection("Errors and re-plan latency", _histograms(doc["trials"]),
                                      caption="Dotted: 1 mm, and the 25 ms re-plan budget."))  # fmt: skip
    if s["crashed"]:
        sections.append(TableSection("Trials that crashed", s["crashed"]))
    lit = [{"source": r["source"], "setting": r["setting"],
            "error": r["note"] or f"{r['mean_mm']:g}" + (f" +- {r['sd_mm']:g}" if r["sd_mm"] else "") + " mm"}
           for r in s["literature"]]  # fmt: skip
    sections.append(TableSection("Published closed-loop errors", lit,
                                 caption="Phantoms, tissue and patients, not this simulation: "
                                 "context, not a reproduction."))  # fmt: skip
    return sections


def write_execute_report(path: str | os.PathLike, doc: dict, problem, plan) -> Path:
    """Write the page (atomically).

    Parameters
    ----------
    path : path-like
    doc : dict
        ``execute.json``'s document.
    problem : SteerableProblem
    plan : SteerablePlan

    Returns
    -------
    Path
    """
    return write_report_html(path, title=TITLE,
                             sections=execute_sections(doc, problem, plan))  # fmt: skip
