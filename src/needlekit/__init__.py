"""needlekit: planning and executing robot-assisted needle insertions.

Layers (imports point down): ``geometry`` (rotations, SE(3), Euler-rate maps) under
``needle`` (bevel-tip needle kinematics); planners, control and I/O build on them. See
:mod:`needlekit.conventions` for units, frames and the needle's bending side.
"""

from __future__ import annotations

from needlekit.errors import (
    InvalidInputError,
    NeedlekitError,
    SingularityError,
    UnreachableTargetError,
)


def __getattr__(name: str):
    """``needlekit.__version__``, looked up the first time it is read: the package
    metadata's reader (``importlib.metadata``, with the email parser it loads) took 70-80 ms
    of every process's start, a third of a command's start-up, most of which never print
    a version."""
    if name != "__version__":
        raise AttributeError(f"module 'needlekit' has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        found = version("needlekit")
    except PackageNotFoundError:  # running from a source tree that is not installed
        found = "0+unknown"
    globals()["__version__"] = found
    return found

__all__ = [
    "InvalidInputError",
    "NeedlekitError",
    "SingularityError",
    "UnreachableTargetError",
    "__version__",
]
