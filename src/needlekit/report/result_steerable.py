"""Report parts of steerable-needle results: a plan, plans to several targets, a sweep.

Each plan is checked again against its scenario (:func:`_check`), and the verdicts summed
up in one line (:func:`_verdict`). :mod:`needlekit.report.result_report` picks the builder
by the result's kind.
"""

from __future__ import annotations

import numpy as np

from needlekit.io.results import ResultFile
from needlekit.report.html_page import TableSection
from needlekit.report.result_parts import ReportPart, _steerable_problem
from needlekit.report.steerable_report import goals_sections, plan_check, plan_rows, plan_sections

__all__: list[str] = []


def _check(problem, result, *, free_direction: bool = False):
    """:func:`~needlekit.report.steerable_report.plan_check` (the name the builders use)."""
    return plan_check(problem, result, free_direction=free_direction)


def _own_goal(problem, results) -> str:
    """Says when the plans were made for goals other than the scenario's (``plan --goal``,
    ``--goals``): they are checked against those."""
    if all(np.allclose(r.goal_mm, problem.goal_mm, atol=1e-9) for r in results):
        return ""
    return " (checked against the goals given when planning, not the scenario's)"


def _verdict(checks) -> tuple[bool | None, str]:
    done = [c for c in checks if c is not None]
    if not done:
        return None, "nothing to check"
    bad = sum(not c.ok for c in done)
    return not bad, "check passed" if not bad else f"check FAILED ({bad} of {len(done)})"


def _plan_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.result import PlanResult

    result = PlanResult.from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf)
    check = _check(problem, result, free_direction=rf.data.get("start_direction") == "swept")
    ok, verdict = _verdict([check])
    verdict += _own_goal(problem, [result])
    problem = problem.with_goal(result.goal_mm)
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

    results = goals_from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf)
    checks = [_check(problem, r) for r in results]
    own_goal = _own_goal(problem, results)
    problem = problem.with_goal(results[0].goal_mm)
    planner, mode = rf.data["planner"], rf.data["mode"]
    sections = goals_sections(problem, results, planner=planner, mode=mode, checks=checks)
    for i, r in enumerate(results, start=1):
        if r.plan is not None:
            sections.append(TableSection(f"Target {i}: motions", plan_rows(r.plan)))
    ok, verdict = _verdict(checks)
    verdict += own_goal
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
    check = None if best is None else _check(problem, best, free_direction=True)
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
