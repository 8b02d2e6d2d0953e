"""The page of ``needlekit study feng-lungs``: Feng et al.'s protocol on a Med-RAD lung.

One self-contained page: the measured Table 4 beside Feng's, whether their order of the
mean costs holds, the two targets, how the case differs from Feng's, how often the direct
connection would have done, the independent checks, and per target the standard sweep
sections (:func:`needlekit.report.sweep_report.sweep_sections`: each planner's goal
connection, Tables 2-4, Figs. 7-9).
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.scene import Scene
from needlekit.report.html_page import (
    ListSection,
    PartSection,
    TableSection,
    TextSection,
    write_report_html,
)
from needlekit.report.sweep_report import sweep_sections

__all__ = [
    "TITLE",
    "differences_from_feng",
    "feng_lungs_sections",
    "table4_rows",
    "write_feng_lungs_report",
]

#: The page's title.
TITLE = "Feng et al.'s protocol on a Med-RAD lung (patient 5, start 1)"

_LABELS = {"rcs": "RCS", "rcs_star": "RCS*", "rrt": "RRT"}
_GOAL_NAMES = {"goal1": "goal 1", "goal2": "goal 2"}
#: Anatomy drawn around the paths, start and target (mm beyond them on every side): the
#: figures zoom onto the paths with a 15-20 mm margin (report.scene3d, report.sweep_report).
VIEW_MARGIN_MM: float = 20.0
#: How far from a surface the drawn fields must be exact (mm): more than a cell of the
#: meshing grid, whose marching cubes read values only around the zero level.
VIEW_SURFACE_REACH_MM: float = 3.0


class _Window(DistanceField):
    """A field drawn over a box only: its surface is meshed on a grid of that box, finer
    than the whole lung's grid would be at the same number of cells (display only)."""

    def __init__(self, field: DistanceField, box: np.ndarray) -> None:
        self.field, self.box = field, np.asarray(box, dtype=float)
        self.error_bound_mm = field.error_bound_mm

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        return self.field._signed_distance(points)

    def bounds(self) -> np.ndarray:
        return self.box


def _view_scene(problem, sweeps: dict) -> Scene:
    """The problem's scene cut to the box around its start, target and every solved path."""
    pts = [problem.start_point_mm[None], problem.goal_mm[None]]
    for sw in sweeps.values():
        pts += [r.plan.points_mm(1.0) for r in sw.results if r is not None and r.plan is not None]
    pts = np.vstack(pts)
    box = np.stack([pts.min(axis=0) - VIEW_MARGIN_MM, pts.max(axis=0) + VIEW_MARGIN_MM])
    scene = problem.scene
    cut = []
    for s in scene.structures:
        # a window of a CT structure's mask around the box, not its whole field: exact where
        # a surface crosses the box, the right side everywhere else (anatomy.voxel_local)
        field = s.field.near_box(box, VIEW_SURFACE_REACH_MM)
        if field is not None:  # None: the structure lies farther than that from the box
            cut.append(replace(s, field=_Window(field, box)))
    return Scene(cut, name=scene.name)


def _page_wall_s(record: dict) -> float:
    """The study's wall time up to its page (the record's ``wall_s`` counts the page too;
    a record written before it kept the two apart has only that one)."""
    return record.get("page_wall_s", record.get("wall_s", 0.0))


def _mm(v) -> str:
    return "-" if v is None else f"{v:.3f} mm"


