"""Exceptions raised by needlekit.

Every error needlekit raises on purpose derives from :class:`NeedlekitError`, so a caller
(and the command line) can tell a problem with the input from a bug. Errors about user
input name the argument, field or file they concern and say what was expected, in one
line.
"""

from __future__ import annotations

__all__ = [
    "Interrupted",
    "InvalidInputError",
    "NeedlekitError",
    "OutputError",
    "SingularityError",
    "UnreachableTargetError",
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
