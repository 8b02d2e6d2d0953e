"""Exceptions raised by needlekit.

Every error needlekit raises on purpose derives from :class:`NeedlekitError`, so a caller
(and the command line) can tell a problem with the input from a bug. Errors about user
input name the argument, field or file they concern and say what was expected, in one
line.
"""

from __future__ import annotations

import difflib
import sys

__all__ = [
    "INTERRUPT_FORMS",
    "Interrupted",
    "InvalidInputError",
    "NeedlekitError",
    "OutputError",
    "SingularityError",
    "UnreachableTargetError",
    "did_you_mean",
    "is_interrupt",
    "raise_if_interrupt",
]


class NeedlekitError(Exception):
    """Base class of every error needlekit raises deliberately."""


class InvalidInputError(NeedlekitError, ValueError):
    """An argument, field or file does not hold what was expected.

    Parameters
    ----------
    field : str
        Name of the argument, field or file at fault (shown first in the message).
    message : str
        What was wrong and what was expected, e.g. ``"must be finite, got NaN"``.
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.reason = message
        super().__init__(f"{field}: {message}")


class UnreachableTargetError(NeedlekitError, ValueError):
    """A target point cannot be reached under the given kinematic limits."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.reason = message
        super().__init__(f"{field}: {message}")


class OutputError(NeedlekitError):
    """A result cannot be written as it is (a computed number that is not finite, where the
    format holds finite numbers only); nothing was written.

    Parameters
    ----------
    field : str
        The file (or output) and the field at fault, e.g. ``"plan.json: cost_mm"``.
    message : str
        What was wrong.
    """

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.reason = message
        super().__init__(f"{field}: {message}")


class SingularityError(NeedlekitError, ArithmeticError):
    """A map is singular at the given configuration (e.g. an Euler-angle gimbal lock)."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        self.reason = message
        super().__init__(f"{field}: {message}")


class Interrupted(Exception):
    """A long run stopped by the user (Ctrl-C, SIGINT) after some of its work was done.

    Not a :class:`NeedlekitError`: nothing was wrong with the input. The command line
    prints the message on one line and exits with status 130 (128 + SIGINT), and the
    files written for the partial result are kept (:func:`needlekit.io.files.staged_outputs`).

    Parameters
    ----------
    message : str
        What was done and where it was written.
    partial : object, optional
        The partial result (e.g. a sweep's directions done so far).
    """

    def __init__(self, message: str, partial=None) -> None:
        super().__init__(message)
        self.partial = partial


#: The exception types a Ctrl-C can arrive as (:func:`is_interrupt` tells which are one):
#: ``except INTERRUPT_FORMS as exc: if not is_interrupt(exc): raise``.
INTERRUPT_FORMS = (KeyboardInterrupt, SystemError, ImportError)


def is_interrupt(exc: BaseException | None) -> bool:
    """Whether ``exc`` is Ctrl-C: a ``KeyboardInterrupt``, the ``SystemError`` a
    compiled (numba) function turns one into, or the ``ImportError`` an extension module
    turns one into while it is imported.

    Python runs the SIGINT handler at the next bytecode it executes. When that bytecode
    belongs to a helper a numba kernel calls back (``_numba_unpickle``), the kernel returns
    with the ``KeyboardInterrupt`` pending and the interpreter reports ``SystemError:
    CPUDispatcher(...) returned a result with an exception set``, caused (through one
    ``SystemError`` per compiled frame) by the ``KeyboardInterrupt``. An extension module
    whose initialisation is interrupted (numba's, while a command is still importing it)
    fails its import: ``ImportError: numba._devicearray failed to import``, raised while
    the ``KeyboardInterrupt`` is handled, or after the module printed it (``PyErr_Print``:
    the chain is cut, the interrupt kept as ``sys.last_value``). Every place that keeps
    work on Ctrl-C, or records a task's failure and goes on, asks this instead of matching
    ``KeyboardInterrupt`` alone.

    Parameters
    ----------
    exc : BaseException or None

    Returns
    -------
    bool

    Examples
    --------
    >>> try:
    ...     try:
    ...         raise KeyboardInterrupt
    ...     except KeyboardInterrupt as ki:
    ...         raise SystemError("CPUDispatcher(f) returned a result with an exception set") from ki
    ... except SystemError as exc:
    ...     is_interrupt(exc), is_interrupt(SystemError("other"))
    (True, False)
    >>> try:
    ...     try:
    ...         raise KeyboardInterrupt
    ...     except KeyboardInterrupt:
    ...         raise ImportError("numba._devicearray failed to import")
    ... except ImportError as exc:
    ...     is_interrupt(exc), is_interrupt(ImportError("no module named x"))
    (True, False)
    """
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        if not isinstance(exc, INTERRUPT_FORMS[1:]):
            return False
        seen.add(id(exc))
        if exc.__cause__ is None and exc.__context__ is None:
            # the chain cut: an extension module's initialisation that printed the
            # KeyboardInterrupt (``PyErr_Print``, which clears it and keeps it as
            # ``sys.last_value``) before raising its own error, as numba's
            # ``_dispatcher`` does when importing ``_devicearray`` is interrupted
            return isinstance(getattr(sys, "last_value", None), KeyboardInterrupt)
        exc = exc.__cause__ or exc.__context__
    return False


def raise_if_interrupt(exc: BaseException) -> None:
    """Raise ``KeyboardInterrupt`` when ``exc`` is Ctrl-C (:func:`is_interrupt`); a
    catch-all that records a failure and goes on calls this first.

    Parameters
    ----------
    exc : BaseException

    Returns
    -------
    None

    Raises
    ------
    KeyboardInterrupt
        ``exc`` is an interrupt, whatever its type.
    """
    if is_interrupt(exc):
        raise KeyboardInterrupt from None


def did_you_mean(word: str, choices, *, n: int = 1) -> str:
    """The nearest of ``choices`` to a misspelt ``word``, as a message's end: ``"; did you
    mean --trials?"`` (with ``n`` > 1 perhaps ``"; did you mean a or b?"``), or ``""`` when none is close
    (:func:`difflib.get_close_matches` with a cut-off of 0.7: "astar" is not offered
    "rcs_star", "lnug" is offered "lung").

    Parameters
    ----------
    word : str
    choices : iterable of str
    n : int
        At most this many suggestions.

    Returns
    -------
    str

    Examples
    --------
    >>> did_you_mean("--trails", ["--trials", "--seed"])
    '; did you mean --trials?'
    >>> did_you_mean("nope", ["plan", "sweep"])
    ''
    """
    # flags are compared without their dashes: "--bogus" is nothing like "--out"
    names = {str(c).lstrip("-"): str(c) for c in choices}
    close = difflib.get_close_matches(str(word).lstrip("-"), list(names), n=n, cutoff=0.7)
    return f"; did you mean {' or '.join(names[c] for c in close)}?" if close else ""
