"""A Ctrl-C that Python swallowed is delivered again.

Python raises ``KeyboardInterrupt`` in whatever Python code runs when the signal is
handled. When that code is a callback called from C (a ``ctypes`` callback: llvmlite's
object cache while numba compiles a kernel) or a finaliser (``__del__``), the exception
cannot propagate: the interpreter reports it as "Exception ignored ..." through
:func:`sys.unraisablehook` and goes on, and the command would run to its end as if
nobody had pressed Ctrl-C.

:func:`interrupts_not_lost` puts a hook in place for the command's run: a
``KeyboardInterrupt`` reported as unraisable is not printed but delivered again, a few
milliseconds later, by :func:`_thread.interrupt_main` (the main thread is then back in
ordinary code, where the interrupt propagates as usual; a new landing in a callback
repeats the cycle). The command's own handling of Ctrl-C (its one line, exit 130, its
partial record) then applies, wherever the first signal landed.

An extension module whose initialisation meets the interrupt may print it itself
(``PyErr_Print``, through :func:`sys.excepthook`) and raise an ``ImportError`` of its own:
while the block runs, the hook prints no ``KeyboardInterrupt``, and
:func:`~needlekit.errors.is_interrupt` knows that ``ImportError`` for what it is. And an
object the interrupt left half made (its ``__init__`` cut before it set what its
``__del__`` reads: llvmlite's string buffer) fails in its finaliser: once a SIGINT has
arrived in the block, such failures are the interrupt's wake and are not printed (the
program's own end does the same: :func:`quiet_finalisers`).
"""

from __future__ import annotations

import _thread
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from needlekit.errors import is_interrupt

#: How long the re-delivery waits for the main thread to leave the callback, in seconds.
REDELIVERY_DELAY_S = 0.005


@contextmanager
def interrupts_not_lost() -> Iterator[None]:
    """While the block runs (in the main thread), a ``KeyboardInterrupt`` that Python
    reports as unraisable is delivered to the main thread again instead of being printed.

    Yields
    ------
    None
        The block runs with the hook in place; the previous hook is put back after it.

    Examples
    --------
    >>> import sys
    >>> before = sys.unraisablehook
    >>> with interrupts_not_lost():
    ...     sys.unraisablehook is before
    False
    >>> sys.unraisablehook is before
    True
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = sys.unraisablehook
    seen: list[int] = []  # the SIGINTs that arrived while the block ran
    handler = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame) -> None:
        seen.append(signum)
        signal.default_int_handler(signum, frame)  # raises KeyboardInterrupt

    def hook(unraisable) -> None:
        if is_interrupt(unraisable.exc_value):
            threading.Thread(target=_interrupt_main_soon, daemon=True).start()
            return
        if seen:  # a finaliser of an object the interrupt left half made: its wake
            return _drop(unraisable)
        previous(unraisable)

    printing = sys.excepthook

    def quiet(kind, value, tb) -> None:
        # an extension module's initialisation that ``PyErr_Print``-s the interrupt it met
        # (numba's ``_dispatcher``) would print its traceback: the command's own one line
        # says it (``is_interrupt`` reads the interrupt back from ``sys.last_value``)
        if not isinstance(value, KeyboardInterrupt):
            printing(kind, value, tb)

    if isinstance(getattr(sys, "last_value", None), KeyboardInterrupt):
        del sys.last_value  # an earlier command's, in this process: not this one's
    sys.unraisablehook, sys.excepthook = hook, quiet
    ours = handler is signal.default_int_handler
    if ours:
        signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        sys.unraisablehook, sys.excepthook = previous, printing
        if ours and signal.getsignal(signal.SIGINT) is on_sigint:
            signal.signal(signal.SIGINT, handler)


def quiet_finalisers(program: bool) -> None:
    """After Ctrl-C the program ends: an object the interrupt left half made (llvmlite's
    string buffer, its ``__init__`` cut before it set what its ``__del__`` reads) fails in
    its finaliser when the interrupt's frames are let go or the interpreter shuts down,
    and Python would print that as "Exception ignored in ...". The command's one line is
    all it prints (a ``main`` called by a program that goes on keeps its hook).

    Parameters
    ----------
    program : bool
        ``main`` runs as the program (its process ends with the command).

    Returns
    -------
    None
    """
    if program:
        sys.unraisablehook = _drop


def _drop(unraisable) -> None:
    """An unraisable report in the wake of Ctrl-C: nothing printed."""


def _interrupt_main_soon() -> None:
    """Deliver SIGINT's handling to the main thread once it has had time to return from
    the callback that swallowed the first one (a no-op where SIGINT is ignored)."""
    time.sleep(REDELIVERY_DELAY_S)
    _thread.interrupt_main()
