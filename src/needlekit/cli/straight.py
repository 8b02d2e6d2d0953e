"""``needlekit cfrw`` and ``needlekit multi``: straight-needle planning on scenarios."""

from __future__ import annotations

import argparse
from pathlib import Path

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _positive,
    _positive_int,
    _positive_mm,
)
from needlekit.cli._paths import add_input, add_output
from needlekit.errors import InvalidInputError
from needlekit.io.files import json_text
from needlekit.io.results import scenario_reference


def _document(args: argparse.Namespace) -> dict:
    """The scenario's document, checked against the schema and for a straight block before
    any heavy module (numba) is imported."""
    from needlekit.io.scenario_schema import read_scenario_document

    # read once: the memory estimate (cli._sizes.cfrw_sizes) may have read it already
    doc = getattr(args, "scenario_document", None) or read_scenario_document(args.scenario)
    if not doc.get("straight"):
        raise InvalidInputError(
            f"{Path(args.scenario).name}: straight", "the scenario has no straight block"
        )
    return doc


def _check_target(args: argparse.Namespace, doc: dict) -> None:
    """``--target`` against the straight block's list of targets, before anything is built
    (targets chosen by coverage are counted once chosen: the caller checks those)."""
    listed = doc["straight"].get("targets")
    if isinstance(listed, list) and not 1 <= args.target <= len(listed):
        raise InvalidInputError("--target", f"expected 1 to {len(listed)}, got {args.target}")


def _multi_problem(args: argparse.Namespace, doc: dict | None = None):
    doc = _document(args) if doc is None else doc
    from needlekit.scenario.loading import load_scenario
    from needlekit.scenario.straight import multi_problem_from_scenario

    sc = load_scenario(args.scenario, document=doc)
    return sc, *multi_problem_from_scenario(sc)


def _cmd_cfrw(args: argparse.Namespace) -> int:
    doc = _document(args)
    _check_target(args, doc)
    import numpy as np

    from needlekit.io.files import write_json
    from needlekit.planning.straight.cfrw import cfrw_map
    from needlekit.planning.straight.entry import Objective, best_on_map, pareto_front

    _, multi, options = _multi_problem(args, doc)
    k = len(multi.targets_mm)
    if not 1 <= args.target <= k:
        raise InvalidInputError("--target", f"expected 1 to {k}, got {args.target}")
    problem = multi.problem.with_target(multi.targets_mm[args.target - 1])
    res = args.resolution_deg or options.get("resolution_deg", 1.0)
    m = cfrw_map(problem, resolution_deg=res)
    record = m.to_dict()
    record["scenario"] = scenario_reference(args.scenario, args.out)
    record["target"] = args.target
    record["resolution_deg"] = res
    record["layers"] = {
        f"{h:g}": [np.round(p, 4).tolist() for p in m.layer(h)] for h in args.layers
    }
    record["best"] = {
        o.value: (None if (e := best_on_map(m, o)) is None else e.to_dict()) for o in Objective
    }
    record["pareto_front"] = [
        {
            "theta_deg": float(np.degrees(m.theta_rad[i])),
            "phi_deg": float(np.degrees(m.phi_rad[j])),
            "length_mm": float(m.length_mm[i, j]),
            "clearance_mm": float(m.clearance_mm[i, j]),
        }
        for i, j in pareto_front(m)
    ]
    write_json(args.out, record)
    c = m.counts()
    best = record["best"]["min_length"]
    line = (
        f"CFRW of target {args.target}: {c['free']} of {m.blocked.size} directions at "
        f"{res:g} deg clear by gamma {problem.gamma_mm:g} mm"
    )
    if best is not None:
        line += f"; shortest {best['length_mm']:.2f} mm, clearance {best['clearance_mm']:.2f} mm"
    print(f"{line} -> {args.out}")
    return EXIT_OK if c["free"] else 1


