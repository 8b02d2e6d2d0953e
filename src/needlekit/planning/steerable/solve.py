"""One entry point for the steerable-needle planners: ``solve(problem, planner, ...)``."""

from __future__ import annotations

from needlekit.anatomy.occupancy import VoxelObstacles
from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult

__all__ = ["PLANNERS", "solve"]

#: Planner names accepted by :func:`solve`.
PLANNERS: tuple[str, ...] = ("rcs_star", "rcs", "rrt")


def solve(
    problem: SteerableProblem,
    planner: str = "rcs_star",
    *,
    time_limit_s: float = 1.0,
    obstacles: VoxelObstacles | None = None,
    seed: int | None = None,
    max_iterations: int | None = None,
    options: dict | None = None,
) -> PlanResult:
    """Plan with the named planner.

    Parameters
    ----------
    problem : SteerableProblem
    planner : str
        One of :data:`PLANNERS`.
    time_limit_s : float
    obstacles : VoxelObstacles, optional
        Exact voxel-centre collision test (default: the scene's obstacle field).
    seed : int, optional
        Seed of RRT's samples (RCS and RCS* are deterministic).
    max_iterations : int, optional
        Budget in iterations, beside the time limit (makes anytime runs reproducible).
    options : dict, optional
        Planner settings: RRT's ``connection`` (``"arc_line"`` or ``"arc"``); RCS's and
        RCS*'s ``resolution`` (a :class:`~needlekit.planning.steerable.rcs.Resolution` or
        a dict of its fields).

    Returns
    -------
    PlanResult
    """
    from needlekit.planning.steerable.rcs import solve_rcs
    from needlekit.planning.steerable.rrt import solve_rrt

    if planner not in PLANNERS:
        raise InvalidInputError(
            "planner", f"expected one of {', '.join(PLANNERS)}, got {planner!r}"
        )
    opts = dict(options or {})
    allowed = {"connection"} if planner == "rrt" else {"resolution"}
    unknown = sorted(set(opts) - allowed)
    if unknown:
        raise InvalidInputError(
            "options",
            f"{planner} takes {', '.join(sorted(allowed))}; unknown: {', '.join(unknown)}",
        )
    if planner == "rrt":
        return solve_rrt(
            problem,
            time_limit_s=time_limit_s,
            seed=seed,
            obstacles=obstacles,
            max_iterations=max_iterations,
            **opts,
        )
    from needlekit.planning.steerable.rcs import Resolution

    if isinstance(opts.get("resolution"), dict):
        opts["resolution"] = Resolution(**opts["resolution"])
    return solve_rcs(
        problem,
        time_limit_s=time_limit_s,
        optimal=planner == "rcs_star",
        obstacles=obstacles,
        max_iterations=max_iterations,
        **opts,
    )
