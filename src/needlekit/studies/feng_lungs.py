"""Feng et al.'s effective-puncture-region protocol on real anatomy: a Med-RAD lung.

Feng et al. (2023) sweep 544 start directions at one start point, keep
those at least alpha = 20 deg off the punctured surface, and run RRT, RCS and RCS* for 1 s
from each, to two targets (their Tables 2-4, Figs. 7-9). They print their start and goals
but not their lung obstacles, so the protocol cannot be rerun on their case. Here it runs
on a public one:

- the case: Med-RAD lung patient 5 (LIDC525), start pose 1 (its point only: the
  direction is swept), a transbronchial start on the airway wall. Its given target is
  48.9 mm away in a straight line, and the bronchial tree, vessels and fissures
  (:mod:`needlekit.io.medrad`) block the direct turn-then-straight connection from almost
  every effective direction that can reach the target at all, so the paths bend around
  them;
- the targets: goal 1 is Med-RAD's target (in the nodule); goal 2 is goal 1 moved by
  Feng's own offset between their two goals, (-10, -10, +10) mm, taken in RAS here (their
  frame is not stated). It lies in free lung tissue, 55.0 mm from the start (deeper than
  goal 1, as Feng's goal 2 lies deeper than their goal 1). The nodule is too small
  (5.7 mm across) to give a second target at another depth;
- Feng's needle: diameter 2 mm, r_min 50 mm, l_max 100 mm, alpha 20 deg, tau 1 mm,
  heading change at most 90 deg, 1 s per direction per planner, 544 directions;
- the certified collision model (``field``): the obstacle field grown by the needle radius,
  less its error bound, so that every reported path is clear of the anatomy. The
  ``voxel_centres`` model reproduces the reference C++ planner's sampled test against
  voxel centres, for matching that planner's verdicts; there are no such verdicts to
  match here.

:func:`run_feng_lungs` sweeps both targets with the three planners, re-checks every solved
plan independently, asks of every effective direction whether the direct connection
would have done, and writes (:data:`FENG_LUNGS_FILES`) one folder per target (the
scenario, ``sweep.json`` with Tables 2-4 and ``plan.json`` with the best RCS* plan), a
summary ``feng_lungs.json`` beside Feng's Table 4 with the run's ``timing``, and one HTML
page. The six sweeps run as one batch of tasks on any executor (a process pool, a Dask
cluster): the scenarios travel with the tasks, and each worker prepares the patient once.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from needlekit.batch import executor_workers
from needlekit.errors import Interrupted, InvalidInputError
from needlekit.io.files import staged_outputs, write_json
from needlekit.io.plans import write_plan_json
from needlekit.planning.result import PlanStatus
from needlekit.provenance import machine_info
from needlekit.scenario.problems import ScenarioSource
from needlekit.studies.feng_case import (
    FENG_GOAL2_OFFSET_MM,
    FENG_SCENARIO,
    _case_record,
    _check_goal,
    _write_scenario,
    feng_lung_scenario,
    feng_patient_folder,
)
from needlekit.studies.feng_timing import timing_record
from needlekit.studies.sweep_study import read_partial_sweep, write_partial_sweep

__all__ = [
    "FENG_GOAL2_OFFSET_MM",
    "FENG_LUNGS_FILES",
    "FENG_PLANNERS",
    "FENG_SCENARIO",
    "FENG_TABLE4",
    "QUICK",
    "FengLungsStudy",
    "direct_connection_fates",
    "feng_lung_scenario",
    "feng_patient_folder",
    "run_feng_lungs",
]


#: The planners, RCS* first (it gives Fig. 7 and plan.json, as in Feng's Fig. 7).
FENG_PLANNERS: tuple[str, ...] = ("rcs_star", "rcs", "rrt")

#: RRT joins the goal by one arc, the reference implementation's rule behind Feng's tables.
FENG_RRT_CONNECTION: str = "arc"

#: Feng's protocol: candidate directions and budget per direction and planner (s).
FENG_DIRECTIONS: int = 544

FENG_TIME_LIMIT_S: float = 1.0

#: ``--quick``: a quarter of the directions and an iteration budget (the same figures on
#: every machine); the time limit only caps a loaded machine.
QUICK: dict = {"directions": 136, "time_limit_s": 5.0, "max_iterations": 300}

#: Feng's Table 4 as printed, with the solved count and best cost of Tables 2-3. Table 2's
#: RCS mean is printed 62.7956 mm; its 11 rows average 62.6647 mm (below RRT's 62.6661).
FENG_TABLE4: dict = {
    "goal1": {
        "rcs": {"n_solved": 11, "best_cost_mm": 61.0548, "mean_cost_mm": 62.79560,
                "cost_before_lowest_mm": 438.4809},
        "rcs_star": {"n_solved": 10, "best_cost_mm": 59.8760, "mean_cost_mm": 61.14570,
                     "cost_before_lowest_mm": 365.1960},
        "rrt": {"n_solved": 9, "best_cost_mm": 61.0429, "mean_cost_mm": 62.66610,
                "cost_before_lowest_mm": 373.8506},
    },
    "goal2": {
        "rcs": {"n_solved": 17, "best_cost_mm": 72.7510, "mean_cost_mm": 76.10370,
                "cost_before_lowest_mm": 692.2541},
        "rcs_star": {"n_solved": 12, "best_cost_mm": 71.5848, "mean_cost_mm": 74.07100,
                     "cost_before_lowest_mm": 524.8486},
        "rrt": {"n_solved": 16, "best_cost_mm": 72.7260, "mean_cost_mm": 75.52310,
                "cost_before_lowest_mm": 607.8828},
    },
}  # fmt: skip

#: Feng's start and goals (their Section 5, mm, their CT frame). The start's x is printed
#: 64.8324 there and -64.8324 in their worked example of Fig. 8b; only the latter puts the
#: goals 60.8 and 72.6 mm away, as their costs (59.9-65.0 and 71.6-81.9 mm) need.
FENG_POINTS_MM: dict = {
    "start": (-64.8324, 139.4900, -654.0964),
    "goal1": (-105.8713, 158.2018, -613.2506),
    "goal2": (-115.8713, 148.2018, -603.2506),
}

#: What :func:`run_feng_lungs` writes in its folder.
FENG_LUNGS_FILES: tuple[str, ...] = (
    "goal1/scenario.yaml",
    "goal1/sweep.json",
    "goal1/plan.json",
    "goal2/scenario.yaml",
    "goal2/sweep.json",
    "goal2/plan.json",
    "feng_lungs.json",
    "report.html",
)

_GOALS = ("goal1", "goal2")

_LABELS = {"rcs": "RCS", "rcs_star": "RCS*", "rrt": "RRT"}

#: Feng's order of the mean costs, cheapest first (their Table 4 and text).
FENG_ORDER: tuple[str, ...] = ("rcs_star", "rrt", "rcs")


def _direct_fate(problem, direction) -> str:
    """What becomes of the direct turn-then-straight connection from one start direction."""
    from needlekit.planning.steerable.goal import goal_connection
    from needlekit.planning.steerable.plan import SteerablePlan
    from needlekit.planning.steerable.sweep import pose_from_direction
    from needlekit.planning.steerable.verify import verify_plan

    pose = pose_from_direction(problem.start_point_mm, direction)
    c = goal_connection(pose, problem.goal_mm, problem.r_min_mm, problem.goal_tolerance_mm)
    if c is None:
        return "unreachable"
    if c.length_mm > problem.max_length_mm:
        return "too long"
    check = verify_plan(problem.with_start_pose(pose), SteerablePlan(pose, c.primitives))
    if check.ok:
        return "valid"
    return ", ".join(dict.fromkeys(v.split(":")[0] for v in check.violations))


def direct_connection_fates(problem, directions, effective) -> list[str | None]:
    """Per start direction, whether the direct connection (turn at r_min, then straight,
    ending tau short: the shortest path to the goal) passes the independent check.

    Where it does, it is the best path from that direction; where it does not, a plan from
    that direction has to bend around what blocks it.

    Parameters
    ----------
    problem : SteerableProblem
        Start point, goal and limits.
    directions : array_like, shape (n, 3)
    effective : array_like of bool, shape (n,)

    Returns
    -------
    list of str or None
        None outside the effective region; else ``"valid"``, ``"unreachable"`` (goal behind
        the tip or inside the r_min torus), ``"too long"`` (over l_max), or the kinds of
        violation the check reports (``"collision"``, ``"heading"``, ...).
    """
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    eff = np.asarray(effective, dtype=bool)
    return [_direct_fate(problem, d[i]) if eff[i] else None for i in range(len(d))]


@dataclass(frozen=True)
class FengLungsStudy:
    """What :func:`run_feng_lungs` did.

    Attributes
    ----------
    record : dict
        The summary written as ``feng_lungs.json``.
    sweeps : dict
        Per goal (``goal1``, ``goal2``), per planner, its SweepResult.
    files : dict of str to Path
    problems : dict
        Per goal, its SteerableProblem.
    options : dict
        Per planner, its options.
    """

    record: dict
    sweeps: dict
    files: dict = field(default_factory=dict)
    problems: dict = field(default_factory=dict, repr=False)
    options: dict = field(default_factory=dict)


def _settings(time_limit_s, directions, max_iterations, quick: bool) -> dict:
    """Feng's protocol, or :data:`QUICK`, under the values given."""
    base = {"directions": FENG_DIRECTIONS, "time_limit_s": FENG_TIME_LIMIT_S}
    base |= QUICK if quick else {"max_iterations": None}
    given = {"directions": directions, "time_limit_s": time_limit_s}
    base |= {k: v for k, v in (given | {"max_iterations": max_iterations}).items() if v is not None}
    if isinstance(base["directions"], bool) or int(base["directions"]) < 1:
        raise InvalidInputError("--directions", f"expected a whole number >= 1, got {directions}")
    if not float(base["time_limit_s"]) > 0:
        raise InvalidInputError("--time-limit-s", f"expected a positive time, got {time_limit_s}")
    return base