def _cmd_multi(args: argparse.Namespace) -> int:
    from needlekit.planning.interface import Termination, check_planner_options, get_planner

    doc = _document(args)
    check_planner_options(args.planner)  # its name, before numba; its options below
    from needlekit.io.files import staged_outputs, write_json

    sc, multi, options = _multi_problem(args, doc)
    if args.resolution_deg is not None:
        options["resolution_deg"] = args.resolution_deg
    if args.objective is not None:
        options["objective"] = args.objective
    if args.order is not None:
        options["order"] = [i - 1 for i in args.order]
    planner = get_planner(args.planner, options)
    coverage = None
    if isinstance(sc.straight.get("targets"), str):  # targets: coverage
        plan, coverage = _plan_coverage(sc, multi, planner, args)
    else:
        plan = planner.solve(multi, Termination(args.time_limit_s))
    record = plan.to_dict()
    record["planner"] = args.planner
    record["scenario"] = scenario_reference(args.scenario, args.out)
    record["resolution_deg"] = options.get("resolution_deg", 1.0)  # to redraw the maps
    record["coverage"] = None if coverage is None else coverage.to_dict()
    if coverage is not None and not coverage.ok:
        record["status"] = "infeasible"
        record["reason"] = record["reason"] or coverage.reason
    with staged_outputs():
        write_json(args.out, record)
        if args.report is not None:
            from needlekit.report.straight_report import write_straight_report

            write_straight_report(
                args.report,
                plan=plan,
                maps=list(plan.maps),
                scene=multi.problem.scene,
                zones=None if coverage is None else coverage.chosen.zone,
                coverage=coverage,
                title=f"Straight multi-needle plan: {args.scenario}",
            )
        if args.markups is not None and plan.solved:
            from needlekit.io.markups import write_markups_lines

            pairs = [(n.entry.entry_mm, n.entry.target_mm) for n in plan.needles]
            write_markups_lines(
                args.markups, pairs, names=[f"needle{n.order}" for n in plan.needles]
            )
    for n in plan.needles:
        e = n.entry
        if e is None:
            continue
        nc = (
            ""
            if n.needle_clearance_mm == float("inf")
            else f", {n.needle_clearance_mm:.2f} mm from earlier needles"
        )
        print(
            f"needle {n.order} -> target {n.target_index + 1}: length {e.length_mm:.2f} mm, "
            f"clearance {e.clearance_mm:.2f} mm{nc}"
        )
    status = "solved" if plan.solved else f"not solved: {plan.reason}"
    print(f"{args.planner}: {status} ({plan.orders_tried} orders tried) -> {args.out}")
    if coverage is not None:
        from needlekit.planning.straight.coverage import fraction_text

        rep = coverage.planned or coverage.chosen.report
        print(
            f"coverage: {fraction_text(rep.coverage)} of tumour + margin "
            f"({rep.region_volume_ml:.1f} mL), tumour {fraction_text(rep.tumour_coverage)}, "
            f"{rep.needles} needles, healthy ablated "
            f"{rep.healthy_ablated_ml:.1f} mL"
            + ("" if coverage.ok else f"; not covered: {coverage.reason}")
        )
        return EXIT_OK if plan.solved and coverage.ok else 1
    return EXIT_OK if plan.solved else 1


def _plan_coverage(sc, multi, planner, args):
    """Choose targets covering the tumour plus margin, plan them, re-check the coverage."""
    from needlekit.planning.straight.ablation import plan_coverage
    from needlekit.planning.straight.sequence import MultiNeedlePlan
    from needlekit.scenario.straight import coverage_region

    region, settings = coverage_region(sc, multi.problem)
    plan, outcome = plan_coverage(multi, planner, region, settings, time_limit_s=args.time_limit_s)
    if plan is None:
        p = multi.problem
        plan = MultiNeedlePlan((), (), False, 0, p.gamma_mm, p.needle.radius_mm, outcome.reason)
    return plan, outcome


