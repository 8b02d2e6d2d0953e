"""needlekit: planning and executing robot-assisted needle insertions.

Layers (imports point down): ``geometry`` (rotations, SE(3), Euler-rate maps) under
``needle`` (bevel-tip needle kinematics); planners, control and I/O build on them. See
:mod:`needlekit.conventions` for units, frames and the needle's bending side.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

from needlekit.errors import (
    InvalidInputError,
    NeedlekitError,
    SingularityError,
    UnreachableTargetError,
)

try:
    __version__ = version("needlekit")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0+unknown"

__all__ = [
    "InvalidInputError",
    "NeedlekitError",
    "SingularityError",
    "UnreachableTargetError",
    "__version__",
]
