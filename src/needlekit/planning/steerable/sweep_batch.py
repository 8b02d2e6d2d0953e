"""Several direction sweeps as one batch of tasks: no wait between sweeps, the long tasks
first, the cheap ones grouped, each worker building its problems once.

Feng's protocol runs three planners to two targets from every effective direction: six
sweeps. Run one after the other, each waits for its slowest direction before the next
starts, and every task, even one the pre-checks refuse in a millisecond, costs a round
trip to a worker. :func:`sweep_many` submits every (sweep, direction) task at once, the
directions that will be searched first (a lower :attr:`SweepJob.rank` before a higher
one), those refused by geometry alone (:func:`refused_before_search`) last and
:data:`REFUSED_PER_TASK` to a task, then splits the results back into one
:class:`~needlekit.planning.steerable.sweep.SweepResult` per sweep, equal to what
:func:`~needlekit.planning.steerable.sweep.sweep` gives for it. Tasks report which
worker ran them and how long it spent preparing problems
(:func:`needlekit.batch.worker_builds`).
"""

from __future__ import annotations

import pickle
import time
from concurrent.futures import Executor, as_completed
from dataclasses import dataclass, field

import numpy as np

from needlekit.batch import worker_builds, worker_name
from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import INTERRUPT_FORMS, Interrupted, InvalidInputError, is_interrupt
from needlekit.geometry.se3 import pose_from_direction
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.search import geometric_refusal
from needlekit.planning.steerable.solve import build_planner, solve
from needlekit.planning.steerable.sweep_result import (
    SweepResult,
    effective_directions,
    sphere_directions,
)
from needlekit.planning.steerable.sweep_result import sweep_stats as _stats

__all__ = [
    "REFUSED_PER_TASK",
    "SweepBatch",
    "SweepJob",
    "refused_before_search",
    "sweep_many",
]


def _plan_tasks(tasks: list) -> tuple:
    """Several directions of one or more sweeps, in one task (module level, so process and
    Dask workers can run it).

    Returns
    -------
    tuple
        ``(worker, prep_s, built, results)``: this process (``host:pid``), the seconds this
        task spent building problems from their sources (0 when its worker had them), the
        kinds it built (``"ScenarioSource"``, ``"MedradCase"``) and the PlanResults.
    """
    n_built, prep_s, results = len(worker_builds()), 0.0, []
    for problem, source, direction, planner, time_limit_s, max_iterations in tasks:
        if source is not None:  # built once per worker, reused for its other directions
            t0, n0 = time.perf_counter(), len(worker_builds())
            _, problem = source.cached()
            if len(worker_builds()) > n0:
                prep_s += time.perf_counter() - t0
        p = problem.with_start_pose(pose_from_direction(problem.start_point_mm, direction))
        results.append(solve(p, planner, time_limit_s=time_limit_s, max_iterations=max_iterations))
    built = tuple(kind for kind, _ in worker_builds()[n_built:])
    return worker_name(), prep_s, built, results


#: Largest pickled problem a remote task may carry (bytes); larger scenes need a source.
MAX_TASK_BYTES: int = 8 * 2**20
#: Directions refused before any search (:func:`refused_before_search`) answer in about a
#: millisecond: they travel this many to a task, so that sending them costs less than
#: planning them. A searched direction travels alone (the tail of a sweep stays short).
REFUSED_PER_TASK: int = 16


def _check_task_size(problem) -> None:
    try:
        size = len(pickle.dumps(problem, protocol=pickle.HIGHEST_PROTOCOL))
    except Exception as exc:
        raise InvalidInputError(
            "source",
            f"the problem cannot be sent to workers ({exc}); pass source=ScenarioSource.of(...)",
        ) from exc
    if size > MAX_TASK_BYTES:
        raise InvalidInputError(
            "source",
            f"the problem pickles to {size / 2**20:.0f} MB per task; pass "
            "source=ScenarioSource.of(...) so that each worker builds it once",
        )


