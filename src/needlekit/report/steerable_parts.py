"""The parts of a result page for steerable-needle results: a plan, plans to several
targets, a sweep and a run among moving obstacles, each rebuilt from its file and checked
again against its scenario (:mod:`needlekit.report.result_report` says what each shows).
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile
from needlekit.report.html_page import TableSection
from needlekit.report.report_part import ReportPart

__all__ = []


def _steerable_problem(sc, rf: ResultFile, start_pose=None, goal_mm=None):
    """The scenario's steerable problem, from the result's start pose and goal when given
    (a plan is checked against the goal it was made for)."""
    from needlekit.io.problems import problem_from_scenario

    overrides: dict = {}
    if start_pose is not None:
        overrides |= {"start_pose": np.asarray(start_pose, float), "start_point_mm": None}
    if goal_mm is not None:
        overrides["goal_mm"] = np.asarray(goal_mm, float)
    try:
        return problem_from_scenario(sc, **overrides)
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
    from needlekit.io.records import plan_result_from_dict
    from needlekit.report.steerable_report import plan_sections

    result = plan_result_from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(sc, rf, result.start_pose, result.goal_mm)
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
    from needlekit.io.records import goals_from_dict
    from needlekit.report.steerable_report import goals_sections, plan_rows

    results = goals_from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(sc, rf, results[0].start_pose, results[0].goal_mm)
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
    from needlekit.io.records import sweeps_from_dict
    from needlekit.report.sweep_report import sweep_study_sections

    sc = load(rf.scenario)
    problem = _steerable_problem(sc, rf)
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


class _Loaded:
    """A loaded scenario and its problem, handed to
    :func:`~needlekit.io.problems.moving_case` as a
    :class:`~needlekit.io.problems.ScenarioSource` hands them (so the scenarios loaded once
    serve it too)."""

    def __init__(self, scenario, problem) -> None:
        self.scenario, self.problem = scenario, problem

    def load(self):
        return self.scenario, self.problem


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
    from needlekit.io.problems import moving_case
    from needlekit.io.records import dynamic_from_dict
    from needlekit.planning.steerable.dynamic import DynamicResult
    from needlekit.report.dynamic_report import dynamic_sections

    rec = dynamic_from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(sc, rf, rec.executed.start_pose, rec.goal_mm)
    _, static, moving = moving_case(_Loaded(sc, problem))
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
