"""Report parts of straight-needle results: a CFRW map and a multi-needle plan.

Each is drawn from its scenario's problem, which must match the file (safety distance,
needle radius), and its CFRW maps are recomputed and compared with the file's counts.
:func:`cfrw_sections` draws one CFRW map (re-exported by
:mod:`needlekit.report.result_report`).
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile
from needlekit.report.html_page import FigureSection, TableSection, TextSection
from needlekit.report.result_parts import ReportPart

__all__ = ["cfrw_sections"]


def _straight_problem(load, sc, rf: ResultFile):
    multi, options = load.multi_problem(sc)
    p = multi.problem
    for key, mine in (("gamma_mm", p.gamma_mm), ("needle_radius_mm", p.needle.radius_mm)):
        theirs = float(rf.data[key])
        if not np.isclose(theirs, mine, rtol=0, atol=1e-9):
            raise InvalidInputError(
                str(rf.path),
                f"{key} is {theirs:g}, the scenario {rf.scenario} gives {mine:g}: it was made "
                "from another scenario (give that one with --scenario)",
            )
    return multi, options


def _map_mismatch(rf: ResultFile, what: str, file_counts: dict, counts: dict) -> None:
    diff = {k: (file_counts.get(k), v) for k, v in counts.items() if file_counts.get(k) != v}
    if diff:
        said = ", ".join(f"{k} {a} in the file, {b} now" for k, (a, b) in diff.items())
        raise InvalidInputError(
            str(rf.path),
            f"{what} recomputed from {rf.scenario} differs ({said}): the scenario changed "
            "since; give the one it was made from with --scenario",
        )


def cfrw_sections(cfrw, record: dict) -> list:
    """The sections of a CFRW map (``needlekit cfrw``'s ``cfrw.json``): summary, blocking
    counts, best entries, Pareto front, the layers (Liu's Fig. 11) and the accessibility
    map.

    Parameters
    ----------
    cfrw : CFRWMap
        The map (recomputed from the scenario: the record keeps no entry points).
    record : dict
        The ``cfrw.json`` document: its ``best``, ``pareto_front`` and ``layers`` are
        drawn as recorded.

    Returns
    -------
    list of FigureSection, TableSection and TextSection
    """
    from needlekit.report.straight_figures import (
        LIU_HEIGHTS_MM,
        accessibility_map_figure,
        cfrw_layers_figure,
    )

    pr = cfrw.problem
    counts = cfrw.counts()
    target = record.get("target")
    name = "the target" if target is None else f"target {target}"
    res = record.get("resolution_deg")
    grid = "" if res is None else f" at {res:g} deg"
    text = (
        f"CFRW of {name} ({', '.join(f'{c:.2f}' for c in pr.target_mm)}) RAS mm: "
        f"{counts['free']} of {cfrw.blocked.size} directions{grid} clear by gamma "
        f"{pr.gamma_mm:g} mm (needle radius {pr.needle.radius_mm:g} mm, at most "
        f"{pr.needle.max_length_mm:g} mm inserted). {cfrw.blocking_summary()}"
    )
    best = [(k, e) for k, e in (record.get("best") or {}).items() if e is not None]
    best_rows = [
        {"objective": k, **{c: e[c] for c in ("entry_mm", "length_mm", "clearance_mm")},
         "theta_deg": e["theta_deg"], "phi_deg": e["phi_deg"],
         "normal_angle_deg": e["normal_angle_deg"]}
        for k, e in best
    ]  # fmt: skip
    chosen = [(k.replace("_", " "), e["target_mm"], e["entry_mm"]) for k, e in best]
    layers = {
        float(h): [np.asarray(p, float) for p in ps] for h, ps in record.get("layers", {}).items()
    }
    heights = sorted(layers) or list(LIU_HEIGHTS_MM)
    sections = [
        TextSection(text, "Summary"),
        TableSection(
            "Directions by blocking reason",
            [{**counts, "directions": int(cfrw.blocked.size)}],
            "free: in the CFRW; clearance: closer than gamma to the anatomy; too_long, "
            "normal_angle, angle_limit, no_entry: the needle's length, the angle to the "
            "surface normal, the angle limits, no entry point.",
        ),
    ]
    if best_rows:
        sections.append(TableSection("Best entry per objective", best_rows, "RAS mm."))
    if record.get("pareto_front"):
        sections.append(
            TableSection(
                "Pareto front: length against clearance",
                record["pareto_front"],
                "Directions no other beats in both insertion length and certified clearance.",
            )
        )
    sections += [
        FigureSection(
            "CFRW layers (as Liu's Fig. 11)",
            cfrw_layers_figure(cfrw, heights, chosen, layers=layers or None),
            f"(a) the CFRW in the plane z = {heights[0]:g} mm of Sigma with the best entries' "
            f"crossings; (b) its boundaries at z = {', '.join(f'{h:g}' for h in heights)} mm.",
        ),
        FigureSection(
            "Accessibility map",
            accessibility_map_figure(cfrw, chosen),
            "Each direction at its entry point, coloured by certified clearance when in the "
            "CFRW, else by what blocks it; the best entries marked.",
        ),
    ]
    return sections


def _cfrw_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.straight.cfrw import cfrw_map

    sc = load(rf.scenario)
    multi, _ = _straight_problem(load, sc, rf)
    d = rf.data
    theta = np.asarray(d["theta_deg"], float)
    phi = np.asarray(d["phi_deg"], float)
    res = d.get("resolution_deg")
    if res is None:  # files from before the field: the grid's step
        res = float(theta[1] - theta[0]) if len(theta) > 1 else float(phi[1] - phi[0])
    problem = multi.problem.with_target(np.asarray(d["target_mm"], float))
    m = cfrw_map(problem, resolution_deg=float(res))
    grid = (np.degrees(m.theta_rad), np.degrees(m.phi_rad))
    if m.blocked.shape != (len(theta), len(phi)) or not (
        np.allclose(grid[0], theta, atol=1e-5) and np.allclose(grid[1], phi, atol=1e-5)
    ):
        raise InvalidInputError(
            str(rf.path),
            f"the map recomputed from {rf.scenario} at {res:g} deg has a {len(grid[0])} x "
            f"{len(grid[1])} grid of other angles than the file's {len(theta)} x {len(phi)}: "
            "the scenario's angle limits changed; give the one it was made from with --scenario",
        )
    _map_mismatch(rf, "the map", d["counts"], m.counts())
    moved = int(np.count_nonzero(m.feasible != np.asarray(d["feasible"], bool)))
    if moved:
        raise InvalidInputError(
            str(rf.path),
            f"the map recomputed from {rf.scenario} has {moved} directions in or out of the "
            "CFRW unlike the file: the scenario changed since; give the one it was made from "
            "with --scenario",
        )
    return ReportPart(
        rf,
        f"CFRW map: {sc.name or rf.scenario}",
        cfrw_sections(m, d),
        f"CFRW: {m.counts()['free']} of {m.blocked.size} directions clear; the map recomputed "
        "from the scenario matches the file",
    )


def _multi_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.straight.ablation import AblationOutcome
    from needlekit.planning.straight.sequence import MultiNeedlePlan
    from needlekit.planning.straight.verify import verify_multi
    from needlekit.report.straight_report import plan_maps, straight_sections

    sc = load(rf.scenario)
    multi, options = _straight_problem(load, sc, rf)
    plan = MultiNeedlePlan.from_dict(rf.data, rf.path.name)
    coverage = AblationOutcome.from_dict(rf.data.get("coverage"), f"{rf.path.name}: coverage")
    res = rf.data.get("resolution_deg", options.get("resolution_deg", 1.0))
    maps = plan_maps(multi.problem, plan, resolution_deg=float(res))
    for n, m in zip(plan.needles, maps, strict=True):
        _map_mismatch(rf, f"needle {n.order}'s CFRW map", n.blocked, m.counts())
    check = verify_multi(multi.problem, rf.data)
    sections = straight_sections(
        plan, maps, multi.problem.scene,
        zones=None if coverage is None else coverage.chosen.zone, coverage=coverage,
    )  # fmt: skip
    verdict = "passed" if check.ok else "FAILED: " + "; ".join(check.violations)
    sections[1:1] = [
        TableSection(
            f"Independent check: {verdict}",
            check.metrics["needles"],
            "Each needle rebuilt from its target and entry points and measured again against "
            "the scenario: length, entry on the surface, angles, certified clearance to the "
            "anatomy and to the needles placed before it.",
        )
    ]
    status = "solved" if plan.solved else "not solved"
    return ReportPart(
        rf,
        f"Straight multi-needle plan: {rf.scenario or rf.data.get('scenario')}",
        sections,
        f"{len(plan.needles)} needles, {status}; check {'passed' if check.ok else 'FAILED'}",
        check.ok,
    )
