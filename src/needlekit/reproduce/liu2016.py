"""Liu et al. 2016 re-run: three straight needles planned one after another in their CFRWs.

The paper's simulation (its Figs 10-18): targets (0, 0, 0), (0, -15, 0) and (0, -30, 0)
mm of its frame Sigma, superquadric vessels as obstacles, safety distance gamma 1.5 mm,
needles inserted in the order 1, 2, 3, each placed needle an obstacle for the next. The
scenario is needlekit's own rendering of it (``needlekit/data/liu2016_three_needles.yaml``:
the paper does not publish its vessels or skin), so the numbers compared are the paper's
*properties* (every trajectory on the CFRW boundary exactly gamma from the vessels, every
planned trajectory inside its CFRW, no interference) and the plan's own figures.

Parts: (1) needle 1's CFRW and its layers (Fig. 11); (2) the Fig. 12 check on the
boundary; (3) the three needles (Figs 13-18), re-checked by ``verify``; (4) the same with
the targets moved by tissue deformation (the paper's Fig. 4 loop with its deformation
step; needlekit's default needle-drag model, whose parameters are assumptions).
"""

from __future__ import annotations

import os
from dataclasses import replace
from importlib import resources
from pathlib import Path

import numpy as np

from needlekit.io.files import write_json, write_text
from needlekit.planning.interface import Termination, get_planner
from needlekit.report.html_page import FigureSection, TableSection, TextSection
from needlekit.reproduce._page import Reproduction, Stages
from needlekit.scenario.straight import multi_problem_from_scenario

__all__ = ["SCENARIO", "boundary_clearance", "run"]

#: The packaged scenario (the paper's case on the liver phantom).
SCENARIO = "liu2016_three_needles.yaml"
#: The superquadric vessels of the scenario (the obstacles the paper's Fig. 12 measures).
VESSELS = ("vessel_a", "vessel_b", "vessel_c")
CITATION = (
    "S. Liu, Z. Xia, J. Liu, J. Xu, H. Ren, T. Lu, X. Yang, 'Automatic Multiple-Needle "
    "Surgical Planning of Robotic-Assisted Microwave Coagulation in Large Liver Tumor "
    "Therapy', PLoS ONE 11(3): e0149482, 2016"
)
#: The layer of needle 1's CFRW where the Fig. 12 check runs: below the skin (78 mm above
#: the targets), where the vessels, not the ribs, bound the workspace.
FIG12_LAYER_MM = 60.0


def _vessel_distance(scene, points):
    return np.min([scene[v].field.signed_distance(points) for v in VESSELS], axis=0)


def _vessel_clearance(scene, tip, points, radius, step_mm, coarse_mm=0.5):
    """Clearance of the needle's surface from the vessels along each segment tip -> point,
    the least distance over samples every ``step_mm``.

    The distance is 1-Lipschitz, so the fine samples' least value lies within half a coarse
    step of a coarse sample no more than ``coarse_mm / 2`` above the coarse least value:
    only the coarse cells around those are sampled finely (the result equals sampling the
    whole segment every ``step_mm``, up to where the fine samples fall).
    """
    out = np.empty(len(points))
    for k, p in enumerate(points):
        length = float(np.linalg.norm(p - tip))
        u = (p - tip) / length
        t = np.linspace(0.0, length, int(np.ceil(length / coarse_mm)) + 1)
        d = _vessel_distance(scene, tip + t[:, None] * u)
        low = t[d <= d.min() + 0.5 * coarse_mm + 1e-9]
        fine = np.unique(
            np.concatenate(
                [
                    np.arange(max(c - coarse_mm, 0.0), min(c + coarse_mm, length), step_mm)
                    for c in low
                ]
                + [[length]]
            )
        )
        out[k] = min(float(d.min()), float(_vessel_distance(scene, tip + fine[:, None] * u).min()))
    return out - radius


def _rib_clearance(scene, tip, directions, radius, step_mm=0.05):
    """Clearance of the needle's surface from the ribs along each ray from the tip to the skin."""
    t = np.arange(0.0, 150.0, step_mm)
    out = np.empty(len(directions))
    for k, u in enumerate(directions):
        s = tip + t[:, None] * u
        inside = scene["body"].field.signed_distance(s) < 0
        s = s[: int(np.argmin(inside)) if not inside.all() else len(s)]
        out[k] = float(scene["ribs"].field.signed_distance(s).min()) - radius
    return out


