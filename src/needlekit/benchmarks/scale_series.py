"""The series of ``needlekit bench scale`` (:mod:`needlekit.benchmarks.scale`): one
lung's preparation, planning against path length and obstacle density, sweeps against
directions and workers, the control study against trials.

Each returns plain data (rows, points, fits) with the load average at its start and end;
:func:`~needlekit.benchmarks.scale.run_scale_benchmark` puts them in one record.
"""

from __future__ import annotations

import contextvars
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from needlekit.batch import executor_workers, open_executor
from needlekit.benchmarks.prepare import prepare_in_subprocess
from needlekit.benchmarks.scale_math import (
    CAPSULE_RADIUS_MM,
    capsule_obstacle_fraction,
    linear_fit,
    loglog_fit,
)
from needlekit.studies.puncture_study import run_puncture_study

__all__ = [
    "MAX_ITERATIONS",
    "STUDY_TARGET_TRIALS",
    "TIME_LIMIT_S",
    "executor_label",
    "planning_series",
    "preparation_point",
    "study_series",
    "sweep_series",
]

#: Iteration budget per planner run: every executor does the same searches, and RCS*
#: stops earlier when it certifies.
MAX_ITERATIONS: int = 1000
#: Time cap per planner run (s): it stops a run only on a loaded machine.
TIME_LIMIT_S: float = 30.0
#: The study's size the fitted line is read at (Tang et al. run 100 trials).
STUDY_TARGET_TRIALS: int = 100
#: The sweep's planner (the part of Feng's protocol whose time is bounded).
SWEEP_PLANNER: str = "rcs_star"

Progress = Callable[[str], None] | None


def _load() -> list[float]:
    return [round(v, 2) for v in os.getloadavg()]


def _say(progress: Progress, msg: str) -> None:
    if progress is not None:
        progress(msg)


# ---------------------------------------------------------------------------------------
# preparation and planning


def preparation_point(patient: int, medrad_dir=None) -> dict:
    """One lung made ready for a first plan in a fresh process, cold then warm (a temporary
    cache), Python's imports counted apart (as ``bench fields``).

    Parameters
    ----------
    patient : int
        Med-RAD lung.
    medrad_dir : path-like, optional

    Returns
    -------
    dict
        ``patient``, ``cold_s`` and ``warm_s`` (imports left out), ``import_s``,
        ``cold_process_s``, ``warm_process_s``, ``peak_rss_mb`` and ``load_average`` (at the
        start and the end).
    """
    load = {"start": _load()}
    with tempfile.TemporaryDirectory(prefix="needlekit-bench-scale-") as cache:
        cold = prepare_in_subprocess(medrad_dir, patient, cache)
        warm = prepare_in_subprocess(medrad_dir, patient, cache)
    load["end"] = _load()
    return {
        "patient": patient,
        "cold_s": cold["ready_s"] - cold["stages"]["import"]["s"],
        "warm_s": warm["ready_s"] - warm["stages"]["import"]["s"],
        "import_s": cold["stages"]["import"]["s"],
        "cold_process_s": cold["process_wall_s"],
        "warm_process_s": warm["process_wall_s"],
        "peak_rss_mb": max(cold["peak_rss_mb"] or 0.0, warm["peak_rss_mb"] or 0.0),
        "load_average": load,
    }


