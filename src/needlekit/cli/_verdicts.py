"""What the planning and execution commands say of their results, and the exit status it
implies: ``plan``'s and ``verify``'s clearance line (one figure for both), the margin that
plans when the one asked for does not, ``execute``'s tables (units in every numeric header,
a dash and a footnote where there is no value) and the reasons it exits 1."""

from __future__ import annotations

import argparse
import functools
import math

from needlekit.cli._common import EXIT_OK, _fmt_table
from needlekit.errors import InvalidInputError

#: The library's names of the values the flags replace, as the flags say them.
_FLAG_OF_FIELD = {"goal_mm": "--goal", "start_pose": "--start-pose", "planner": "--planner"}


def flags_named(handler):
    """The command's handler, an error about a value a flag gave named by the flag
    (``--goal``, not the library's ``goal_mm``).

    Parameters
    ----------
    handler : callable
        ``handler(args) -> int``.

    Returns
    -------
    callable
        The same, with the library's field names turned into the flags that gave them.
    """

    @functools.wraps(handler)
    def run(args: argparse.Namespace) -> int:
        try:
            return handler(args)
        except InvalidInputError as exc:
            flag = _FLAG_OF_FIELD.get(exc.field)
            if flag is None or getattr(args, flag[2:].replace("-", "_"), None) is None:
                raise
            raise InvalidInputError(flag, exc.reason) from None

    return run


def say_plan(res, problem, planner, settings, out) -> int:
    """``plan``'s account of one search: the cost and the clearance line when solved; else
    that there is no plan (an approximate path is no plan to execute) and, under a margin,
    one that does plan (:func:`margin_advice`).

    Parameters
    ----------
    res : PlanResult
    problem : SteerableProblem
    planner : Planner
        The planner that ran (searched again for the advice).
    settings : PlannerSettings
    out : Path
        Where the record went.

    Returns
    -------
    int
        The exit status: 0 with a plan, 1 without.
    """
    from needlekit.planning.result import PlanStatus

    name = settings.name
    times = (f"({1000 * res.time_s:.1f} ms search, {1000 * res.stats.get('setup_s', 0.0):.1f} "
             f"ms set-up) -> {out}")  # fmt: skip
    margin = problem.safety_margin_mm
    if res.status is PlanStatus.SOLVED:
        cert = ", certified optimal at the finest resolution" if res.stats.get("certified") else ""
        print(f"{name}: solved, cost {res.cost_mm:.4f} mm{cert} {times}")
        print(clearance_line(res.stats, margin))
        return EXIT_OK
    why = f": {res.stats['reason']}" if res.stats.get("reason") else ""
    if res.status is PlanStatus.INVALID_INPUT:  # nothing to search: the margin plays no part
        print(f"{name}: {res.status.value}, no plan{why} {times}")
        return 1
    print(f"{name}: {res.status.value}, no plan to the goal with a {margin:g} mm safety "
          f"margin{why} {times}")  # fmt: skip
    if res.status is PlanStatus.APPROXIMATE:
        print(f"  the nearest path it found stops {res.stats['goal_distance_mm']:.3f} mm from the "
              f"goal (tolerance {problem.goal_tolerance_mm:g} mm): recorded with status "
              "approximate, not a plan to execute")  # fmt: skip
    if margin > 0:
        print(margin_advice(problem, planner, settings))
    return 1


def clearance_line(metrics, margin_mm: float) -> str:
    """The clearance of a path in one line, as ``plan`` and ``verify`` both print it: the
    certified figure of the one clearance rule (:mod:`needlekit.constants`, a lower bound
    over the whole path), the smallest sampled distance beside it, and the margin kept.

    Parameters
    ----------
    metrics : mapping
        ``certified_clearance_mm``, ``min_clearance_mm``, ``collision_model``
        (:func:`~needlekit.planning.steerable.verify.verify_plan`'s metrics, or a plan's
        ``stats``, which are the same check's).
    margin_mm : float
        The problem's safety margin.

    Returns
    -------
    str
    """

    def mm(key: str) -> str:
        v = metrics.get(key)
        return "-" if v is None else f"{v:.3f} mm"

    return (
        f"clearance: certified {mm('certified_clearance_mm')} over the whole path "
        f"(smallest sampled distance {mm('min_clearance_mm')}; "
        f"{metrics.get('collision_model', '-')}), safety margin kept {margin_mm:g} mm"
    )


