"""One self-contained page from result files (``needlekit report RESULT... --out page.html``).

Each result file (:func:`needlekit.scenario.results.read_results`) becomes one part of the page, drawn by the
builders its own command uses, from the objects rebuilt from the file:

- a plan (``needlekit plan``, ``sweep --plan``): :func:`~.steerable_report.plan_sections`:
  summary, the independent check run again against the scenario, the motions, the path
  in the 3D anatomy;
- plans to several targets (``plan --goals``): :func:`~.steerable_report.goals_sections`,
  each target's plan checked again, and each plan's motions;
- a sweep: :func:`~.sweep_report.sweep_study_sections`, as ``needlekit sweep --report``
  draws it (the best plan checked again; the file keeps no other path, so Fig. 7 is left
  out);
- a CFRW map (``needlekit cfrw``): :func:`cfrw_sections`, the map recomputed from the
  scenario (the file keeps no blocking reasons nor entry points) and compared with the
  file's;
- a multi-needle plan: :func:`~.straight_report.straight_sections`, each needle's CFRW map
  recomputed (:func:`~.straight_report.plan_maps`) and compared with the counts in the
  file, and the independent check (:func:`~needlekit.planning.straight.verify.verify_multi`);
- a puncture study: :func:`~.puncture_report.puncture_sections`;
- a run among moving obstacles (``needlekit plan --dynamic``):
  :func:`~.dynamic_report.dynamic_sections`, the paths rebuilt from their motions, the
  moving obstacles from the scenario (their motions compared with the file's), and the
  independent check (:func:`~needlekit.planning.steerable.moving.certify_execution`) of
  the executed path and of the plan made at ``t = 0`` run again, beside the verdicts the
  file records;
- scaling curves (``needlekit bench scale``): :func:`~.scale_figures.scale_sections`, the
  record's series as measured (nothing to check again);
- a plan's execution (``needlekit execute``): :func:`~.execute_report.execute_sections`,
  the plan rebuilt from the motions the file keeps (:mod:`.result_execute`);
- an approach analysis (``needlekit approach``): :func:`~.approach_report.approach_sections`,
  the skin and obstacles meshed again from the scenario and checked against the file's
  triangles (:mod:`.result_approach`);
- Feng et al.'s protocol on a Med-RAD lung (``needlekit study feng-lungs``):
  :func:`~.feng_lungs_report.feng_lungs_sections`, from the record and the two targets'
  scenarios and sweeps the study wrote beside it (:mod:`.result_feng`).

:func:`write_result_report` takes its scenarios from the caller
(:class:`needlekit.scenario.results.ResultScenarios` loads each once, however many results
name it): the report layer draws and does not load scenarios.

The builders of the steerable parts are in :mod:`needlekit.report.result_steerable`, of the
straight ones in :mod:`needlekit.report.result_straight`, of the moving-obstacle run in
:mod:`needlekit.report.result_dynamic`; :class:`ReportPart` and what they share in
:mod:`needlekit.report.result_parts`. This module keeps the puncture and scale parts, picks
each result's builder, and writes the page.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from needlekit.errors import InvalidInputError
from needlekit.io.results import ResultFile, ResultKind
from needlekit.report.html_page import PartSection, write_report_html
from needlekit.report.result_approach import _approach_part
from needlekit.report.result_dynamic import _dynamic_part
from needlekit.report.result_execute import _execute_multi_part, _execute_part
from needlekit.report.result_feng import _feng_lungs_part
from needlekit.report.result_parts import ReportPart  # re-exported (it lived here)
from needlekit.report.result_steerable import _goals_part, _plan_part, _sweep_part
from needlekit.report.result_straight import (  # cfrw_sections re-exported
    _cfrw_part,
    _multi_part,
    cfrw_sections,
)

__all__ = ["ReportPart", "ResultReport", "cfrw_sections", "result_part", "write_result_report"]


@dataclass(frozen=True)
class ResultReport:
    """What :func:`write_result_report` wrote.

    Attributes
    ----------
    path : Path
    parts : list of ReportPart
    """

    path: Path
    parts: list = field(default_factory=list)


def _puncture_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.report.puncture_report import TITLE, puncture_sections

    summary = {k: v for k, v in rf.data.items() if k != "per_trial"}
    trials = rf.data["per_trial"]
    try:
        sections = puncture_sections(summary, trials)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        # the fields read_result checks are there: this one came later than the file
        raise InvalidInputError(
            str(rf.path),
            f"lacks a field the puncture report draws ({type(exc).__name__}: {exc}); it was "
            "written by an older needlekit: run `needlekit puncture` again",
        ) from None
    return ReportPart(
        rf,
        TITLE,
        sections,
        f"{summary['completed']} of {summary['trials']} trials completed",
    )


def _scale_part(rf: ResultFile, load) -> ReportPart:
    from needlekit.report.scale_figures import scale_sections

    d = rf.data
    try:
        sections = scale_sections(d)
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InvalidInputError(
            str(rf.path),
            f"lacks a field the scale report draws ({type(exc).__name__}: {exc}); run "
            "`needlekit bench scale` again",
        ) from None
    ran = [k for k in ("planning", "sweep", "study") if d.get(k)]
    return ReportPart(
        rf,
        "Scaling curves (needlekit bench scale)",
        sections,
        f"scaling curves: {', '.join(ran) or 'no series'}; measured {d['machine'].get('time_utc')} "
        f"at load {(d.get('load_average') or {}).get('start')}",
    )


_BUILDERS = {
    ResultKind.PLAN: _plan_part,
    ResultKind.GOALS: _goals_part,
    ResultKind.SWEEP: _sweep_part,
    ResultKind.CFRW: _cfrw_part,
    ResultKind.MULTI: _multi_part,
    ResultKind.PUNCTURE: _puncture_part,
    ResultKind.DYNAMIC: _dynamic_part,
    ResultKind.SCALE: _scale_part,
    ResultKind.EXECUTE: _execute_part,
    ResultKind.EXECUTE_MULTI: _execute_multi_part,
    ResultKind.APPROACH: _approach_part,
    ResultKind.FENG_LUNGS: _feng_lungs_part,
}


def result_part(result: ResultFile, load=None) -> ReportPart:
    """Draw one result file.

    Parameters
    ----------
    result : ResultFile
        As :func:`needlekit.scenario.results.read_result` returns it.
    load : ResultScenarios, optional
        Where the scenarios come from: ``load(path) -> Scenario``, and
        ``load.steerable_problem(scenario, **overrides)``, ``load.multi_problem(scenario)``,
        ``load.moving_case(scenario, problem)``
        (:class:`needlekit.scenario.results.ResultScenarios`; the report layer does not
        load scenarios itself). Needed by every kind that reads a scenario.

    Returns
    -------
    ReportPart

    Raises
    ------
    InvalidInputError
        The scenario does not give what the result was made from (other safety distance,
        a recomputed map that differs from the file's).
    """
    if not isinstance(result, ResultFile):
        raise InvalidInputError("result", f"expected a ResultFile, got {type(result).__name__}")
    if load is None and result.kind.needs_scenario:
        raise InvalidInputError(
            "scenarios",
            f"{result.path} ({result.kind.value}) is drawn with its scenario: pass "
            "needlekit.scenario.results.ResultScenarios()",
        )
    return _BUILDERS[result.kind](result, load)


def write_result_report(
    path: str | os.PathLike,
    results: Sequence[ResultFile],
    *,
    title: str | None = None,
    scenarios=None,
) -> ResultReport:
    """Draw result files on one self-contained HTML page, written atomically.

    One result fills the page as its own command would; several give one part each, in
    order, under a list of links.

    Parameters
    ----------
    path : path-like
        The page (``.html``).
    results : sequence of ResultFile
        As :func:`needlekit.scenario.results.read_results` returns them.
    title : str, optional
        Default: the result's own title, or the files' names.
    scenarios : ResultScenarios, optional
        Loads each scenario once, however many results name it (see :func:`result_part`);
        needed when a result reads a scenario.

    Returns
    -------
    ResultReport
    """
    if isinstance(results, ResultFile) or not results:
        raise InvalidInputError("results", "expected one or more ResultFile")
    parts = [result_part(r, scenarios) for r in results]
    if len(parts) == 1:
        sections = parts[0].sections
        title = title or parts[0].title
    else:
        sections = []
        for p in parts:
            about = f"{p.result.path}: {p.result.kind.label}"
            if p.result.scenario is not None:
                about += f", from the scenario {p.result.scenario}"
            sections += [PartSection(p.title, about + "."), *p.sections]
        title = title or "needlekit report: " + ", ".join(p.result.path.name for p in parts)
    return ResultReport(write_report_html(path, title=title, sections=sections), parts)
