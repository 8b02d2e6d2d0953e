"""One entry point for the steerable-needle planners: ``solve(problem, planner, ...)``.

Planners come from the registry (:mod:`needlekit.planning.interface`): needlekit's
``rcs_star``, ``rcs`` and ``rrt``, and any planner registered in code or declared by
another package's entry point.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import Termination, get_planner, planner_class, planner_names
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult

__all__ = ["planners", "solve"]


def planners() -> list[str]:
    """Names of the registered steerable-needle planners.

    Returns
    -------
    list of str
    """
    return planner_names("steerable")


def solve(
    problem: SteerableProblem,
    planner: str = "rcs_star",
    *,
    termination: Termination | None = None,
    time_limit_s: float | None = None,
    max_iterations: int | None = None,
    seed: int | None = None,
    options: Mapping | Any | None = None,
) -> PlanResult:
    """Plan with a registered planner.

    Parameters
    ----------
    problem : SteerableProblem
        Start, goal, limits and collision model.
    planner : str
        A registered steerable planner (:func:`planners`).
    termination : Termination, optional
        When to stop; default: ``time_limit_s`` and ``max_iterations``.
    time_limit_s : float, optional
        Budget (default :data:`~needlekit.constants.DEFAULT_TIME_LIMIT_S`); only without
        ``termination``.
    max_iterations : int, optional
        Iteration budget (reproducible anytime runs); only without ``termination``.
    seed : int, optional
        Seed of randomised planners (sets the ``seed`` option of planners that have one;
        deterministic planners ignore it).
    options : mapping or the planner's options dataclass, optional
        Planner settings; unknown keys are an error.

    Returns
    -------
    PlanResult

    Raises
    ------
    InvalidInputError
        Unknown planner or option, a planner of another family, or both ``termination``
        and budgets.
    """
    factory = planner_class(planner)
    if factory.family != "steerable":
        raise InvalidInputError(
            "planner", f"{planner!r} plans {factory.family} needles, not steerable ones"
        )
    if seed is not None and "seed" in {f.name for f in dataclasses.fields(factory.options_type)}:
        if options is None or isinstance(options, Mapping):
            options = {**(options or {}), "seed": seed}
        else:
            options = dataclasses.replace(options, seed=seed)
    instance = get_planner(planner, options)
    if termination is None:
        termination = Termination(
            DEFAULT_TIME_LIMIT_S if time_limit_s is None else time_limit_s, max_iterations
        )
    elif time_limit_s is not None or max_iterations is not None:
        raise InvalidInputError(
            "termination", "give a Termination or time_limit_s/max_iterations, not both"
        )
    return instance.solve(problem, termination)
