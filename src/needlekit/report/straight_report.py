"""A self-contained HTML report of a straight multi-needle plan (Liu et al. 2016).

The planner (:mod:`needlekit.planning.straight`) returns data; this module draws it:

- the CFRW layers and the accessibility map of each needle
  (:mod:`needlekit.report.straight_figures`, re-exported here);
- :func:`scene_figure`: the anatomy (drawn by :func:`needlekit.report.scene3d.scene_figure`),
  every needle from its entry to its target with its order, the heads outside the body and
  the ablation zones as translucent ellipsoids;
- :func:`needle_table`, :func:`blocking_table`: the rows of the page's tables;
- :func:`write_straight_report`: all of them on one page
  (:func:`needlekit.report.html_page.write_report_html`: plotly.js inlined once, opens
  offline, written atomically).

``plan_needles`` keeps no maps; :func:`plan_maps` recomputes the CFRW map each needle was
chosen on (the same inputs, so the same map)::

    maps = plan_maps(problem, plan, resolution_deg=1.0)
    write_straight_report("multi.html", plan=plan, maps=maps, scene=problem.scene)
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from needlekit.anatomy.needle_body import LIU_HEAD, NeedleBody
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.cfrw import (
    CLEARANCE_CAP_ABOVE_GAMMA_MM,
    Blocked,
    CFRWMap,
    cfrw_map,
)
from needlekit.planning.straight.coverage import fraction_text
from needlekit.planning.straight.problem import StraightProblem
from needlekit.planning.straight.sequence import MultiNeedlePlan
from needlekit.report._style import _ORANGE, _PALETTE, _PURPLE
from needlekit.report.html_page import FigureSection, TableSection, TextSection, write_report_html
from needlekit.report.scene3d import scene_figure as _anatomy_figure
from needlekit.report.straight_figures import (
    _GAMMA,
    _PHI,
    _SIGMA,
    _THETA,
    LIU_HEIGHTS_MM,
    _check_map,
    _heights,
    accessibility_map_figure,
    cfrw_layers_figure,
)

__all__ = [
    "LIU_HEIGHTS_MM",
    "accessibility_map_figure",
    "blocking_table",
    "cfrw_layers_figure",
    "needle_table",
    "plan_maps",
    "scene_figure",
    "straight_sections",
    "write_straight_report",
]

#: The paper's figures of the CFRWs of needles 1, 2 and 3.
_PAPER_FIGURES = {1: "Fig. 11", 2: "Fig. 14 and 15", 3: "Fig. 17"}


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` to an orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _ellipsoid_mesh(centre, axis, along_mm: float, across_mm: float, n: int = 18):
    """Vertices (v, 3) and faces (f, 3) of a spheroid: semi-axis ``along_mm`` on ``axis``."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    e1, e2 = _frame(axis)
    u = np.linspace(0.0, np.pi, n + 1)[1:-1]  # rings; the poles are added once
    v = np.linspace(0.0, 2 * np.pi, 2 * n, endpoint=False)
    U, V = np.meshgrid(u, v, indexing="ij")
    ring = (
        along_mm * np.cos(U)[..., None] * axis
        + across_mm * np.sin(U)[..., None] * (np.cos(V)[..., None] * e1 + np.sin(V)[..., None] * e2)
    ).reshape(-1, 3)
    verts = np.vstack([ring, along_mm * axis, -along_mm * axis]) + np.asarray(centre, float)
    r, k = len(u), len(v)
    top, bottom = r * k, r * k + 1
    faces = []
    for i in range(r - 1):
        for j in range(k):
            a, b = i * k + j, i * k + (j + 1) % k
            faces += [(a, b, a + k), (b, b + k, a + k)]
    for j in range(k):
        faces += [(top, (j + 1) % k, j), (bottom, (r - 1) * k + j, (r - 1) * k + (j + 1) % k)]
    return verts, np.array(faces)