def margin_advice(problem, planner, settings) -> str:
    """Which margin plans, when the one asked for does not: the same search without a
    margin, then at the margin the path it found passes by the search's own clearance test
    (:func:`~needlekit.planning.steerable.verify.search_clearance_mm`), to confirm it
    (two more searches, each within the budget). That margin plans, so the largest one is
    at least it; a costlier path may keep more.

    Parameters
    ----------
    problem : SteerableProblem
        The problem under the margin that left no plan.
    planner : Planner
    settings : PlannerSettings
        Its termination (the budget) for each search.

    Returns
    -------
    str
        One line, indented.
    """
    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.solve import solve
    from needlekit.planning.steerable.verify import search_clearance_mm

    free_problem = problem.with_safety_margin(0.0)
    free = solve(free_problem, planner, termination=settings.termination())
    if free.status is not PlanStatus.SOLVED:
        return ("  without a margin it finds no plan either: the margin is not what stops it "
                "(the goal, the needle or the budget is)")  # fmt: skip
    c = free.stats["certified_clearance_mm"]
    bound = math.floor(1000 * search_clearance_mm(free_problem, free.plan)) / 1000
    head = (f"  without a margin it plans (cost {free.cost_mm:.4f} mm, certified clearance "
            f"{c:.3f} mm)")  # fmt: skip
    if bound <= 0:
        return head + "; that path passes the search's clearance test at no margin above 0"
    again = solve(problem.with_safety_margin(bound), planner, termination=settings.termination())
    if again.status is PlanStatus.SOLVED:
        return (f"{head}; the largest margin that plans is at least {bound:g} mm (checked: "
                f"--safety-margin-mm {bound:g} plans, cost {again.cost_mm:.4f} mm; a costlier "
                "path may keep more)")  # fmt: skip
    return (
        f"{head}; that path passes the search's clearance test up to a {bound:g} mm "
        f"margin, but at {bound:g} mm the planner found no plan within its budget"
    )


def execute_failures(s: dict) -> list[str]:
    """Why a steerable ``execute`` run exits 1, one line each (none: exit 0), as its
    ``--help`` says: a run that crossed an obstacle (open loop, closed loop, or the closed
    loop under any breathing policy: ignore, gate or track, or any sensing policy run side
    by side), a trial that crashed, an
    insertion aborted on a sensor fault (``--on-fault abort``, or a hold longer than
    ``--hold-timeout-s``), an insertion stopped with its estimated tip near an obstacle
    (``--stop-clearance-mm``).

    Parameters
    ----------
    s : dict
        ``summary`` of ``execute.json``.

    Returns
    -------
    list of str
    """
    runs = {"open loop": s["open_loop"], "closed loop": s["closed_loop"]}
    runs.update({f"breathing, {k}": r for k, r in (s.get("breathing") or {}).items()})
    runs.update({f"sensing, {k}": r for k, r in (s.get("sensing") or {}).items()})
    out = []
    for name, r in runs.items():
        if r.get("violated"):
            out.append(f"{name}: {r['violated']} of {r['runs']} runs crossed an obstacle")
    for name, r in runs.items():
        if r.get("aborted"):
            out.append(f"{name}: {r['aborted']} of {r['runs']} insertions aborted on a sensor "
                       "fault (execute.json: faults)")  # fmt: skip
    for name, r in runs.items():
        if r.get("stopped_near_obstacle"):
            out.append(f"{name}: {r['stopped_near_obstacle']} of {r['runs']} insertions stopped "
                       "short: the estimated tip came too close to an obstacle (execute.json: "
                       "stopped_near_obstacle)")  # fmt: skip
    if s["crashed"]:
        out.append(f"{len(s['crashed'])} of {s['trials']} trials crashed")
    return out


#: Why a cell of the execute tables has no value (the footnote under the table).
_NO_REPLAN = "no re-plan ran, so there is no latency to measure (the open loop never re-plans)"


