"""One registry class for every kind of plug-in: names -> factories.

A :class:`Registry` holds the factories of one kind (the execution's truths, tip sensors,
estimators and feedback laws: :mod:`needlekit.execute.plugins`). needlekit's own entries
are :class:`Builtin` records, ``name -> "module:attr"``: their names (and declared
capabilities) are known, checked and offered without importing their modules, which load
only when the factory is asked for. Other packages add entries with :meth:`Registry.register`
or, with no code run, under the kind's entry-point group (``name = module:attr`` in their
``entry_points.txt``), read the first time a name is not found among those registered. A
wrong name gets one line naming the field (the command-line flag), the names known, and
the nearest of them.

The module imports nothing but the standard library and :mod:`needlekit.errors`, so that
any layer may keep a registry.
"""

from __future__ import annotations

import dataclasses
import importlib
import logging
import threading
from collections.abc import Callable, Iterable
from typing import Any

from needlekit.errors import InvalidInputError, did_you_mean

__all__ = ["Builtin", "Registry"]

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class Builtin:
    """One of needlekit's own entries, as a registry holds it until it is needed.

    Attributes
    ----------
    name : str
    target : str
        ``"module:attr"`` (a dotted attribute after the colon is followed).
    capabilities : tuple of str
        What it declares it can do (e.g. ``"warm_start"``), read without importing it.
    summary : str
        One line for listings.
    """

    name: str
    target: str
    capabilities: tuple[str, ...] = ()
    summary: str = ""

    def load(self) -> Any:
        """The factory (imports its module).

        Returns
        -------
        object
        """
        module, _, attr = self.target.partition(":")
        obj: Any = importlib.import_module(module)
        for part in attr.split("."):
            obj = getattr(obj, part)
        return obj


class _EntryPoint(Builtin):
    """An entry another package declared under the registry's group (its capabilities are
    read from the factory, once loaded)."""