def boundary_clearance(scene, problem, cfrw, h_mm: float, *, step_mm: float = 0.02) -> dict:
    """The paper's Fig. 12 measurement: how far trajectories on the CFRW boundary pass
    from the vessels.

    The boundary vertices of the layer ``z = h_mm`` that were refined onto the clearance
    level, and that the vessels bound (the ribs are more than gamma + 0.5 mm away along
    them), are measured with the vessels' exact distance, sampled every ``step_mm`` along
    the needle.

    Parameters
    ----------
    scene : Scene
        The paper's phantom (its vessels are measured exactly).
    problem : StraightProblem
    cfrw : CFRWMap
        The target's map.
    h_mm : float
        Height of the layer (mm).
    step_mm : float
        Sampling step along each needle (mm).

    Returns
    -------
    dict
        ``vertices`` (all of the layer), ``vessel_bound`` (those measured),
        ``min_mm``, ``max_mm``, ``mean_mm`` of their clearance, and ``all_min_mm``, the
        least clearance over every vertex of the layer.
    """
    g = problem.world_T_sigma
    tip = g[:3, 3]
    raw = np.concatenate([p[:-1] for p in cfrw.layer(h_mm, refine=False)])
    verts = np.concatenate([p[:-1] for p in cfrw.layer(h_mm)])
    refined = np.linalg.norm(verts - raw, axis=1) > 1e-9
    world = np.column_stack([verts, np.full(len(verts), h_mm)]) @ g[:3, :3].T + tip
    r = problem.needle.radius_mm
    c = _vessel_clearance(scene, tip, world, r, step_mm)
    near = np.flatnonzero(refined & (c < problem.gamma_mm + 0.5))
    u = world[near] - tip
    ribs = _rib_clearance(scene, tip, u / np.linalg.norm(u, axis=1)[:, None], r)
    bound = near[ribs > problem.gamma_mm + 0.5]
    vals = c[bound]
    return {
        "layer_mm": float(h_mm),
        "vertices": int(len(verts)),
        "vessel_bound": int(len(bound)),
        "min_mm": float(vals.min()) if len(vals) else None,
        "max_mm": float(vals.max()) if len(vals) else None,
        "mean_mm": float(vals.mean()) if len(vals) else None,
        "all_min_mm": float(c.min()),
    }


def _needle_rows(plan, world_T_sigma, check) -> list[dict]:
    """One row per needle: the target in Sigma, the trajectory, and verify's measurement."""
    rows = []
    rot, origin = world_T_sigma[:3, :3], world_T_sigma[:3, 3]
    by_order = {row["order"]: row for row in check.metrics.get("needles", [])}
    for n in plan.needles:
        e = n.entry
        sigma = rot.T @ (n.planned_target_mm - origin)
        moved = float(np.linalg.norm(n.target_mm - n.planned_target_mm))
        v = by_order.get(n.order, {})
        rows.append(
            {
                "needle": n.order,
                "target": n.target_index + 1,
                "target (Sigma, mm)": ", ".join(f"{c:.0f}" for c in sigma + 0.0),
                "target moved_mm": moved,
                "theta_deg": None if e is None else float(np.degrees(e.theta_rad)),
                "phi_deg": None if e is None else float(np.degrees(e.phi_rad)),
                "length_mm": None if e is None else e.length_mm,
                "clearance_mm": None if e is None else e.clearance_mm,
                "verify clearance_mm": v.get("clearance_mm"),
                "from earlier needles_mm": (
                    None if n.needle_clearance_mm == float("inf") else n.needle_clearance_mm
                ),
            }
        )
    return rows


def _same_map(a, b) -> bool:
    """Whether two CFRW maps are of one problem's anatomy with no further obstacles and
    hold the same grid, directions, entries and verdicts, bit for bit: their layers, refined
    on that anatomy, are then the same."""
    if a is b:
        return True
    if a.problem.extra_obstacles or b.problem.extra_obstacles or a.problem.scene is not b.problem.scene:
        return False
    names = ("theta_rad", "phi_rad", "directions", "entry_mm", "length_mm", "clearance_mm",
             "normal_angle_deg", "blocked")  # fmt: skip
    return all(np.array_equal(getattr(a, n), getattr(b, n), equal_nan=True) for n in names)


def _plan(multi, options, resolution_deg):
    opts = dict(options, resolution_deg=resolution_deg)
    return get_planner("liu_cfrw", opts).solve(multi, Termination(3600.0))


