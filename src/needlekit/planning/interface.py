"""The planner interface every planner family shares: planners, budgets and a registry.

Modelled on OMPL's separation of ``Planner``, ``PlannerTerminationCondition`` and
``PlannerStatus``:

- a :class:`Planner` has a ``name``, a typed ``options_type`` (a frozen dataclass) and
  ``solve(problem, termination) -> result``; it talks only to the problem;
- a :class:`Termination` says when to stop (a time limit, an iteration limit, the first
  solution, a user callback: whichever comes first); :meth:`Termination.start` gives the
  :class:`SearchRun` a planner polls once per iteration, and which records the time to the
  first solution and the best cost over time;
- the registry maps names to planner factories: needlekit's own, those registered in code
  with :func:`register_planner`, and those other packages declare under the entry-point
  group :data:`ENTRY_POINT_GROUP`, so ``needlekit plan --planner NAME`` runs a planner
  written outside needlekit without any edit to needlekit.

needlekit's own planners (:data:`BUILTIN_PLANNERS`) are listed with their family and
option names, and their modules (numba) imported only when one is built or its class asked
for: :func:`planner_names` and :func:`check_planner_options` answer a wrong name or option
at once.

Example: a planner written outside needlekit

>>> from dataclasses import dataclass
>>> from needlekit.planning.interface import register_planner, get_planner, unregister_planner
>>> @dataclass(frozen=True)
... class EchoOptions:
...     greeting: str = "hello"
>>> class Echo:
...     name = "echo"
...     family = "steerable"
...     options_type = EchoOptions
...     def __init__(self, options=None):
...         self.options = options or EchoOptions()
...     def solve(self, problem, termination):
...         return self.options.greeting
>>> register_planner("echo", Echo)
>>> get_planner("echo", {"greeting": "hi"}).solve(None, Termination()).upper()
'HI'
>>> unregister_planner("echo")
"""

from __future__ import annotations

import functools
import gc
import logging
import math
import time
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from needlekit.constants import DEFAULT_TIME_LIMIT_S, PLANNER_FINISH_RESERVE_S
from needlekit.errors import InvalidInputError
from needlekit.planning.options import options_from_mapping  # re-exported
from needlekit.planning.registry import (  # re-exported: the registry is part of this API
    BUILTIN_PLANNERS,
    ENTRY_POINT_GROUP,
    BuiltinPlanner,
    check_planner_options,
    get_planner,
    option_names,
    planner_class,
    planner_names,
    register_planner,
    seeded_options,
    unregister_planner,
)

__all__ = [
    "BUILTIN_PLANNERS",
    "ENTRY_POINT_GROUP",
    "BuiltinPlanner",
    "Planner",
    "SearchRun",
    "Termination",
    "check_planner_options",
    "cyclic_gc_paused",
    "get_planner",
    "option_names",
    "options_from_mapping",
    "planner_class",
    "planner_names",
    "register_planner",
    "seeded_options",
    "unregister_planner",
]

log = logging.getLogger(__name__)


@runtime_checkable
class Planner(Protocol):
    """What every planner is.

    Attributes
    ----------
    name : str
        The registry name (``"rcs_star"``).
    family : str
        The problems it solves: ``"steerable"`` (curved needles) or ``"straight"``.
    options_type : type
        A frozen dataclass of its settings; ``Planner(options)`` takes an instance.
    """

    name: str
    family: str
    options_type: type

    def solve(self, problem: Any, termination: Termination) -> Any:
        """Plan; always returns a result (never raises for an unsolvable problem).

        Parameters
        ----------
        problem : object
            The family's problem.
        termination : Termination

        Returns
        -------
        object
            The family's result (a status, the plan if any, statistics).
        """
        ...


