"""One paper's reproduction: what was measured, and its page and JSON."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from needlekit import __version__
from needlekit.io.files import staged_outputs, write_json
from needlekit.provenance import machine_info
from needlekit.report.html_page import ListSection, TableSection, TextSection, write_report_html

__all__ = ["Reproduction", "Stages", "write_reproduction"]


@dataclass
class Reproduction:
    """A paper's experiments as re-run by needlekit.

    Attributes
    ----------
    key : str
        The paper's key (``feng2023``, ``liu2016``, ``tang``, ``lecture``).
    title : str
        The page's title.
    citation : str
        The paper, as cited.
    quick : bool
        The reduced run.
    summary : str
        What was run, in a paragraph.
    comparisons : list of dict
        Rows ``quantity``, ``paper``, ``needlekit``, ``agrees`` (``yes``, ``no``,
        ``partly`` or ``-`` where the paper gives no number) and ``note``.
    setup : list of dict
        Rows ``item``, ``paper``, ``needlekit``.
    deviations : list of str
        Every way needlekit's setup differs from the paper's, each with what it moves.
    sections : list
        The paper's figures and tables as :mod:`needlekit.report.html_page` sections.
    commands : list of str
        Commands that re-run each part on its own.
    record : dict
        The measured numbers (JSON-ready).
    files : dict of str to Path
        What was written (filled in by :func:`write_reproduction` and the runners).
    wall_s : float
        How long the run took.
    """

    key: str
    title: str
    citation: str
    quick: bool
    summary: str
    comparisons: list = field(default_factory=list)
    setup: list = field(default_factory=list)
    deviations: list = field(default_factory=list)
    sections: list = field(default_factory=list)
    commands: list = field(default_factory=list)
    record: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)
    wall_s: float = 0.0


class Stages:
    """Numbered progress lines: ``[k/n] label`` with the time since the first stage."""

    def __init__(self, progress: Callable[[str], None], total: int, name: str) -> None:
        self._progress, self._total, self._name = progress, total, name
        self._k, self._t0, self._clock = 0, time.perf_counter(), time.perf_counter

    def __call__(self, label: str) -> None:
        self._k += 1
        elapsed = self._clock() - self._t0
        self._progress(f"{self._name} [{self._k}/{self._total}] {label} ({elapsed:.0f} s so far)")

    def bar(self, desc: str, total: int | None = None, unit: str = "task"):
        """A progress bar of the stage's tasks (total and time left; shown on a terminal).

        Parameters
        ----------
        desc : str
            What the tasks are (after the stage's name).
        total : int, optional
            Number of tasks, when known.
        unit : str
            A task's name in the bar.

        Returns
        -------
        callable
            ``update(result)``, one task done; ``update.set_total(n)`` sets the total
            where it is known only later (a sweep's effective directions), and
            ``update.close()`` ends the bar.
        """
        from tqdm import tqdm

        bar = tqdm(total=total, desc=f"{self._name} {desc}", unit=unit, disable=None, leave=False)

        class _Update:
            def __call__(self, _result=None) -> None:
                bar.update(1)

            def set_total(self, n: int) -> None:
                bar.total = n
                bar.refresh()

            def close(self) -> None:
                bar.close()

        return _Update()


def _machine() -> dict:
    """The benchmark records' machine description (:func:`~needlekit.provenance.machine_info`)
    with needlekit's version and the load average at the end of the run."""
    info = machine_info()
    info["needlekit"] = __version__
    info["load_average"] = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    return info


def _duration(s: float) -> str:
    m, sec = divmod(round(s), 60)
    return f"{m} min {sec} s" if m else f"{s:.1f} s"


def write_reproduction(rep: Reproduction, out_dir: str | os.PathLike) -> dict:
    """Write ``out_dir/KEY.html`` and ``out_dir/KEY.json`` (atomically, both or neither).

    Parameters
    ----------
    rep : Reproduction
    out_dir : path-like
        The folder written into.

    Returns
    -------
    dict
        ``rep.files`` with ``page`` and ``json`` added.
    """
    out = Path(out_dir)
    when = datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    machine = _machine()
    kind = "quick (reduced) run" if rep.quick else "full run"
    run_line = (
        f"{kind}, {_duration(rep.wall_s)} on {machine['cpu_count']} CPUs ({machine['cpu']}, "
        f"Python {machine['python']}, needlekit {machine['needlekit']}), {when}; load average "
        f"at the end {machine['load_average']} (1, 5, 15 min: other work on the machine "
        "slows the run)."
    )
    sections = [
        TextSection(f"{rep.citation}. {rep.summary}"),
        TextSection(run_line, heading="This run"),
        TableSection(
            "needlekit beside the paper",
            rep.comparisons,
            caption="agrees: yes, partly, no, or - where the paper gives no number to compare.",
        ),
        TableSection("The setup, side by side", rep.setup),
        ListSection(rep.deviations, heading="Deviations from the paper's setup"),
        *rep.sections,
        ListSection(rep.commands, heading="Re-run each part"),
    ]
    doc = {
        "paper": rep.key,
        "title": rep.title,
        "citation": rep.citation,
        "quick": rep.quick,
        "date": when,
        "machine": machine,
        "wall_s": rep.wall_s,
        "summary": rep.summary,
        "comparisons": rep.comparisons,
        "setup": rep.setup,
        "deviations": rep.deviations,
        "commands": rep.commands,
        "record": rep.record,
        "files": {k: str(v) for k, v in rep.files.items()},
    }
    with staged_outputs():
        rep.files["page"] = write_report_html(
            out / f"{rep.key}.html", title=rep.title, sections=sections
        )
        rep.files["json"] = out / f"{rep.key}.json"
        doc["files"].update(page=str(rep.files["page"]), json=str(rep.files["json"]))
        write_json(rep.files["json"], doc)
    return rep.files