def _tube_mesh(start, end, radius_mm: float, n: int = 16):
    """Vertices and faces of a closed cylinder from ``start`` to ``end``."""
    start, end = np.asarray(start, float), np.asarray(end, float)
    axis = (end - start) / np.linalg.norm(end - start)
    e1, e2 = _frame(axis)
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    circle = radius_mm * (np.cos(a)[:, None] * e1 + np.sin(a)[:, None] * e2)
    verts = np.vstack([start + circle, end + circle, start, end])
    faces = []
    for j in range(n):
        k = (j + 1) % n
        faces += [(j, k, n + j), (k, n + k, n + j), (2 * n, k, j), (2 * n + 1, n + j, n + k)]
    return verts, np.array(faces)


def _zones(zones, plan: MultiNeedlePlan) -> list[tuple[np.ndarray, np.ndarray, object]]:
    """``(centre_mm, axis, zone)`` to draw: one AblationZone for every needle, an object
    with ``centres_mm``, ``directions``, ``zone`` (a CoveragePlan), or such triples."""
    if zones is None:
        return []
    if hasattr(zones, "semi_axes_mm"):
        out = []
        for r in plan.needles:
            if r.entry is not None:
                w = r.entry.target_mm - r.entry.entry_mm  # insertion direction
                out.append((zones.centre_of(r.entry.target_mm, w), w, zones))
        return out
    if all(hasattr(zones, a) for a in ("centres_mm", "directions", "zone")):
        zones = [
            (c, d, zones.zone) for c, d in zip(zones.centres_mm, zones.directions, strict=True)
        ]
    out = []
    for i, z in enumerate(zones):
        if not (isinstance(z, (tuple, list)) and len(z) == 3 and hasattr(z[2], "semi_axes_mm")):
            msg = "expected (centre_mm, direction, AblationZone)"
            raise InvalidInputError(f"zones[{i}]", msg)
        c, d = np.asarray(z[0], float).reshape(-1), np.asarray(z[1], float).reshape(-1)
        if c.shape != (3,) or d.shape != (3,) or not np.linalg.norm(d) > 0:
            raise InvalidInputError(f"zones[{i}]", "expected a centre (3,) and a direction (3,)")
        out.append((c, d, z[2]))
    return out