def planning_series(
    patients: Sequence[int],
    planners: Sequence[str] = ("rcs_star",),
    *,
    max_iterations: int = MAX_ITERATIONS,
    time_limit_s: float = TIME_LIMIT_S,
    seed: int = 0,
    r_min_mm: float = 50.0,
    medrad_dir=None,
    progress: Progress = None,
) -> dict:
    """Planning time against path length and obstacle density on Med-RAD lungs.

    Parameters
    ----------
    patients : sequence of int
        Lungs; every start of each, to its target.
    planners : sequence of str
    max_iterations : int
        Iteration budget per run.
    time_limit_s : float
        Time cap per run (s).
    seed : int
    r_min_mm : float
    medrad_dir : path-like, optional
    progress : callable, optional
        Called with a line per case.

    Returns
    -------
    dict
        ``rows`` (per case and planner: ``patient``, ``start``, ``planner``, ``status``,
        ``certified``, ``straight_distance_mm``, ``path_length_mm`` (when solved),
        ``planner_wall_s``, ``time_s``, ``setup_s``, ``iterations``,
        ``obstacle_density``, ``capsule_voxels``), ``load_s`` (per lung, from the cache),
        ``fits`` (per planner: ``time_vs_distance``, ``time_vs_density``,
        ``time_vs_path_length`` (solved cases), log-log) and ``load_average``.
    """
    from needlekit.benchmarks.steerable import medrad_lung_problem
    from needlekit.io.medrad import load_medrad
    from needlekit.planning.steerable.solve import solve

    load, rows, loads = {"start": _load()}, [], {}
    for patient in patients:
        t0 = time.perf_counter()
        case = load_medrad("lung", patient, medrad_dir)
        loads[str(patient)] = time.perf_counter() - t0
        occ = case.occupancy if case.occupancy is not None else ~case.free_space.data
        for s in case.starts:
            problem = medrad_lung_problem(case, s.name, r_min_mm)
            a, b = problem.start_point_mm, problem.goal_mm
            dens = capsule_obstacle_fraction(occ, case.free_space.affine, a, b)
            for planner in planners:
                res = solve(problem, planner, time_limit_s=time_limit_s,
                            max_iterations=max_iterations, seed=seed)  # fmt: skip
                st, solved = res.stats, res.status.value == "solved"
                rows.append({
                    "patient": patient, "start": s.name, "planner": planner,
                    "status": res.status.value, "certified": bool(st.get("certified", False)),
                    "straight_distance_mm": float(np.linalg.norm(b - a)),
                    "path_length_mm": float(res.cost_mm) if solved else None,
                    "planner_wall_s": float(st.get("planner_wall_s", res.time_s)),
                    "time_s": float(res.time_s), "setup_s": st.get("setup_s"),
                    "iterations": st.get("iterations"),
                    "obstacle_density": dens["fraction"], "capsule_voxels": dens["voxels"],
                })  # fmt: skip
                _say(progress, f"planning: lung {patient} {s.name} {planner}: {res.status.value}")
        del case, occ
    fits = {}
    for planner in planners:
        mine = [r for r in rows if r["planner"] == planner]
        t = [r["planner_wall_s"] for r in mine]
        solved = [r for r in mine if r["path_length_mm"] is not None]
        fits[planner] = {
            "time_vs_distance": loglog_fit([r["straight_distance_mm"] for r in mine], t),
            "time_vs_density": loglog_fit([r["obstacle_density"] or np.nan for r in mine], t),
            "time_vs_path_length": loglog_fit(
                [r["path_length_mm"] for r in solved], [r["planner_wall_s"] for r in solved]
            ),
        }
    load["end"] = _load()
    return {
        "rows": rows,
        "load_s": loads,
        "fits": fits,
        "capsule_radius_mm": CAPSULE_RADIUS_MM,
        "r_min_mm": r_min_mm,
        "load_average": load,
    }


# ---------------------------------------------------------------------------------------
# sweep


def _signature(result) -> tuple | None:
    """What must agree between executors: status, cost (to 1e-9 mm), iterations."""
    if result is None:
        return None
    cost = round(float(result.cost_mm), 9) if np.isfinite(result.cost_mm) else None
    return (result.status.value, cost, result.stats.get("iterations"))


def _executors(workers: Sequence[int], dask_workers: Sequence[int]) -> list[tuple[str, int]]:
    out = [("serial", 1)] if 1 in workers else []
    out += [("process", w) for w in workers if w > 1]
    return out + [("dask", w) for w in dask_workers]


def sweep_series(
    source,
    directions: Sequence[int],
    *,
    workers: Sequence[int] = (1, 2),
    dask_workers: Sequence[int] = (4,),
    planner: str = SWEEP_PLANNER,
    max_iterations: int = MAX_ITERATIONS,
    time_limit_s: float = TIME_LIMIT_S,
    seed: int = 0,
    progress: Progress = None,
) -> dict:
    """Sweep time against the number of directions and workers.

    Parameters
    ----------
    source : needlekit.scenario.problems.ScenarioSource
        The case; this process builds it once (for the serial runs), each worker of every
        executor once.
    directions : sequence of int
        Candidate directions (Fibonacci sphere) per point.
    workers : sequence of int
        1: this process; more: a process pool of that size.
    dask_workers : sequence of int
        Local Dask clusters of that many single-threaded workers.
    planner : str
    max_iterations : int
        Iteration budget per direction: every executor does the same searches.
    time_limit_s : float
        Time cap per direction (s).
    seed : int
    progress : callable, optional

    Returns
    -------
    dict
        ``points`` (per executor and size: ``executor``, ``workers``, ``oversubscribed``
        (more workers than CPUs), ``directions``, ``effective``, ``searched``, ``solved``,
        ``wall_s`` (the batch, first task to last result), ``start_s`` (opening the
        executor), ``planner_s_sum``, ``setup_s_sum``, ``prep_s_by_worker``, ``prep_s``
        (the largest), ``efficiency``, ``equal_to_serial`` (None without a serial run)
        and ``load_average``), ``fits`` (per executor: a line and a power law of the wall
        time against directions), ``main_prep_s`` and ``cpu_count``.
    """
    from needlekit.planning.steerable.sweep import sphere_directions
    from needlekit.planning.steerable.sweep_batch import SweepJob, sweep_many

    t0 = time.perf_counter()
    _, problem = source.cached()
    main_prep_s = time.perf_counter() - t0
    job = SweepJob(problem, planner, source)
    cpus = os.cpu_count() or 1
    serial: dict[int, list] = {}
    points = []
    for kind, n_workers in _executors(workers, dask_workers):
        for n in directions:
            load = {"start": _load()}
            t_open = time.perf_counter()
            with open_executor(kind, workers=n_workers) as ex:
                start_s = time.perf_counter() - t_open
                executor = None if kind == "serial" else ex
                batch = sweep_many([job], directions=sphere_directions(n), executor=executor,
                                   time_limit_s=time_limit_s, seed=seed,
                                   max_iterations=max_iterations)  # fmt: skip
                measured = executor_workers(executor)
            load["end"] = _load()
            sw = batch.sweeps[0]
            runs = [r for r in sw.results if r is not None]
            signature = [_signature(r) for r in sw.results]
            if kind == "serial":
                serial[n] = signature
            prep = {k: float(w["prep_s"]) for k, w in batch.workers.items()}
            prep_s = max(prep.values(), default=0.0)
            planner_s = float(sum(r.time_s for r in runs))
            busy = measured * (batch.wall_s - prep_s)
            points.append({
                "executor": kind, "workers": measured, "oversubscribed": measured > cpus,
                "directions": n, "effective": int(sw.stats["n_effective"]),
                "searched": sum(bool(r.stats.get("iterations")) for r in runs),
                "solved": int(sw.stats["n_solved"]),
                "wall_s": float(batch.wall_s), "start_s": start_s,
                "planner_s_sum": planner_s,
                "setup_s_sum": float(sum(r.stats.get("setup_s", 0.0) for r in runs)),
                "prep_s_by_worker": prep, "prep_s": prep_s,
                "tasks_by_worker": {k: int(w["tasks"]) for k, w in batch.workers.items()},
                "efficiency": planner_s / busy if busy > 0 else None,
                "equal_to_serial": None if n not in serial else signature == serial[n],
                "load_average": load,
            })  # fmt: skip
            _say(progress, f"sweep: {n} directions, {kind} x {measured}: {batch.wall_s:.1f} s")
    fits = {}
    for label in dict.fromkeys(executor_label(p) for p in points):
        mine = [p for p in points if executor_label(p) == label]
        x, y = [p["directions"] for p in mine], [p["wall_s"] for p in mine]
        fits[label] = {"wall_vs_directions": linear_fit(x, y), "power_law": loglog_fit(x, y)}
    return {
        "points": points,
        "fits": fits,
        "planner": planner,
        "max_iterations": max_iterations,
        "time_limit_s": time_limit_s,
        "main_prep_s": main_prep_s,
        "cpu_count": cpus,
    }


