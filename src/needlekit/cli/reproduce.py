"""``needlekit reproduce``: re-run a source paper's experiments beside its numbers."""

from __future__ import annotations

import argparse
import sys

from needlekit.cli import _flags
from needlekit.cli._common import EXIT_OK

#: The papers ``needlekit reproduce`` re-runs (keys of :data:`needlekit.reproduce.PAPERS`).
REPRODUCE_PAPERS = ("feng2023", "liu2016", "tang", "lecture")
#: What ``needlekit reproduce`` writes in its --out folder (besides a folder per paper).
REPRODUCE_FILES = tuple(f"{k}.{e}" for k in REPRODUCE_PAPERS for e in ("html", "json"))


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from needlekit.batch import open_executor
    from needlekit.reproduce import PAPERS, reproduce

    papers = list(PAPERS) if "all" in args.papers else list(dict.fromkeys(args.papers))
    failed = []
    with open_executor(
        args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
    ) as ex:
        for paper in papers:
            rep = reproduce(
                paper,
                args.out,
                quick=args.quick,
                executor=None if args.executor == "serial" else ex,
                progress=lambda line: print(line, file=sys.stderr, flush=True),
            )
            agree = [c["agrees"] for c in rep.comparisons]
            print(
                f"{paper}: {agree.count('yes')} of {len(agree)} comparisons agree with the paper"
                f" ({agree.count('no')} do not, {agree.count('partly')} partly, "
                f"{agree.count('-')} without a paper number); {rep.wall_s:.0f} s "
                f"-> {rep.files['page']}"
            )
            if not rep.record.get("checks_ok", True):
                failed.append(paper)
    for paper in failed:
        print(f"{paper}: a planned path failed its independent check (see its page)")
    return 1 if failed else EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``reproduce`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    rq = sub.add_parser(
        "reproduce",
        help="re-run a source paper's experiments; one page beside the paper's numbers",
        description="Re-run the experiments of one or more source papers (feng2023: Feng et "
        "al. 2023; liu2016: Liu et al. 2016; tang: Tang et al.; lecture: the needle path "
        "planning lecture) and write, per paper, PAPER.html (needlekit's figures and numbers "
        "beside the paper's, the setup side by side, the deviations listed, the duration), "
        "PAPER.json and the results in PAPER/. --quick runs a reduced version in under 2 "
        "minutes per paper on 2 cores. Exit 1 when a planned path fails its independent check.",
    )
    rq.add_argument(
        "papers",
        nargs="+",
        choices=[*REPRODUCE_PAPERS, "all"],
        metavar="PAPER",
        help=f"one or more of {', '.join(REPRODUCE_PAPERS)}, or all",
    )
    _flags.OUT.add(
        rq,
        folder=True,
        contents=REPRODUCE_FILES,
        default="out/reproduce",
        help="output folder (default out/reproduce)",
    )
    _flags.QUICK.add(rq, help="the reduced version (under 2 minutes per paper)")
    _flags.add_executor_options(rq)
    _flags.PLOTLY.add(rq)
    rq.set_defaults(command_handler=_cmd_reproduce)