def table4_rows(record: dict) -> list[dict]:
    """Feng's Table 4 beside the measured one: one row per target and planner.

    Parameters
    ----------
    record : dict
        The study record (``feng_lungs.json``).

    Returns
    -------
    list of dict
        ``target``, ``planner``, solved directions (of the effective ones) and Feng's,
        best, mean and "before lowest" costs and Feng's (mm), and the mean over the
        directions every planner solved.
    """
    rows = []
    for g, rec in record["goals"].items():
        feng = record["feng"]["table4"][g]
        for k, ours in rec["table4"].items():
            f = feng.get(k, {})
            rows.append(
                {
                    "target": _GOAL_NAMES.get(g, g),
                    "planner": _LABELS.get(k, k),
                    "solved": f"{ours['n_solved']} of {ours['n_effective']}",
                    "Feng solved": f.get("n_solved"),
                    "best_mm": ours["best_cost_mm"],
                    "Feng best_mm": f.get("best_cost_mm"),
                    "mean_mm": ours["mean_cost_mm"],
                    "Feng mean_mm": f.get("mean_cost_mm"),
                    "before lowest_mm": ours["cost_before_lowest_mm"],
                    "Feng before lowest_mm": f.get("cost_before_lowest_mm"),
                    "mean over common_mm": rec["mean_over_common_mm"][k],
                }
            )
    return rows


def _order_text(record: dict) -> str:
    parts = []
    for g, rec in record["goals"].items():
        means = {k: v["mean_cost_mm"] for k, v in rec["table4"].items()}
        if rec["order"] is None:
            unsolved = [_LABELS.get(k, k) for k, v in means.items() if v is None]
            parts.append(f"{_GOAL_NAMES[g]}: no order ({', '.join(unsolved)} solved no direction)")
            continue
        chain = " < ".join(f"{_LABELS.get(k, k)} {means[k]:.3f}" for k in rec["order"])
        verdict = "holds" if rec["order_holds"] else "does NOT hold"
        common = rec["mean_over_common_mm"]
        if rec["n_common"]:
            over = ", ".join(f"{_LABELS.get(k, k)} {v:.3f}" for k, v in common.items())
            extra = f"; over the {rec['n_common']} directions all three solved: {over} mm"
        else:
            extra = "; no direction was solved by all three"
        parts.append(f"{_GOAL_NAMES[g]}: {chain} mm, Feng's order {verdict}{extra}")
    return (
        "Feng's Table 4 orders the mean costs RCS* < RRT < RCS for both targets. Here "
        "(means over each planner's own solved directions, as Feng's): " + "; ".join(parts) + "."
    )


def _targets_rows(record: dict) -> list[dict]:
    feng = record["feng"]["points_mm"]
    rows = []
    for g, rec in record["goals"].items():
        how = (
            "Med-RAD's target (in the nodule)"
            if g == "goal1"
            else "goal 1 moved by Feng's goal offset (-10, -10, +10) mm, in RAS"
        )
        fs = [a - b for a, b in zip(feng[g], feng["start"], strict=True)]
        rows.append(
            {
                "target": _GOAL_NAMES.get(g, g),
                "point_mm": rec["goal_mm"],
                "chosen as": how,
                "straight from start_mm": rec["straight_distance_mm"],
                "Feng straight from start_mm": sum(v * v for v in fs) ** 0.5,
                "clearance to obstacles_mm": rec["goal_clearance_mm"],
                "in the nodule": rec["in_nodule"],
            }
        )
    return rows


