"""``needlekit bench steerable``: curved-needle planners on the Med-RAD lungs.

Cases: lungs x starts x r_min (needle 1 mm, tau 1 mm, l_max 150 mm, heading change at most
90 degrees, path-length cost, obstacles within 3 mm of the start ignored), each planner
with a time budget. Field building is timed separately from planning. Patient 1's
reference figures (the reference planner by the authors of RCS*, as given in the issue)
are recorded beside ours.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Sequence
from contextlib import ExitStack
from typing import Any

import numpy as np

from needlekit.benchmarks.reference_app import check_reference_app
from needlekit.benchmarks.reference_comparison import ReferenceComparison
from needlekit.benchmarks.target_screening import (
    SAMPLE_CONE_DEG,
    SAMPLE_DISTANCE_MM,
    screening_summary,
)
from needlekit.benchmarks.target_screening import sample_targets as draw_targets
from needlekit.constants import (
    DEFAULT_GOAL_TOLERANCE_MM,
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_MAX_LENGTH_MM,
    DEFAULT_NEEDLE_DIAMETER_MM,
    DEFAULT_R_MIN_MM,
    DEFAULT_START_EXCLUSION_MM,
    DEFAULT_TIME_LIMIT_S,
)
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.provenance import machine_info
from needlekit.scenario.problems import load_problem, problem_from_scenario

__all__ = [
    "BENCH_NEEDLE",
    "REFERENCE_LUNG1",
    "medrad_lung_problem",
    "run_steerable_benchmark",
]

#: The reference for Med-RAD lung 1, RCS*: (start, r_min) -> certified cost (mm),
#: None where the goal is unreachable, "no plan" where nothing is found within 1 s.
REFERENCE_LUNG1: dict[tuple[int, int], float | str | None] = {
    (1, 50): 58.26, (2, 50): "no plan", (3, 50): 53.24, (4, 50): 58.12, (5, 50): 58.09,
    (1, 100): None, (2, 100): "no plan", (3, 100): 54.83, (4, 100): None, (5, 100): 58.41,
}  # fmt: skip


def _us_per_iteration(stats: dict) -> float | None:
    """Search time per iteration (microseconds), None without iterations."""
    wall, iterations = stats.get("planner_wall_s"), stats.get("iterations")
    return 1e6 * wall / iterations if iterations and wall is not None else None


def _row(res, **case) -> dict:
    st = res.stats
    return {
        **case,
        "planner": res.planner,
        "status": res.status.value,
        "cost_mm": None if not math.isfinite(res.cost_mm) else res.cost_mm,
        "time_s": res.time_s,
        "setup_s": st.get("setup_s"),
        "planner_wall_s": st.get("planner_wall_s"),
        "overrun_s": st.get("overrun_s"),
        "first_solution_s": st.get("first_solution_s"),
        "cost_history": st.get("cost_history", []),
        "certified": bool(st.get("certified", False)),
        "certified_clearance_mm": st.get("certified_clearance_mm"),
        "iterations": st.get("iterations"),
        "us_per_iteration": _us_per_iteration(st),
        "reason": st.get("reason"),
        "goal_distance_mm": st.get("goal_distance_mm"),
    }


def medrad_lung_problem(case, start: str, r_min_mm: float, target_mm=None):
    """The benchmark's problem for one Med-RAD lung start, built the way a scenario file
    with that case, start, target and needle is (:func:`needlekit.scenario.problems.problem_from_scenario`).

    Parameters
    ----------
    case : needlekit.io.medrad.MedradCase
    start : str
        ``"start1"`` ...
    r_min_mm : float
    target_mm : array_like, shape (3,), optional
        The goal (RAS mm; default: the case's own ``target``).

    Returns
    -------
    SteerableProblem
    """
    from needlekit.scenario.loading import GoalSpec, NeedleSpec, Scenario, StartSpec

    s = case.start(start)
    scenario = Scenario(
        name=f"Med-RAD {case.organ} {case.patient}, {start}",
        description="needlekit bench steerable",
        scene=case.scene,
        needle=NeedleSpec(
            diameter_mm=BENCH_NEEDLE["needle_diameter_mm"],
            r_min_mm=float(r_min_mm),
            max_length_mm=BENCH_NEEDLE["max_length_mm"],
            max_heading_change_deg=BENCH_NEEDLE["max_heading_change_deg"],
            start_exclusion_mm=BENCH_NEEDLE["start_exclusion_mm"],
        ),
        start=StartSpec(s.world_T_tip[:3, 3].copy(), s.world_T_tip, start),
        goal=GoalSpec(
            case.targets_mm["target"] if target_mm is None else np.asarray(target_mm, float),
            BENCH_NEEDLE["goal_tolerance_mm"],
            "target",
        ),
        base=case,
        collision_model="voxel_centres",
    )
    return problem_from_scenario(scenario)


#: The benchmark's needle: the reference planner's Med-RAD set-up (needlekit's defaults).
BENCH_NEEDLE: dict[str, float] = {
    "needle_diameter_mm": DEFAULT_NEEDLE_DIAMETER_MM,
    "goal_tolerance_mm": DEFAULT_GOAL_TOLERANCE_MM,
    "max_length_mm": DEFAULT_MAX_LENGTH_MM,
    "max_heading_change_deg": DEFAULT_MAX_HEADING_CHANGE_DEG,
    "start_exclusion_mm": DEFAULT_START_EXCLUSION_MM,
}


def run_steerable_benchmark(
    patients: Sequence[int] = (1, 2, 3, 4, 5),
    radii_mm: Sequence[float] = (DEFAULT_R_MIN_MM, 100.0),
    planners: Sequence[str] = ("rcs_star", "rcs", "rrt"),
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    medrad_dir=None,
    progress=None,
    scenarios: Sequence = (),
    reference_app=None,
    reference_work=None,
    sample_targets: int = 0,
    target_seed: int = 0,
) -> dict[str, Any]:
    """Run the planners on every case and record status, cost and time.

    Parameters
    ----------
    patients : sequence of int
        Med-RAD lung patients (every start of each, against its target).
    radii_mm : sequence of float
        Minimum radii of curvature.
    planners : sequence of str
        Registered steerable planners (seed 0).
    time_limit_s : float
        Budget per case and planner.
    medrad_dir : path-like, optional
    progress : callable, optional
        Called with a short string after each case (e.g. to advance a progress bar).
    scenarios : sequence of path-like
        Scenario files run as further cases, each with its own settings but these
        planners and budget (no Med-RAD grid when ``patients`` is empty).
    reference_app : path-like, optional
        A built ``rcs_star`` of the UNC reference planner: every lung case's ``rcs_star``
        run is interleaved with a run of the app on the same case
        (:mod:`needlekit.benchmarks.reference_comparison`; needs ``rcs_star`` among ``planners``
        and the app's 1 s budget). Checked before any work.
    reference_work : path-like, optional
        Where the app's case folders go (default: a temporary folder, removed at the end).
    sample_targets : int
        With ``reference_app``: instead of each patient's own target, this many targets
        drawn in its lung ahead of its starts
        (:func:`needlekit.benchmarks.target_screening.sample_targets`, seed ``target_seed``),
        each a case per r_min; the obstacle file's crop covers them. 0: the own target.
    target_seed : int
        Seed of the sampled targets.

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs``, ``fields`` (per patient: load and
        field-building seconds), ``results`` (one row per case and planner: ``patient``,
        ``start``, ``r_min_mm`` or ``scenario``, ``planner``, ``status``, ``cost_mm``,
        ``time_s``, ``setup_s``, ``planner_wall_s``, ``overrun_s`` (time beyond the budget),
        ``first_solution_s``, ``cost_history``, ``certified``, ``iterations``,
        ``reference_cost_mm``, ``us_per_iteration``: ``planner_wall_s`` per iteration in
        microseconds) and ``summary`` (per planner: median time to a certified plan and
        median time per iteration, worst time of infeasible answers, largest overrun;
        agreement with the reference). With ``reference_app`` also ``reference_app``
        (:meth:`~needlekit.benchmarks.reference_comparison.ReferenceComparison.record`);
        with ``sample_targets`` the rows also carry ``sample`` and ``target_mm``, and
        ``reference_app`` also holds ``samples`` (per patient, what
        :func:`~needlekit.benchmarks.target_screening.sample_targets` drew) and
        ``screening`` (:func:`~needlekit.benchmarks.target_screening.screening_summary`).
    """
    from needlekit.io.medrad import load_medrad
    from needlekit.planning.steerable.solve import solve

    def run(problem, planner, budget_s=time_limit_s):
        return solve(problem, planner, time_limit_s=budget_s, seed=0)

    _check_sampling(sample_targets, reference_app)
    with ExitStack() as stack:
        reference = None
        if reference_app is not None:  # checked before any work
            reference = _reference(reference_app, reference_work, planners, time_limit_s, stack)
        rows, fields, samples = [], [], {}
        for patient in patients:
            t0 = time.perf_counter()
            case = load_medrad("lung", patient, medrad_dir)
            fields.append(
                {"patient": patient, **case.timings_s, "total_s": time.perf_counter() - t0}
            )
            drawn = None
            if sample_targets:
                t0 = time.perf_counter()
                drawn = draw_targets(
                    case, sample_targets, target_seed,
                    needle_diameter_mm=BENCH_NEEDLE["needle_diameter_mm"],
                )  # fmt: skip
                samples[str(patient)] = {"sample_s": time.perf_counter() - t0, "targets": drawn}
            if reference is not None:
                extra = None if drawn is None else [d["target_mm"] for d in drawn]
                reference.add_patient(patient, case, extra)
            rows += _patient_rows(case, radii_mm, planners, run, reference, progress, drawn)
            del case
        comparison = None if reference is None else reference.record()
        if comparison is not None and sample_targets:
            comparison["samples"] = samples
            comparison["screening"] = screening_summary(comparison["rows"])
    for path in scenarios:
        _, problem = load_problem(path)
        for planner in planners:
            res = run(problem, planner)
            rows.append(
                _row(res, scenario=str(path))
                | {"collision_model": problem.collision_model}
                | {"reference_cost_mm": "n/a"}
            )
            if progress is not None:
                progress(f"{path} {planner}: {res.status.value}")
    return {
        "benchmark": "steerable",
        "machine": machine_info(),
        "inputs": {
            "patients": list(patients),
            "radii_mm": list(radii_mm),
            "planners": list(planners),
            "scenarios": [str(p) for p in scenarios],
            "time_limit_s": time_limit_s,
            **BENCH_NEEDLE,
            "sample_targets": int(sample_targets),
            "target_seed": int(target_seed) if sample_targets else None,
            "sample_distance_mm": list(SAMPLE_DISTANCE_MM) if sample_targets else None,
            "sample_cone_deg": SAMPLE_CONE_DEG if sample_targets else None,
            "medrad_collision_model": "voxel_centres: exact distance to obstacle voxel "
            "centres (radius + half voxel diagonal); scenario cases use their own",
        },
        "fields": fields,
        "results": rows,
        "summary": _summary(rows),
    } | ({} if comparison is None else {"reference_app": comparison})


def _check_sampling(sample_targets, reference_app) -> None:
    """``--sample-targets``: a whole number >= 0, and only beside the reference app."""
    if (
        not isinstance(sample_targets, (int, np.integer))
        or isinstance(sample_targets, bool)
        or sample_targets < 0
    ):
        raise InvalidInputError(
            "--sample-targets", f"expected a whole number >= 0, got {sample_targets!r}"
        )
    if sample_targets and reference_app is None:
        raise InvalidInputError(
            "--sample-targets",
            "screens sampled targets beside the reference app: give --reference-app too",
        )


def _reference(app, work, planners, time_limit_s, stack: ExitStack):
    """The app comparison, its settings checked (before any work)."""
    check_reference_app(app)
    if "rcs_star" not in planners:
        raise InvalidInputError(
            "--reference-app",
            "compares needlekit's rcs_star with the app: add rcs_star to --planners",
        )
    if work is None:
        work = stack.enter_context(tempfile.TemporaryDirectory(prefix="needlekit-refapp-"))
    return ReferenceComparison(app, work, BENCH_NEEDLE, time_limit_s)


def _cases(case, drawn) -> list[tuple[str, int, np.ndarray, int | None]]:
    """(start name, start number, target, sample) of a patient's cases: every start against
    its own target, or the sampled targets each with its start."""
    if drawn is not None:
        return [(d["start_name"], d["start"], np.asarray(d["target_mm"], float), d["sample"])
                for d in drawn]  # fmt: skip
    target = np.asarray(case.targets_mm["target"], dtype=float)
    return [(s.name, int(s.name.removeprefix("start")), target, None) for s in case.starts]


def _patient_rows(case, radii_mm, planners, run, reference, progress, drawn=None) -> list[dict]:
    """One patient's rows: every case x r_min x planner (``rcs_star`` beside the app when
    ``reference`` is given); the cases are the starts against the patient's target, or
    the ``drawn`` targets (:func:`~needlekit.benchmarks.target_screening.sample_targets`)."""
    rows = []
    for name, start, target, sample in _cases(case, drawn):
        pose = case.start(name).world_T_tip
        for r in radii_mm:
            problem = medrad_lung_problem(case, name, r, target)
            for planner in planners:
                if reference is not None and planner == "rcs_star":
                    res = reference.compare(
                        case.patient, start, pose, target, r,
                        lambda budget, p=problem: run(p, "rcs_star", budget), sample,
                    )  # fmt: skip
                else:
                    res = run(problem, planner)
                ref = (
                    REFERENCE_LUNG1.get((start, int(r)))
                    if case.patient == 1 and planner == "rcs_star" and sample is None
                    else "n/a"
                )
                extra = {} if sample is None else {"sample": sample, "target_mm": target.tolist()}
                rows.append(
                    _row(res, patient=case.patient, start=start, r_min_mm=float(r), **extra)
                    | {"collision_model": problem.collision_model}
                    | {"reference_cost_mm": ref}
                )
                if progress is not None:
                    tag = "" if sample is None else f" target {sample}"
                    progress(
                        f"lung {case.patient} start {start}{tag} r {r:g} {planner}: "
                        f"{res.status.value}"
                    )
    return rows


def _summary(rows: list[dict]) -> dict:
    out: dict[str, Any] = {}
    for planner in sorted({r["planner"] for r in rows}):
        mine = [r for r in rows if r["planner"] == planner]
        certified = [r["time_s"] for r in mine if r["certified"]]
        infeasible = [r["time_s"] for r in mine if r["status"] == PlanStatus.INFEASIBLE.value]
        overruns = [r["overrun_s"] for r in mine if r.get("overrun_s") is not None]
        per_it = [r["us_per_iteration"] for r in mine if r["us_per_iteration"] is not None]
        out[planner] = {
            "cases": len(mine),
            "max_overrun_s": max(overruns) if overruns else None,
            "solved": sum(r["status"] == "solved" for r in mine),
            "certified": len(certified),
            "median_time_to_certified_s": float(np.median(certified)) if certified else None,
            "median_us_per_iteration": float(np.median(per_it)) if per_it else None,
            "max_time_infeasible_s": max(infeasible) if infeasible else None,
        }
    ref_rows = [r for r in rows if r["reference_cost_mm"] != "n/a"]
    agree = 0
    for r in ref_rows:
        ref = r["reference_cost_mm"]
        if ref is None:
            agree += r["status"] == PlanStatus.INFEASIBLE.value
        elif ref == "no plan":
            agree += r["status"] != PlanStatus.SOLVED.value  # no plan reaching the goal
        else:
            agree += r["status"] == PlanStatus.SOLVED.value and r["cost_mm"] <= ref + 0.5
    out["lung1_reference_agreement"] = f"{agree}/{len(ref_rows)}"
    return out
