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

import dataclasses
import importlib
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any, Protocol, runtime_checkable

from needlekit.constants import DEFAULT_TIME_LIMIT_S, PLANNER_FINISH_RESERVE_S
from needlekit.errors import InvalidInputError

__all__ = [
    "BUILTIN_PLANNERS",
    "ENTRY_POINT_GROUP",
    "BuiltinPlanner",
    "Planner",
    "SearchRun",
    "Termination",
    "check_planner_options",
    "get_planner",
    "options_from_mapping",
    "planner_class",
    "planner_names",
    "register_planner",
    "unregister_planner",
]

log = logging.getLogger(__name__)

#: Entry-point group under which other packages declare planners: ``name = module:Factory``.
ENTRY_POINT_GROUP = "needlekit.planners"


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


# -- options ------------------------------------------------------------------------------


def options_from_mapping(options_type: type, mapping: Mapping | Any | None, planner: str):
    """A planner's typed options from a mapping (a scenario's ``planner.options``).

    Unknown keys are an error naming them; a dataclass-typed field accepts a mapping of its
    own fields (e.g. RCS's ``resolution``).

    Parameters
    ----------
    options_type : type
        The planner's frozen options dataclass.
    mapping : mapping, options_type instance or None
    planner : str
        For error messages.

    Returns
    -------
    options_type instance

    Raises
    ------
    InvalidInputError
        Unknown keys, or values the options refuse.
    """
    if mapping is None:
        return options_type()
    if isinstance(mapping, options_type):
        return mapping
    if not isinstance(mapping, Mapping):
        raise InvalidInputError(
            "planner.options", f"{planner}: expected a mapping, got {type(mapping).__name__}"
        )
    fields = {f.name: f for f in dataclasses.fields(options_type)}
    _refuse_unknown_options(planner, fields, mapping)
    values = {}
    for key, value in mapping.items():
        default = fields[key].default
        if dataclasses.is_dataclass(default) and isinstance(value, Mapping):
            value = options_from_mapping(type(default), value, f"{planner}.{key}")
        values[key] = value
    try:
        return options_type(**values)
    except InvalidInputError as exc:
        raise InvalidInputError("planner.options", f"{planner}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise InvalidInputError("planner.options", f"{planner}: {exc}") from None


def _refuse_unknown_options(planner: str, names, mapping: Mapping) -> None:
    unknown = sorted(set(mapping) - set(names), key=str)
    if unknown:
        known = ", ".join(sorted(names)) or "no options"
        raise InvalidInputError(
            "planner.options", f"{planner} takes {known}; unknown: {', '.join(map(str, unknown))}"
        )


# -- registry -----------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class BuiltinPlanner:
    """One of needlekit's own planners as the registry holds it until it is needed.

    Its module (which loads numba) is imported only when the planner is built or its class
    asked for; its name, family and option names are known before.

    Attributes
    ----------
    name : str
        The registry name.
    family : str
        ``"steerable"`` or ``"straight"``.
    option_names : tuple of str
        The fields of its ``options_type``.
    factory : str
        ``"module:Class"``.
    """

    name: str
    family: str
    option_names: tuple[str, ...]
    factory: str

    def load(self) -> Callable[..., Planner]:
        """The planner class (imports its module).

        Returns
        -------
        type
        """
        module, cls = self.factory.split(":")
        return getattr(importlib.import_module(module), cls)

    def names(self, factory: object) -> bool:
        """Whether ``factory`` is the class this entry stands for (without importing it).

        Parameters
        ----------
        factory : object

        Returns
        -------
        bool
        """
        where = f"{getattr(factory, '__module__', '')}:{getattr(factory, '__qualname__', '')}"
        return where == self.factory


#: needlekit's own planners, in registry order; a test keeps each entry equal to its class.
BUILTIN_PLANNERS: tuple[BuiltinPlanner, ...] = (
    BuiltinPlanner(
        "rcs_star", "steerable", ("resolution",), "needlekit.planning.steerable.rcs:RCSStarPlanner"
    ),
    BuiltinPlanner(
        "rcs", "steerable", ("resolution",), "needlekit.planning.steerable.rcs:RCSPlanner"
    ),
    BuiltinPlanner(
        "rrt", "steerable", ("connection", "seed"), "needlekit.planning.steerable.rrt:RRTPlanner"
    ),
    BuiltinPlanner(
        "liu_cfrw",
        "straight",
        ("resolution_deg", "objective", "order"),
        "needlekit.planning.straight.planner:LiuPlanner",
    ),
)

#: Name -> planner factory, or the :class:`BuiltinPlanner` standing for it until needed.
_REGISTRY: dict[str, Callable[..., Planner] | BuiltinPlanner] = {}
_BUILTINS_LOADED = False
_ENTRY_POINTS_LOADED = False
_LOCK = threading.Lock()


def register_planner(name: str, factory: Callable[..., Planner], *, replace: bool = False) -> None:
    """Make a planner available by name (to :func:`get_planner`, the CLI, sweeps, studies).

    Parameters
    ----------
    name : str
    factory : callable
        ``factory(options) -> Planner`` (a planner class); it must have ``options_type``
        (a dataclass) and ``family`` attributes.
    replace : bool
        Allow replacing a planner of the same name.

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        The name is taken (without ``replace``) or the factory lacks ``options_type``.
    """
    if not isinstance(name, str) or not name.strip():
        raise InvalidInputError("name", f"a planner needs a non-empty name, got {name!r}")
    opts = getattr(factory, "options_type", None)
    if opts is None or not dataclasses.is_dataclass(opts):
        raise InvalidInputError(
            "factory", f"planner {name!r}: options_type must be a dataclass type"
        )
    if getattr(factory, "family", None) not in ("steerable", "straight"):
        raise InvalidInputError(
            "factory", f"planner {name!r}: family must be 'steerable' or 'straight'"
        )
    _load_builtins()
    with _LOCK:
        held = _REGISTRY.get(name)
        same = held is factory or (isinstance(held, BuiltinPlanner) and held.names(factory))
        if held is not None and not replace and not same:
            raise InvalidInputError("name", f"a planner named {name!r} is already registered")
        _REGISTRY[name] = factory


def unregister_planner(name: str) -> None:
    """Remove a planner from the registry (no error when absent).

    Parameters
    ----------
    name : str

    Returns
    -------
    None
    """
    with _LOCK:
        _REGISTRY.pop(name, None)


def _load_builtins() -> None:
    global _BUILTINS_LOADED
    if _BUILTINS_LOADED:
        return
    _BUILTINS_LOADED = True
    with _LOCK:
        for entry in BUILTIN_PLANNERS:  # their modules are imported when first needed
            _REGISTRY.setdefault(entry.name, entry)


def _load_entry_points() -> None:
    global _ENTRY_POINTS_LOADED
    if _ENTRY_POINTS_LOADED:
        return
    _ENTRY_POINTS_LOADED = True
    from importlib.metadata import entry_points

    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _REGISTRY:
            continue
        try:
            factory = ep.load()
            register_planner(ep.name, factory)
        except Exception as exc:  # a broken plug-in must not break needlekit: say which
            log.warning("planner entry point %r (%s) not loaded: %s", ep.name, ep.value, exc)


def _entry(name: str) -> Callable[..., Planner] | BuiltinPlanner:
    """The registry's entry for ``name`` (a built-in planner's module not imported)."""
    _load_builtins()
    if name not in _REGISTRY:
        _load_entry_points()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InvalidInputError(
            "planner", f"unknown planner {name!r}; available: {', '.join(planner_names())}"
        ) from None


def _lookup(name: str) -> Callable[..., Planner]:
    entry = _entry(name)
    if not isinstance(entry, BuiltinPlanner):
        return entry
    factory = entry.load()
    with _LOCK:
        if _REGISTRY.get(name) is entry:
            _REGISTRY[name] = factory
    return factory


def planner_names(family: str | None = None) -> list[str]:
    """Registered planner names (needlekit's, then others, in registration order).

    Parameters
    ----------
    family : str, optional
        Only this family's (``"steerable"`` or ``"straight"``).

    Returns
    -------
    list of str
    """
    _load_builtins()
    _load_entry_points()
    return [n for n, f in _REGISTRY.items() if family is None or f.family == family]


def check_planner_options(
    name: str, options: Mapping | None = None, *, family: str | None = None
) -> None:
    """Check a planner's name, family and option names, without importing a built-in
    planner's module (the values are checked when the planner is built: :func:`get_planner`).

    Parameters
    ----------
    name : str
    options : mapping, optional
        Its settings (only their names are checked here).
    family : str, optional
        The family it must belong to (``"steerable"`` or ``"straight"``).

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Unknown planner, another family, or an unknown option; the same messages as
        :func:`get_planner` and :func:`needlekit.io.problems.planner_settings`.
    """
    entry = _entry(name)
    if family is not None and entry.family != family:
        raise InvalidInputError(
            "planner",
            f"{name!r} plans {entry.family} needles; {family} planners: "
            f"{', '.join(planner_names(family))}",
        )
    if isinstance(entry, BuiltinPlanner):
        fields = entry.option_names
    else:
        fields = tuple(f.name for f in dataclasses.fields(entry.options_type))
    if isinstance(options, Mapping):
        _refuse_unknown_options(name, fields, options)


def planner_class(name: str) -> Callable[..., Planner]:
    """The registered factory of a planner (its ``options_type`` and ``family``).

    Parameters
    ----------
    name : str

    Returns
    -------
    callable
        The planner's class (its module imported now if it was not yet).

    Raises
    ------
    InvalidInputError
        No planner of that name.
    """
    return _lookup(name)


def get_planner(name: str, options: Mapping | Any | None = None) -> Planner:
    """A planner by name, with its options checked.

    Parameters
    ----------
    name : str
    options : mapping or the planner's options dataclass, optional
        Unknown keys are an error.

    Returns
    -------
    Planner

    Raises
    ------
    InvalidInputError
        Unknown planner or option.
    """
    factory = _lookup(name)
    return factory(options_from_mapping(factory.options_type, options, name))