def executor_label(point: dict) -> str:
    """An executor in words: ``serial``, ``process x2``, ``dask x4``.

    Parameters
    ----------
    point : dict
        A series point with ``executor`` and ``workers``.

    Returns
    -------
    str
    """
    return "serial" if point["executor"] == "serial" else f"{point['executor']} x{point['workers']}"


# ---------------------------------------------------------------------------------------
# the control study


def study_series(
    trials: Sequence[int],
    *,
    workers: Sequence[int] = (1, 2),
    seed: int = 0,
    target_trials: int = STUDY_TARGET_TRIALS,
    progress: Progress = None,
) -> dict:
    """Control-study time against trials (:func:`run_puncture_study`, no report page).

    Parameters
    ----------
    trials : sequence of int
    workers : sequence of int
        1: this process; more: a process pool of that size (a fresh one per point).
    seed : int
    target_trials : int
        Where the fitted line is read (an extrapolation beyond the largest size run).
    progress : callable, optional

    Returns
    -------
    dict
        ``points`` (per worker count and size: ``workers``, ``trials``, ``completed``,
        ``wall_s`` (the trials, first submitted to last done), ``total_s`` (with the
        guide-line filter and the file), ``equal_to_serial`` (every trial's outcome as in
        this process) and ``load_average``), ``fits`` (per worker count: the line of
        ``wall_s`` against trials, read at ``target_trials``).
    """
    points, serial = [], {}
    for w in workers:
        for n in trials:
            load = {"start": _load()}
            with (
                tempfile.TemporaryDirectory(prefix="needlekit-bench-scale-") as tmp,
                open_executor("serial" if w == 1 else "process", workers=w) as ex,
            ):
                t0 = time.perf_counter()
                # in a fresh context: the study's scratch file is written at once, not
                # staged with the command's own outputs (it is gone by then)
                study = contextvars.Context().run(
                    run_puncture_study, Path(tmp), trials=n, seed=seed, executor=ex, report=False
                )
                total_s = time.perf_counter() - t0
            load["end"] = _load()
            outcome = [(t["trial"], t["status"], t.get("position_error_mm")) for t in study.trials]
            if w == 1:
                serial[n] = outcome
            points.append({
                "workers": w, "trials": n, "completed": int(study.summary["completed"]),
                "wall_s": float(study.summary["wall_s"]), "total_s": total_s,
                "equal_to_serial": None if n not in serial else outcome == serial[n],
                "load_average": load,
            })  # fmt: skip
            _say(progress, f"study: {n} trials on {w} worker(s): {total_s:.1f} s")
    fits = {}
    for w in workers:
        mine = [p for p in points if p["workers"] == w]
        fits[str(w)] = linear_fit([p["trials"] for p in mine], [p["wall_s"] for p in mine],
                                  at=target_trials)  # fmt: skip
    return {"points": points, "fits": fits, "target_trials": target_trials, "seed": seed}


# ---------------------------------------------------------------------------------------
# the whole run
