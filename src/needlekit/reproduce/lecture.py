"""The lecture re-run: bevel-tip kinematics, multi-target RRT, and re-planning among
moving obstacles.

The lecture (M. F. Orlando, *Path planning of robotic needle*) gives models and
procedures rather than tables, so its "numbers" are its formulas and examples: each is
re-derived and checked against an independent computation (closed forms, round trips,
the lecture's own reachability inequality), and the procedures are run on a scene of
ours in the spirit of its figures:

1. forward steering (planar unicycle and 3D models), inverse steering (with the slide's
   missing factor 2), reachability (the lecture's inequality against the frame-free test);
2. multi-target RRT as the lecture gives it (a new tree from the start node for each
   target) beside needlekit's one-tree variant, at the same total iteration budget;
3. the dynamic environment: a vessel drifting across the needle's way while the needle is
   inserted, the plan made once at the start (executed open-loop) against RRT re-planning
   from the current tip every few millimetres.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

import numpy as np

from needlekit.io.files import write_bytes, write_json, write_text
from needlekit.io.results import scenario_reference
from needlekit.planning.result import PlanStatus
from needlekit.report.dynamic_report import dynamic_sections
from needlekit.report.html_page import FigureSection, ImageSection, PartSection, TableSection
from needlekit.report.steerable_report import goals_figure
from needlekit.reproduce._page import Reproduction, Stages
from needlekit.scenario.dynamic import dynamic_settings, moving_case
from needlekit.scenario.planners import planner_settings
from needlekit.scenario.problems import ScenarioSource

__all__ = ["GOALS_MM", "run"]

CITATION = (
    "M. F. Orlando, 'Path planning of robotic needle' (lecture: needle path planning, "
    "greedy reachability-guided RRT for several targets, bevel-tip kinematics), IIT Roorkee"
)
#: The multi-target scene and its targets (RAS mm), planned in this order.
TARGETS_SCENARIO = "lecture_targets.yaml"
GOALS_MM = np.array(
    [[0.0, -20.0, 60.0], [15.0, 5.0, 55.0], [-10.0, 10.0, 70.0], [20.0, -15.0, 75.0]]
)
#: Iteration budgets: per target (the lecture's procedure) and for the one shared tree
#: (the same total), and the seed of every tree.
PER_TARGET_ITERATIONS = 500
SEED = 1
#: The dynamic scene (lung phantom, a vessel drifting across the way).
MOVING_SCENARIO = "lung_phantom_moving.yaml"


def _kinematics(case: Path, quick: bool):
    """Part 1: the kinematics figures (PNG) and the numbers behind them."""
    from needlekit.report.kinematics import FIGURE_NAMES, kinematics_figures

    folder = case / "kinematics"
    pngs, summary = kinematics_figures(dpi=90 if quick else 150)
    for name in FIGURE_NAMES:
        write_bytes(folder / name, pngs[name])
    write_json(folder / "kinematics.json", summary)
    captions = (
        "Forward steering in the plane (lecture Method 1, the unicycle model): the three "
        "input sequences and their closed forms.",
        "Forward steering in 3D (insertion u1 and spin u2): arcs, the helix of constant "
        "spin, and the planar model as a special case.",
        "Inverse steering: the single arc to each target from the tip frame, and the "
        "slide's waypoint example with and without the factor 2.",
        "Reachability: the region one forward arc reaches (the lecture's inequality), and "
        "what an arc followed by a straight line adds.",
    )
    titles = ("Forward steering, planar", "Forward steering, 3D", "Inverse steering",
              "Reachability")  # fmt: skip
    sections = [
        ImageSection(t, pngs[n], c) for t, n, c in zip(titles, FIGURE_NAMES, captions, strict=True)
    ]
    fp, f3, inv, reach = (summary[k] for k in ("forward_planar", "forward_3d", "inverse",
                                               "reachability"))  # fmt: skip
    slide = inv["planar_waypoints"]
    comparisons = [
        {
            "quantity": "planar unicycle model: integrated against its closed form (mm)",
            "paper": "model (Method 1)",
            "needlekit": f"{fp['closed_form_error_mm']:.1e}",
            "agrees": "yes" if fp["closed_form_error_mm"] < 1e-9 else "no",
            "note": "largest end-point difference over the three input sequences",
        },
        {
            "quantity": "3D model: helix pitch of constant spin, and the planar model as a "
            "special case (mm)",
            "paper": "model (mu_1 u_1 + mu_2 u_2)",
            "needlekit": f"{f3['helix']['pitch_check_error_mm']:.1e}, "
            f"{f3['planar_vs_3d_s_curve_error_mm']:.1e}",
            "agrees": "yes"
            if max(f3["helix"]["pitch_check_error_mm"], f3["planar_vs_3d_s_curve_error_mm"]) < 1e-9
            else "no",
            "note": "closed-form helix against the integrated one; planar S-curve against 3D",
        },
        {
            "quantity": "inverse steering: the arc's end at the target (mm)",
            "paper": "r = (y^2 + z^2) / (2|y|) ...",
            "needlekit": f"{inv['end_point_error_mm']:.1e}",
            "agrees": "yes" if inv["end_point_error_mm"] < 1e-9 else "no",
            "note": f"{len(inv['targets'])} random targets (seed {inv['seed']})",
        },
        {
            "quantity": "the slide's waypoint W1 with its printed radius",
            "paper": f"radius {slide['lecture_slide_radius_w1_mm']:g} mm reaches W1",
            "needlekit": f"misses W1 by {slide['lecture_slide_miss_w1_mm']:.2f} mm; with "
            f"the factor 2, radius {slide['steps'][0]['radius_mm']:g} mm reaches it "
            f"({slide['forward_check_error_mm']:.1e} mm)",
            "agrees": "no",
            "note": "the slide's formula lacks a factor 2 (docs/kinematics.md)",
        },
        {
            "quantity": "reachability: P_z >= sqrt(2 r_min rho - rho^2) against the "
            "frame-free test",
            "paper": "the inequality",
            "needlekit": f"{reach['lecture_vs_frame_free_disagreements']} cells disagree of "
            f"{reach['cells_single_forward_arc'] + reach['cells_inside_r_min_torus']:,}",
            "agrees": "yes" if reach["lecture_vs_frame_free_disagreements"] == 0 else "no",
            "note": f"r_min {reach['r_min_mm']:g} mm",
        },
    ]
    record = {"kinematics": summary}
    return sections, comparisons, record


def _multi_target(case: Path, quick: bool):
    """Part 2: the lecture's per-target RRT beside one shared tree."""
    from needlekit.planning.steerable.rrt import solve_rrt_multi, solve_rrt_per_target
    from needlekit.planning.steerable.verify import verify_plan

    src = resources.files("needlekit") / "data" / TARGETS_SCENARIO
    with resources.as_file(src) as path:
        text = Path(path).read_text(encoding="utf-8")
        _, problem = ScenarioSource.of(path).load()
    scenario = write_text(case / "targets.yaml", text)
    n = PER_TARGET_ITERATIONS
    per = solve_rrt_per_target(problem, GOALS_MM, time_limit_s=3600.0, seed=SEED,
                               max_iterations=n)  # fmt: skip
    one = solve_rrt_multi(problem, GOALS_MM, time_limit_s=3600.0, seed=SEED,
                          max_iterations=n * len(GOALS_MM))  # fmt: skip
    rows, ok = [], True
    for k, (g, a, b) in enumerate(zip(GOALS_MM, per, one, strict=True), start=1):
        checks = []
        for r in (a, b):
            if r.status is PlanStatus.SOLVED:
                v = verify_plan(problem.with_goal(g), r.plan)
                ok &= v.ok
                checks.append("ok" if v.ok else "VIOLATED")
            else:
                checks.append("-")
        rows.append(
            {
                "target": k,
                "target (RAS, mm)": ", ".join(f"{c:g}" for c in g),
                "per target: status": a.status.value,
                "per target: cost_mm": a.cost_mm if a.status.has_plan else None,
                "per target: nodes": a.stats.get("nodes"),
                "per target: check": checks[0],
                "one tree: status": b.status.value,
                "one tree: cost_mm": b.cost_mm if b.status.has_plan else None,
                "one tree: check": checks[1],
            }
        )
    for mode, results in (("per-target", per), ("one-tree", one)):
        write_json(
            case / f"targets_{mode}.json",
            {"planner": "rrt", "mode": mode,
             "scenario": scenario_reference(scenario, case / f"targets_{mode}.json"),
             "targets": [r.to_dict() for r in results]},
        )  # fmt: skip
    solved = sum(r.status is PlanStatus.SOLVED for r in per)
    sections = [
        FigureSection(
            "Several targets: a tree from the start node for each (the lecture's procedure)",
            goals_figure(problem, per, title="per-target RRT: one optimal path per target"),
            f"Each target reached by its own RRT grown from the start node ({n} iterations, "
            f"seed {SEED}), as the lecture's figure of several targets shows.",
        ),
        FigureSection(
            "Several targets from one shared tree (needlekit's variant)",
            goals_figure(problem, one, title="one RRT tree for all targets"),
            f"One tree of {n * len(GOALS_MM)} iterations (the same total budget) serves every "
            "target: branches the targets share are grown once.",
        ),
        TableSection(
            "Per-target trees beside one shared tree",
            rows,
            "cost: path length (mm); check: the independent check of each solved plan.",
        ),
    ]
    comparisons = [
        {
            "quantity": "multi-target RRT: an optimal path from the start node to each target",
            "paper": "one path per target (figure: targets 2, 4, 5, 6)",
            "needlekit": f"{solved} of {len(GOALS_MM)} targets solved, every plan checked "
            + ("ok" if ok else "VIOLATED"),
            "agrees": "yes" if solved == len(GOALS_MM) and ok else "no",
            "note": "our scene: the lecture's obstacles and targets are drawn, not given",
        }
    ]
    record = {"multi_target": {"iterations_per_target": n, "seed": SEED, "rows": rows,
                               "checks_ok": ok}}  # fmt: skip
    files = {"targets_scenario": scenario}
    return sections, comparisons, record, ok, files