def scene_figure(
    scene,
    plan: MultiNeedlePlan,
    zones=None,
    *,
    head=None,
    shaft_outside_mm: float = 0.0,
    max_cells: int = 80,
    title: str | None = None,
):
    """The anatomy with every planned needle, its head and the ablation zones (3D).

    Parameters
    ----------
    scene : Scene
        The anatomy (drawn by :func:`needlekit.report.scene3d.scene_figure`).
    plan : MultiNeedlePlan
    zones : AblationZone, CoveragePlan or sequence of (centre_mm, direction, AblationZone), optional
        One zone for every needle (centred ``tip_offset_mm`` behind its tip, long axis on
        the needle), or the zones of a coverage plan, or explicit ones (centre (3,) RAS
        mm, long-axis direction (3,)).
    head : NeedleHead, optional
        The needle head to draw outside the body (default the paper's Eq. 4,
        :data:`~needlekit.anatomy.needle_body.LIU_HEAD`, as the planner assumes); drawn
        as a cylinder of its length and diameter. ``False`` draws none.
    shaft_outside_mm : float
        Shaft between the entry point and the head (mm), as in ``NeedleBody``.
    max_cells : int
        Resolution of the anatomy's surfaces.
    title : str, optional

    Returns
    -------
    plotly.graph_objects.Figure
        The anatomy's traces, then per needle with an entry a line trace
        ``"needle <order>"`` from its entry to its target (RAS mm) and a text label at the
        entry, a mesh ``"head <order>"``, and per zone a translucent mesh
        ``"ablation zone <i>"``.
    """
    import plotly.graph_objects as go

    if not isinstance(plan, MultiNeedlePlan):
        raise InvalidInputError("plan", f"expected a MultiNeedlePlan, got {type(plan).__name__}")
    head = LIU_HEAD if head is None else (None if head is False else head)
    targets = np.array([r.planned_target_mm for r in plan.needles]).reshape(-1, 3)
    entries = []  # each needle's entry, and the end of its head outside the skin
    for r in plan.needles:
        if r.entry is not None:
            e, t = np.asarray(r.entry.entry_mm, float), np.asarray(r.entry.target_mm, float)
            out = (e - t) / max(float(np.linalg.norm(e - t)), 1e-12)
            reach = 0.0 if head is None else float(shaft_outside_mm) + head.length_mm
            entries.append(np.array([e, e + reach * out]))
    fig = _anatomy_figure(
        scene,
        targets_mm=targets if len(targets) else None,
        max_cells=max_cells,
        title=title if title is not None else "Planned needles",
        # framed on the needles and their targets, when there are needles to frame
        focus_mm=np.vstack([targets, *entries]) if entries else None,
    )
    aimed = np.array([r.target_mm for r in plan.needles]).reshape(-1, 3)
    if len(aimed) and not np.allclose(aimed, targets):
        fig.add_trace(
            go.Scatter3d(
                x=aimed[:, 0], y=aimed[:, 1], z=aimed[:, 2], mode="markers",
                name="targets displaced by deformation",
                marker={"size": 4, "color": _PURPLE, "symbol": "circle"},
            )
        )  # fmt: skip
    for r in plan.needles:
        if r.entry is None:
            continue
        colour = _PALETTE[(r.order - 1) % len(_PALETTE)]
        tip, entry = r.entry.target_mm, r.entry.entry_mm
        seg = np.array([entry, tip])
        fig.add_trace(
            go.Scatter3d(
                x=seg[:, 0], y=seg[:, 1], z=seg[:, 2], mode="lines+markers",
                name=f"needle {r.order}", legendgroup=f"needle {r.order}",
                line={"width": 7, "color": colour}, marker={"size": [3, 4], "color": colour},
                hovertemplate=f"needle {r.order}<br>(%{{x:.2f}}, %{{y:.2f}}, %{{z:.2f}}) mm"
                "<extra></extra>",
            )
        )  # fmt: skip
        out = (entry - tip) / np.linalg.norm(entry - tip)
        label = entry + 8.0 * out
        fig.add_trace(
            go.Scatter3d(
                x=label[:1], y=label[1:2], z=label[2:], mode="text", text=[str(r.order)],
                textfont={"size": 16, "color": colour}, showlegend=False,
                legendgroup=f"needle {r.order}", name=f"label {r.order}", hoverinfo="skip",
            )
        )  # fmt: skip
        if head is not None:
            start = entry + float(shaft_outside_mm) * out
            v, f = _tube_mesh(start, start + head.length_mm * out, 0.5 * head.diameter_mm)
            fig.add_trace(
                go.Mesh3d(
                    x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                    color=colour, opacity=0.35, name=f"head {r.order}",
                    legendgroup=f"needle {r.order}", showlegend=False, hoverinfo="skip",
                )
            )  # fmt: skip
    for i, (c, d, z) in enumerate(_zones(zones, plan), start=1):
        a, b = z.semi_axes_mm
        v, f = _ellipsoid_mesh(c, d, a, b)
        fig.add_trace(
            go.Mesh3d(
                x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                color=_ORANGE, opacity=0.25, name=f"ablation zone {i}",
                legendgroup="zones", showlegend=True, hoverinfo="skip",
            )
        )  # fmt: skip
    return fig


# ---------------------------------------------------------------------------------------
# data for the page