def verify_multi_file(args: argparse.Namespace, data: dict) -> int:
    """``needlekit verify SCENARIO multi.json``: re-check every needle from the file.

    Parameters
    ----------
    args : argparse.Namespace
    data : dict
        The multi.json document.

    Returns
    -------
    int
        0 when every needle passes, else 1.
    """

    doc = _document(args)
    from needlekit.planning.straight.verify import verify_multi

    _, multi, _ = _multi_problem(args, doc)
    check = verify_multi(multi.problem, data)
    if args.json:
        print(
            json_text(
                {"ok": check.ok, "violations": list(check.violations), **check.metrics},
                "--json",
                indent=2,
            )
        )
    else:
        for row in check.metrics["needles"]:
            extra = (
                f", {row['needle_clearance_mm']:.3f} mm from earlier needles"
                if "needle_clearance_mm" in row
                else ""
            )
            print(
                f"needle {row['order']}: length {row['length_mm']:.3f} mm, certified clearance "
                f"{row['clearance_mm']:.3f} mm{extra}, theta {row['theta_deg']:.2f} deg, "
                f"normal angle {row['normal_angle_deg']:.2f} deg"
            )
        print("ok" if check.ok else "VIOLATED")
        for v in check.violations:
            print(f"  - {v}")
    return EXIT_OK if check.ok else 1


def _cmd_approach(args: argparse.Namespace) -> int:
    """``needlekit approach``: PAA's approach analysis, and needlekit's, on a scenario."""
    import time

    doc = _document(args)
    _check_target(args, doc)
    import numpy as np

    from needlekit.io.files import staged_outputs, write_json
    from needlekit.planning.straight.approach import (
        ApproachAnalysis,
        approach_analysis,
        approach_meshes,
    )

    sc, multi, _ = _multi_problem(args, doc)
    k = len(multi.targets_mm)
    if not 1 <= args.target <= k:
        raise InvalidInputError("--target", f"expected 1 to {k}, got {args.target}")
    problem = multi.problem
    target = np.asarray(multi.targets_mm[args.target - 1], dtype=float)
    t0 = time.perf_counter()
    skin, obstacles = approach_meshes(problem, target, max_cells=args.max_cells)
    mesh_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    a = approach_analysis(
        target,
        skin,
        list(obstacles.values()),
        field=problem.obstacle_field(),
        needle_radius_mm=problem.needle.radius_mm,
        gamma_mm=problem.gamma_mm,
        max_length_mm=problem.needle.max_length_mm,
        max_normal_angle_deg=problem.max_normal_angle_deg,
    )
    analysis_s = time.perf_counter() - t1
    record = a.to_dict(per_face=not args.summary_only)
    record["scenario"] = scenario_reference(args.scenario, args.out)
    # what `needlekit report approach.json` meshes the scenario again with
    record["target"] = args.target
    record["max_cells"] = args.max_cells
    record["skin"] = {"structure": problem.entry_surface, "faces": int(len(skin.faces))}
    record["obstacles"] = {name: int(len(m.faces)) for name, m in obstacles.items()}
    record["timings_s"] = {"meshes": mesh_s, "analysis": analysis_s}
    with staged_outputs():
        write_json(args.out, record)
        if args.report is not None:
            from needlekit.report.approach_report import approach_title, write_approach_report

            # drawn from the record as written (`needlekit report approach.json` draws the
            # same page from it), or, without its per-triangle arrays, from the analysis
            shown = a if args.summary_only else ApproachAnalysis.from_dict(record, str(args.out))
            write_approach_report(
                args.report, shown, skin, obstacles, title=approach_title(sc, args.scenario)
            )
    for label, key in (("PAA (line, no thickness)", "paa"), ("needlekit", "needlekit")):
        s = record[key]
        best = s["shortest"]
        line = f"{label}: score {s['score']:.4f}"
        line += (
            "; no accessible triangle"
            if best is None
            else f"; shortest {best['length_mm']:.2f} mm from "
            f"({', '.join(f'{c:.2f}' for c in best['entry_mm'])})"
        )
        print(line)
    b = record["blocked"]
    print(
        f"{record['faces']} skin triangles: {b['obstacle_on_line']} with an obstacle on the "
        f"line, {b['clearance_below_gamma']} closer than gamma {problem.gamma_mm:g} mm to an "
        f"obstacle (needle radius {problem.needle.radius_mm:g} mm), {b['leaves_body']} leaving "
        f"the body, {b['too_long']} too long, {b['too_oblique']} too oblique "
        f"({analysis_s:.2f} s) -> {args.out}"
    )
    return EXIT_OK if record["needlekit"]["shortest"] is not None else 1