def _comparisons(fig12, m1, counts, res, gamma, rigid, rigid_check, moved, moved_check, moved_rows):
    """The rows of the comparison with the paper (Fig. 12, the needles, their interference,
    the deformed plan, needle 1's map)."""
    sep = [n.needle_clearance_mm for n in rigid.needles[1:]]

    def agree(ok):
        return "yes" if ok else "no"

    f12_ok = (
        fig12["vessel_bound"] > 0
        and abs(fig12["min_mm"] - gamma) <= 0.05
        and abs(fig12["max_mm"] - gamma) <= 0.05
    )
    return [
        {
            "quantity": "closest distance of boundary trajectories to the vessels (Fig. 12)",
            "paper": "all 1.5 mm (gamma 1.5 mm)",
            "needlekit": (
                f"{fig12['min_mm']:.3f}-{fig12['max_mm']:.3f} mm over {fig12['vessel_bound']} "
                f"vessel-bound vertices (layer z = {FIG12_LAYER_MM:g} mm)"
                if fig12["vessel_bound"]
                else "no vessel-bound vertex in the layer"
            ),
            "agrees": agree(f12_ok),
            "note": "exact distance sampled every 0.02 mm along each trajectory",
        },
        {
            "quantity": "needles planned, in their CFRWs",
            "paper": "3 of 3",
            "needlekit": f"{len([n for n in rigid.needles if n.entry])} of 3, verify "
            + ("ok" if rigid_check.ok else "VIOLATED"),
            "agrees": agree(rigid.solved and rigid_check.ok),
            "note": "certified clearance >= gamma to the anatomy for each",
        },
        {
            "quantity": "needles interfere with each other",
            "paper": "no",
            "needlekit": "no (closest " + ", ".join(f"{d:.2f}" for d in sep) + " mm)"
            if sep and min(sep) >= gamma
            else "yes",
            "agrees": agree(bool(sep) and min(sep) >= gamma),
            "note": "tube and Eq. 4 head of each placed needle as obstacles",
        },
        {
            "quantity": "with target displacement (deformation) compensated",
            "paper": "planned (in vitro: target error 2.1 +- 0.6 mm)",
            "needlekit": f"{len([n for n in moved.needles if n.entry])} of 3 planned, verify "
            + ("ok" if moved_check.ok else "VIOLATED")
            + "; targets moved "
            + ", ".join(f"{r['target moved_mm']:.2f}" for r in moved_rows)
            + " mm",
            "agrees": "-",
            "note": "the in-vitro target error is a physical measurement; not simulated",
        },
        {
            "quantity": "needle 1's CFRW, directions free",
            "paper": "-",
            "needlekit": f"{counts['free']} of {m1.blocked.size} at {res:g} deg",
            "agrees": "-",
            "note": "the paper draws the boundary, gives no area or count",
        },
    ]


def _setup(problem, res: float) -> list[dict]:
    """The rows of the set-up table: the paper's against needlekit's."""
    gamma = problem.gamma_mm
    return [
        {"item": "targets (Sigma)", "paper": "(0, 0, 0), (0, -15, 0), (0, -30, 0) mm",
         "needlekit": "the same, Sigma's origin at the phantom's tumour centre"},
        {"item": "obstacles", "paper": "primary blood vessels as superquadrics (Eq. 4), "
         "parameters not given", "needlekit": "three superquadric tubes (2.5 mm radius) "
         "10-12 mm from the targets, and the phantom's ribs"},
        {"item": "skin", "paper": "parametric surface; CFRW layers at z = 150-170 mm",
         "needlekit": "the phantom's elliptic cylinder, 78 mm above the targets"},
        {"item": "safety distance gamma", "paper": "1.5 mm", "needlekit": f"{gamma:g} mm"},
        {"item": "needle", "paper": "tube + Eq. 4 head, size not given",
         "needlekit": f"diameter {2 * problem.needle.radius_mm:g} mm, length "
         f"{problem.needle.max_length_mm:g} mm, Eq. 4 head"},
        {"item": "insertion order", "paper": "1, 2, 3", "needlekit": "1, 2, 3"},
        {"item": "CFRW boundary", "paper": "continuation method on Eq. 10-12",
         "needlekit": f"{res:g} degree grid, boundary refined by bisection on the "
         "certified clearance"},
        {"item": "optimal entry", "paper": "grid method, delta 1e-5, epsilon 1e-4, "
         "shortest trajectory", "needlekit": "the same criterion over the map"},
        {"item": "theta limits", "paper": "from the robot (not given)",
         "needlekit": "0-60 degrees"},
        {"item": "deformation", "paper": "a liver deformation model (refs. 31, 38)",
         "needlekit": "none in the main plan; needle drag (parameters assumed) in part 4"},
    ]  # fmt: skip


