"""What each part builder of :mod:`needlekit.report.result_report` returns, and what
several of them share.

:class:`ReportPart` is one result drawn; :func:`_steerable_problem` gives a result's
steerable problem from its scenario (the plan, goals, sweep and moving-obstacle parts use
it). The builders themselves are in :mod:`needlekit.report.result_steerable`,
:mod:`needlekit.report.result_straight`, :mod:`needlekit.report.result_dynamic` and
:mod:`needlekit.report.result_report`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile

__all__ = ["ReportPart"]


@dataclass(frozen=True)
class ReportPart:
    """One result drawn.

    Attributes
    ----------
    result : ResultFile
    title : str
        What its own command titles its page.
    sections : list
        For :func:`~needlekit.report.html_page.write_report_html`.
    summary : str
        One line for the terminal.
    checks_ok : bool or None
        Whether every independent check run again passed (None: nothing to check).
    """

    result: ResultFile
    title: str
    sections: list
    summary: str
    checks_ok: bool | None = None


def _steerable_problem(load, sc, rf: ResultFile, start_pose=None, goal_mm=None):
    """The scenario's steerable problem, from the result's start pose and goal when given
    (a plan is checked against the goal it was made for)."""
    overrides: dict = {}
    if start_pose is not None:
        overrides |= {"start_pose": np.asarray(start_pose, float), "start_point_mm": None}
    if goal_mm is not None:
        overrides["goal_mm"] = np.asarray(goal_mm, float)
    try:
        return load.steerable_problem(sc, **overrides)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{rf.scenario}: {exc.field}", exc.reason) from None
