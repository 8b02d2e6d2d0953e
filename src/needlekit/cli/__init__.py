"""The ``needlekit`` command line: a thin layer over the library.

Every command returns an exit status; errors in the input print one line
``error: <message>`` on stderr and exit with status 2.

Before a command runs, every path it reads or writes is checked
(:mod:`needlekit.cli._paths`), and only then is the command's module imported: a bad
argument is answered at once, without loading numba, scipy or plotly. A command's
output files are written as one unit (:func:`needlekit.io.files.staged_outputs`): if
it fails, every file that was there before is left as it was.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
from collections.abc import Sequence

from needlekit.cli._common import EXIT_OK, EXIT_USAGE
from needlekit.cli._parser import _build_parser
from needlekit.cli._paths import check_paths
from needlekit.errors import NeedlekitError

__all__ = ["main"]

#: Commands with sub-commands, and the attribute that holds the sub-command.
_GROUPS = {
    "kinematics": "kin_command",
    "scene": "scene_command",
    "study": "study_command",
    "bench": "bench_command",
}

#: What runs each command: ``module:function(args) -> exit status``, imported only then.
_HANDLERS = {
    "kinematics forward": "needlekit.cli.kinematics:_cmd_forward",
    "kinematics inverse": "needlekit.cli.kinematics:_cmd_inverse",
    "schema": "needlekit.cli.scene:_cmd_schema",
    "scene info": "needlekit.cli.scene:_cmd_scene",
    "scene render": "needlekit.cli.scene:_cmd_scene",
    "plan": "needlekit.cli.planning:_cmd_plan",
    "sweep": "needlekit.cli.planning:_cmd_sweep",
    "verify": "needlekit.cli.planning:_cmd_verify",
    "markups": "needlekit.cli.markups:_cmd_markups",
    "cfrw": "needlekit.cli.straight:_cmd_cfrw",
    "multi": "needlekit.cli.straight:_cmd_multi",
    "approach": "needlekit.cli.straight:_cmd_approach",
    "puncture": "needlekit.cli.puncture:_cmd_puncture",
    "report": "needlekit.cli.report:_cmd_report",
    "demo": "needlekit.cli.demo:_cmd_demo",
    "reproduce": "needlekit.cli.reproduce:_cmd_reproduce",
    "study livers": "needlekit.cli.study:_cmd_study_livers",
    "study feng-lungs": "needlekit.cli.study:_cmd_study_feng_lungs",
    "bench kinematics": "needlekit.cli.bench:_cmd_bench",
    "bench fields": "needlekit.cli.bench:_cmd_bench",
    "bench control": "needlekit.cli.bench:_cmd_bench",
    "bench steerable": "needlekit.cli.bench:_cmd_bench",
    "bench straight": "needlekit.cli.bench:_cmd_bench",
    "bench approach": "needlekit.cli.bench:_cmd_bench",
    "bench scale": "needlekit.cli.bench:_cmd_bench",
}


def _run(command: str, args) -> int:
    """Import the command's module and run it."""
    module, function = _HANDLERS[command].split(":")
    return getattr(importlib.import_module(module), function)(args)


def _quiet_stdout() -> None:
    """Send what is left of stdout to /dev/null (the reader of the pipe has left)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status.

    Parameters
    ----------
    argv : sequence of str, optional
        The arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 1 when the result fails its check, 2 on bad input.
    """
    parser = _build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE if argv else EXIT_OK
    command = args.command
    if command in _GROUPS:
        sub = getattr(args, _GROUPS[command])
        if sub is None:
            parser.parse_args([command, "--help"])  # prints the group's help and exits
            return EXIT_USAGE
        command = f"{command} {sub}"
    try:
        check_paths(args)
        from needlekit.io.files import staged_outputs

        with staged_outputs():
            try:
                return _run(command, args)
            except BrokenPipeError:  # the work is done: keep its files
                _quiet_stdout()
                return EXIT_OK
    except NeedlekitError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. `needlekit schema | head`: the reader left early
        _quiet_stdout()
        return EXIT_OK
    except OSError as exc:  # the disk filled up, a folder vanished...: nothing was replaced
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"error: {where}{exc.strerror or exc}; no output was changed", file=sys.stderr)
        return EXIT_USAGE