def plan_maps(problem: StraightProblem, plan: MultiNeedlePlan, *, resolution_deg: float = 1.0,
              head=None, body_factory=None) -> list:  # fmt: skip
    """The CFRW map each needle of a plan was chosen on (``plan_needles`` keeps none).

    Needle ``i``'s map is recomputed as ``plan_needles`` computed it: its (displaced)
    target, the anatomy, and the bodies of the needles before it as obstacles. Same
    inputs, same map: pass the same ``resolution_deg``, ``head`` and ``body_factory``.

    Parameters
    ----------
    problem : StraightProblem
        The problem given to ``plan_needles``.
    plan : MultiNeedlePlan
    resolution_deg : float
    head : NeedleHead, optional
    body_factory : callable, optional
        ``body_factory(tip_mm, entry_mm, radius_mm) -> DistanceField``.

    Returns
    -------
    list of CFRWMap
        One per needle of ``plan.needles``, in insertion order.
    """
    if not isinstance(plan, MultiNeedlePlan):
        raise InvalidInputError("plan", f"expected a MultiNeedlePlan, got {type(plan).__name__}")
    if body_factory is None:
        chosen = LIU_HEAD if head is None else head

        def body_factory(tip, entry, r):
            return NeedleBody(tip, entry, radius_mm=r, head=chosen)

    maps, bodies = [], []
    for r in plan.needles:
        pr = problem.with_target(r.target_mm).with_obstacles(*bodies)
        maps.append(cfrw_map(pr, resolution_deg=resolution_deg))
        if r.entry is not None:
            bodies.append(body_factory(r.entry.target_mm, r.entry.entry_mm, plan.needle_radius_mm))
    return maps


def needle_table(plan: MultiNeedlePlan) -> list[dict]:
    """Rows of the needle table, one per needle in insertion order.

    Parameters
    ----------
    plan : MultiNeedlePlan

    Returns
    -------
    list of dict
        ``order``, ``target`` (index), ``target_mm`` (aimed at, RAS; plus
        ``planned_target_mm`` when deformation moved any), ``entry_mm`` (RAS),
        ``length_mm``, ``clearance_to_anatomy_mm`` (certified), ``clearance_to_needles_mm``
        (certified, to the needles before it; None for the first), ``theta_deg``,
        ``phi_deg``, ``normal_angle_deg`` (None where the needle has no trajectory).
    """
    moved = any(not np.allclose(r.target_mm, r.planned_target_mm) for r in plan.needles)
    rows = []
    for r in plan.needles:
        e = r.entry
        row = {"order": r.order, "target": r.target_index}
        if moved:
            row["planned_target_mm"] = r.planned_target_mm
        row["target_mm"] = r.target_mm
        row["entry_mm"] = None if e is None else e.entry_mm
        row["length_mm"] = None if e is None else e.length_mm
        row["clearance_to_anatomy_mm"] = None if e is None else e.clearance_mm
        nc = r.needle_clearance_mm
        row["clearance_to_needles_mm"] = float(nc) if e is not None and np.isfinite(nc) else None
        row["theta_deg"] = None if e is None else float(np.degrees(e.theta_rad))
        row["phi_deg"] = None if e is None else float(np.degrees(e.phi_rad))
        row["normal_angle_deg"] = None if e is None else e.normal_angle_deg
        rows.append(row)
    return rows


def blocking_table(plan: MultiNeedlePlan) -> list[dict]:
    """Directions of each needle's CFRW map by blocking reason.

    Parameters
    ----------
    plan : MultiNeedlePlan

    Returns
    -------
    list of dict
        ``order``, then one count per :class:`Blocked` reason (lower-case names, ``free``
        being the CFRW) and ``directions`` (their sum).
    """
    rows = []
    for r in plan.needles:
        row = {"order": r.order}
        row.update({b.name.lower(): int(r.blocked.get(b.name.lower(), 0)) for b in Blocked})
        row["directions"] = int(sum(r.blocked.values()))
        rows.append(row)
    return rows


def _check_maps(plan: MultiNeedlePlan, maps) -> list:
    if maps is None:
        return [None] * len(plan.needles)
    if isinstance(maps, CFRWMap) or not isinstance(maps, Sequence):
        raise InvalidInputError("maps", "expected a sequence of CFRWMap, one per needle")
    if len(maps) != len(plan.needles):
        raise InvalidInputError(
            "maps", f"expected one map per needle ({len(plan.needles)}), got {len(maps)}"
        )
    return [None if m is None else _check_map(m, f"maps[{i}]") for i, m in enumerate(maps)]


