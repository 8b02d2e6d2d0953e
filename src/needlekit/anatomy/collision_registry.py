"""The registry of collision checkers by name (:mod:`needlekit.anatomy.collision`).

Light on purpose: the built-ins are named here and their factories imported only when a
problem builds one, so a scenario's ``collision_model`` is checked against the registry
before any kernel loads (the command line's one-line errors answer in a tenth of a second).
A user's checker registers in code (:func:`register_collision_checker`) or by the
``needlekit.collision_checkers`` entry-point group (``name = "package.module:factory"``).

Examples
--------
>>> collision_checker_names()[:2]
['field', 'voxel_centres']
>>> check_collision_model("voxel_centres")
'voxel_centres'
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from needlekit.errors import InvalidInputError

__all__ = [
    "check_collision_model",
    "collision_checker_names",
    "collision_factory",
    "register_collision_checker",
    "unregister_collision_checker",
]

#: Built-in checkers: name -> (module, factory), imported when first built.
_BUILTIN: dict[str, tuple[str, str]] = {
    "field": ("needlekit.anatomy.collision", "_field"),
    "voxel_centres": ("needlekit.anatomy.collision", "_voxel_centres"),
}
_REGISTERED: dict[str, Callable[..., Any]] = {}
_entry_points: dict[str, Any] | None = None


def _from_entry_points() -> dict[str, Any]:
    global _entry_points
    if _entry_points is None:
        from importlib import metadata  # deferred: 25-70 ms, only when a name is not registered

        _entry_points = {
            ep.name: ep for ep in metadata.entry_points(group="needlekit.collision_checkers")
        }
    return _entry_points


def register_collision_checker(name: str, factory: Callable[..., Any], *, replace: bool = False) -> None:  # fmt: skip
    """Make a collision checker available by name (``collision_model: NAME``).

    Parameters
    ----------
    name : str
    factory : callable
        ``factory(setup: CollisionSetup) -> CollisionChecker``.
    replace : bool
        Allow replacing a registered (not built-in) checker of that name.

    Raises
    ------
    InvalidInputError
        A built-in name, a name already taken (without ``replace``), or a factory that
        is not callable.

    Returns
    -------
    None
    """
    if not isinstance(name, str) or not name.isidentifier():
        raise InvalidInputError("name", f"expected an identifier, got {name!r}")
    if not callable(factory):
        raise InvalidInputError("factory", f"expected a callable, got {type(factory).__name__}")
    if name in _BUILTIN:
        raise InvalidInputError("name", f"{name!r} is a built-in collision checker")
    if name in _REGISTERED and not replace:
        raise InvalidInputError("name", f"a collision checker {name!r} is already registered")
    _REGISTERED[name] = factory


def unregister_collision_checker(name: str) -> None:
    """Remove a registered (not built-in) collision checker.

    Parameters
    ----------
    name : str

    Raises
    ------
    InvalidInputError
        No such registered checker.

    Returns
    -------
    None
    """
    if name not in _REGISTERED:
        raise InvalidInputError("name", f"no registered collision checker {name!r} to remove")
    del _REGISTERED[name]


def collision_checker_names() -> list[str]:
    """The names problems and scenario files may give as ``collision_model``.

    Returns
    -------
    list of str
        Built-ins first, then registered ones and entry points, sorted.
    """
    others = (set(_REGISTERED) | set(_from_entry_points())) - set(_BUILTIN)
    return [*_BUILTIN, *sorted(others)]


def check_collision_model(name: Any) -> str:
    """The name, when it names a collision checker.

    Parameters
    ----------
    name : str

    Returns
    -------
    str

    Raises
    ------
    InvalidInputError
        Naming ``collision_model`` and the known names.
    """
    if not isinstance(name, str) or name not in collision_checker_names():
        raise InvalidInputError(
            "collision_model",
            f"expected one of {', '.join(collision_checker_names())}, got {name!r}",
        )
    return name


def collision_factory(name: str) -> Callable[..., Any]:
    """The factory of a named checker (a built-in's module is imported here).

    Parameters
    ----------
    name : str

    Returns
    -------
    callable
        ``factory(setup) -> CollisionChecker``.

    Raises
    ------
    InvalidInputError
        An unknown name.
    """
    if name in _BUILTIN:
        module, attr = _BUILTIN[name]
        return getattr(importlib.import_module(module), attr)
    if name in _REGISTERED:
        return _REGISTERED[name]
    ep = _from_entry_points().get(name)
    if ep is None:
        check_collision_model(name)  # raises, naming the known ones
    return ep.load()