def refused_before_search(problem: SteerableProblem, directions) -> np.ndarray:
    """Which start directions the planners' pre-checks refuse by geometry alone (the goal
    beyond l_max, outside the heading cone or the reachable set, or its shortest
    curvature-bounded path not shorter than l_max), before any search.

    The planners' own geometric pre-check
    (:func:`needlekit.planning.steerable.search.geometric_refusal`), per direction; used to
    order a sweep's tasks (searched directions first), so it could only cost balance
    between workers, never change a result.

    Parameters
    ----------
    problem : SteerableProblem
        Start point, goal and limits.
    directions : array_like, shape (n, 3)
        Unit vectors.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    dirs = np.asarray(directions, dtype=float).reshape(-1, 3)
    p0, goal = np.asarray(problem.start_point_mm, dtype=float), problem.goal_mm
    return np.array(
        [geometric_refusal(problem, pose_from_direction(p0, d), goal) is not None for d in dirs],
        dtype=bool,
    )


@dataclass(frozen=True)
class SweepJob:
    """One sweep of a :func:`sweep_many` batch.

    Attributes
    ----------
    problem : SteerableProblem
        Start point, goal and limits.
    planner : str or Planner
        A registered steerable planner's name (built once for the whole sweep, with
        ``options`` and the batch's seed) or a planner built already
        (:func:`~needlekit.planning.steerable.solve.build_planner`), which carries its
        options and seed.
    source : ScenarioSource, optional
        How workers rebuild ``problem`` (see :func:`sweep`).
    options : dict, optional
        Planner settings (with a planner's name only).
    normal : array_like, shape (3,), optional
        Normal of the punctured surface (default: the problem's).
    rank : int
        Jobs of a lower rank go first: their sweeps finish first, and a study can say how
        long they took (e.g. RCS* before RCS and RRT).
    """

    problem: SteerableProblem
    planner: object = "rcs_star"
    source: object = None
    options: dict | None = None
    normal: object = None
    rank: int = 0


@dataclass(frozen=True)
class SweepBatch:
    """What :func:`sweep_many` did.

    Attributes
    ----------
    sweeps : list of SweepResult
        One per job, in the jobs' order.
    workers : dict
        Per worker (``host:pid``): ``tasks``, ``directions``, ``prep_s`` (seconds spent
        building problems from sources) and ``built`` (kind -> count: ``ScenarioSource``,
        ``MedradCase``). Empty when the sweeps ran in this process without sources.
    wall_s : float
        From the first submission to the last result.
    """

    sweeps: list
    workers: dict = field(default_factory=dict)
    wall_s: float = 0.0


def _effective(job: SweepJob, dirs: np.ndarray) -> np.ndarray:
    normal = job.problem.puncture_normal if job.normal is None else job.normal
    if normal is not None and np.all(np.isfinite(normal)):
        return effective_directions(dirs, normal, job.problem.min_puncture_angle_deg)
    return np.ones(len(dirs), dtype=bool)


def _built(job: SweepJob, seed: int | None):
    """The job's planner, built once (a name) or as given (a planner built already)."""
    if isinstance(job.planner, str):
        return build_planner(job.planner, job.options, seed=seed)
    if job.options is not None:
        raise InvalidInputError(
            "options", "a built planner carries its options; give its name to set them"
        )
    return job.planner


def sweep_many(
    jobs,
    *,
    directions=None,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    executor: Executor | None = None,
    seed: int | None = None,
    max_iterations: int | None = None,
    progress=None,
    done=None,
) -> SweepBatch:
    """Several sweeps at once: every (job, direction) task is submitted together, with no
    wait between sweeps, searched directions before those the pre-checks refuse
    (:func:`refused_before_search`), and the results split back per sweep.

    Each sweep equals the one :func:`sweep` gives for the same job (with an iteration
    budget, exactly; with time budgets, as much as the machine's load allows).

    Parameters
    ----------
    jobs : sequence of SweepJob
    directions : array_like, shape (n, 3), optional
        Candidates, the same for every job (default :func:`sphere_directions`).
    time_limit_s, max_iterations
        Budget per direction (see :func:`sweep`).
    seed : int, optional
        Seed of the randomised planners given by name (it wins over a ``seed`` in their
        options); a planner built already carries its own.
    executor : concurrent.futures.Executor, optional
        Runs the tasks (default: one after the other in this process).
    progress : callable, optional
        Called once per finished direction (with its result); ``set_total(n)`` first, if
        it has one.
    done : sequence of (list or None), optional
        Per job, the results of directions done already (an interrupted run's, read back:
        ``None`` where a direction is still to do); those are kept, not planned again.

    Returns
    -------
    SweepBatch
        Each sweep's ``stats["time_s"]`` is the time from the start of the batch until its
        last direction was done.

    Raises
    ------
    InvalidInputError
        No jobs, or a problem too heavy to send to workers without a source.
    Interrupted
        Ctrl-C (KeyboardInterrupt) during the batch: the pending tasks are cancelled and
        the directions finished so far come back as the exception's ``partial``
        :class:`SweepBatch` (``None`` results where a direction was not finished).
    """
    jobs = list(jobs)
    if not jobs:
        raise InvalidInputError("jobs", "expected at least one sweep")
    planners = [_built(job, seed) for job in jobs]  # once per sweep, not per direction
    t0 = time.perf_counter()
    dirs = (
        sphere_directions()
        if directions is None
        else np.asarray(directions, dtype=float).reshape(-1, 3)
    )
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    # executors that run tasks elsewhere get the recipe, or a scene small enough to ship
    remote = executor is not None and not getattr(executor, "in_process", False)
    results = _prefilled(done, len(jobs), len(dirs))
    effs, order = [], []
    for j, job in enumerate(jobs):
        eff = _effective(job, dirs)
        effs.append(eff)
        if remote and job.source is None:
            _check_task_size(job.problem)
        idx = np.array([i for i in np.flatnonzero(eff) if results[j][i] is None], dtype=int)
        refused = refused_before_search(job.problem, dirs[idx])
        order += [(job.rank, bool(r), j, int(i)) for i, r in zip(idx, refused, strict=True)]
    order.sort()
    tasks: list = []  # per task to submit: [((job, direction), task tuple), ...]
    for rank in sorted({job.rank for job in jobs}):
        batch: list = []
        for _, refused, j, i in (o for o in order if o[0] == rank):
            job = jobs[j]
            ship = remote and job.source is not None
            carry = (None, job.source) if ship else (job.problem, None)
            args = (*carry, dirs[i], planners[j], time_limit_s, max_iterations)
            if refused:
                batch.append(((j, i), args))
            else:
                tasks.append([((j, i), args)])
        tasks += [batch[k : k + REFUSED_PER_TASK] for k in range(0, len(batch), REFUSED_PER_TASK)]
    if progress is not None and hasattr(progress, "set_total"):
        progress.set_total(len(order))
    last_s = [0.0] * len(jobs)
    workers: dict = {}

    def collect(keys, out) -> None:
        name, prep_s, built, res = out
        w = workers.setdefault(name, {"tasks": 0, "directions": 0, "prep_s": 0.0, "built": {}})
        w["tasks"] += 1
        w["directions"] += len(res)
        w["prep_s"] += prep_s
        for kind in built:
            w["built"][kind] = w["built"].get(kind, 0) + 1
        now = time.perf_counter() - t0
        for (j, i), r in zip(keys, res, strict=True):
            results[j][i] = r
            last_s[j] = now
            if progress is not None:
                progress(r)

    def batch() -> SweepBatch:
        sweeps = [
            SweepResult(
                dirs, effs[j], results[j], planners[j].name, _stats(dirs, effs[j], results[j], t)
            )
            for j, t in enumerate(last_s)
        ]
        # this process planned from the problems it was given: no worker to report
        return SweepBatch(sweeps, workers if remote else {}, time.perf_counter() - t0)

    try:
        if not remote:
            for t in tasks:  # here, one task after another (Ctrl-C keeps those done)
                collect([k for k, _ in t], _plan_tasks([a for _, a in t]))
        else:
            pending = {executor.submit(_plan_tasks, [a for _, a in t]): t for t in tasks}
            try:
                for fut in as_completed(list(pending)):
                    collect([k for k, _ in pending.pop(fut)], fut.result())
            finally:
                for fut in pending:
                    fut.cancel()
    except INTERRUPT_FORMS as exc:  # Ctrl-C, also inside a compiled kernel
        if not is_interrupt(exc):
            raise
        n = sum(r is not None for rs in results for r in rs)
        raise Interrupted(f"{n} directions done", partial=batch()) from None
    return batch()


def _prefilled(done, n_jobs: int, n_dirs: int) -> list[list]:
    """Per job, a results list of the directions done already (``done``), else empty."""
    if done is None:
        return [[None] * n_dirs for _ in range(n_jobs)]
    done = list(done)
    if len(done) != n_jobs:
        raise InvalidInputError("done", f"expected one entry per sweep ({n_jobs}), got {len(done)}")
    out = []
    for j, d in enumerate(done):
        if d is not None and len(d) != n_dirs:
            raise InvalidInputError(
                f"done[{j}]", f"expected a result or None per direction ({n_dirs}), got {len(d)}"
            )
        out.append([None] * n_dirs if d is None else list(d))
    return out
