"""The QP solver registry: names -> :class:`~needlekit.control.qp.QPSolver` factories.

needlekit's own solvers are listed as ``module:Class`` (``daqp``, the default, and
``quadprog``, an optional extra) and imported when first built; other packages add theirs
in code (:func:`register_qp_solver`) or under the entry-point group
:data:`ENTRY_POINT_GROUP` (``name = module:Factory``). The controller, the adaptation,
the procedure and the command line take a solver as a name or an object through
:func:`get_qp_solver`; none of them branches on a solver's name.

Examples
--------
>>> from needlekit.control.qp import DAQPSolver
>>> class Mine(DAQPSolver):
...     name = "mine"
>>> register_qp_solver("mine", Mine)
>>> get_qp_solver("mine").name, "mine" in qp_solver_names()
('mine', True)
>>> unregister_qp_solver("mine")
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Callable

from needlekit.control.qp import DEFAULT_SOLVER, QPSolver
from needlekit.errors import InvalidInputError

__all__ = [
    "BUILTIN_QP_SOLVERS",
    "DEFAULT_QP_SOLVER",
    "ENTRY_POINT_GROUP",
    "check_qp_solver",
    "get_qp_solver",
    "qp_solver_names",
    "register_qp_solver",
    "unregister_qp_solver",
]

log = logging.getLogger(__name__)

#: Entry-point group under which other packages declare QP solvers.
ENTRY_POINT_GROUP = "needlekit.qp_solvers"
#: The solver the controller and the adaptation use unless told otherwise.
DEFAULT_QP_SOLVER = "daqp"
#: needlekit's own solvers (name -> ``module:Class``), imported when first built.
BUILTIN_QP_SOLVERS = {
    "daqp": "needlekit.control.qp:DAQPSolver",
    "quadprog": "needlekit.control.qp_quadprog:QuadprogSolver",
}

_REGISTRY: dict[str, Callable[[], QPSolver] | str] = dict(BUILTIN_QP_SOLVERS)
_INSTANCES: dict[str, QPSolver] = {DEFAULT_QP_SOLVER: DEFAULT_SOLVER}
_ENTRY_POINTS_LOADED = False
_LOCK = threading.Lock()


def register_qp_solver(
    name: str, factory: Callable[[], QPSolver], *, replace: bool = False
) -> None:
    """Make a QP solver available by name.

    Parameters
    ----------
    name : str
    factory : callable
        ``factory() -> QPSolver`` (a :class:`~needlekit.control.qp.QPSolver` subclass).
    replace : bool
        Allow replacing a solver of the same name.

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        An empty name, a factory that is not callable, or a name taken (without
        ``replace``).
    """
    if not isinstance(name, str) or not name.strip():
        raise InvalidInputError("name", f"a QP solver needs a non-empty name, got {name!r}")
    if not callable(factory):
        raise InvalidInputError("factory", f"QP solver {name!r}: expected a callable factory")
    with _LOCK:
        held = _REGISTRY.get(name)
        if held is not None and held is not factory and not replace:
            raise InvalidInputError("name", f"a QP solver named {name!r} is already registered")
        _REGISTRY[name] = factory
        _INSTANCES.pop(name, None)


def unregister_qp_solver(name: str) -> None:
    """Remove a QP solver from the registry (no error when absent; the default stays).

    Parameters
    ----------
    name : str

    Returns
    -------
    None
    """
    if name == DEFAULT_QP_SOLVER:
        return
    with _LOCK:
        _REGISTRY.pop(name, None)
        _INSTANCES.pop(name, None)


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
            register_qp_solver(ep.name, ep.load())
        except Exception as exc:  # a broken plug-in must not break needlekit: say which
            log.warning("QP solver entry point %r (%s) not loaded: %s", ep.name, ep.value, exc)


def qp_solver_names() -> list[str]:
    """Registered QP solver names (needlekit's first; an extra that is not installed is
    listed, and says so when built).

    Returns
    -------
    list of str
    """
    _load_entry_points()
    return list(_REGISTRY)


def check_qp_solver(name: str, field: str = "qp_solver") -> None:
    """Refuse a QP solver name that is not registered, without building the solver or
    importing its package.

    Parameters
    ----------
    name : str
    field : str
        Named in the error (a command line gives its flag).

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        An unknown name.
    """
    if name not in _REGISTRY:
        _load_entry_points()
    if name not in _REGISTRY:
        raise InvalidInputError(
            field, f"unknown QP solver {name!r}; available: {', '.join(qp_solver_names())}"
        )


def get_qp_solver(solver: str | QPSolver | None = None) -> QPSolver:
    """A QP solver by name (built once per name), or the object itself.

    Parameters
    ----------
    solver : str or QPSolver, optional
        None: :data:`DEFAULT_QP_SOLVER`.

    Returns
    -------
    QPSolver

    Raises
    ------
    InvalidInputError
        An unknown name, or an object without a ``solve`` method.
    NeedlekitError
        The solver's package is not installed (its adapter says which extra to install).
    """
    if solver is None:
        return DEFAULT_SOLVER
    if not isinstance(solver, str):
        if not callable(getattr(solver, "solve", None)):
            raise InvalidInputError(
                "qp_solver", f"expected a solver name or a QPSolver, got {solver!r}"
            )
        return solver
    hit = _INSTANCES.get(solver)
    if hit is not None:
        return hit
    check_qp_solver(solver)
    factory = _REGISTRY[solver]
    if isinstance(factory, str):
        module, cls = factory.split(":")
        factory = getattr(importlib.import_module(module), cls)
    instance = factory()
    with _LOCK:
        return _INSTANCES.setdefault(solver, instance)