def _coverage_section(outcome) -> TableSection:
    """The ablation coverage of the plan, as measured along the planned needles."""
    rep = outcome.planned or outcome.chosen.report
    z = outcome.chosen.zone
    zone = (
        f"sphere of {z.diameter_mm:g} mm"
        if z.kind == "sphere"
        else f"ellipsoid {z.length_mm:g} x {z.diameter_mm:g} mm along the needle"
    )
    rows = [
        {"quantity": "status", "value": "covered" if outcome.ok else "not covered"},
        {"quantity": "tumour plus margin covered", "value": fraction_text(rep.coverage)},
        {"quantity": "tumour covered", "value": fraction_text(rep.tumour_coverage)},
        {"quantity": "needles", "value": str(rep.needles)},
        {"quantity": "tumour (mL)", "value": f"{rep.tumour_volume_ml:.1f}"},
        {"quantity": "tumour plus margin (mL)", "value": f"{rep.region_volume_ml:.1f}"},
        {"quantity": "healthy tissue ablated (mL)", "value": f"{rep.healthy_ablated_ml:.1f}"},
        {"quantity": "zone", "value": zone},
        {"quantity": "goal", "value": f"{outcome.chosen.coverage_goal:g}"},
    ]
    if outcome.reason:
        rows.append({"quantity": "why not covered", "value": outcome.reason})
    return TableSection(
        "Ablation coverage",
        rows,
        "Fractions of the tumour-plus-margin voxels inside some ablation zone, each zone along "
        "its planned needle (rounded down); healthy tissue ablated: zone volume outside the "
        "tumour.",
    )


