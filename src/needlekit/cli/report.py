"""``needlekit report``: result files drawn again on one self-contained page."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from needlekit.cli import _flags
from needlekit.cli._common import EXIT_OK
from needlekit.errors import InvalidInputError


def _check_inputs(args: argparse.Namespace) -> None:
    """Every result and scenario can be read, and the page overwrites none of them."""
    from needlekit.cli._paths import _input_problem

    inputs = [("RESULT", p) for p in args.results]
    inputs += [("--scenario", p) for p in args.scenario or ()]
    for name, path in inputs:
        problem = _input_problem(path, folder=False)
        if problem:
            raise InvalidInputError(name, f"{path}: {problem}")
    out = os.path.realpath(args.out)
    for name, path in inputs:
        if os.path.realpath(path) == out:
            raise InvalidInputError(
                "--out", f"{args.out}: is the input {name}; it would be overwritten"
            )


def _cmd_report(args: argparse.Namespace) -> int:
    from needlekit.report.result_report import write_result_report
    from needlekit.scenario.results import ResultScenarios, read_results

    _check_inputs(args)
    # every file read and checked, and its scenario found, before any anatomy loads
    results = read_results(args.results, args.scenario or (), flag="--scenario")
    report = write_result_report(
        args.out,
        results,
        title=args.title,
        scenarios=ResultScenarios(args.cache_dir, use_cache=not args.no_cache),
    )
    for part in report.parts:
        print(f"{part.result.path}: {part.result.kind.value}: {part.summary}")
    drew = ", ".join(f"{p.result.path.name} ({p.result.kind.word})" for p in report.parts)
    print(f"drew {drew} -> {report.path}")
    failed = [p for p in report.parts if p.checks_ok is False]
    if failed:
        names = ", ".join(str(p.result.path) for p in failed)
        print(f"error: an independent check failed ({names}); the page shows why")
        return 1
    return EXIT_OK


def write_plan_and_page(args: argparse.Namespace, sc, problem, res) -> None:
    """``needlekit plan``'s files: plan.json, and with ``--report`` the plan's page (as
    ``needlekit report plan.json`` draws it), put in place together.

    Parameters
    ----------
    args : argparse.Namespace
        ``out``, ``report``, ``scenario``.
    sc : Scenario
    problem : SteerableProblem
    res : PlanResult

    Returns
    -------
    None
    """
    from needlekit.io.files import staged_outputs
    from needlekit.io.plans import write_plan_json
    from needlekit.io.results import scenario_reference

    with staged_outputs():
        write_plan_json(args.out, res, scenario=scenario_reference(args.scenario, args.out))
        if args.report is not None:
            from needlekit.report.steerable_report import write_plan_report

            title = f"Steerable-needle plan: {sc.name or args.scenario.name}"
            write_plan_report(args.report, problem, res, title=title)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``report`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    rp = sub.add_parser(
        "report",
        help="draw result files (plan, sweep, cfrw, multi, puncture, dynamic, execute, "
        "bench scale, approach, study feng-lungs) on one page",
        description="Read result files written by plan, plan --goals, plan --dynamic, sweep, "
        "cfrw, multi, puncture, execute (its execute.json), bench scale, approach and study "
        "feng-lungs (its feng_lungs.json, in its folder), alone or several together, load the "
        "scenarios they name, check their plans again and write one HTML page (opens "
        "offline) with a part per result, as each command draws its own: 3D scenes, tables, "
        "figures. Says on stdout which kinds it drew. Exit 1 when an independent check fails "
        "(the page is written).",
    )
    rp.add_argument("results", type=Path, nargs="+", metavar="RESULT", help="result files (JSON)")
    _flags.OUT.add(rp, required=True, help="HTML page to write")
    rp.add_argument(
        "--scenario",
        type=Path,
        action="append",
        metavar="FILE",
        help="the scenario, where the one a result names has moved: once for every result "
        "that reads one, or repeated, once per such result in order",
    )
    rp.add_argument("--title", help="page title (default: from the results)")
    _flags.PLOTLY.add(rp)
    _flags.add_cache_options(rp)
    rp.set_defaults(command_handler=_cmd_report)
