"""The planner registry: names -> planner factories, needlekit's own listed without importing
them, others found under an entry-point group (split from :mod:`needlekit.planning.interface`,
which re-exports every name here).

needlekit's planners are :data:`BUILTIN_PLANNERS` entries (name, family, option names,
``module:Class``): a name or an option is checked, and the command line refuses a wrong one,
without importing numba; a planner's module is imported when it is built or its class asked
for.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import threading
import typing
from collections.abc import Callable, Mapping
from typing import Any

from needlekit.errors import InvalidInputError, did_you_mean
from needlekit.planning.options import options_from_mapping, refuse_unknown_options

__all__ = [
    "BUILTIN_PLANNERS",
    "ENTRY_POINT_GROUP",
    "BuiltinPlanner",
    "check_planner_options",
    "check_replanner",
    "planner_capabilities",
    "get_planner",
    "option_names",
    "option_types",
    "planner_class",
    "planner_names",
    "register_planner",
    "seeded_options",
    "unregister_planner",
]

log = logging.getLogger(__name__)

#: What the registry holds: ``factory(options) -> planner``, a class with ``options_type``
#: whose instances follow :class:`needlekit.planning.interface.Planner` (not imported here:
#: the interface re-exports this module).
PlannerFactory = Callable[..., Any]

#: Entry-point group under which other packages declare planners: ``name = module:Factory``.
ENTRY_POINT_GROUP = "needlekit.planners"


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
    option_types : tuple of (str, type or tuple) pairs
        Each option's type as text is read into it (the command line's ``--option``):
        ``int``, ``float``, ``bool``, ``str``, ``tuple`` (whole numbers), or the
        ``(name, type)`` pairs of a dataclass-typed option's own fields; as
        :func:`option_types` derives them from the class (a test keeps them equal).
    capabilities : tuple of str
        What the planner declares beyond planning, as its class's ``capabilities`` (a test
        keeps them equal): ``"warm_start"``, its ``solve`` takes ``warm_start=`` plans
        (a re-planner of ``needlekit execute``: :func:`check_replanner`).
    """

    name: str
    family: str
    option_names: tuple[str, ...]
    factory: str
    option_types: tuple[tuple[str, Any], ...] = ()
    capabilities: tuple[str, ...] = ()

    def load(self) -> PlannerFactory:
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


#: RCS's and RCS*'s ``resolution`` option: the fields of ``Resolution``.
_RESOLUTION = (("max_length_mm", float), ("length_levels", int), ("spin_levels", int))

#: needlekit's own planners, in registry order; a test keeps each entry equal to its class.
BUILTIN_PLANNERS: tuple[BuiltinPlanner, ...] = (
    BuiltinPlanner(
        "rcs_star",
        "steerable",
        ("resolution",),
        "needlekit.planning.steerable.rcs:RCSStarPlanner",
        (("resolution", _RESOLUTION),),
        ("warm_start",),
    ),
    BuiltinPlanner(
        "rcs",
        "steerable",
        ("resolution",),
        "needlekit.planning.steerable.rcs:RCSPlanner",
        (("resolution", _RESOLUTION),),
        ("warm_start",),
    ),
    BuiltinPlanner(
        "rrt",
        "steerable",
        ("connection", "seed"),
        "needlekit.planning.steerable.rrt:RRTPlanner",
        (("connection", str), ("seed", int)),
    ),
    BuiltinPlanner(
        "liu_cfrw",
        "straight",
        ("resolution_deg", "objective", "order"),
        "needlekit.planning.straight.planner:LiuPlanner",
        (("resolution_deg", float), ("objective", str), ("order", tuple)),
    ),
)

#: Name -> planner factory, or the :class:`BuiltinPlanner` standing for it until needed.
_REGISTRY: dict[str, PlannerFactory | BuiltinPlanner] = {}
_BUILTINS_LOADED = False
_ENTRY_POINTS_LOADED = False
_LOCK = threading.Lock()


def register_planner(name: str, factory: PlannerFactory, *, replace: bool = False) -> None:
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

    from importlib import metadata  # deferred: 25-70 ms, only when a name is not registered
    for ep in metadata.entry_points(group=ENTRY_POINT_GROUP):
        if ep.name in _REGISTRY:
            continue
        try:
            factory = ep.load()
            register_planner(ep.name, factory)
        except Exception as exc:  # a broken plug-in must not break needlekit: say which
            log.warning("planner entry point %r (%s) not loaded: %s", ep.name, ep.value, exc)


def _entry(name: str) -> PlannerFactory | BuiltinPlanner:
    """The registry's entry for ``name`` (a built-in planner's module not imported)."""
    _load_builtins()
    if name not in _REGISTRY:
        _load_entry_points()
    try:
        return _REGISTRY[name]
    except KeyError:
        raise InvalidInputError(
            "planner",
            f"unknown planner {name!r}; available: {', '.join(planner_names())}"
            + did_you_mean(name, planner_names()),
        ) from None


