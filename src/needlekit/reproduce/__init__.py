"""Each source paper's experiments, re-run and set beside the paper's own numbers.

``needlekit reproduce PAPER --out DIR`` (or :func:`reproduce`) runs one paper's
experiments and writes, in ``DIR``:

- ``PAPER.html``: one self-contained page: needlekit's numbers beside the paper's, the
  setup side by side, every deviation listed, the figures, the commands that re-run each
  part, and how long the run took;
- ``PAPER.json``: the same numbers, machine-readable;
- ``PAPER/``: the results of the parts (plans, sweeps, studies) in their usual formats,
  each one a file ``needlekit report`` and ``needlekit verify`` read.

``quick=True`` runs a reduced version (fewer trials, directions or iterations, named on
the page) in under two minutes on two cores. The papers:

=========== ===================================================================
``feng2023`` Feng et al. 2023, the effective puncture region of a flexible needle
``liu2016``  Liu et al. 2016, straight multi-needle planning with CFRWs
``tang``     Tang et al., adaptive constrained VFI control of a robotic puncture
``lecture``  the lecture on needle path planning and bevel-tip kinematics
=========== ===================================================================
"""

from __future__ import annotations

import importlib
import os
import time
from collections.abc import Callable

from needlekit.errors import InvalidInputError
from needlekit.reproduce._page import Reproduction, write_reproduction

__all__ = ["PAPERS", "Reproduction", "reproduce", "write_reproduction"]

#: Paper key -> the module whose ``run(out_dir, *, quick, executor, progress)`` reproduces it.
PAPERS = {
    "feng2023": "needlekit.reproduce.feng2023",
    "liu2016": "needlekit.reproduce.liu2016",
    "tang": "needlekit.reproduce.tang",
    "lecture": "needlekit.reproduce.lecture",
}


def reproduce(
    paper: str,
    out_dir: str | os.PathLike,
    *,
    quick: bool = False,
    executor=None,
    progress: Callable[[str], None] | None = None,
) -> Reproduction:
    """Run one paper's experiments and write its page, JSON and results into ``out_dir``.

    Parameters
    ----------
    paper : str
        A key of :data:`PAPERS`.
    out_dir : path-like
        The folder written (created when missing).
    quick : bool
        The reduced version (under two minutes on two cores).
    executor : concurrent.futures.Executor, optional
        Runs the independent parts (trials, directions) where a part can use it.
    progress : callable, optional
        Called with one line per stage (``"[2/5] needle 1's CFRW"``).

    Returns
    -------
    Reproduction
        What was measured; ``files`` holds the paths written.
    """
    if paper not in PAPERS:
        raise InvalidInputError("paper", f"expected one of {', '.join(PAPERS)}, got {paper!r}")
    module = importlib.import_module(PAPERS[paper])
    t0 = time.perf_counter()
    rep = module.run(out_dir, quick=quick, executor=executor, progress=progress or _silent)
    rep.wall_s = time.perf_counter() - t0
    write_reproduction(rep, out_dir)
    return rep


def _silent(_line: str) -> None:
    pass
