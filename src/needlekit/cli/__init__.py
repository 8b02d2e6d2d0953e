"""The ``needlekit`` command line: a thin layer over the library.

Every command returns an exit status; errors in the input print one line
``error: <message>`` on stderr, naming the flag or the file and what was expected, and exit
with status 2. Every numeric flag's type is the one numeric gate (:mod:`needlekit._numbers`),
so a number out of range is refused by the parser. While a command runs, only needlekit's
own log records reach stderr: a library's log lines (nibabel's header notes, trimesh's) and
Python warnings (numpy, numba) are shown with ``-v`` only, so nothing precedes the error
line.

Each command declares its flags beside its handler (the ``register`` of its module,
assembled by :mod:`needlekit.cli._parser`); flags several commands share are defined once
(:mod:`needlekit.cli._flags`). Before a command runs, every path it reads or writes is
checked (:mod:`needlekit.cli._paths`), and only then does its handler import the heavy
modules: a bad argument is answered at once, without loading numba, scipy or plotly. A command's
output files are written as one unit (:func:`needlekit.io.files.staged_outputs`): if
it fails (an error, exit 2; a verdict that fails, exit 1; Ctrl-C, exit 130), every file
that was there before is left as it was, and the run's own record goes beside it
(``X.failed.json``, ``X.partial.json``).

Ctrl-C is recognised here once for every command, wherever it landed
(:func:`needlekit.errors.is_interrupt`: inside a numba kernel it surfaces as a
``SystemError``): one line, exit 130. Once the command's result is decided and its files
are being put in place, a late Ctrl-C is ignored: the outcome reported is the one on disk.
A Ctrl-C that Python itself swallowed (one landing in a callback called from C, as while
numba compiles) is delivered again (:mod:`needlekit.cli._interrupts`), so it is never lost.
"""

from __future__ import annotations

import argparse
import copy
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from concurrent.futures import BrokenExecutor
from contextlib import contextmanager

from needlekit.cli._common import EXIT_FAILED, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE
from needlekit.cli._flags import check_dashboard
from needlekit.cli._interrupts import interrupts_not_lost, quiet_finalisers
from needlekit.cli._parser import _build_parser, walk_commands
from needlekit.cli._paths import check_paths
from needlekit.errors import INTERRUPT_FORMS, Interrupted, NeedlekitError, is_interrupt
from needlekit.plausibility import flag_warnings, warn

__all__ = ["main"]


def _tables() -> tuple[dict[str, str], dict[str, str]]:
    """What the commands declare: the groups (``kinematics``) with the attribute that holds
    their sub-command, and per command (``"kinematics forward"``) its handler,
    ``module:function``."""
    groups, handlers = {}, {}
    for words, child, dest in walk_commands(_build_parser()):
        if dest is not None:
            groups[" ".join(words)] = dest
        else:
            run = child.get_default("command_handler")
            handlers[" ".join(words)] = f"{run.__module__}:{run.__name__}"
    return groups, handlers


def __getattr__(name: str):
    # ``_GROUPS`` and ``_HANDLERS``: read off the parser when asked for (tests, tools)
    if name in ("_GROUPS", "_HANDLERS"):
        return _tables()[name == "_HANDLERS"]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: Libraries that log on their own (nibabel even adds its own handler): quiet unless -v.
_CHATTY_LOGGERS = ("nibabel", "nibabel.global", "trimesh", "numba", "py.warnings")