def _dynamic(case: Path):
    """Part 3: the plan made at t = 0 against re-planning from the tip, a vessel drifting."""
    from needlekit.planning.steerable.dynamic import replan_among_moving
    from needlekit.scenario.loading import read_scenario_document

    src = resources.files("needlekit") / "data" / MOVING_SCENARIO
    with resources.as_file(src) as path:
        text = Path(path).read_text(encoding="utf-8")
        kw = dynamic_settings(path)
        settings = planner_settings(read_scenario_document(path).get("planner"))
        sc, static, moving = moving_case(ScenarioSource.of(path))
    scenario = write_text(case / "moving.yaml", text)
    res = replan_among_moving(static, moving, **kw, **settings.replanning())
    record = {"scenario": scenario_reference(scenario, case / "dynamic.json"), **res.to_dict()}
    write_json(case / "dynamic.json", record)
    plan0, check0 = res.static
    m = res.check.metrics
    s = res.settings
    if check0 is None:
        once = f"plan made at t = 0: {plan0.status.value}, nothing to execute"
    else:
        once = (
            "the plan made once at t = 0 "
            + ("passes" if check0.ok else "fails")
            + f" the check (certified clearance {check0.metrics['certified_moving_clearance_mm']:.3f}"
            " mm to the vessel as the tip passed)"
        )
    replanned = (
        f"re-planned every {s['step_mm']:g} mm at {s['insertion_speed_mm_s']:g} mm/s: "
        f"{res.status.value} ({res.reason}), {res.executed.length_mm:.2f} mm, certified "
        f"clearance {m.get('certified_moving_clearance_mm', float('nan')):.3f} mm"
    )
    ok = bool(res.reached and res.check.ok)
    comparisons = [
        {
            "quantity": "dynamic environment: RRT re-planning among moving obstacles",
            "paper": "re-plans around dynamic obstacles (no motion, period or numbers given)",
            "needlekit": f"{once}; {replanned}",
            "agrees": "yes" if ok and check0 is not None and not check0.ok else "no",
            "note": "our scene; time is the inserted length over the insertion speed",
        }
    ]
    sections = dynamic_sections(static, res, title=sc.name or MOVING_SCENARIO)
    return sections, comparisons, {"dynamic": record}, ok, {"moving_scenario": scenario}