class Registry:
    """Names -> factories of one kind of plug-in (see the module notes).

    Parameters
    ----------
    kind : str
        What an entry is, in messages (``"truth"``, ``"estimator"``).
    group : str
        The entry-point group other packages register under.
    builtins : iterable of Builtin
        needlekit's own, in listing order.
    field : str, optional
        What a wrong name's message is named by (a flag: ``"--truth"``); default ``kind``.
    check : callable, optional
        ``check(name, factory)`` refuses a factory that cannot serve (raises
        InvalidInputError); run on every factory registered or loaded.

    Examples
    --------
    >>> r = Registry("colour", "example.colours", [Builtin("red", "builtins:str")])
    >>> r.names()
    ['red']
    >>> r.get("red")("x")
    'x'
    >>> r.check("redd")
    Traceback (most recent call last):
    ...
    needlekit.errors.InvalidInputError: colour: unknown colour 'redd'; available: red; did you mean red?
    """

    def __init__(
        self,
        kind: str,
        group: str,
        builtins: Iterable[Builtin] = (),
        *,
        field: str | None = None,
        check: Callable[[str, Any], None] | None = None,
    ) -> None:
        self.kind = kind
        self.group = group
        self.field = field or kind
        self._check = check
        self._entries: dict[str, Any] = {b.name: b for b in builtins}
        self._declared = {b.name: b.capabilities for b in self._entries.values()}
        self._entry_points_read = False
        self._lock = threading.Lock()

    def register(self, name: str, factory: Any, *, replace: bool = False) -> None:
        """Make ``factory`` available as ``name``.

        Parameters
        ----------
        name : str
        factory : callable or Builtin
        replace : bool
            Allow replacing an entry of the same name.

        Returns
        -------
        None

        Raises
        ------
        InvalidInputError
            An empty name, a name taken (without ``replace``), or a factory the registry's
            check refuses.
        """
        if not isinstance(name, str) or not name.strip():
            raise InvalidInputError("name", f"a {self.kind} needs a non-empty name, got {name!r}")
        if self._check is not None and not isinstance(factory, Builtin):
            self._check(name, factory)
        with self._lock:
            held = self._entries.get(name)
            if held is not None and held is not factory and not replace:
                raise InvalidInputError("name", f"a {self.kind} named {name!r} is already registered")
            self._entries[name] = factory
            self._declared.pop(name, None)
            if isinstance(factory, Builtin) and not isinstance(factory, _EntryPoint):
                self._declared[name] = factory.capabilities

    def unregister(self, name: str) -> None:
        """Remove an entry (no error when absent).

        Parameters
        ----------
        name : str

        Returns
        -------
        None
        """
        with self._lock:
            self._entries.pop(name, None)
            self._declared.pop(name, None)

    def _read_entry_points(self) -> None:
        if self._entry_points_read:
            return
        self._entry_points_read = True
        from importlib import metadata  # deferred: 25-70 ms, only when a name is not registered
        for ep in metadata.entry_points(group=self.group):
            if ep.name in self._entries:
                continue
            # loaded when first asked for, as a built-in is
            self._entries[ep.name] = _EntryPoint(ep.name, ep.value, summary=f"entry point {ep.value}")

    def names(self, keep: Callable[[str], bool] | None = None) -> list[str]:
        """Every name: needlekit's, then others in registration order, then entry points.

        Parameters
        ----------
        keep : callable, optional
            Only the names it keeps (e.g. those declaring a capability).

        Returns
        -------
        list of str
        """
        self._read_entry_points()
        return [n for n in list(self._entries) if keep is None or keep(n)]

    def _entry(self, name: str) -> Any:
        if name not in self._entries:
            self._read_entry_points()
        try:
            return self._entries[name]
        except KeyError:
            known = self.names()
            raise InvalidInputError(
                self.field,
                f"unknown {self.kind} {name!r}; available: {', '.join(known)}"
                + did_you_mean(str(name), known),
            ) from None

    def check(self, name: str) -> None:
        """Refuse an unknown name (without importing a built-in entry).

        Parameters
        ----------
        name : str

        Returns
        -------
        None

        Raises
        ------
        InvalidInputError
            Named by the registry's field, with the names known and the nearest.
        """
        self._entry(name)

    def capabilities(self, name: str) -> tuple[str, ...]:
        """What an entry declares it can do: a built-in's ``capabilities``, else the
        factory's ``capabilities`` attribute (none: empty).

        Parameters
        ----------
        name : str

        Returns
        -------
        tuple of str
        """
        entry = self._entry(name)
        if name in self._declared:
            return self._declared[name]
        if isinstance(entry, _EntryPoint):
            entry = self.get(name)
        return tuple(getattr(entry, "capabilities", ()))

    def target(self, name: str) -> str:
        """Where an entry's factory lives, ``"module:attr"`` (for records).

        Parameters
        ----------
        name : str

        Returns
        -------
        str
        """
        entry = self._entry(name)
        if isinstance(entry, Builtin):
            return entry.target
        return f"{getattr(entry, '__module__', '?')}:{getattr(entry, '__qualname__', '?')}"

    def get(self, name: str) -> Any:
        """The factory of ``name`` (a built-in's module imported now).

        Parameters
        ----------
        name : str

        Returns
        -------
        object

        Raises
        ------
        InvalidInputError
            Unknown name, or a factory that cannot be loaded or that the check refuses.
        """
        entry = self._entry(name)
        if not isinstance(entry, Builtin):
            return entry
        try:
            factory = entry.load()
        except Exception as exc:  # a broken plug-in: one line naming it, not a traceback
            raise InvalidInputError(
                self.field, f"{self.kind} {name!r} ({entry.target}) cannot be loaded: {exc}"
            ) from None
        if self._check is not None:
            self._check(name, factory)
        with self._lock:
            if self._entries.get(name) is entry:
                self._entries[name] = factory
        return factory
