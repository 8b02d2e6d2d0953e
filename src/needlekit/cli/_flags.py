"""The flags several commands share, each defined once.

A shared flag is a :class:`Flag`: its name and what every command that takes it shares
(the type, the action, the metavar); a command adds it with :meth:`Flag.add`, giving only
what is its own (the help line, a default, ``required``). ``tests/cli/test_flags.py``
walks the whole parser and checks that every argument of a shared flag's name was made by
its one definition here.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from needlekit.cli._common import _positive, _positive_int, _seed
from needlekit.cli._paths import add_input, add_output
from needlekit.errors import InvalidInputError

#: What a command may give :meth:`Flag.add` besides the definition.
_PER_COMMAND = frozenset({"help", "default", "required", "folder", "contents", "dest"})


@dataclass(frozen=True)
class Flag:
    """One flag shared by several commands.

    Attributes
    ----------
    name : str
        The option string, e.g. ``"--time-limit-s"``.
    kwargs : mapping
        What every command's argument shares (``type``, ``action``, ``metavar``, ...).
    path : {None, "input", "output"}
        A path argument, checked before any work by :mod:`needlekit.cli._paths`.
    """

    name: str
    kwargs: Mapping = field(default_factory=dict)
    path: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kwargs", MappingProxyType(dict(self.kwargs)))

    def add(self, p, **per_command) -> argparse.Action:
        """Add this flag to a (sub)parser or an argument group.

        Parameters
        ----------
        p : argparse.ArgumentParser or argument group
        **per_command
            ``help``, ``default``, ``required`` (and ``folder``, ``contents`` of an output
            path): what this command says of the flag.

        Returns
        -------
        argparse.Action
            The argument, tagged ``action.flag = self``.
        """
        own = set(per_command) - _PER_COMMAND
        if own:  # the definition is the one place for these
            raise TypeError(f"{self.name}: {sorted(own)} belong to the shared definition")
        kwargs = {**self.kwargs, **per_command}
        if self.path == "output":
            action = add_output(p, self.name, **kwargs)
        elif self.path == "input":
            action = add_input(p, self.name, **kwargs)
        else:
            action = p.add_argument(self.name, **kwargs)
        action.flag = self
        return action


# -- budgets and randomness ------------------------------------------------------------------

TIME_LIMIT_S = Flag("--time-limit-s", {"type": _positive})
MAX_ITERATIONS = Flag("--max-iterations", {"type": _positive_int})
SEED = Flag("--seed", {"type": _seed})

# -- what a command writes -------------------------------------------------------------------

OUT = Flag("--out", path="output")
JSON = Flag("--json", {"action": "store_true"})
#: Where a page's plotly.js comes from (:mod:`needlekit.report.plotly_js`).
PLOTLY = Flag(
    "--plotly",
    {
        "choices": ["inline", "shared"],
        "default": "inline",
        "help": "plotly.js inlined in each page (self-contained, default) or written once as "
        "plotly.min.js beside the page(s) and loaded from there (each page 4.8 MB lighter)",
    },
)
QUICK = Flag("--quick", {"action": "store_true"})
#: Carry on from the partial result an interrupted run wrote (:mod:`needlekit.io.partial`).
RESUME = Flag("--resume", {"action": "store_true"})

# -- data and caches -------------------------------------------------------------------------

MEDRAD = Flag("--medrad", {"folder": True}, path="input")
CACHE_DIR = Flag("--cache-dir", {"type": Path, "metavar": "DIR"})
NO_CACHE = Flag("--no-cache", {"action": "store_true"})

# -- steerable planners ----------------------------------------------------------------------

RRT_CONNECTION = Flag("--rrt-connection", {"choices": ["arc_line", "arc"]})
DIRECTIONS = Flag("--directions", {"type": _positive_int})


def _option_pair(text: str) -> tuple[str, str]:
    """``--option NAME=VALUE``: the name and the value's text (typed by the planner)."""
    name, eq, value = text.partition("=")
    if not eq or not name.strip():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    return name.strip(), value.strip()


OPTION = Flag(
    "--option",
    {"type": _option_pair, "action": "append", "metavar": "NAME=VALUE", "dest": "option"},
)


def add_option(p, **per_command) -> argparse.Action:
    """``--option NAME=VALUE`` (repeatable): a planner option, typed and checked by
    :func:`needlekit.cli._options.planner_flag_options`.

    Parameters
    ----------
    p : argparse.ArgumentParser
    **per_command
        ``help`` and other keyword arguments of this command's flag.

    Returns
    -------
    argparse.Action
    """
    help_ = per_command.pop(
        "help",
        "a planner option, typed as the planner declares it (repeatable); a field of an "
        "option that has fields as OPTION.FIELD, e.g. resolution.max_length_mm=8 "
        "(see docs/steerable.md)",
    )
    return OPTION.add(p, help=help_, **per_command)


def add_cache_options(p) -> None:
    """``--cache-dir`` and ``--no-cache``: the prepared-anatomy cache of Med-RAD patients.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    None
    """
    CACHE_DIR.add(
        p,
        help="prepared-anatomy cache of Med-RAD patients (default $NEEDLEKIT_CACHE_DIR, "
        "else $XDG_CACHE_HOME/needlekit or ~/.cache/needlekit)",
    )
    NO_CACHE.add(p, help="prepare the anatomy in memory only: neither read nor write the cache")


