"""Sizes refused before the work: a flag that would need more memory than the machine has.

A flag such as ``--directions 1000000000`` or ``--resolution-deg 1e-5`` used to reach
numpy, which failed deep inside with a traceback after the anatomy had loaded. The
commands estimate instead, up front, the memory the request needs *at least* (the arrays
it is certain to hold, never more), and refuse it in one line when that is more than the
memory available now: ``--directions: 1000000000 directions would need at least 478 GiB;
this machine has 21.3 GiB available``. A request that fits the estimate may still be
slow: the estimate is a floor, not a promise.

Every command that sizes arrays from its input says so in one table
(:mod:`needlekit.cli._sizes`): per flag, a :class:`Size`, checked by
:func:`refuse_sizes` before the command's handler runs, so before any anatomy loads or
any array is made.
"""

from __future__ import annotations

import os
from typing import NamedTuple

from needlekit.errors import InvalidInputError

__all__ = ["Size", "available_bytes", "format_bytes", "refuse_if_too_big", "refuse_sizes"]


class Size(NamedTuple):
    """What one flag asks for, in memory: at least ``count * bytes_each`` bytes.

    Parameters
    ----------
    flag : str
        The flag (or file field) that sets it, named in the error (``"--trials"``).
    count : float
        How many items it asks for (a float: a request may pass any integer's range).
    bytes_each : float
        The least memory one item holds (bytes): the arrays it is certain to need.
    what : str
        The request in words (``"1e+12 trials"``).
    """

    flag: str
    count: float
    bytes_each: float
    what: str


def refuse_sizes(sizes) -> None:
    """Refuse the first request of ``sizes`` that needs more memory than is available.

    Parameters
    ----------
    sizes : iterable of Size

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Named by the request's flag (:func:`refuse_if_too_big`).

    Examples
    --------
    >>> refuse_sizes([Size("--trials", 3, 64, "3 trials")])
    >>> refuse_sizes([Size("--trials", 1e18, 64, "1e+18 trials")])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    needlekit.errors.InvalidInputError: --trials: 1e+18 trials would need at least 5.68e+04 PiB; ...
    """
    for s in sizes:
        refuse_if_too_big(float(s.count) * float(s.bytes_each), s.flag, s.what)


def available_bytes() -> int:
    """Memory a new allocation can use now: ``MemAvailable`` on Linux, else the physical
    memory.

    Returns
    -------
    int
        Bytes.
    """
    try:
        with open("/proc/meminfo", encoding="ascii") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 2**62  # unknown: refuse nothing on this ground


def format_bytes(n: float) -> str:
    """``n`` bytes as text in binary units.

    Parameters
    ----------
    n : float

    Returns
    -------
    str

    Examples
    --------
    >>> format_bytes(3 * 2**30), format_bytes(1.5 * 2**50), format_bytes(512)
    ('3 GiB', '1.5 PiB', '512 B')
    """
    for unit, size in (
        ("PiB", 2**50),
        ("TiB", 2**40),
        ("GiB", 2**30),
        ("MiB", 2**20),
        ("KiB", 2**10),
    ):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{int(n)} B"


def refuse_if_too_big(needed: float, flag: str, what: str) -> None:
    """Raise when ``needed`` bytes are more than :func:`available_bytes`.

    Parameters
    ----------
    needed : float
        The least memory the request needs (bytes).
    flag : str
        Named in the error (``"--directions"``).
    what : str
        The request in words (``"1000000000 directions"``).

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"<flag>: <what> would need at least <X>; this machine has <Y> available"``.
    """
    have = available_bytes()
    if needed > have:
        raise InvalidInputError(
            flag,
            f"{what} would need at least {format_bytes(needed)}; this machine has "
            f"{format_bytes(have)} available",
        )