def differences_from_feng(record: dict) -> list[str]:
    """How the Med-RAD case differs from Feng's setup, one sentence each.

    Parameters
    ----------
    record : dict
        The study record (``feng_lungs.json``).

    Returns
    -------
    list of str
    """
    case, s = record["case"], record["settings"]
    g1, g2 = record["goals"]["goal1"], record["goals"]["goal2"]
    pts = record["feng"]["points_mm"]
    f1, f2 = (sum((a - b) ** 2 for a, b in zip(pts[g], pts["start"], strict=True)) ** 0.5
              for g in ("goal1", "goal2"))  # fmt: skip
    budget = f"{s['time_limit_s']:g} s per direction and planner"
    if s["max_iterations"] is not None:
        budget += f" or {s['max_iterations']} iterations, whichever comes first"
    rrt = s["options"]["rrt"]["connection"]
    return [
        "Obstacles: Feng et al. print their start and goals but not their lung obstacles "
        "(the paper names vessels, bronchi and bone), so their case cannot be rerun. Here: "
        "Med-RAD lung patient 5 (LIDC525), with the bronchial tree, vessels and fissures "
        "as obstacles and everything outside the pleural boundary off limits.",
        f"Start: Med-RAD's start pose 1 of that patient, its point only "
        f"({', '.join(f'{v:.2f}' for v in case['start_point_mm'])}) mm RAS, on the airway "
        "wall; its direction is swept. Feng's start lies in their own CT frame.",
        f"Targets: goal 1 is Med-RAD's target, {g1['straight_distance_mm']:.1f} mm from the "
        f"start (Feng's goal 1: {f1:.1f} mm); goal 2 is it moved by Feng's own offset between "
        f"their goals, {g2['straight_distance_mm']:.1f} mm from the start (Feng's: {f2:.1f} mm), "
        "in free lung tissue outside the 5.7 mm nodule. Feng's frame is not stated: the "
        "offset is applied in RAS.",
        "The surface of the puncture angle: the airway wall's outward normal at the start "
        f"({case['puncture_normal_source']}); Feng do not print theirs.",
        f"Directions: {s['directions']} on a Fibonacci lattice; Feng's 544 come from a "
        "refined sphere whose construction is not given, so the effective directions are "
        "not theirs and their count differs.",
        f"Collision test: the certified field model (clearance less the field's "
        f"{case['field_error_bound_mm']:.2f} mm error bound) for Feng's 2 mm needle, with "
        "obstacles within 3 mm of the start ignored (the reference planner's rule; the "
        "needle leaves the airway through its wall); Feng do not describe their test.",
        f"Planners: needlekit's RCS*, RCS and RRT (Python and numba), RRT joining the goal by "
        f"{'one arc, the reference implementation rule' if rrt == 'arc' else 'arc then line'} "
        f"(seed {s['seed']}); Feng's are their own implementation of their Algorithm 1.",
        f"Budget: {budget}, the clock counting search only (set-up apart), run on "
        f"{record['machine']['cpu_count']} cores shared with other work; Feng ran 1 s per "
        "direction on an Intel i5-7200U.",
        "Feng's k_max = 50 mm^-1 is read as r_min = 50 mm (a curvature of 0.02 per mm), and "
        "their start's x as -64.8324 (their worked example of Fig. 8b), not 64.8324 (their "
        f"Section 5): only that sign puts their goals {f1:.1f} and {f2:.1f} mm from the start, "
        "within their costs. Table 2's RCS mean is printed 62.7956 mm; its rows average "
        "62.6647 mm.",
    ]


def _direct_rows(record: dict) -> list[dict]:
    rows = []
    for g, rec in record["goals"].items():
        d = dict(rec["direct"])
        row = {"target": _GOAL_NAMES.get(g, g), "effective": d.pop("n_effective")}
        row["direct valid"] = d.pop("valid", 0)
        row.update({f"direct: {k}": v for k, v in sorted(d.items())})
        for k, t in rec["table4"].items():
            row[f"{_LABELS.get(k, k)} solved, not direct"] = (
                f"{t['solved_not_direct']} of {t['n_solved']}"
            )
        rows.append(row)
    return rows


def _check_rows(record: dict) -> list[dict]:
    rows = []
    for g, rec in record["goals"].items():
        for k, c in rec["checks"].items():
            best = c["best"]
            rows.append(
                {
                    "target": _GOAL_NAMES.get(g, g),
                    "planner": _LABELS.get(k, k),
                    "solved plans passed": f"{c['passed']} of {c['solved']}",
                    "best passed": None if best is None else best["ok"],
                    "best certified clearance_mm": None
                    if best is None
                    else best["certified_clearance_mm"],
                    "best puncture angle_deg": None if best is None else best["puncture_angle_deg"],
                }
            )
    return rows