class Termination:
    """When a planner stops: whichever of its conditions comes first.

    Parameters
    ----------
    time_limit_s : float
        Wall-clock budget of the search (s, > 0). A small part (:attr:`reserve_s`) is kept
        back for building and checking the returned path, so a run answers within it.
    max_iterations : int, optional
        Budget in iterations (reproducible runs: same budget, same result).
    stop_at_first_solution : bool
        Stop as soon as a plan is found (anytime planners otherwise keep improving).
    callback : callable, optional
        ``callback(run) -> bool`` called every iteration with the :class:`SearchRun`;
        returning True stops the search (reason ``"callback"``).

    Examples
    --------
    >>> t = Termination(time_limit_s=5.0, max_iterations=2)
    >>> run = t.start()
    >>> [run.keep_going() for _ in range(3)], run.reason
    ([True, True, False], 'iteration limit')
    """

    def __init__(
        self,
        time_limit_s: float = DEFAULT_TIME_LIMIT_S,
        max_iterations: int | None = None,
        stop_at_first_solution: bool = False,
        callback: Callable[[SearchRun], bool] | None = None,
    ) -> None:
        t = float(time_limit_s)
        if not (math.isfinite(t) and t > 0):
            raise InvalidInputError(
                "time_limit_s", f"must be a finite number > 0, got {time_limit_s!r}"
            )
        if max_iterations is not None and (
            isinstance(max_iterations, bool)
            or not isinstance(max_iterations, int)
            or max_iterations < 0
        ):
            raise InvalidInputError(
                "max_iterations", f"expected a whole number >= 0, got {max_iterations!r}"
            )
        if callback is not None and not callable(callback):
            raise InvalidInputError("callback", "must be callable")
        self.time_limit_s = t
        self.max_iterations = max_iterations
        self.stop_at_first_solution = bool(stop_at_first_solution)
        self.callback = callback

    @property
    def reserve_s(self) -> float:
        """Time kept back for building and checking the returned path (s)."""
        return min(PLANNER_FINISH_RESERVE_S, 0.05 * self.time_limit_s)

    def start(self) -> SearchRun:
        """Start the clock.

        Returns
        -------
        SearchRun
        """
        return SearchRun(self)

    def __repr__(self) -> str:
        return (
            f"Termination(time_limit_s={self.time_limit_s:g}, max_iterations={self.max_iterations}, "
            f"stop_at_first_solution={self.stop_at_first_solution})"
        )


def cyclic_gc_paused(search: Callable) -> Callable:
    r"""Run ``search`` with Python's cyclic garbage collector paused, then restore it.

    A search allocates nodes by the hundred thousand, none in reference cycles (reference
    counting frees them), yet each allocation counts toward the collector's next full pass,
    which walks every live object: on a Med-RAD lung, RCS* for 1 s ran two to four such
    passes of 90-120 ms each, and one begun near the deadline overran the budget by as much.
    Garbage in cycles made during the search waits until it returns.

    Parameters
    ----------
    search : callable

    Returns
    -------
    callable
        The same function, wrapped.
    """

    @functools.wraps(search)
    def paused(*args, **kwargs):
        enabled = gc.isenabled()
        gc.disable()
        try:
            return search(*args, **kwargs)
        finally:
            if enabled:
                gc.enable()

    return paused


class SearchRun:
    """One search under a :class:`Termination`: the clock, the iteration count, why it
    stopped, and the solutions found over time.

    Planners call :meth:`keep_going` once per iteration and :meth:`improved` for every better
    plan; :meth:`stats` gives the figures every result records.
    """

    def __init__(self, termination: Termination) -> None:
        self.termination = termination
        self.t0 = time.perf_counter()
        self.deadline_s = termination.time_limit_s - termination.reserve_s
        self.iterations = 0
        self.reason = "search space exhausted"
        self.stopped = False
        self.first_solution_s: float | None = None
        self.best_cost = math.inf
        self.history: list[tuple[float, float]] = []

    @property
    def elapsed_s(self) -> float:
        """Seconds since the clock started."""
        return time.perf_counter() - self.t0

    def stop(self, reason: str) -> None:
        """Stop the search (the next :meth:`keep_going` answers False) with a reason.

        Parameters
        ----------
        reason : str

        Returns
        -------
        None
        """
        if not self.stopped:
            self.stopped, self.reason = True, reason

    def keep_going(self) -> bool:
        """Whether the search may run one more iteration (counts it when it may).

        Returns
        -------
        bool
        """
        if self.stopped:
            return False
        t = self.termination
        if self.elapsed_s > self.deadline_s:
            self.stop("time limit")
        elif t.max_iterations is not None and self.iterations >= t.max_iterations:
            self.stop("iteration limit")
        elif t.stop_at_first_solution and self.first_solution_s is not None:
            self.stop("first solution")
        elif t.callback is not None and t.callback(self):
            self.stop("callback")
        if self.stopped:
            return False
        self.iterations += 1
        return True

    def improved(self, cost: float) -> None:
        """Record a better plan (its cost) at the current time.

        Parameters
        ----------
        cost : float

        Returns
        -------
        None
        """
        now = self.elapsed_s
        if self.first_solution_s is None:
            self.first_solution_s = now
        self.best_cost = float(cost)
        self.history.append((now, float(cost)))

    def stats(self) -> dict:
        """The figures every result records.

        Returns
        -------
        dict
            ``iterations``, ``reason``, ``planner_wall_s`` (search time, s),
            ``time_limit_s``, ``overrun_s`` (time beyond the budget, >= 0),
            ``first_solution_s`` (None without a solution) and ``cost_history``
            (``[time_s, cost]`` of each improvement).
        """
        wall = self.elapsed_s
        return {
            "iterations": self.iterations,
            "reason": self.reason,
            "planner_wall_s": wall,
            "time_limit_s": self.termination.time_limit_s,
            "overrun_s": max(0.0, wall - self.termination.time_limit_s),
            "first_solution_s": self.first_solution_s,
            "cost_history": [list(p) for p in self.history],
        }