def _deviations(res: float) -> list[str]:
    """Where the reproduction departs from the paper, and why."""
    return [
        "The vessels are ours (the paper draws them in Fig. 10(A) but gives no parameters): "
        "they set every clearance and length in the tables.",
        "The phantom's ribs stay as obstacles (the paper's simulation has vessels only); "
        "they bound part of needle 1's CFRW, so the Fig. 12 check uses only the boundary "
        "vertices the vessels decide.",
        "The skin lies 78 mm above the targets (the paper's CFRW layers are drawn at "
        "z = 150-170 mm): lengths are shorter than the paper's would be. The layer figures "
        "use the paper's heights, as planes the directions cross.",
        "theta is limited to 0-60 degrees: the paper derives its limits from its robot and "
        "does not give them.",
        f"The boundary comes from a {res:g} degree grid refined by bisection on the certified "
        "clearance, not from the continuation method: any obstacle with a distance field "
        "works, and the Fig. 12 measurement is within 0.05 mm of gamma.",
        "Part 4 moves the targets with needlekit's needle-drag model (drag 2 mm, support "
        "radius 30 mm: assumptions; the paper's model is in its refs. 31 and 38).",
        "The in-vitro experiments (porcine liver, 10 trials, target error 2.1 +- 0.6 mm) are "
        "physical and are not reproduced.",
    ]


def _sections(m1, layer1, counts, res, fig12, rigid_rows, moved_rows, straight) -> list:
    """The page's own sections (the map, Figs 11 and 12, the two plans), then ``straight``
    (``layer1``: needle 1's layers already refined, by height)."""
    from needlekit.report.straight_figures import LIU_HEIGHTS_MM, cfrw_layers_figure

    return [
        TextSection(
            f"Needle 1's CFRW: {counts['free']} of {m1.blocked.size} directions free at "
            f"{res:g} degrees. {m1.blocking_summary()}",
            heading="Needle 1's CFRW",
        ),
        FigureSection(
            "Fig. 11: the boundaries of needle 1's CFRW",
            cfrw_layers_figure(m1, LIU_HEIGHTS_MM, [], layers=layer1, title="CFRW of needle 1"),
            "As the paper's Fig. 11: (a) the CFRW in the plane z = 150 mm of Sigma; (b) its "
            "boundaries at z = 150, 160, 170 mm.",
        ),
        TableSection(
            "Fig. 12: the boundary against the vessels",
            [fig12],
            f"Vertices of needle 1's CFRW boundary in the layer z = {FIG12_LAYER_MM:g} mm "
            "refined onto the clearance level and bound by a vessel (the ribs farther than "
            "gamma + 0.5 mm along them); their exact clearance from the vessels. all_min: "
            "the least over every vertex of the layer (the whole boundary is clear).",
        ),
        TableSection(
            "The three needles (rigid anatomy)",
            rigid_rows,
            "clearance: the certified lower bound to the anatomy (the better of the "
            "planner's samples and dense ones); verify clearance: needlekit verify's, "
            "re-derived from the record by the same rule (equal by construction); from "
            "earlier needles: closed form between the placed tubes.",
        ),
        TableSection(
            "The three needles with the targets moved (needle drag)",
            moved_rows,
            "Each target moved by the needles placed before it, then planned in its CFRW.",
        ),
        *straight,
    ]