def write_feng_lungs_report(
    path: str | os.PathLike, record: dict, sweeps: dict, problems: dict, options: dict
) -> Path:
    """Write the study's page (:func:`feng_lungs_sections`), atomically.

    Parameters
    ----------
    path : path-like
        The HTML page.
    record, sweeps, problems, options : dict
        As :func:`feng_lungs_sections` takes them.

    Returns
    -------
    Path
    """
    return write_report_html(
        path,
        title=TITLE,
        sections=feng_lungs_sections(record, sweeps, problems, options),
    )


def feng_lungs_sections(record: dict, sweeps: dict, problems: dict, options: dict) -> list:
    """The study page's sections: Table 4 beside Feng's, the order of the mean costs, the
    targets, the differences from Feng's setup, the direct connections, the checks, and per
    target the sweep's tables and figures.

    Parameters
    ----------
    record : dict
        The study record (``feng_lungs.json``).
    sweeps : dict
        Per goal, per planner, its SweepResult.
    problems : dict
        Per goal, its SteerableProblem (scene, normal).
    options : dict
        Per planner, its options (RRT's connection).

    Returns
    -------
    list
    """
    s = record["settings"]
    n = s["needle"]
    intro = (
        "Feng et al.'s effective-puncture-region protocol (their Algorithm 1, Tables 2-4, "
        "Figs. 7-9) on real anatomy: one start point, "
        f"{s['directions']} candidate start directions, those at least "
        f"{n['min_puncture_angle_deg']} deg off the airway wall effective, RCS*, RCS and RRT "
        f"from each, to two targets. Feng's needle: diameter {n['diameter_mm']} mm, r_min "
        f"{n['r_min_mm']} mm, l_max {n['max_length_mm']} mm, tau {s['tolerance_mm']} mm, "
        f"turns at most {n['max_heading_change_deg']} deg. Budget {s['time_limit_s']:g} s per "
        "direction and planner"
        + ("" if s["max_iterations"] is None else f" or {s['max_iterations']} iterations")
        + f"; wall time {_page_wall_s(record):.0f} s. Costs are path lengths (mm)."
    )
    sections: list = [
        TextSection(intro),
        TableSection(
            "Table 4 beside Feng's",
            table4_rows(record),
            "Feng's columns as printed (Tables 2-4). \u201cBefore lowest\u201d: the sum of the "
            "solved directions' costs in sweep order up to and including the lowest; it "
            "depends on the order the directions are visited in, which differs from Feng's.",
        ),
        TextSection(_order_text(record), heading="Feng's order of the mean costs"),
        TableSection("The two targets", _targets_rows(record)),
        ListSection(differences_from_feng(record), heading="How this case differs from Feng's"),
        TableSection(
            "Does the direct connection do?",
            _direct_rows(record),
            "From each effective direction, the direct connection (turn at r_min, then "
            "straight, ending tau short: the shortest path to the target) through the "
            "independent check. Where it fails, a plan from that direction bends around "
            "what blocks it; \u201cnot direct\u201d counts the solved directions where it fails.",
        ),
        TableSection(
            "Independent check of every solved plan",
            _check_rows(record),
            "Every solved plan re-derived from its motions and checked (samples 0.25 mm "
            "apart, certified clearance, puncture angle, heading, length, goal, cost).",
        ),
    ]
    for g, sw in sweeps.items():
        rec = record["goals"][g]
        p = problems[g]
        sections.append(
            PartSection(
                f"{_GOAL_NAMES.get(g, g).capitalize()}: "
                f"({', '.join(f'{v:.2f}' for v in rec['goal_mm'])}) mm",
                f"{rec['straight_distance_mm']:.1f} mm from the start in a straight line, "
                f"{rec['goal_clearance_mm']:.2f} mm from the nearest obstacle.",
            )
        )
        view = _view_scene(p, sw)
        sections += sweep_sections(sw, normal=p.puncture_normal, scene=view, options=options)
    return sections