def summary_table(s: dict) -> str:
    """``execute``'s table of the open and the closed loop (and, under breathing, one row
    per policy), units in every numeric header, a dash with its reason where there is no
    value.

    Parameters
    ----------
    s : dict
        ``summary`` of ``execute.json``.

    Returns
    -------
    str
    """
    rows = []
    for loop in ("open_loop", "closed_loop"):
        r = s[loop]
        e, c, lat = r["final_error_mm"], r["min_clearance_mm"], r["replan_latency_ms"]
        within = None if r["within_1mm"] is None else 100.0 * r["within_1mm"]
        rows.append([
            loop.replace("_", " "), e.get("mean"), e.get("sd"), e.get("max"), within,
            c.get("min"), r["violated"], r["replans"].get("mean"), lat.get("p95"),
        ])  # fmt: skip
    head = ["run", "error mean mm", "sd mm", "max mm", "% <= 1 mm", "min clearance mm",
            "crossed", "re-plans", "re-plan p95 ms"]  # fmt: skip
    text = _fmt_table(head, rows, why={
        "re-plan p95 ms": _NO_REPLAN,
        "min clearance mm": "no run ended (every trial crashed)",
    })  # fmt: skip
    if "breathing" in s:
        text += "\n\n" + breathing_table(s["breathing"])
    if "sensing" in s:
        text += "\n\n" + sensing_table(s["sensing"])
    return text + f"\n{s['trials']} trials; plans and re-plans keep a {s['margin_mm']:g} mm margin"


def _policy_row(label: str, r: dict, *between) -> list:
    """A closed-loop row of a policy's summary: the error's mean, SD and max, the share
    within 1 mm (%), the crossings, ``between``, then the mean procedure time."""
    e = r["final_error_mm"]
    within = None if r["within_1mm"] is None else 100.0 * r["within_1mm"]
    return [label, e.get("mean"), e.get("sd"), e.get("max"), within, r["violated"], *between,
            r["procedure_s"].get("mean")]  # fmt: skip


def breathing_table(per_policy: dict) -> str:
    """The closed loop under breathing, a row per policy.

    Parameters
    ----------
    per_policy : dict
        ``summary["breathing"]`` of ``execute.json``.

    Returns
    -------
    str
    """
    rows = [_policy_row(f"breathing, {name}", r) for name, r in per_policy.items()]
    return _fmt_table(
        ["policy", "error mean mm", "sd mm", "max mm", "% <= 1 mm", "crossed", "procedure s"],
        rows,
        why={"procedure s": "no run ended (every trial crashed)"},
    )


def sensing_table(per_policy: dict) -> str:
    """The closed loop under each sensing policy side by side, a row per policy.

    Parameters
    ----------
    per_policy : dict
        ``summary["sensing"]`` of ``execute.json``.

    Returns
    -------
    str
    """
    rows = [
        _policy_row(
            f"sensing, {name}",
            r,
            r["target_displacement_max_mm"].get("max"),
            r["target_error_mm"].get("mean"),
            r["scans"].get("mean"),
        )
        for name, r in per_policy.items()
    ]
    return _fmt_table(
        ["policy", "error mean mm", "sd mm", "max mm", "% <= 1 mm", "crossed",
         "target moved max mm", "target belief error mm", "scans", "procedure s"],
        rows,
        why={"target moved max mm": _NO_TARGET, "target belief error mm": _NO_TARGET,
             "scans": _NO_TARGET, "procedure s": "no run ended (every trial crashed)"},
    )  # fmt: skip


#: Why a sensing row has no target figures.
_NO_TARGET = ("em senses no target and the truth carries none: the plan's target, assumed "
              "still")  # fmt: skip


def dynamic_summary(res) -> list[str]:
    """``plan --dynamic``'s account: how the re-planning run and the plan made at t = 0 went.

    Parameters
    ----------
    res : DynamicResult

    Returns
    -------
    list of str
        The lines to print.
    """
    s, m = res.settings, res.check.metrics
    clear = m.get("certified_moving_clearance_mm")
    lines = [
        f"{s['planner']}, re-planning every {s['step_mm']:g} mm at {s['insertion_speed_mm_s']:g} "
        f"mm/s ({s['predict']} prediction): {res.status.value}, {res.reason}; path "
        f"{res.executed.length_mm:.2f} mm, certified clearance to the moving obstacles "
        + ("-" if clear is None else f"{clear:.3f} mm")
    ]
    lines += [f"  - {v}" for v in res.check.violations]
    if res.static is not None:
        plan, check = res.static
        if check is None:
            lines.append(f"plan made once at t = 0: {plan.status.value}, no plan to execute")
        else:
            verdict = "passes" if check.ok else "fails"
            lines.append(
                f"plan made once at t = 0, executed open-loop: {verdict} the check "
                f"(certified clearance to the moving obstacles "
                f"{check.metrics['certified_moving_clearance_mm']:.3f} mm)"
            )
            lines += [f"  - {v}" for v in check.violations]
    return lines
