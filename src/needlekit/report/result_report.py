"""One self-contained page from result files (``needlekit report RESULT... --out page.html``).

Each result file (:func:`needlekit.scenario.results.read_results`) becomes one part of the page, drawn by the
builders its own command uses, from the objects rebuilt from the file:

- a plan (``needlekit plan``, ``sweep --plan``): :func:`~.steerable_report.plan_sections`:
  summary, the independent check run again against the scenario, the motions, the path
  in the 3D anatomy;
- plans to several targets (``plan --goals``): :func:`~.steerable_report.goals_sections`,
  each target's plan checked again, and each plan's motions;
- a sweep: :func:`~.sweep_report.sweep_study_sections`, as ``needlekit sweep --report``
  draws it (the best plan checked again; the file keeps no other path, so Fig. 7 is left
  out);
- a CFRW map (``needlekit cfrw``): :func:`cfrw_sections`, the map recomputed from the
  scenario (the file keeps no blocking reasons nor entry points) and compared with the
  file's;
- a multi-needle plan: :func:`~.straight_report.straight_sections`, each needle's CFRW map
  recomputed (:func:`~.straight_report.plan_maps`) and compared with the counts in the
  file, and the independent check (:func:`~needlekit.planning.straight.verify.verify_multi`);
- a puncture study: :func:`~.puncture_report.puncture_sections`;
- a run among moving obstacles (``needlekit plan --dynamic``):
  :func:`~.dynamic_report.dynamic_sections`, the paths rebuilt from their motions, the
  moving obstacles from the scenario (their motions compared with the file's), and the
  independent check (:func:`~needlekit.planning.steerable.moving.certify_execution`) of
  the executed path and of the plan made at ``t = 0`` run again, beside the verdicts the
  file records;
- scaling curves (``needlekit bench scale``): :func:`~.scale_figures.scale_sections`, the
  record's series as measured (nothing to check again).

:func:`write_result_report` takes its scenarios from the caller
(:class:`needlekit.scenario.results.ResultScenarios` loads each once, however many results
name it): the report layer draws and does not load scenarios.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile, ResultKind
from needlekit.report.html_page import (
    FigureSection,
    PartSection,
    TableSection,
    TextSection,
    write_report_html,
)

__all__ = ["ReportPart", "ResultReport", "cfrw_sections", "result_part", "write_result_report"]


@dataclass(frozen=True)
class ReportPart:
    """One result drawn.

    Attributes
    ----------
    result : ResultFile
    title : str
        What its own command titles its page.
    sections : list
        For :func:`~needlekit.report.html_page.write_report_html`.
    summary : str
        One line for the terminal.
    checks_ok : bool or None
        Whether every independent check run again passed (None: nothing to check).
    """

    result: ResultFile
    title: str
    sections: list
    summary: str
    checks_ok: bool | None = None


@dataclass(frozen=True)
class ResultReport:
    """What :func:`write_result_report` wrote.

    Attributes
    ----------
    path : Path
    parts : list of ReportPart
    """

    path: Path
    parts: list = field(default_factory=list)


def _steerable_problem(load, sc, rf: ResultFile, start_pose=None, goal_mm=None):
    """The scenario's steerable problem, from the result's start pose and goal when given
    (a plan is checked against the goal it was made for)."""
    overrides: dict = {}
    if start_pose is not None:
        overrides |= {"start_pose": np.asarray(start_pose, float), "start_point_mm": None}
    if goal_mm is not None:
        overrides["goal_mm"] = np.asarray(goal_mm, float)
    try:
        return load.steerable_problem(sc, **overrides)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{rf.scenario}: {exc.field}", exc.reason) from None


def _check(problem, result):
    """The independent check of a result's plan (None without one); a path that stops short
    of the goal is checked as such."""
    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.verify import verify_approximate, verify_plan

    if result.plan is None:
        return None
    p = problem.with_start_pose(result.plan.start_pose).with_goal(result.goal_mm)
    if result.status is PlanStatus.APPROXIMATE:
        return verify_approximate(p, result.plan)
    cost = None if not np.isfinite(result.cost_mm) else result.cost_mm
    return verify_plan(p, result.plan, expected_cost_mm=cost)


def _verdict(checks) -> tuple[bool | None, str]:
    done = [c for c in checks if c is not None]
    if not done:
        return None, "nothing to check"
    bad = sum(not c.ok for c in done)
    return not bad, "check passed" if not bad else f"check FAILED ({bad} of {len(done)})"


def _plan_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.result import PlanResult
    from needlekit.report.steerable_report import plan_sections

    result = PlanResult.from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf, result.start_pose, result.goal_mm)
    check = _check(problem, result)
    ok, verdict = _verdict([check])
    cost = "" if result.plan is None else f", cost {result.cost_mm:.4f}"
    return ReportPart(
        rf,
        f"Steerable-needle plan: {sc.name or rf.scenario.name}",
        plan_sections(problem, result, check),
        f"{result.planner} plan, {result.status.value}{cost}; {verdict}",
        ok,
    )


def _goals_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.result import goals_from_dict
    from needlekit.report.steerable_report import goals_sections, plan_rows

    results = goals_from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf, results[0].start_pose, results[0].goal_mm)
    checks = [_check(problem, r) for r in results]
    planner, mode = rf.data["planner"], rf.data["mode"]
    sections = goals_sections(problem, results, planner=planner, mode=mode, checks=checks)
    for i, r in enumerate(results, start=1):
        if r.plan is not None:
            sections.append(TableSection(f"Target {i}: motions", plan_rows(r.plan)))
    ok, verdict = _verdict(checks)
    solved = sum(r.status.value == "solved" for r in results)
    return ReportPart(
        rf,
        f"Plans to {len(results)} targets",
        sections,
        f"{planner} ({mode}): {solved} of {len(results)} targets solved; {verdict}",
        ok,
    )


def _sweep_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.sweep_result import sweeps_from_dict
    from needlekit.report.sweep_report import sweep_study_sections

    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf)
    sweeps = sweeps_from_dict(rf.data, rf.path.name, goal_mm=problem.goal_mm)
    first = next(iter(sweeps))
    best = sweeps[first].best
    check = None if best is None else _check(problem, best)
    sections = sweep_study_sections(
        sweeps, problem, options=rf.data.get("options") or {}, best=best, check=check
    )
    ok, verdict = _verdict([check])
    st = sweeps[first].stats
    return ReportPart(
        rf,
        f"Effective puncture region: {sc.name}",
        sections,
        f"sweep of {', '.join(sweeps)}: {st.get('n_solved')} of {st.get('n_effective')} "
        f"effective directions solved by {first}; best plan {verdict}",
        ok,
    )


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
        f"Straight multi-needle plan: {rf.data.get('scenario', rf.scenario)}",
        sections,
        f"{len(plan.needles)} needles, {status}; check {'passed' if check.ok else 'FAILED'}",
        check.ok,
    )


def _puncture_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.report.puncture_report import TITLE, puncture_sections

    summary = {k: v for k, v in rf.data.items() if k != "per_trial"}
    trials = rf.data["per_trial"]
    try:
        sections = puncture_sections(summary, trials)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        # the fields read_result checks are there: this one came later than the file
        raise InvalidInputError(
            str(rf.path),
            f"lacks a field the puncture report draws ({type(exc).__name__}: {exc}); it was "
            "written by an older needlekit: run `needlekit puncture` again",
        ) from None
    return ReportPart(
        rf,
        TITLE,
        sections,
        f"{summary['completed']} of {summary['trials']} trials completed",
    )


def _same_motions(rf: ResultFile, recorded: dict, moving) -> None:
    """The scenario moves the obstacles the file names, as the file says."""
    mine = {m.name: m.motion for m in moving}
    bad = sorted(set(mine) ^ set(recorded))
    for name in sorted(set(mine) & set(recorded)):
        a, b = recorded[name], mine[name]
        nums = [np.r_[m.velocity_mm_s, m.amplitude_mm, m.period_s or 0.0, m.phase_deg]
                for m in (a, b)]  # fmt: skip
        if (a.period_s is None) != (b.period_s is None) or not np.allclose(*nums, atol=1e-9):
            bad.append(name)
    if bad:
        raise InvalidInputError(
            str(rf.path),
            f"the moving obstacles {', '.join(map(repr, bad))} move otherwise (or not at all) in "
            f"the scenario {rf.scenario}: it was made from another scenario (give that one with "
            "--scenario)",
        )


def _dynamic_checks(rf: ResultFile, rec, static, moving):
    """The checks of the executed path and of the plan made at t = 0, run again."""
    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.dynamic import DynamicStatus
    from needlekit.planning.steerable.moving import certify_execution

    speed = rec.settings["insertion_speed_mm_s"]
    whole = rec.status in (DynamicStatus.REACHED, DynamicStatus.CHECK_FAILED)
    try:
        check = certify_execution(static, moving, rec.executed, speed, require_goal=whole)
        base = None
        if rec.static is not None:
            plan = rec.static.plan
            solved = rec.static.status is PlanStatus.SOLVED
            again = (
                None
                if plan is None
                else certify_execution(static, moving, plan, speed, require_goal=solved)
            )
            base = (rec.static, again)
    except InvalidInputError as exc:  # the scenario's collision model or start
        raise InvalidInputError(f"{rf.scenario}: {exc.field}", exc.reason) from None
    return check, base


def _recheck_rows(rec, check, base) -> tuple[list, list]:
    """The verdicts recorded and run again, and the paths where they differ."""

    def verdict(ok):
        return "-" if ok is None else "passed" if ok else "FAILED"

    def clearance(metrics):
        return None if metrics is None else metrics.get("certified_moving_clearance_mm")

    paths = [("executed path", rec.checks["executed"], check)]
    if base is not None:
        paths.append(("plan made once at t = 0", rec.checks["static"], base[1]))
    rows, differ = [], []
    for name, recorded, again in paths:
        before = None if recorded is None else recorded["ok"]
        now = None if again is None else again.ok
        if None not in (before, now) and before != now:
            differ.append(name)
        rows.append(
            {
                "path": name,
                "recorded": verdict(before),
                "run_again": verdict(now),
                "recorded_clearance_mm": clearance(
                    None if recorded is None else recorded["metrics"]
                ),
                "clearance_now_mm": clearance(None if again is None else again.metrics),
            }
        )
    return rows, differ


def _dynamic_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.dynamic import DynamicResult
    from needlekit.planning.steerable.dynamic_record import DynamicRecord
    from needlekit.report.dynamic_report import dynamic_sections

    rec = DynamicRecord.from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf, rec.executed.start_pose, rec.goal_mm)
    _, static, moving = load.moving_case(sc, problem)
    _same_motions(rf, rec.motions, moving)
    check, base = _dynamic_checks(rf, rec, static, moving)
    result = DynamicResult(rec.status, rec.reason, rec.executed, check, rec.cycles,
                           dict(rec.settings), tuple(moving), base)  # fmt: skip
    name = sc.name or rf.scenario.name
    sections = dynamic_sections(static, result, title=name)
    rows, differ = _recheck_rows(rec, check, base)
    sections[1:1] = [
        TableSection(
            "Independent checks run again",
            rows,
            f"Each path checked again against {rf.scenario}: the anatomy at rest, and each "
            "moving obstacle where it was when the tip passed (certified clearance to the "
            "moving obstacles, mm), beside what the file records. The report fails when the "
            "executed path fails, or when a verdict differs from the file's.",
        )
    ]
    s = rec.settings
    said = (
        f"{s['planner']} re-planning every {s['step_mm']:g} mm ({s['predict']}): "
        f"{rec.status.value} after {len(rec.cycles)} cycles; executed path check "
        f"{'passed' if check.ok else 'FAILED'}"
    )
    if base is not None and base[1] is not None:
        said += f"; plan made at t = 0 {'passes' if base[1].ok else 'fails'} the check"
    if differ:
        said += f"; the file records otherwise for the {' and the '.join(differ)}"
    return ReportPart(
        rf,
        f"Re-planning among moving obstacles: {name}",
        sections,
        said,
        check.ok and not differ,
    )


def _scale_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.report.scale_figures import scale_sections

    d = rf.data
    try:
        sections = scale_sections(d)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InvalidInputError(
            str(rf.path),
            f"lacks a field the scale report draws ({type(exc).__name__}: {exc}); run "
            "`needlekit bench scale` again",
        ) from None
    ran = [k for k in ("planning", "sweep", "study") if d.get(k)]
    return ReportPart(
        rf,
        "Scaling curves (needlekit bench scale)",
        sections,
        f"scaling curves: {', '.join(ran) or 'no series'}; measured {d['machine'].get('time_utc')} "
        f"at load {(d.get('load_average') or {}).get('start')}",
    )


_BUILDERS = {
    ResultKind.PLAN: _plan_part,
    ResultKind.GOALS: _goals_part,
    ResultKind.SWEEP: _sweep_part,
    ResultKind.CFRW: _cfrw_part,
    ResultKind.MULTI: _multi_part,
    ResultKind.PUNCTURE: _puncture_part,
    ResultKind.DYNAMIC: _dynamic_part,
    ResultKind.SCALE: _scale_part,
}


def result_part(result: ResultFile, load=None) -> ReportPart:
    """Draw one result file.

    Parameters
    ----------
    result : ResultFile
        As :func:`needlekit.scenario.results.read_result` returns it.
    load : ResultScenarios, optional
        Where the scenarios come from: ``load(path) -> Scenario``, and
        ``load.steerable_problem(scenario, **overrides)``, ``load.multi_problem(scenario)``,
        ``load.moving_case(scenario, problem)``
        (:class:`needlekit.scenario.results.ResultScenarios`; the report layer does not
        load scenarios itself). Needed by every kind that reads a scenario.

    Returns
    -------
    ReportPart

    Raises
    ------
    InvalidInputError
        The scenario does not give what the result was made from (other safety distance,
        a recomputed map that differs from the file's).
    """
    if not isinstance(result, ResultFile):
        raise InvalidInputError("result", f"expected a ResultFile, got {type(result).__name__}")
    if load is None and result.kind.needs_scenario:
        raise InvalidInputError(
            "scenarios",
            f"{result.path} ({result.kind.value}) is drawn with its scenario: pass "
            "needlekit.scenario.results.ResultScenarios()",
        )
    return _BUILDERS[result.kind](result, load)


def write_result_report(
    path: str | os.PathLike,
    results: Sequence[ResultFile],
    *,
    title: str | None = None,
    scenarios=None,
) -> ResultReport:
    """Draw result files on one self-contained HTML page, written atomically.

    One result fills the page as its own command would; several give one part each, in
    order, under a list of links.

    Parameters
    ----------
    path : path-like
        The page (``.html``).
    results : sequence of ResultFile
        As :func:`needlekit.scenario.results.read_results` returns them.
    title : str, optional
        Default: the result's own title, or the files' names.
    scenarios : ResultScenarios, optional
        Loads each scenario once, however many results name it (see :func:`result_part`);
        needed when a result reads a scenario.

    Returns
    -------
    ResultReport
    """
    if isinstance(results, ResultFile) or not results:
        raise InvalidInputError("results", "expected one or more ResultFile")
    parts = [result_part(r, scenarios) for r in results]
    if len(parts) == 1:
        sections = parts[0].sections
        title = title or parts[0].title
    else:
        sections = []
        for p in parts:
            about = f"{p.result.path}: {p.result.kind.label}"
            if p.result.scenario is not None:
                about += f", from the scenario {p.result.scenario}"
            sections += [PartSection(p.title, about + "."), *p.sections]
        title = title or "needlekit report: " + ", ".join(p.result.path.name for p in parts)
    return ResultReport(write_report_html(path, title=title, sections=sections), parts)
