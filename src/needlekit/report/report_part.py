"""What one result file contributes to a result page: :class:`ReportPart` (the contract of
the part builders of :mod:`needlekit.report.result_report`).
"""

from __future__ import annotations

from dataclasses import dataclass

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