def _scenario_and_out(p, out_default: str, out_help: str) -> None:
    add_input(p, "scenario", help="scenario file with a straight block (YAML)")
    _flags.OUT.add(p, default=out_default, help=out_help)


def _target(p) -> None:
    p.add_argument("--target", type=_positive_int, default=1, help="which target (default 1)")


def _register_cfrw(sub) -> None:
    cf = sub.add_parser(
        "cfrw",
        help="the collision-free reachable workspace of a straight needle (Liu et al. 2016)",
        description="Map every direction to one target of the scenario's straight block: entry, "
        "length, certified clearance, blocking reason; boundary layers; best entries; Pareto front.",
    )
    _scenario_and_out(cf, "cfrw.json", "map to write (default cfrw.json)")
    _target(cf)
    cf.add_argument(
        "--resolution-deg", type=_positive, help="grid step (default: the scenario's, else 1)"
    )
    cf.add_argument(
        "--layers",
        type=_positive_mm,
        nargs="+",
        default=[150.0, 160.0, 170.0],
        metavar="H_MM",
        help="heights of the boundary layers above the target (default 150 160 170, Fig. 11)",
    )
    _flags.add_cache_options(cf)
    cf.set_defaults(command_handler=_cmd_cfrw, sizes=_sizes.cfrw_sizes)


def _register_multi(sub) -> None:
    mu = sub.add_parser(
        "multi",
        help="plan several straight needles one after another (Liu et al. 2016, Fig. 4)",
        description="CFRW per needle, the optimal entry in it, placed needles as obstacles, "
        "targets moved by the deformation; write multi.json; exit 0 when every needle is planned "
        "(with targets: coverage, and the tumour plus margin is covered), else 1.",
    )
    _scenario_and_out(mu, "multi.json", "plan to write (default multi.json)")
    add_output(
        mu, "--markups", folder=True, help="also write each trajectory as a Slicer line (.mrk.json)"
    )
    add_output(
        mu, "--report", help="also write a self-contained HTML report (Fig. 11/14/17, scene)"
    )
    mu.add_argument(
        "--planner", default="liu_cfrw", metavar="NAME", help="straight planner (default liu_cfrw)"
    )
    mu.add_argument(
        "--resolution-deg", type=_positive, help="CFRW grid step (default: the scenario's, else 1)"
    )
    mu.add_argument(
        "--objective",
        choices=["min_length", "max_clearance", "min_normal_angle"],
        help="what each trajectory optimises (default: the scenario's, else min_length)",
    )
    mu.add_argument(
        "--order",
        type=_positive_int,
        nargs="+",
        metavar="K",
        help="fixed insertion order (1-based targets)",
    )
    _flags.TIME_LIMIT_S.add(mu, default=3600.0, help="budget (default 3600 s)")
    _flags.add_cache_options(mu)
    _flags.PLOTLY.add(mu)
    mu.set_defaults(command_handler=_cmd_multi, sizes=_sizes.cfrw_sizes)


def _register_approach(sub) -> None:
    ap = sub.add_parser(
        "approach",
        help="which skin triangles a straight needle can come from (Slicer's "
        "PercutaneousApproachAnalysis, exactly, and with needlekit's criteria)",
        description="For one target, every triangle of the entry surface's mesh: the line to "
        "the target against the obstacles' meshes (PAA's test, exact), and the needle's "
        "certified clearance, inside-the-body, length and angle limits (needlekit's); the "
        "accessible area fractions and shortest lines. Exit 1 when no triangle is accessible.",
    )
    _scenario_and_out(ap, "approach.json", "analysis (default approach.json)")
    add_output(ap, "--report", help="also write a self-contained HTML view of the skin map")
    _target(ap)
    ap.add_argument(
        "--max-cells",
        type=_positive_int,
        default=200,
        help="marching-cubes samples per axis for structures without a mesh file (default 200)",
    )
    ap.add_argument("--summary-only", action="store_true", help="leave the per-triangle arrays out")
    _flags.add_cache_options(ap)
    _flags.PLOTLY.add(ap)
    ap.set_defaults(command_handler=_cmd_approach, sizes=_sizes.cells_sizes)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``cfrw``, ``multi`` and ``approach`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    _register_cfrw(sub)
    _register_multi(sub)
    _register_approach(sub)