class _OwnRecords(logging.Filter):
    """Pass needlekit's own records only: a library's log line (nibabel's header notes,
    trimesh's, a numpy or numba warning) never precedes needlekit's one error line."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.name == "needlekit" or record.name.startswith("needlekit.")


@contextmanager
def _logging(verbose: int) -> Iterator[None]:
    """needlekit's warnings on stderr while a command runs; the libraries' log lines and
    Python warnings (numpy, numba) only with ``-v`` (``-vv``: debug). Everything is put
    back on leaving (``main`` may run inside another program, or a test)."""
    logging.basicConfig(
        level=logging.WARNING - 10 * min(verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    if verbose:
        yield
        return
    own = _OwnRecords()
    handlers = list(logging.getLogger().handlers)
    chatty = {name: logging.getLogger(name).level for name in _CHATTY_LOGGERS}
    logging.captureWarnings(True)  # Python warnings become records of "py.warnings"
    for handler in handlers:
        handler.addFilter(own)
    for name in chatty:  # a library's own handler (nibabel's) is beyond the root's filter
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logging.captureWarnings(False)
        for handler in handlers:
            handler.removeFilter(own)
        for name, level in chatty.items():
            logging.getLogger(name).setLevel(level)


def _run(command: str, args) -> int:
    """Run the command's handler (its heavy modules are imported inside it), its pages
    getting plotly.js as ``--plotly`` says (inlined where the command has no such flag)."""
    from needlekit.report.plotly_js import plotly_mode

    with plotly_mode(getattr(args, "plotly", None) or "inline"):
        return args.command_handler(args)


def _quiet_stdout() -> None:
    """Send what is left of stdout to /dev/null (the reader of the pipe has left)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def _ignore_interrupts(program: bool):
    """From now on Ctrl-C changes nothing (the files are being put in place): returns what
    puts the previous handling back when ``main`` was called in a process that goes on
    (``program`` false); the program itself keeps ignoring it to its exit, so that a late
    Ctrl-C cannot interrupt the interpreter's shutdown with a traceback."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    return (lambda: None) if program else (lambda: signal.signal(signal.SIGINT, previous))


def _interrupt_handled() -> None:
    """Tell CPython the Ctrl-C was handled. A ``KeyboardInterrupt`` that passed through
    ``exec`` of a string (imports run some: scipy's array-API shim) is marked unhandled
    even when caught, and the interpreter then ends by SIGINT instead of with the status
    ``main`` returns; running any string clears the mark (``run_eval_code_obj`` resets it
    before it evaluates)."""
    exec("None")


def _interrupted_before_any_result() -> int:
    """A Ctrl-C before any result was decided: one line, exit 130."""
    _interrupt_handled()
    print("interrupted: stopped before any result; no output was changed", file=sys.stderr)
    return EXIT_INTERRUPTED


#: The parser, built once per builder (a test may put another builder in its place): building
#: it registers every command and flag, about 30 ms, which a program calling ``main`` many
#: times (a study script, the test suite: thousands of calls) would pay each time.
_PARSERS: dict = {}


def _parse(argv: Sequence[str] | None) -> tuple[argparse.ArgumentParser, argparse.Namespace]:
    """The parser and ``argv`` parsed by it. A value the parser holds as its default (a
    list, say) is copied into the namespace, so a command that changes its arguments
    changes nothing the next call reads."""
    build = _build_parser  # looked up at each call: a replaced builder is honoured
    parser = _PARSERS.get(build)
    if parser is None:
        parser = _PARSERS[build] = build()
    args = parser.parse_args(argv)
    for key, value in vars(args).items():
        if isinstance(value, (list, dict, set)):
            setattr(args, key, copy.deepcopy(value))
    return parser, args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 1 when the result fails its check (its files then replace no file
        that exists: :meth:`needlekit.io.files.Outputs.keep_earlier`), 2 on bad input, 130
        when interrupted.
    """
    try:  # a Ctrl-C while the flags are read: the same one line as during the work
        parser, args = _parse(argv)
    except INTERRUPT_FORMS as exc:
        if not is_interrupt(exc):
            raise
        return _interrupted_before_any_result()
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE if argv else EXIT_OK
    command = args.command
    if getattr(args, "command_handler", None) is None:  # a group without its sub-command
        print(
            f"error: {command}: expected a sub-command (needlekit {command} --help)",
            file=sys.stderr,
        )
        return EXIT_USAGE
    with _logging(args.verbose):
        return _checked_run(command, args, program=argv is None)


def _checked_run(command: str, args, *, program: bool) -> int:
    """Check the arguments, run the command, and turn what can go wrong into one line."""
    restore = lambda: None  # noqa: E731
    try:
        check_paths(args)
        check_dashboard(args)
        warn(flag_warnings(vars(args)))
        if getattr(args, "sizes", None) is not None:  # memory asked for, before any work
            from needlekit.memory import refuse_sizes

            refuse_sizes(args.sizes(args))
        from needlekit.io.files import staged_outputs

        with staged_outputs() as outputs:
            try:
                with interrupts_not_lost():
                    code = _run(command, args)
            except BrokenPipeError:  # the work is done: keep its files
                _quiet_stdout()
                code = EXIT_OK
            if code != EXIT_OK:  # a verdict that fails replaces no earlier output
                outputs.keep_earlier()
            restore = _ignore_interrupts(program=program)
        _say_where(outputs)
        return code
    except NeedlekitError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Interrupted as exc:  # the partial result is written: the message says where
        _interrupt_handled()
        quiet_finalisers(program)
        print(f"interrupted: {exc}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except INTERRUPT_FORMS as exc:  # SystemError: inside a numba kernel
        if not is_interrupt(exc):
            raise
        quiet_finalisers(program)
        return _interrupted_before_any_result()
    except BrokenExecutor as exc:  # a worker process died (killed, out of memory)
        why = str(exc).split(".")[0] or type(exc).__name__
        print(f"error: a worker stopped unexpectedly ({why}); no output was changed",
              file=sys.stderr)  # fmt: skip
        return EXIT_FAILED
    except BrokenPipeError:  # e.g. `needlekit schema | head`: the reader left early
        _quiet_stdout()
        return EXIT_OK
    except OSError as exc:  # the disk filled up, a folder vanished...: nothing was replaced
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"error: {where}{exc.strerror or exc}; no output was changed", file=sys.stderr)
        return EXIT_USAGE
    finally:
        restore()


def _say_where(outputs) -> None:
    """One line per file a failing verdict did not replace (logged: the command's own
    output names the destination it asked for)."""
    for kept, written in outputs.diverted:
        logging.getLogger("needlekit").warning(
            "%s: an earlier output, kept; this run's result (it did not succeed) is in %s",
            kept,
            written,
        )