def _checks(problem, sw) -> dict:
    """Every solved plan of a sweep through the independent check (0.25 mm samples)."""
    from needlekit.planning.steerable.verify import verify_plan

    passed, failures, best = 0, [], None
    for i, r in enumerate(sw.results):
        if r is None or r.status is not PlanStatus.SOLVED:
            continue
        c = verify_plan(problem.with_start_pose(r.start_pose), r.plan, expected_cost_mm=r.cost_mm)
        passed += c.ok
        if not c.ok:
            failures.append({"index": i, "violations": list(c.violations)})
        if i == sw.stats["best_index"]:
            best = {"ok": c.ok, "violations": list(c.violations), **c.metrics}
    return {
        "solved": int(sw.stats["n_solved"]),
        "passed": passed,
        "failures": failures,
        "best": best,
    }


def _statuses(sw) -> dict:
    """How many effective directions ended in each status (solved, approximate, ...)."""
    found = [r.status.value for r in sw.results if r is not None]
    return {k: found.count(k) for k in sorted(set(found))}


def _mean_over(sweeps: dict, mask: np.ndarray) -> dict:
    return {k: float(sw.costs_mm[mask].mean()) if mask.any() else None for k, sw in sweeps.items()}


def _order(means: dict) -> list[str] | None:
    if any(v is None for v in means.values()):
        return None
    return sorted(means, key=lambda k: means[k])