def run(out_dir: str | os.PathLike, *, quick: bool = False, executor=None, progress=print):
    """Re-run the lecture's models and procedures; see the module's docstring.

    Parameters
    ----------
    out_dir : path-like
        Results land in ``out_dir/lecture/``.
    quick : bool
        Lower-resolution figures.
    executor : optional
        Unused (every part runs in this process).
    progress : callable

    Returns
    -------
    Reproduction
    """
    del executor
    case = Path(out_dir) / "lecture"
    stage = Stages(progress, 3, "lecture")
    stage("kinematics: forward and inverse steering, reachability")
    k_sections, k_cmp, k_rec = _kinematics(case, quick)
    stage(f"several targets: RRT per target and one tree ({len(GOALS_MM)} targets)")
    m_sections, m_cmp, m_rec, m_ok, m_files = _multi_target(case, quick)
    stage("dynamic environment: a drifting vessel, planned once and re-planned")
    d_sections, d_cmp, d_rec, d_ok, d_files = _dynamic(case)
    goals = " ".join(",".join(f"{c:g}" for c in g) for g in GOALS_MM)
    commands = [
        "needlekit kinematics forward --help; needlekit kinematics inverse --help",
        "needlekit demo --out out/demo   # writes the four kinematics figures",
        f"needlekit plan lecture/targets.yaml --planner rrt --goals {goals} --multi "
        f"per-target --max-iterations {PER_TARGET_ITERATIONS} --seed {SEED} --out per.json "
        "--report per.html",
        f"needlekit plan lecture/targets.yaml --planner rrt --goals {goals} --multi one-tree "
        f"--max-iterations {PER_TARGET_ITERATIONS * len(GOALS_MM)} --seed {SEED} "
        "--out one.json --report one.html",
        "needlekit plan lecture/moving.yaml --dynamic --out dynamic.json --report dynamic.html",
    ]
    setup = [
        {"item": "needle models", "paper": "planar unicycle; 3D with insertion u1 and spin u2; "
         "transformation-matrix method", "needlekit": "the same (docs/kinematics.md)"},
        {"item": "r_min", "paper": "r_n >= r_min", "needlekit": "50 mm (reachability, targets "
         "scene); 30 mm (inverse-steering figure)"},
        {"item": "RRT", "paper": "greedy, reachability-guided; optimal path = shortest",
         "needlekit": "the same, goal connection arc then line, cost = path length"},
        {"item": "several targets", "paper": "for each target, again from the start node",
         "needlekit": f"the same ({PER_TARGET_ITERATIONS} iterations per target), beside one "
         "shared tree"},
        {"item": "scene", "paper": "drawn in the lecture's figures",
         "needlekit": "ours: a tissue sphere, a vessel, a lesion and a duct; 4 targets"},
        {"item": "dynamic obstacles", "paper": "obstacles 'dynamic in nature'; no motion "
         "model, re-planning period or speed given", "needlekit": "the lung phantom with a "
         "3 mm vessel drifting 0.4 mm/s across the way; needle at 2 mm/s; RRT re-plans from "
         "the tip every 5 mm against where the vessel may be when the tip passes"},
    ]  # fmt: skip
    deviations = [
        "The scenes are ours: the lecture draws its obstacles and targets without giving them.",
        "The slide's inverse-steering radius lacks a factor 2; needlekit uses the corrected "
        "formula (the row above shows the slide's radius missing its waypoint).",
        "RRT runs on iteration budgets with a fixed seed (the same numbers on every machine) "
        "rather than a time limit.",
        "The dynamic environment is needlekit's reading of the lecture's one sentence: time "
        "is the inserted length over a constant insertion speed, obstacles move rigidly (a "
        "drift, optionally breathing) with a known motion, tissue does not deform, and each "
        "cycle plans against where an obstacle may be when the tip passes (the 'arrival' "
        "prediction); planning only where it is now does not get through this scene.",
    ]
    sections = [
        PartSection("1. Bevel-tip needle kinematics"),
        *k_sections,
        PartSection("2. Several targets"),
        *m_sections,
        PartSection("3. A dynamic environment: re-planning from the tip"),
        *d_sections,
    ]
    return Reproduction(
        key="lecture",
        title="Reproducing the lecture: needle kinematics and RRT path planning",
        citation=CITATION,
        quick=quick,
        summary=(
            "The lecture's needle models re-derived and checked against closed forms and "
            "round trips, its multi-target RRT run as it gives it (a tree from the start "
            "node for each target) beside one shared tree, and RRT re-planning from the tip "
            "while a vessel drifts across the needle's way."
        ),
        comparisons=k_cmp + m_cmp + d_cmp,
        setup=setup,
        deviations=deviations,
        sections=sections,
        commands=commands,
        record={"checks_ok": m_ok and d_ok, **k_rec, **m_rec, **d_rec},
        files={**m_files, **d_files},
    )
