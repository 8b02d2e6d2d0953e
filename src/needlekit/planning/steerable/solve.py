"""One entry point for the steerable-needle planners: ``solve(problem, planner, ...)``.

Planners come from the registry (:mod:`needlekit.planning.interface`): needlekit's
``rcs_star``, ``rcs`` and ``rrt``, and any planner registered in code or declared by
another package's entry point.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import (
    Planner,
    Termination,
    get_planner,
    planner_class,
    planner_names,
    seeded_options,
)
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult

__all__ = ["build_planner", "planners", "solve"]


def planners() -> list[str]:
    """Names of the registered steerable-needle planners.

    Returns
    -------
    list of str
    """
    return planner_names("steerable")


def solve(
    problem: SteerableProblem,
    planner: str | Planner = "rcs_star",
    *,
    termination: Termination | None = None,
    time_limit_s: float | None = None,
    max_iterations: int | None = None,
    seed: int | None = None,
    options: Mapping | Any | None = None,
) -> PlanResult:
    """Plan with a registered planner, or with a planner already built.

    Parameters
    ----------
    problem : SteerableProblem
        Start, goal, limits and collision model.
    planner : str or Planner
        A registered steerable planner's name (:func:`planners`), built here with
        ``options`` and ``seed``; or a planner built once already
        (:func:`build_planner`, e.g. for every direction of a sweep), which carries its
        options and seed.
    termination : Termination, optional
        When to stop; default: ``time_limit_s`` and ``max_iterations``.
    time_limit_s : float, optional
        Budget (default :data:`~needlekit.constants.DEFAULT_TIME_LIMIT_S`); only without
        ``termination``.
    max_iterations : int, optional
        Iteration budget (reproducible anytime runs); only without ``termination``.
    seed : int, optional
        Seed of randomised planners (:func:`~needlekit.planning.interface.seeded_options`:
        it wins over a ``seed`` in ``options``; deterministic planners ignore it). Only
        with a planner's name.
    options : mapping or the planner's options dataclass, optional
        Planner settings; unknown keys are an error. Only with a planner's name.

    Returns
    -------
    PlanResult

    Raises
    ------
    InvalidInputError
        Unknown planner or option, a planner of another family, options or a seed beside
        a built planner, or both ``termination`` and budgets.
    """
    if isinstance(planner, str):
        instance = build_planner(planner, options, seed=seed)
    else:
        if options is not None or seed is not None:
            raise InvalidInputError(
                "planner", "a built planner carries its options and seed; give its name instead"
            )
        _check_family(planner, getattr(planner, "name", type(planner).__name__))
        instance = planner
    if termination is None:
        termination = Termination(
            DEFAULT_TIME_LIMIT_S if time_limit_s is None else time_limit_s, max_iterations
        )
    elif time_limit_s is not None or max_iterations is not None:
        raise InvalidInputError(
            "termination", "give a Termination or time_limit_s/max_iterations, not both"
        )
    return instance.solve(problem, termination)


def build_planner(
    name: str, options: Mapping | Any | None = None, *, seed: int | None = None
) -> Planner:
    """A steerable planner, built once (its options' values checked), to plan many times.

    Parameters
    ----------
    name : str
        A registered steerable planner.
    options : mapping or the planner's options dataclass, optional
    seed : int, optional
        Wins over a ``seed`` in ``options``
        (:func:`~needlekit.planning.interface.seeded_options`).

    Returns
    -------
    Planner

    Raises
    ------
    InvalidInputError
        Unknown planner or option, a bad value, or a planner of another family.
    """
    _check_family(planner_class(name), name)
    return get_planner(name, seeded_options(name, options, seed))


def _check_family(factory, name: str) -> None:
    family = getattr(factory, "family", None)
    if family != "steerable":
        raise InvalidInputError("planner", f"{name!r} plans {family} needles, not steerable ones")
