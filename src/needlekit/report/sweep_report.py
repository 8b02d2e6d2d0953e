"""Figures and a self-contained HTML report of start-direction sweeps (Feng et al. 2023).

A sweep (:func:`needlekit.planning.steerable.sweep.sweep`) plans from one start point over
many candidate directions; those at least alpha off the entry surface are "effective".
Here, per planner, the direction sphere of Feng's Fig. 8 (effective region yellow, solved
directions coloured by cost, the best one red), the cost per effective direction of their
Fig. 9 and the rows of their Table 4, as plotly figures (drawn in
:mod:`needlekit.report.sweep_figures`, re-exported here) and plain rows. The page itself is
written by :func:`needlekit.report.html_page.write_report_html` (re-exported here)::

    write_report_html("sweep.html", title="...", sections=sweep_sections(sweeps))

A direction counts as solved when its planner returned ``PlanStatus.SOLVED`` with a finite
cost, as in the sweep's own statistics; approximate, infeasible and timed-out runs are
effective directions without a plan.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.sweep import SweepResult
from needlekit.report.html_page import FigureSection, TableSection, TextSection, write_report_html
from needlekit.report.steerable_report import check_text, plan_rows
from needlekit.report.sweep_figures import (
    FIG9_OFFSET,
    _check_sweeps,
    _costs,
    _label,
    best_paths_figure,
    cost_per_direction_figure,
    direction_sphere_figure,
    valid_paths_figure,
)

__all__ = [
    "FIG9_OFFSET",
    "GOAL_CONNECTIONS",
    "FigureSection",
    "TableSection",
    "TextSection",
    "best_paths_figure",
    "cost_per_direction_figure",
    "direction_sphere_figure",
    "direction_table",
    "goal_connection_rule",
    "best_plan_sections",
    "sweep_sections",
    "sweep_study_sections",
    "sweep_table",
    "valid_paths_figure",
    "write_report_html",
]


#: How each built-in planner joins the goal (the rule that decides its costs).
GOAL_CONNECTIONS = {
    "rcs_star": "turn at r_min, then straight, ending tau short of the target",
    "rcs": "one arc to the target itself",
    "rrt": {
        "arc_line": "greedy from every new node: turn at r_min, then straight into the tau-ball",
        "arc": "greedy from every new node: one arc to the target itself",
    },
}

_TABLE_KEYS = ("n_effective", "n_solved", "best_cost_mm", "best_direction", "mean_cost_mm")


_TABLE_KEYS += ("cost_before_lowest_mm", "time_s")


def sweep_table(sweeps: Mapping[str, SweepResult]) -> list[dict]:
    """Feng's Table 4, one row per planner, from the sweeps' statistics.

    Parameters
    ----------
    sweeps : mapping of str to SweepResult

    Returns
    -------
    list of dict
        ``planner``, ``n_effective``, ``n_solved``, ``best_cost_mm``, ``best_direction``
        (3 floats), ``mean_cost_mm``, ``cost_before_lowest_mm`` (Feng's Table 4: the sum of
        the solved directions' costs in sweep order up to and including the lowest) and ``time_s``; ``None`` where missing.
    """
    sweeps = _check_sweeps(sweeps)
    return [
        {"planner": k, **{key: s.stats.get(key) for key in _TABLE_KEYS}} for k, s in sweeps.items()
    ]


def direction_table(sweeps: Mapping[str, SweepResult]) -> list[dict]:
    """Feng's Tables 2-3: every effective direction some planner solved, with each
    planner's cost.

    Parameters
    ----------
    sweeps : mapping of str to SweepResult

    Returns
    -------
    list of dict
        ``effective #`` (1-based, sweep order), ``direction`` (x, y, z) and one cost
        column per planner (mm, ``"-"`` without a plan), in sweep order.
    """
    sweeps = _check_sweeps(sweeps)
    sw = next(iter(sweeps.values()))
    idx = np.flatnonzero(np.asarray(sw.effective, dtype=bool))
    costs = {k: _costs(s) for k, s in sweeps.items()}
    rows = []
    for pos, i in enumerate(idx, start=1):
        if all(np.isnan(c[i]) for c in costs.values()):
            continue
        d = np.asarray(sw.directions[i], dtype=float)
        row = {"effective #": pos, "direction": f"({d[0]:.3f}, {d[1]:.3f}, {d[2]:.3f})"}
        for k, c in costs.items():
            row[f"{_label(k)} cost (mm)"] = "-" if np.isnan(c[i]) else f"{c[i]:.3f}"
        rows.append(row)
    return rows


def goal_connection_rule(planner: str, options: Mapping | None = None) -> str:
    """How a planner joins the goal, in words (:data:`GOAL_CONNECTIONS`).

    Parameters
    ----------
    planner : str
    options : mapping, optional
        The planner's options (RRT's ``connection``).

    Returns
    -------
    str
    """
    rule = GOAL_CONNECTIONS.get(planner)
    if isinstance(rule, dict):
        return rule[(options or {}).get("connection", "arc_line")]
    return rule or "its own (a planner from a plug-in)"


def sweep_sections(
    sweeps: Mapping[str, SweepResult], *, normal=None, scene=None, options=None
) -> list:
    """The standard sections of a sweep report: summary, each planner's goal connection,
    Table 4, Tables 2-3, Fig. 8, Fig. 9 and, given the scene, the best paths.

    Parameters
    ----------
    sweeps : mapping of str to SweepResult
    normal : array_like, shape (3,), optional
        Outward normal of the entry surface, drawn on the direction spheres.
    scene : needlekit.anatomy.scene.Scene, optional
    options : mapping of str to mapping, optional
        Each planner's options (its goal connection depends on them).

    Returns
    -------
    list of FigureSection, TableSection and TextSection
        For :func:`write_report_html`.
    """
    sweeps = _check_sweeps(sweeps)
    sw = next(iter(sweeps.values()))
    text = (
        f"{len(sw.directions)} candidate start directions, {int(np.sum(sw.effective))} in the "
        f"effective puncture region; planners {', '.join(map(_label, sweeps))}. Costs are "
        "path lengths (mm); \u201ccost before lowest\u201d is Feng's planning-rapidity figure, "
        "the sum of the solved directions' costs in sweep order up to and including the lowest."
    )
    sphere = direction_sphere_figure(sweeps, normal=normal)
    rules = [
        {"planner": _label(k), "goal connection": goal_connection_rule(k, (options or {}).get(k))}
        for k in sweeps
    ]
    out = [
        TextSection(text),
        TableSection(
            "How each planner joins the goal",
            rules,
            "The connection decides the costs: planners that find the same path to the same "
            "point differ by it alone.",
        ),
        TableSection("Summary per planner (Table 4)", sweep_table(sweeps)),
        TableSection(
            "Cost per solved effective direction (Tables 2-3)",
            direction_table(sweeps),
            "Every effective direction some planner solved, in sweep order.",
        ),
        FigureSection("Effective puncture region and solved directions (Fig. 8)", sphere),
        FigureSection(
            "Cost per effective direction (Fig. 9)",
            cost_per_direction_figure(sweeps),
            f"Each planner's series sits {FIG9_OFFSET:g} of a position beside the next, with "
            "its own marker size, so that equal costs stay visible.",
        ),
    ]
    if scene is not None:
        first = next(iter(sweeps))
        solved = [r for r in sweeps[first].results if r is not None and r.status.value == "solved"]
        if all(r.plan is not None for r in solved):
            out.append(
                FigureSection(
                    f"Every valid path of {_label(first)} (Fig. 7)",
                    valid_paths_figure(scene, sweeps[first]),
                    "One path per solved effective direction, dark (cheapest) to light "
                    "(costliest); the best in red.",
                )
            )
        else:  # a sweep read back from sweep.json, which keeps the best plans only
            out.append(
                TextSection(
                    f"The sweep's record keeps each planner's best plan only, not the "
                    f"{len(solved)} paths of {_label(first)}'s solved directions that Fig. 7 "
                    "draws; `needlekit sweep --report` draws them as it plans.",
                    heading=f"Every valid path of {_label(first)} (Fig. 7)",
                )
            )
        out.append(FigureSection("Best path per planner", best_paths_figure(scene, sweeps)))
    return out


def best_plan_sections(planner: str, best, check) -> list:
    """The best plan of a sweep: its cost and independent check in words, and its motions.

    Parameters
    ----------
    planner : str
        The planner whose best plan it is.
    best : PlanResult
        With a plan.
    check : Verification
        Its independent check (:func:`~needlekit.planning.steerable.verify.verify_plan`).

    Returns
    -------
    list of TableSection and TextSection
    """
    m = check.metrics
    cert = " and certified optimal at the finest resolution" if best.stats.get("certified") else ""
    angle = m.get("puncture_angle_deg")
    text = (
        f"Best {planner} plan: cost {best.cost_mm:.3f}, length {m['length_mm']:.3f} mm, "
        f"{len(best.plan.primitives)} motions{cert}. Independent check: {check_text(check)} "
        f"(goal distance {m['goal_distance_mm']:.3f} mm, min clearance "
        f"{m['min_clearance_mm']:.3f} mm, heading change {m['max_heading_change_deg']:.1f} deg, "
        f"puncture angle {'-' if angle is None else f'{angle:.1f}'} deg)."
    )
    return [
        TextSection(text, heading="Best plan"),
        TableSection("Best plan: motions", plan_rows(best.plan)),
    ]


def sweep_study_sections(
    sweeps: Mapping[str, SweepResult], problem, *, options=None, best=None, check=None
) -> list:
    """The page of a sweep study (``needlekit sweep --report``, ``needlekit report``): the
    sections of :func:`sweep_sections` in the problem's scene, then the first planner's best
    plan (:func:`best_plan_sections`).

    Parameters
    ----------
    sweeps : mapping of str to SweepResult
    problem : SteerableProblem
        Its scene and the entry surface's normal at the start.
    options : mapping of str to mapping, optional
        Each planner's options.
    best : PlanResult, optional
        The first planner's best plan (None: none).
    check : Verification, optional
        Its independent check; needed with ``best``.

    Returns
    -------
    list of FigureSection, TableSection and TextSection
    """
    sections = sweep_sections(
        sweeps, normal=problem.puncture_normal, scene=problem.scene, options=options
    )
    if best is not None and best.plan is not None:
        if check is None:
            raise InvalidInputError("check", "the best plan's independent check is needed")
        sections += best_plan_sections(next(iter(_check_sweeps(sweeps))), best, check)
    return sections
