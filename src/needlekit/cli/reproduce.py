"""``needlekit reproduce``: re-run a source paper's experiments beside its numbers."""

from __future__ import annotations

import argparse
import sys

from needlekit.cli._common import EXIT_OK


def _cmd_reproduce(args: argparse.Namespace) -> int:
    from needlekit.batch import open_executor
    from needlekit.reproduce import PAPERS, reproduce

    papers = list(PAPERS) if "all" in args.papers else list(dict.fromkeys(args.papers))
    failed = []
    with open_executor(args.executor, workers=args.workers, address=args.scheduler) as ex:
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