def _lookup(name: str) -> PlannerFactory:
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
        :func:`get_planner` and :func:`needlekit.scenario.planners.planner_settings`.
    """
    entry = _entry(name)
    if family is not None and entry.family != family:
        raise InvalidInputError(
            "planner",
            f"{name!r} plans {entry.family} needles; {family} planners: "
            f"{', '.join(planner_names(family))}",
        )
    if isinstance(options, Mapping):
        refuse_unknown_options(name, option_names(name), options)


def option_names(name: str) -> tuple[str, ...]:
    """The names of a planner's options, without importing a built-in planner.

    Parameters
    ----------
    name : str

    Returns
    -------
    tuple of str

    Raises
    ------
    InvalidInputError
        No planner of that name.
    """
    entry = _entry(name)
    if isinstance(entry, BuiltinPlanner):
        return entry.option_names
    return tuple(f.name for f in dataclasses.fields(entry.options_type))


def seeded_options(
    name: str, options: Mapping | Any | None, seed: int | None, *, fallback: int | None = None
) -> Mapping | Any | None:
    """The one seed rule: a planner's options with the seed it runs with.

    An explicit ``seed`` (a ``--seed`` flag, ``solve(seed=...)``) wins over a ``seed`` in
    the options, which wins over ``fallback`` (a scenario block's ``seed``). A planner
    without a ``seed`` option (a deterministic one) gets its options back as they are.

    Parameters
    ----------
    name : str
        A registered planner (its option names are read without importing it).
    options : mapping or the planner's options dataclass, optional
    seed : int, optional
    fallback : int, optional

    Returns
    -------
    mapping or dataclass or None
        A new mapping (or a replaced dataclass) when the seed was set; else ``options``.

    Raises
    ------
    InvalidInputError
        No planner of that name.
    """
    if "seed" not in option_names(name):
        return options
    if seed is None:
        has = (
            "seed" in options
            if isinstance(options, Mapping)
            else options is not None  # a dataclass always carries its seed
        )
        if has or fallback is None:
            return options
        seed = fallback
    if options is None or isinstance(options, Mapping):
        return {**(options or {}), "seed": seed}
    return dataclasses.replace(options, seed=seed)


def option_types(name: str) -> dict[str, Any]:
    """The type of each of a planner's options, without importing a built-in planner.

    Parameters
    ----------
    name : str

    Returns
    -------
    dict
        Option name -> ``int``, ``float``, ``bool``, ``str``, ``tuple`` (whole numbers),
        or for a dataclass-typed option (RCS's ``resolution``) a dict of its fields' types.
        Another type (of a plug-in's option) is given as ``str``: the text as written,
        for the planner's options to check.

    Raises
    ------
    InvalidInputError
        No planner of that name.
    """
    entry = _entry(name)
    if isinstance(entry, BuiltinPlanner):
        return {k: dict(t) if isinstance(t, tuple) else t for k, t in entry.option_types}
    return _dataclass_types(entry.options_type)


def _dataclass_types(cls: type) -> dict[str, Any]:
    hints = typing.get_type_hints(cls)
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        hint = hints.get(f.name, str)
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if dataclasses.is_dataclass(f.default):
            out[f.name] = _dataclass_types(type(f.default))
        elif hint in (bool, int, float, str, tuple):
            out[f.name] = hint
        elif typing.get_origin(hint) is tuple or (len(args) == 1 and args[0] is tuple):
            out[f.name] = tuple
        elif len(args) == 1 and args[0] in (bool, int, float, str):  # X | None
            out[f.name] = args[0]
        else:
            out[f.name] = str
    return out


def planner_class(name: str) -> PlannerFactory:
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


def get_planner(name: str, options: Mapping | Any | None = None) -> Any:
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


def planner_capabilities(name: str) -> tuple[str, ...]:
    """What a planner declares it can do beyond planning (a built-in's without importing
    it; another planner's class attribute ``capabilities``, none when absent).

    Parameters
    ----------
    name : str

    Returns
    -------
    tuple of str

    Raises
    ------
    InvalidInputError
        No planner of that name.
    """
    entry = _entry(name)
    return tuple(getattr(entry, "capabilities", ()))


def check_replanner(name: str, field: str = "--replanner") -> None:
    """Refuse, in one line named ``field``, a planner that cannot re-plan an execution: a
    steerable planner declaring the ``"warm_start"`` capability (its search starts from the
    rest of the plan being followed).

    Parameters
    ----------
    name : str
    field : str
        The flag or field named in the message.

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Unknown planner, another family, or no ``warm_start``.
    """
    able = [n for n in planner_names("steerable") if "warm_start" in planner_capabilities(n)]
    if name not in planner_names():
        raise InvalidInputError(
            field, f"unknown planner {name!r}; planners that re-plan: {', '.join(able)}"
            + did_you_mean(str(name), able),
        )  # fmt: skip
    entry = _entry(name)
    if entry.family != "steerable" or "warm_start" not in planner_capabilities(name):
        raise InvalidInputError(
            field, f"planner {name!r} does not declare the 'warm_start' capability a re-planner "
            f"needs; planners that do: {', '.join(able)}"
        )  # fmt: skip
