"""The ``needlekit`` command line: a thin layer over the library.

Every command returns an exit status; errors in the input print one line
``error: <message>`` on stderr and exit with status 2.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Sequence

from needlekit.cli._common import EXIT_OK, EXIT_USAGE
from needlekit.cli._parser import _build_parser
from needlekit.cli.bench import _cmd_bench
from needlekit.cli.demo import _cmd_demo
from needlekit.cli.kinematics import _cmd_forward, _cmd_inverse
from needlekit.cli.planning import _cmd_plan, _cmd_sweep, _cmd_verify
from needlekit.cli.puncture import _cmd_puncture
from needlekit.cli.scene import _cmd_scene, _cmd_schema
from needlekit.errors import NeedlekitError

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        if args.command == "kinematics":
            if args.kin_command == "forward":
                return _cmd_forward(args)
            if args.kin_command == "inverse":
                return _cmd_inverse(args)
            parser.parse_args(["kinematics", "--help"])
        elif args.command == "schema":
            return _cmd_schema()
        elif args.command == "scene":
            return _cmd_scene(args, parser)
        elif args.command == "plan":
            return _cmd_plan(args)
        elif args.command == "sweep":
            return _cmd_sweep(args)
        elif args.command == "verify":
            return _cmd_verify(args)
        elif args.command == "puncture":
            return _cmd_puncture(args)
        elif args.command == "demo":
            return _cmd_demo(args)
        elif args.command == "bench":
            return _cmd_bench(args, parser)
        else:
            parser.print_help()
            return EXIT_USAGE if argv else EXIT_OK
    except NeedlekitError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. `needlekit schema | head`: the reader left early
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    return EXIT_USAGE
