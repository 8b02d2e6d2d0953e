"""The report part of a run among moving obstacles (``needlekit plan --dynamic``).

The scenario's moving obstacles must move as the file records; the independent checks of
the executed path and of the plan made at ``t = 0`` are run again and shown beside the
verdicts the file records.
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile
from needlekit.planning.result import PlanStatus
from needlekit.report.dynamic_report import dynamic_sections
from needlekit.report.html_page import TableSection
from needlekit.report.result_parts import ReportPart, _steerable_problem

__all__: list[str] = []


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

    rec = DynamicRecord.from_dict(rf.data, rf.path.name)
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf, goal_mm=rec.goal_mm)  # the scenario's start
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