def add_medrad(p) -> argparse.Action:
    """``--medrad DIR``: the Med-RAD folder.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    argparse.Action
    """
    return MEDRAD.add(
        p, help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)"
    )


def add_record_out(p) -> argparse.Action:
    """``--out FILE`` of a benchmark: where its record goes.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    argparse.Action
    """
    return OUT.add(p, help="write the record as JSON here")


# -- where tasks run -------------------------------------------------------------------------

_EXECUTOR_FLAGS = {
    "executor": "--executor",
    "workers": "--workers",
    "dask_workers": "--dask-workers",
    "scheduler": "--scheduler",
}


def _executor_conflict(given: dict) -> str | None:
    """Why the executor flags given contradict each other, or None."""
    kind, sched, dask_n = given.get("executor"), given.get("scheduler"), given.get("dask_workers")
    if sched is not None and dask_n is not None:
        return "--scheduler uses a running Dask cluster, --dask-workers starts one: give one"
    if sched is not None and given.get("workers") is not None:
        return "--workers does not apply with --scheduler: the cluster has its own workers"
    if dask_n is not None and given.get("workers") is not None:
        return "give --dask-workers N or --workers N, not both"
    for name in ("scheduler", "dask_workers"):
        if given.get(name) is not None and kind not in (None, "dask"):
            return f"{_EXECUTOR_FLAGS[name]} runs on Dask: it contradicts --executor {kind}"
    if kind == "serial" and given.get("workers") is not None:
        return "--workers starts worker processes: it contradicts --executor serial"
    if sched is not None and (not sched.strip() or any(c.isspace() for c in sched)):
        return f"--scheduler: expected an address such as tcp://HOST:PORT, got {sched!r}"
    return None


class _ExecutorChoice(argparse.Action):
    """``--executor``, ``--workers``, ``--dask-workers`` and ``--scheduler`` read as one
    choice, in any order: ``--scheduler`` and ``--dask-workers`` mean Dask, ``--workers``
    alone a process pool; a contradiction is an error before any work."""

    def __call__(self, parser, namespace, values, option_string=None):
        given = {**(getattr(namespace, "executor_flags", None) or {}), self.dest: values}
        problem = _executor_conflict(given)
        if problem:
            parser.error(problem)
        namespace.executor_flags = given
        dask = given.get("scheduler") is not None or given.get("dask_workers") is not None
        implied = "dask" if dask else "process" if given.get("workers") else "serial"
        namespace.executor = given.get("executor") or implied
        namespace.workers = given.get("workers") or given.get("dask_workers")
        namespace.dask_workers = given.get("dask_workers")
        namespace.scheduler = given.get("scheduler")


EXECUTOR = Flag(
    "--executor",
    {"choices": ["serial", "process", "dask"], "default": "serial", "action": _ExecutorChoice},
)
WORKERS = Flag("--workers", {"type": _positive_int, "action": _ExecutorChoice})
DASK_WORKERS = Flag(
    "--dask-workers", {"type": _positive_int, "metavar": "N", "action": _ExecutorChoice}
)
SCHEDULER = Flag("--scheduler", {"metavar": "ADDRESS", "action": _ExecutorChoice})
DASHBOARD = Flag("--dashboard", {"action": "store_true"})


def check_dashboard(args) -> None:
    """``--dashboard`` serves the dashboard of the local Dask cluster a command starts:
    given without one, it is an input error before any work.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
    """
    if not getattr(args, "dashboard", False):
        return
    if getattr(args, "scheduler", None) is not None:
        raise InvalidInputError(
            "--dashboard", "the cluster at --scheduler serves its own dashboard, if any"
        )
    if getattr(args, "executor", None) != "dask":
        raise InvalidInputError(
            "--dashboard", "serves a local Dask cluster's dashboard: add --dask-workers N"
        )


def add_executor_options(p) -> None:
    """``--executor``, ``--workers``, ``--dask-workers``, ``--scheduler``: where tasks run.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    None
    """
    EXECUTOR.add(
        p,
        help="where tasks run: this process, a local process pool, or Dask (default serial; "
        "process with --workers alone; dask with --dask-workers or --scheduler)",
    )
    WORKERS.add(
        p,
        help="worker processes of the pool or local Dask cluster (default: one per CPU); "
        "alone, a process pool",
    )
    DASK_WORKERS.add(
        p, help="start a local Dask cluster of N worker processes (--executor dask --workers N)"
    )
    SCHEDULER.add(
        p,
        help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://HOST:PORT; "
        "implies --executor dask); its workers need needlekit and the data at the same paths",
    )
    DASHBOARD.add(
        p,
        help="with a local Dask cluster: serve its dashboard on 127.0.0.1 (the link is "
        "printed); without it the cluster serves no web page, and its comms take only this "
        "run's TLS credentials",
    )


#: Every shared flag by name (the test of "defined once" walks the parser with it).
SHARED_FLAGS: dict[str, Flag] = {
    f.name: f
    for f in (
        TIME_LIMIT_S, MAX_ITERATIONS, SEED, OUT, JSON, QUICK, MEDRAD, CACHE_DIR, NO_CACHE,
        RRT_CONNECTION, DIRECTIONS, OPTION, EXECUTOR, WORKERS, DASK_WORKERS, SCHEDULER,
        DASHBOARD,
    )
}  # fmt: skip
