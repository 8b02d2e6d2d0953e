"""``needlekit report``: result files drawn again on one self-contained page."""

from __future__ import annotations

import argparse
import os

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
    print(f"-> {report.path}")
    failed = [p for p in report.parts if p.checks_ok is False]
    if failed:
        names = ", ".join(str(p.result.path) for p in failed)
        print(f"error: an independent check failed ({names}); the page shows why")
        return 1
    return EXIT_OK
