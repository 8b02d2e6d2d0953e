"""The ``needlekit`` parser: the top level and the assembly of the commands.

Each command declares its own flags beside its handler, in a ``register(subparsers)`` of
its module (:data:`COMMAND_MODULES`, in the order ``needlekit --help`` lists them), and
names its handler with ``set_defaults(command_handler=...)``; a flag several commands
share is defined once, in :mod:`needlekit.cli._flags`. The command modules import only
light modules at their top: the heavy ones are imported inside the handlers.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator

import needlekit
from needlekit.cli import (
    bench,
    cache,
    demo,
    execute,
    kinematics,
    markups,
    planning,
    puncture,
    report,
    reproduce,
    scene,
    slicer,
    straight,
    study,
)
from needlekit.cli._common import _Parser
from needlekit.cli.demo import DEMO_FILES
from needlekit.cli.puncture import PUNCTURE_FILES
from needlekit.cli.reproduce import REPRODUCE_FILES, REPRODUCE_PAPERS
from needlekit.cli.study import FENG_LUNGS_FILES

__all__ = [
    "COMMAND_MODULES",
    "DEMO_FILES",
    "FENG_LUNGS_FILES",
    "PUNCTURE_FILES",
    "REPRODUCE_FILES",
    "REPRODUCE_PAPERS",
    "_build_parser",
]

#: The modules whose ``register`` adds their commands, in the order of ``--help``.
COMMAND_MODULES = (
    kinematics,  # kinematics forward|inverse
    scene,  # schema, scene info|render
    planning,  # plan, sweep, verify
    straight,  # cfrw, multi, approach
    markups,
    slicer,  # the whole case as a Slicer scene
    puncture,
    execute,  # execute SCENARIO PLAN
    report,
    demo,
    reproduce,
    study,  # study livers|feng-lungs
    bench,  # bench SUITE
    cache,  # cache list|clear|limit
)


class _Version(argparse.Action):
    """``--version``: the package's version, looked up only when asked for (reading the
    package metadata takes 25-80 ms, which every other command would pay at start-up)."""

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"needlekit {needlekit.__version__}")  # to stdout, as argparse's own action
        parser.exit()


def _build_parser() -> argparse.ArgumentParser:
    """The parser of every ``needlekit`` command.

    Returns
    -------
    argparse.ArgumentParser
    """
    parser = _Parser(
        prog="needlekit",
        description="Planning and executing robot-assisted needle insertions.",
        epilog="Units: mm, rad (degrees where an option says _deg), s. World frame: RAS.",
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="show the version and exit")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for module in COMMAND_MODULES:
        module.register(sub)
    return parser


def walk_commands(parser: argparse.ArgumentParser, words: tuple[str, ...] = ()) -> Iterator:
    """Every command and command group of the parser, depth first.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    words : tuple of str
        The words that lead to ``parser`` (none for the top level).

    Yields
    ------
    tuple
        ``(words, parser, group_dest)``: ``group_dest`` is the namespace attribute of the
        sub-command for a group (``kin_command``), None for a command.
    """
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, child in action.choices.items():
                inner = [a for a in child._actions if isinstance(a, argparse._SubParsersAction)]
                yield (*words, name), child, inner[0].dest if inner else None
                yield from walk_commands(child, (*words, name))