def _goal_record(problem, sweeps: dict, fates: list, checks: dict) -> dict:
    """Table 4 beside Feng's, the direct-connection counts and the checks of one goal."""
    solved = {k: np.isfinite(sw.costs_mm) for k, sw in sweeps.items()}
    common = np.logical_and.reduce(list(solved.values()))
    eff_fates = [f for f in fates if f is not None]
    means = {k: sw.stats["mean_cost_mm"] for k, sw in sweeps.items()}
    ours = _order(means)
    dist = float(np.linalg.norm(problem.goal_mm - problem.start_point_mm))
    clear = float(problem.scene.obstacle_field(0.0).signed_distance(problem.goal_mm))
    in_nodule = float(problem.scene["nodule"].field.signed_distance(problem.goal_mm)) <= 0.0
    return {
        "goal_mm": [float(v) for v in problem.goal_mm],
        "straight_distance_mm": dist,
        "goal_clearance_mm": clear,
        "in_nodule": bool(in_nodule),
        "table4": {
            k: {
                **{key: sw.stats.get(key) for key in ("n_effective", "n_solved", "best_index")},
                **{key: sw.stats.get(key) for key in ("best_cost_mm", "best_direction")},
                **{key: sw.stats.get(key) for key in ("mean_cost_mm", "cost_before_lowest_mm")},
                "time_s": sw.stats.get("time_s"),
                "statuses": _statuses(sw),
                "solved_not_direct": int(
                    sum(solved[k][i] and fates[i] != "valid" for i in range(len(fates)))
                ),
            }
            for k, sw in sweeps.items()
        },
        "mean_over_common_mm": _mean_over(sweeps, common),
        "n_common": int(common.sum()),
        "order": ours,
        "feng_order": list(FENG_ORDER),
        "order_holds": ours == list(FENG_ORDER),
        "direct": {
            "n_effective": len(eff_fates),
            **{fate: eff_fates.count(fate) for fate in sorted(set(eff_fates))},
        },
        "direct_fates": fates,
        "checks": checks,
    }


