"""Report part of a plan's execution (``execute.json`` of ``needlekit execute``): the page
``execute --report`` writes, drawn again from the file and its scenario.

The plan is rebuilt from the motions the file keeps and the scenario's start pose (the
command checked, before any trial, that the plan starts there); a file whose motions do
not leave the scenario's start for its goal was made from another scenario.
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile
from needlekit.report.execute_multi_report import TITLE as MULTI_TITLE
from needlekit.report.execute_multi_report import multi_execute_sections
from needlekit.report.execute_report import TITLE, execute_sections
from needlekit.report.result_parts import ReportPart, _steerable_problem

__all__: list[str] = []


def _execute_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.planning.steerable.plan import SteerablePlan  # numba: when drawing only

    d = rf.data
    sc = load(rf.scenario)
    problem = _steerable_problem(load, sc, rf)
    plan = SteerablePlan(
        np.asarray(problem.start_pose, float), np.asarray(d["plan_primitives"], float)
    )
    end = plan.points_mm(1.0)[-1]
    off = float(np.linalg.norm(end - np.asarray(problem.goal_mm, float)))
    if off > problem.goal_tolerance_mm + 1e-6:
        raise InvalidInputError(
            str(rf.path),
            f"its plan ends {off:.2f} mm from the goal of {rf.scenario.name} (tolerance "
            f"{problem.goal_tolerance_mm:g} mm): it was made from another scenario; give that "
            "one with --scenario",
        )
    try:
        sections = execute_sections(d, problem, plan)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InvalidInputError(
            str(rf.path),
            f"lacks a field the execution page draws ({type(exc).__name__}: {exc}); it was "
            "written by an older needlekit: run `needlekit execute` again",
        ) from None
    s = d["summary"]
    closed, opened = s["closed_loop"], s["open_loop"]

    def mean(loop) -> str:
        m = loop["final_error_mm"].get("mean")
        return "-" if m is None else f"{m:.2f} mm"

    crossed = closed["violated"] + opened["violated"]
    return ReportPart(
        rf,
        TITLE,
        sections,
        f"{s['trials']} trials: closed loop {mean(closed)} off the target on average, open "
        f"loop {mean(opened)}; {crossed} crossed an obstacle",
    )


def _execute_multi_part(rf: ResultFile, load) -> ReportPart:
    d = rf.data
    sc = load(rf.scenario)
    multi, _ = load.multi_problem(sc)
    record = {"needles": d["plan_needles"]}  # the plan's lines, as the run read them
    try:
        sections = multi_execute_sections(d, multi.problem.scene, record)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InvalidInputError(
            str(rf.path),
            f"lacks a field the execution page draws ({type(exc).__name__}: {exc}); it was "
            "written by an older needlekit: run `needlekit execute` again",
        ) from None
    s = d["summary"]
    mean = (s.get("error_mm") or {}).get("mean")
    error = "" if mean is None else f", {mean:.2f} mm off their targets on average"
    return ReportPart(
        rf,
        MULTI_TITLE,
        sections,
        f"{s['trials']} trials of {len(d['plan_needles'])} needles{error}; "
        f"{len(s['touched'])} needle(s) touched a placed one, {len(s['crashed'])} trial(s) "
        "crashed",
    )