def straight_sections(plan: MultiNeedlePlan, maps, scene, *, zones=None,
                      heights_mm=LIU_HEIGHTS_MM, head=None, max_cells: int = 80,
                      coverage=None, layers=None) -> list:  # fmt: skip
    """The report's sections, in page order (for :func:`write_report_html`).

    Parameters
    ----------
    plan : MultiNeedlePlan
    maps : sequence of CFRWMap or None
        Each needle's CFRW map in insertion order (:func:`plan_maps`), None entries (or
        None) to leave a needle's figures out.
    scene : Scene
    zones : optional
        As :func:`scene_figure`.
    heights_mm : sequence of float
        Layer heights (:func:`cfrw_layers_figure`).
    head : NeedleHead, optional
        As :func:`scene_figure`.
    max_cells : int
        Resolution of the anatomy's surfaces.
    coverage : AblationOutcome, optional
        The ablation coverage of a plan whose targets were chosen for it (a table of it
        follows the summary).
    layers : sequence of (mapping of float to list of ndarray, shape (n_i, 2)) or None, optional
        Per needle, layers of its map already computed (``cfrw_layers_figure``'s
        ``layers``: polylines in Sigma, mm), so that a page drawing a map twice refines it
        once.

    Returns
    -------
    list of FigureSection, TableSection, TextSection
    """
    if not isinstance(plan, MultiNeedlePlan):
        raise InvalidInputError("plan", f"expected a MultiNeedlePlan, got {type(plan).__name__}")
    maps = _check_maps(plan, maps)
    status = "solved" if plan.solved else "not solved"
    summary = (
        f"{len(plan.needles)} needles, {status}; insertion order (target indices) "
        f"{', '.join(str(i) for i in plan.order)} ({plan.orders_tried} orders tried); "
        f"needle radius {plan.needle_radius_mm:g} mm, safety distance {_GAMMA} = "
        f"{plan.gamma_mm:g} mm."
    )
    if plan.reason:
        summary += f" {plan.reason}."
    cap = plan.gamma_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
    sections: list = [
        TextSection(summary, "Summary"),
        TableSection(
            "Needles",
            needle_table(plan),
            f"RAS mm. Clearances are certified lower bounds of the distance from the needle's "
            f"surface, to the anatomy and to the needles placed before it; values of "
            f"{cap:g} mm ({_GAMMA} + {CLEARANCE_CAP_ABOVE_GAMMA_MM:g}) mean at least that. "
            f"{_THETA} and {_PHI}: the direction (target to entry) in Liu's frame "
            f"{_SIGMA} at the target.",
        ),
        TableSection(
            "Directions of each CFRW map by blocking reason",
            blocking_table(plan),
            "free: in the CFRW; clearance: closer than gamma to the anatomy; "
            "placed_needle: clear of the anatomy, closer than gamma to a needle placed "
            "before; too_long, normal_angle, angle_limit, no_entry: the needle's length, "
            "the angle to the surface normal, Eq. 2's angle box (and approach cone), no "
            "entry point.",
        ),
    ]
    if coverage is not None:
        sections.insert(1, _coverage_section(coverage))
    hs = _heights(heights_mm)
    known = [None] * len(maps) if layers is None else list(layers)
    if len(known) != len(maps):
        raise InvalidInputError("layers", f"expected one entry per needle ({len(maps)}), got {len(known)}")
    for r, m, done in zip(plan.needles, maps, known, strict=True):
        if m is None:
            continue
        placed = [q for q in plan.needles if q.order <= r.order]
        paper = _PAPER_FIGURES.get(r.order)
        caption = (
            f"Needle {r.order} (target {r.target_index}): (a) the CFRW (shaded; holes "
            f"excluded) in the plane z = {hs[0]:g} mm of {_SIGMA}, the trajectories' "
            f"crossings; (b) its boundaries at z = {', '.join(f'{h:g}' for h in hs)} mm "
            f"with the trajectories planned so far."
        )
        if paper:
            caption += f" As the paper's {paper}."
        fig = cfrw_layers_figure(m, hs, placed, layers=done, title=f"CFRW of needle {r.order}")
        sections.append(FigureSection(f"CFRW of needle {r.order}", fig, caption))
    for r, m in zip(plan.needles, maps, strict=True):
        if m is None:
            continue
        fig = accessibility_map_figure(m, [r], title=f"Accessibility map of needle {r.order}")
        caption = (
            f"Needle {r.order}: each direction of the map ({m.blocked.size}) at its entry "
            f"point, coloured by certified clearance when in the CFRW, else by what blocks "
            f"it; the star is the chosen trajectory."
        )
        sections.append(FigureSection(f"Accessibility map of needle {r.order}", fig, caption))
    sections.append(
        FigureSection(
            "3D scene",
            scene_figure(scene, plan, zones, head=head, max_cells=max_cells),
            "Every needle from its entry to its target, numbered by insertion order, its "
            "head outside the body" + (", and the ablation zones." if zones is not None else "."),
        )
    )
    return sections


def write_straight_report(
    path: str | os.PathLike,
    *,
    plan: MultiNeedlePlan,
    maps,
    scene,
    zones=None,
    title: str = "Straight multi-needle plan",
    heights_mm=LIU_HEIGHTS_MM,
    head=None,
    max_cells: int = 80,
    coverage=None,
) -> Path:
    """Write a multi-needle plan's report as one self-contained HTML page, atomically.

    The page (plotly.js inlined once; opens offline) holds the summary, the needle table,
    the blocking counts, each needle's CFRW layers and accessibility map, and the 3D
    scene (:func:`straight_sections`). On any error ``path`` keeps its old content.

    Parameters
    ----------
    path : path-like
    plan : MultiNeedlePlan
    maps : sequence of CFRWMap or None
        Each needle's CFRW map in insertion order (:func:`plan_maps`).
    scene : Scene
    zones : optional
        As :func:`scene_figure`.
    title : str
    heights_mm : sequence of float
    head : NeedleHead, optional
    max_cells : int
    coverage : AblationOutcome, optional
        As :func:`straight_sections`.

    Returns
    -------
    Path
        The destination.
    """
    sections = straight_sections(
        plan, maps, scene, zones=zones, heights_mm=heights_mm, head=head, max_cells=max_cells,
        coverage=coverage,
    )  # fmt: skip
    return write_report_html(path, title=title, sections=sections)