def run_feng_lungs(
    out_dir: str | os.PathLike,
    *,
    time_limit_s: float | None = None,
    directions: int | None = None,
    max_iterations: int | None = None,
    quick: bool = False,
    seed: int = 0,
    rrt_connection: str = FENG_RRT_CONNECTION,
    executor=None,
    progress: Callable[[str], Callable] | None = None,
    medrad_dir=None,
    cache_dir=None,
    use_cache: bool = True,
    report: bool = True,
    resume: bool = False,
) -> FengLungsStudy:
    """Run Feng's protocol on the Med-RAD lung case and write :data:`FENG_LUNGS_FILES`.

    Parameters
    ----------
    out_dir : path-like
        Output folder (written as one unit: all files or none).
    time_limit_s : float, optional
        Budget per direction and planner (default 1 s; :data:`QUICK` with ``quick``).
    directions : int, optional
        Candidate directions on the Fibonacci sphere (default 544; 136 with ``quick``).
    max_iterations : int, optional
        Iteration budget per direction (default none; 300 with ``quick``).
    quick : bool
        The :data:`QUICK` settings where no other is given.
    seed : int
        Seed of RRT.
    rrt_connection : {"arc", "arc_line"}
        RRT's goal connection (default: one arc, the rule behind Feng's tables).
    executor : concurrent.futures.Executor, optional
        Runs the directions (:func:`needlekit.batch.open_executor`: a process pool or a
        Dask cluster, whose workers need the Med-RAD data at the same path, or
        ``$NEEDLEKIT_MEDRAD``); default this process. The six sweeps go as one batch
        (:func:`~needlekit.planning.steerable.sweep_batch.sweep_many`), RCS* first.
    progress : callable, optional
        ``progress(label)`` returns the per-direction update of the whole batch (called
        once).
    medrad_dir, cache_dir : path-like, optional
    use_cache : bool
    report : bool
        Also write ``report.html`` (``needlekit reproduce feng2023`` draws its own page).
    resume : bool
        Carry on from the partial ``goal1/sweep.json`` and ``goal2/sweep.json`` an
        interrupted run wrote in ``out_dir`` (the same settings): only the directions not
        done are planned. The record's ``timing`` then covers this run alone and does not
        judge the bound.

    Returns
    -------
    FengLungsStudy
        Its record holds ``timing`` (:func:`~needlekit.studies.feng_timing.timing_record`):
        the wall time beside the planners' and the bound it must keep.

    Raises
    ------
    InvalidInputError
        A bad setting, missing data, or a goal not in free space or out of reach (before
        any sweep); with ``resume``, partial files missing, changed or of other settings.
    Interrupted
        Ctrl-C during the sweeps: each target's ``scenario.yaml`` and ``sweep.json`` (its
        finished directions, marked partial) are written, and nothing else.
    """
    from needlekit.planning.steerable.solve import build_planner
    from needlekit.planning.steerable.sweep import sphere_directions
    from needlekit.planning.steerable.sweep_batch import SweepJob, sweep_many

    t0 = time.perf_counter()
    load_before = os.getloadavg()
    settings = _settings(time_limit_s, directions, max_iterations, quick)
    options = {"rrt": {"connection": rrt_connection}}
    # each planner built once, before any anatomy is read (a bad option fails here)
    planners = {name: build_planner(name, options.get(name), seed=seed) for name in FENG_PLANNERS}
    out = Path(out_dir)
    docs = {g: feng_lung_scenario(i, medrad_dir=medrad_dir) for i, g in enumerate(_GOALS, 1)}
    dirs = sphere_directions(int(settings["directions"]))
    head = _sweep_head(settings, seed, options)
    done = _resumed(out, dirs, head) if resume else None  # before the anatomy
    sources, problems = _sources_and_problems(docs, out, cache_dir, use_cache)
    main_prep_s = time.perf_counter() - t0
    jobs = [  # RCS* first: its part ends first, and its time is measured
        SweepJob(problems[g], planners[name], sources[g], rank=int(name != "rcs_star"))
        for g in _GOALS
        for name in FENG_PLANNERS
    ]
    try:
        batch = sweep_many(
            jobs,
            directions=dirs,
            time_limit_s=float(settings["time_limit_s"]),
            executor=executor,
            max_iterations=settings["max_iterations"],
            progress=None
            if progress is None
            else progress(f"{len(_GOALS)} targets x {len(FENG_PLANNERS)} planners"),
            done=done,
        )
    except Interrupted as exc:  # each target's finished directions, marked partial
        _write_partial(out, docs, head, exc.partial)
    found = iter(batch.sweeps)
    sweeps: dict = {g: {name: next(found) for name in FENG_PLANNERS} for g in _GOALS}
    t_post = time.perf_counter()
    goals = {g: _goal_result(problems[g], sweeps[g]) for g in _GOALS}
    run = {"seed": seed, "options": options, "quick": bool(quick), "resumed": bool(resume)}
    record = _study_record(problems, docs, settings, run, goals)
    post_s = time.perf_counter() - t_post
    files: dict = {}
    with staged_outputs():
        t_write = time.perf_counter()
        for g in _GOALS:
            files.update(_write_goal(out, g, docs[g], sweeps[g], record, settings, seed, options))
        write_s = time.perf_counter() - t_write
        # the page's figure, up to the page (kept: `needlekit report` draws the same page)
        record["page_wall_s"] = time.perf_counter() - t0
        t_report = time.perf_counter()
        if report:
            from needlekit.report.feng_lungs_report import write_feng_lungs_report

            files["report.html"] = write_feng_lungs_report(
                out / "report.html", record, sweeps, problems, options
            )
        report_s = time.perf_counter() - t_report
        wall_s = time.perf_counter() - t0
        record["wall_s"] = wall_s
        record["timing"] = timing_record(
            sweeps,
            batch,
            workers=executor_workers(executor),
            wall_s=wall_s,
            main_prep_s=main_prep_s,
            post_s=post_s,
            write_s=write_s,
            report_s=report_s,
            resumed=resume,
        )
        # the budgets are wall-clock: other work on the machine costs iterations
        record["load_average"] = {"start": list(load_before), "end": list(os.getloadavg())}
        files["feng_lungs.json"] = write_json(out / "feng_lungs.json", record)
    return FengLungsStudy(record, sweeps, files, problems, options)


