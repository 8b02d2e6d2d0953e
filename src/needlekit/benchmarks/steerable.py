"""``needlekit bench steerable``: curved-needle planners on the Med-RAD lungs.

Cases: lungs x starts x r_min (needle 1 mm, tau 1 mm, l_max 150 mm, heading change at most
90 degrees, path-length cost, obstacles within 3 mm of the start ignored), each planner
with a time budget. Field building is timed separately from planning. Patient 1's
reference figures (the reference planner by the authors of RCS*, as given in the issue)
are recorded beside ours.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from needlekit.benchmarks.record import machine_info
from needlekit.planning.result import PlanStatus

__all__ = ["REFERENCE_LUNG1", "run_steerable_benchmark"]

#: Issue 4's reference for Med-RAD lung 1, RCS*: (start, r_min) -> certified cost (mm),
#: None where the goal is unreachable, "no plan" where nothing is found within 1 s.
REFERENCE_LUNG1: dict[tuple[int, int], float | str | None] = {
    (1, 50): 58.26, (2, 50): "no plan", (3, 50): 53.24, (4, 50): 58.12, (5, 50): 58.09,
    (1, 100): None, (2, 100): "no plan", (3, 100): 54.83, (4, 100): None, (5, 100): 58.41,
}  # fmt: skip


def _solve(planner: str, problem, obstacles, time_limit_s: float):
    from needlekit.planning.steerable.solve import solve

    return solve(problem, planner, time_limit_s=time_limit_s, obstacles=obstacles, seed=0)


def run_steerable_benchmark(
    patients: Sequence[int] = (1, 2, 3, 4, 5),
    radii_mm: Sequence[float] = (50.0, 100.0),
    planners: Sequence[str] = ("rcs_star", "rcs", "rrt"),
    time_limit_s: float = 1.0,
    medrad_dir=None,
    progress=None,
) -> dict[str, Any]:
    """Run the planners on every case and record status, cost and time.

    Parameters
    ----------
    patients : sequence of int
        Med-RAD lung patients.
    radii_mm : sequence of float
        Minimum radii of curvature.
    planners : sequence of str
        ``"rcs_star"``, ``"rcs"``, ``"rrt"`` (seed 0).
    time_limit_s : float
        Budget per case and planner.
    medrad_dir : path-like, optional
    progress : callable, optional
        Called with a short string after each case (e.g. to advance a progress bar).

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs``, ``fields`` (per patient: load and
        field-building seconds), ``results`` (one row per case and planner: ``patient``,
        ``start``, ``r_min_mm``, ``planner``, ``status``, ``cost_mm``, ``time_s``,
        ``certified``, ``iterations``, ``reference_cost_mm``) and ``summary`` (median time
        to a certified plan, worst time of infeasible answers, agreement with the
        reference).
    """
    from needlekit.io.medrad import load_medrad
    from needlekit.planning.steerable.problem import SteerableProblem

    rows, fields = [], []
    for patient in patients:
        t0 = time.perf_counter()
        case = load_medrad("lung", patient, medrad_dir)
        obstacles = case.voxel_obstacles(needle_diameter_mm=1.0)
        fields.append({"patient": patient, **case.timings_s, "total_s": time.perf_counter() - t0})
        target = case.targets_mm["target"]
        for s in case.starts:
            start = int(s.name.removeprefix("start"))
            for r in radii_mm:
                problem = SteerableProblem(
                    case.scene,
                    goal_mm=target,
                    start_pose=s.world_T_tip,
                    r_min_mm=r,
                    needle_diameter_mm=1.0,
                    goal_tolerance_mm=1.0,
                    max_length_mm=150.0,
                    max_heading_change_deg=90.0,
                    start_exclusion_mm=3.0,
                )
                for planner in planners:
                    res = _solve(planner, problem, obstacles, time_limit_s)
                    ref = (
                        REFERENCE_LUNG1.get((start, int(r)))
                        if patient == 1 and planner == "rcs_star"
                        else "n/a"
                    )
                    rows.append(
                        {
                            "patient": patient,
                            "start": start,
                            "r_min_mm": float(r),
                            "planner": planner,
                            "status": res.status.value,
                            "cost_mm": None if not math.isfinite(res.cost_mm) else res.cost_mm,
                            "time_s": res.time_s,
                            "certified": bool(res.stats.get("certified", False)),
                            "iterations": res.stats.get("iterations"),
                            "reason": res.stats.get("reason"),
                            "goal_distance_mm": res.stats.get("goal_distance_mm"),
                            "reference_cost_mm": ref,
                        }
                    )
                    if progress is not None:
                        progress(
                            f"lung {patient} start {start} r {r:g} {planner}: {res.status.value}"
                        )
        del case, obstacles
    return {
        "benchmark": "steerable",
        "machine": machine_info(),
        "inputs": {
            "patients": list(patients),
            "radii_mm": list(radii_mm),
            "planners": list(planners),
            "time_limit_s": time_limit_s,
            "needle_diameter_mm": 1.0,
            "goal_tolerance_mm": 1.0,
            "max_length_mm": 150.0,
            "max_heading_change_deg": 90.0,
            "start_exclusion_mm": 3.0,
            "collision_model": "exact distance to obstacle voxel centres (radius + half voxel diagonal)",
        },
        "fields": fields,
        "results": rows,
        "summary": _summary(rows),
    }


def _summary(rows: list[dict]) -> dict:
    out: dict[str, Any] = {}
    for planner in sorted({r["planner"] for r in rows}):
        mine = [r for r in rows if r["planner"] == planner]
        certified = [r["time_s"] for r in mine if r["certified"]]
        infeasible = [r["time_s"] for r in mine if r["status"] == PlanStatus.INFEASIBLE.value]
        out[planner] = {
            "cases": len(mine),
            "solved": sum(r["status"] == "solved" for r in mine),
            "certified": len(certified),
            "median_time_to_certified_s": float(np.median(certified)) if certified else None,
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
