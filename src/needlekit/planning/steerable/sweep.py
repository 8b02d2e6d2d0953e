"""The effective puncture region: plan from one start point over many start directions
(Feng et al. 2023, Algorithm 1 and Tables 2-4).

:func:`sweep` runs one sweep, as a batch of one
(:func:`~needlekit.planning.steerable.sweep_batch.sweep_many`); the candidate directions,
the effective region and the sweep's record are
:mod:`needlekit.planning.steerable.sweep_result`, re-exported here.
"""

from __future__ import annotations

from concurrent.futures import Executor

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import Interrupted
from needlekit.geometry.se3 import pose_from_direction
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.sweep_batch import SweepJob, sweep_many
from needlekit.planning.steerable.sweep_result import (
    DEFAULT_DIRECTIONS,
    SweepResult,
    effective_directions,
    healpix_directions,
    solved_costs,
    sphere_directions,
    sweep_stats,
    sweeps_from_dict,
    sweeps_to_dict,
)

__all__ = [
    "DEFAULT_DIRECTIONS",
    "SweepResult",
    "effective_directions",
    "healpix_directions",
    "pose_from_direction",
    "sphere_directions",
    "solved_costs",
    "sweep",
    "sweep_stats",
    "sweeps_from_dict",
    "sweeps_to_dict",
]


def sweep(
    problem: SteerableProblem,
    planner="rcs_star",
    *,
    directions=None,
    normal=None,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    executor: Executor | None = None,
    source=None,
    seed: int | None = None,
    max_iterations: int | None = None,
    progress=None,
    options: dict | None = None,
    done=None,
) -> SweepResult:
    """Plan from the start point over every effective start direction.

    Parameters
    ----------
    problem : SteerableProblem
        Start point, goal and limits (its start direction, if any, is ignored).
    planner : str or Planner
        A registered steerable planner's name (``"rcs_star"``, ``"rcs"``, ``"rrt"``,
        ...), built once for the whole sweep; or a planner built already
        (:func:`~needlekit.planning.steerable.solve.build_planner`).
    directions : array_like, shape (n, 3), optional
        Candidates (default: :func:`sphere_directions` with :data:`DEFAULT_DIRECTIONS`).
    normal : array_like, shape (3,), optional
        Normal of the punctured surface pointing into the tissue entered (default: the
        problem's ``puncture_normal``; without one, every direction is effective).
    time_limit_s : float
        Budget per direction.
    executor : concurrent.futures.Executor, optional
        Runs the directions (see :func:`needlekit.batch.open_executor`: a process pool or
        a Dask cluster). Default: one after the other in this process.
    source : ScenarioSource, optional
        How workers rebuild ``problem``: tasks then carry this small
        recipe instead of the scene, and each worker builds it once. Without it, tasks
        carry ``problem`` itself (fine for small analytic scenes).
    seed : int, optional
        Seed of randomised planners (the same for every direction; it wins over a
        ``seed`` in ``options``). Only with a planner's name.
    max_iterations : int, optional
        Iteration budget per direction, beside the time limit (reproducible sweeps).
    progress : callable, optional
        Called once per finished direction (with its result); if it has
        ``set_total(n)``, that is called first with the number of directions to plan.
    options : dict, optional
        Planner settings (see :func:`~needlekit.planning.steerable.solve.solve`); only
        with a planner's name.
    done : list of (PlanResult or None), optional
        Results of the directions an interrupted sweep finished (one per direction,
        ``None`` where one is still to do): kept, not planned again.

    Returns
    -------
    SweepResult
        Several sweeps at once, without waiting between them:
        :func:`~needlekit.planning.steerable.sweep_batch.sweep_many`.

    Raises
    ------
    Interrupted
        Ctrl-C during the sweep; its ``partial`` is the :class:`SweepResult` of the
        directions finished (``None`` for the others).
    """
    job = SweepJob(problem, planner, source, options, normal)
    try:
        return sweep_many(
            [job],
            directions=directions,
            time_limit_s=time_limit_s,
            executor=executor,
            seed=seed,
            max_iterations=max_iterations,
            progress=progress,
            done=None if done is None else [done],
        ).sweeps[0]
    except Interrupted as exc:
        raise Interrupted(str(exc), partial=exc.partial.sweeps[0]) from None