def _resumed(out: Path, dirs, head: dict) -> list:
    """Per sweep job (targets, then planners), the directions an interrupted run finished
    (its partial ``sweep.json`` files, checked against this run)."""
    found = {
        g: read_partial_sweep(out / g / "sweep.json", FENG_PLANNERS, dirs, head) for g in _GOALS
    }
    return [found[g][name] for g in _GOALS for name in FENG_PLANNERS]


def _study_record(problems: dict, docs: dict, settings: dict, run: dict, goals: dict) -> dict:
    """``feng_lungs.json`` before its timing: the case, the settings (with ``run``'s seed,
    options, quick and resumed), Feng's figures and every goal's record."""
    return {
        "study": "feng-lungs",
        "case": _case_record(problems["goal1"]),
        "settings": {
            **settings,
            "planners": list(FENG_PLANNERS),
            **run,
            "needle": docs["goal1"]["needle"],
            "tolerance_mm": docs["goal1"]["goal"]["tolerance_mm"],
        },
        "feng": {"table4": FENG_TABLE4, "points_mm": FENG_POINTS_MM, "order": list(FENG_ORDER)},
        "goals": goals,
        "machine": machine_info(),
    }


def _goal_result(problem, sweeps: dict) -> dict:
    """One goal's record: the direct connections' fates and every planner's checks
    (measured at 0.1 s per target: not worth a task)."""
    first = sweeps[FENG_PLANNERS[0]]
    fates = direct_connection_fates(problem, first.directions, first.effective)
    checks = {k: _checks(problem, sw) for k, sw in sweeps.items()}
    return _goal_record(problem, sweeps, fates, checks)