def run(out_dir: str | os.PathLike, *, quick: bool = False, executor=None, progress=print):
    """Re-run Liu et al.'s simulation; see the module's docstring.

    Parameters
    ----------
    out_dir : path-like
        Results land in ``out_dir/liu2016/``.
    quick : bool
        A 2 degree grid everywhere (full: 1 degree for the maps and the plans).
    executor : optional
        Unused (the parts are sequential: each needle depends on the one before).
    progress : callable

    Returns
    -------
    Reproduction
    """
    from needlekit.planning.straight.cfrw import cfrw_map
    from needlekit.planning.straight.deformation import NeedleDragDeformation
    from needlekit.planning.straight.verify import verify_multi
    from needlekit.report.straight_figures import LIU_HEIGHTS_MM
    from needlekit.report.straight_report import plan_maps, straight_sections
    from needlekit.scenario.loading import load_scenario

    del executor
    stage = Stages(progress, 5, "liu2016")
    case = Path(out_dir) / "liu2016"
    res = 2.0 if quick else 1.0
    stage("loading the scene (liver phantom, superquadric vessels)")
    src = resources.files("needlekit") / "data" / SCENARIO
    with resources.as_file(src) as path:
        text = Path(path).read_text(encoding="utf-8")
        sc = load_scenario(path)
    write_text(case / "scenario.yaml", text)
    multi, options = multi_problem_from_scenario(sc)
    problem = multi.problem.with_target(multi.targets_mm[0])

    stage(f"needle 1's CFRW ({res:g} degree grid) and its layers (Fig. 11)")
    m1 = cfrw_map(problem, resolution_deg=res)
    counts = m1.counts()

    stage(f"Fig. 12: the boundary in the layer z = {FIG12_LAYER_MM:g} mm against the vessels")
    fig12 = boundary_clearance(sc.scene, problem, m1, FIG12_LAYER_MM)

    stage("three needles in the order 1, 2, 3 (Figs 13-18), re-checked by verify")
    rigid = _plan(multi, options, res)
    rigid_doc = rigid.to_dict()
    rigid_doc.update(planner="liu_cfrw", scenario="scenario.yaml")  # beside it
    rigid_check = verify_multi(multi.problem, rigid_doc)
    write_json(case / "multi.json", rigid_doc)

    stage("the same with the targets moved by the needles before them (needle drag)")
    deformed = replace(multi, deformation=NeedleDragDeformation())
    moved = _plan(deformed, options, res)
    moved_doc = moved.to_dict()
    moved_doc.update(planner="liu_cfrw", scenario="scenario.yaml", deformation="needle_drag")
    moved_check = verify_multi(multi.problem, moved_doc)
    write_json(case / "multi_deformed.json", moved_doc)

    g = problem.world_T_sigma
    rigid_rows = _needle_rows(rigid, g, rigid_check)
    moved_rows = _needle_rows(moved, g, moved_check)
    gamma = problem.gamma_mm
    comparisons = _comparisons(
        fig12, m1, counts, res, gamma, rigid, rigid_check, moved, moved_check, moved_rows
    )
    # the maps the plan chose its needles on (recomputed only for a plan that keeps none);
    # needle 1's layer refined once for both its figures when its map is needle 1's CFRW
    maps = list(rigid.maps) if len(rigid.maps) == len(rigid.needles) else plan_maps(
        multi.problem, rigid, resolution_deg=res)  # fmt: skip
    layer1 = {LIU_HEIGHTS_MM[0]: m1.layer(LIU_HEIGHTS_MM[0])}
    layers = [layer1 if _same_map(maps[0], m1) else None] + [None] * (len(maps) - 1)
    straight = straight_sections(rigid, maps, multi.problem.scene, layers=layers)
    sections = _sections(m1, layer1, counts, res, fig12, rigid_rows, moved_rows, straight)
    commands = [
        "needlekit multi liu2016/scenario.yaml --out multi.json --report multi.html "
        f"--resolution-deg {res:g}",
        "needlekit verify liu2016/scenario.yaml multi.json",
        f"needlekit cfrw liu2016/scenario.yaml --out cfrw.json --resolution-deg {res:g} "
        "--layers 150 160 170",
    ]
    record = {
        "checks_ok": bool(rigid_check.ok and moved_check.ok),
        "resolution_deg": res,
        "cfrw_counts": counts,
        "fig12": fig12,
        "rigid": {"solved": rigid.solved, "verify_ok": rigid_check.ok, "needles": rigid_rows},
        "deformed": {"solved": moved.solved, "verify_ok": moved_check.ok, "needles": moved_rows},
    }
    rep = Reproduction(
        key="liu2016",
        title="Reproducing Liu et al. 2016: straight multi-needle planning in the CFRW",
        citation=CITATION,
        quick=quick,
        summary=(
            "The paper's three-needle simulation (Figs 10-18) on needlekit's liver phantom "
            "with superquadric vessels in its targets' frame: needle 1's CFRW and the Fig. "
            "12 boundary check, the three needles planned one after another (each placed "
            "needle an obstacle for the next) and re-checked, then the same with the targets "
            "moved by tissue deformation."
        ),
        comparisons=comparisons,
        setup=_setup(problem, res),
        deviations=_deviations(res),
        sections=sections,
        commands=commands,
        record=record,
        files={
            "scenario": case / "scenario.yaml",
            "multi": case / "multi.json",
            "multi_deformed": case / "multi_deformed.json",
        },
    )
    return rep