def _sources_and_problems(docs: dict, out: Path, cache_dir, use_cache: bool):
    """Each goal's scenario source (inline: workers on other machines cannot read files
    written here) and its problem, the patient prepared once in this process for both
    targets, each target checked."""
    sources = {
        g: ScenarioSource.of_document(
            doc, out, name=f"{g}/scenario.yaml", cache_dir=cache_dir, use_cache=use_cache
        )
        for g, doc in docs.items()
    }
    problems = {}
    for g in _GOALS:
        _, problems[g] = sources[g].cached()
        _check_goal(problems[g], g)
    return sources, problems


def _write_goal(out: Path, g: str, doc: dict, sweeps: dict, record: dict, settings: dict,
                seed: int, options: dict) -> dict:  # fmt: skip
    """One goal's ``scenario.yaml``, ``sweep.json`` and (when RCS* found one) ``plan.json``
    with its check; returns them by name."""
    from needlekit.planning.steerable.sweep_result import solved_plans_to_dict, sweeps_to_dict

    files = {f"{g}/scenario.yaml": _write_scenario(out / g / "scenario.yaml", doc, g)}
    # every solved plan kept: the study's page draws each path (Fig. 7), and so does
    # `needlekit report feng_lungs.json`
    sweep = {**_sweep_head(settings, seed, options), **sweeps_to_dict(sweeps)}
    sweep["solved_plans"] = solved_plans_to_dict(sweeps)
    files[f"{g}/sweep.json"] = write_json(out / g / "sweep.json", sweep)
    best = sweeps[FENG_PLANNERS[0]].best
    if best is not None:
        check = record["goals"][g]["checks"][FENG_PLANNERS[0]]["best"]
        files[f"{g}/plan.json"] = write_plan_json(
            out / g / "plan.json",
            best,
            scenario="scenario.yaml",
            # the sweep chose the direction: `verify --any-start-direction` and `report`
            # check it so, as for the plan.json of `sweep --plan`
            start_direction="swept",
            check=check,
        )
    return files


def _sweep_head(settings: dict, seed: int, options: dict) -> dict:
    """What each target's ``sweep.json`` holds beside its directions."""
    return {
        "scenario": "scenario.yaml",
        "time_limit_s": float(settings["time_limit_s"]),
        "max_iterations": settings["max_iterations"],
        "seed": seed,
        "options": options,
    }


def _write_partial(out: Path, docs: dict, head: dict, batch) -> None:
    """An interrupted study: each target's sweeps so far, marked partial, beside the
    complete ``sweep.json`` (raises :class:`~needlekit.errors.Interrupted` saying so)."""
    found = iter(batch.sweeps)
    paths = []
    n_done = n_all = 0
    for g in _GOALS:
        sweeps = {name: next(found) for name in FENG_PLANNERS}
        paths.append(write_partial_sweep(out / g / "sweep.json", head, sweeps))
        for sw in sweeps.values():
            n_all += int(sw.effective.sum())
            n_done += sum(r is not None for r, e in zip(sw.results, sw.effective, strict=True) if e)
    raise Interrupted(
        f"{n_done} of {n_all} effective directions done ({len(_GOALS)} targets x "
        f"{len(FENG_PLANNERS)} planners); written to {' and '.join(map(str, paths))} marked "
        "partial; the same command with --resume carries on"
    )
