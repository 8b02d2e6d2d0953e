"""The effective-puncture-region study of one case: sweep, best plan, tables and report.

:func:`run_sweep_study` sweeps the start directions of a scenario with one or more
planners (Feng et al. 2023, Algorithm 1), re-checks the best plan independently and
writes:

- ``sweep.json``: Feng's Tables 2-4 (:func:`~needlekit.planning.steerable.sweep.sweeps_to_dict`);
- ``plan.json``: the best plan of the first planner (the ``needlekit plan`` format, with
  its check);
- ``report.html``: one self-contained page with the summary table, the direction spheres
  (Fig. 8), the cost per direction (Fig. 9), the best paths in the 3D scene and the best
  plan's primitives and check.

``needlekit sweep`` and ``needlekit demo`` run it.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import Interrupted, InvalidInputError
from needlekit.io.files import staged_outputs, write_json
from needlekit.io.partial import read_partial, write_partial
from needlekit.io.plans import write_plan_json
from needlekit.io.results import scenario_reference

__all__ = [
    "SweepStudy",
    "read_partial_sweep",
    "run_sweep_study",
    "sweep_settings",
    "write_partial_sweep",
]


@dataclass(frozen=True)
class SweepStudy:
    """What :func:`run_sweep_study` did.

    Attributes
    ----------
    sweeps : dict of str to SweepResult
        Per planner, in the order run.
    best : PlanResult or None
        The first planner's best plan.
    check : Verification or None
        Its independent check.
    files : dict of str to Path
        ``sweep``, and ``plan`` (when there is a best plan) and ``report`` when asked for.
    """

    sweeps: dict
    best: object
    check: object
    files: dict = field(default_factory=dict)


def run_sweep_study(
    source,
    sweep_path: str | os.PathLike,
    *,
    plan_path: str | os.PathLike | None = None,
    report_path: str | os.PathLike | None = None,
    planners: Sequence[str] = ("rcs_star",),
    directions=None,
    time_limit_s: float = DEFAULT_TIME_LIMIT_S,
    max_iterations: int | None = None,
    seed: int | None = None,
    executor=None,
    progress: Callable[[str], Callable] | None = None,
    title: str | None = None,
    options: dict | None = None,
    resume: dict | None = None,
) -> SweepStudy:
    """Sweep a scenario's start directions, check the best plan, write the files.

    Parameters
    ----------
    source : ScenarioSource
        The scenario and its overrides (workers rebuild the problem from it).
    sweep_path : str or path
        Where to write the sweep table (``sweep.json``).
    plan_path, report_path : str or path, optional
        Where to write the best plan (``plan.json``) and the report (``report.html``).
    planners : sequence of str or Planner
        Planners to compare, by name (built here, once, with ``options`` and ``seed``) or
        built already (:func:`~needlekit.planning.steerable.solve.build_planner`); the
        first one gives the best plan.
    directions : array_like, shape (n, 3), optional
        Candidate directions (default: Feng's 544 on a Fibonacci sphere).
    time_limit_s : float
        Budget per direction and planner.
    max_iterations : int, optional
        Iteration budget per direction besides the time limit (reproducible results).
    seed : int, optional
        Seed of the randomised planners given by name (it wins over their options').
    executor : concurrent.futures.Executor, optional
        Runs the directions (:func:`needlekit.batch.open_executor`); default: this process.
    progress : callable, optional
        ``progress(planner)`` returns a callable that is called once per finished
        direction (e.g. a progress bar's update).
    title : str, optional
        Report title.
    options : dict, optional
        Per planner name, its settings (e.g. ``{"rrt": {"connection": "arc"}}``), for
        the planners given by name. ``sweep.json`` records every planner's options as it
        ran (``options``), and the seed given (``seed``).
    resume : dict, optional
        Per planner name, the results an interrupted run finished (one per direction,
        ``None`` where one is still to do: :func:`read_partial_sweep`); they are kept.

    Returns
    -------
    SweepStudy

    Raises
    ------
    InvalidInputError
        No planners, or an unknown one.
    Interrupted
        Ctrl-C: the directions finished are written to ``sweep_path`` as a result marked
        ``"partial": true`` (no plan file, no report), which ``resume`` carries on from.
    """
    from needlekit.planning.steerable.solve import build_planner
    from needlekit.planning.steerable.sweep import sphere_directions, sweep, sweeps_to_dict
    from needlekit.planning.steerable.verify import verify_plan

    given = list(dict.fromkeys(planners))
    if not given:
        raise InvalidInputError("planners", "expected at least one planner")
    built = {}  # once each, before any work: unknown planners and options fail here
    for p in given:
        if isinstance(p, str):
            built[p] = build_planner(p, (options or {}).get(p), seed=seed)
        else:
            built[p.name] = p
    sc, problem = source.cached()
    dirs = sphere_directions() if directions is None else np.asarray(directions, dtype=float)
    sweeps = {}
    head = {
        "scenario": scenario_reference(source.scenario_path, sweep_path),
        **sweep_settings(built, time_limit_s, max_iterations, seed, problem.safety_margin_mm),
    }
    options = head["options"]
    for name, planner in built.items():
        try:
            sweeps[name] = sweep(
                problem,
                planner,
                directions=dirs,
                time_limit_s=time_limit_s,
                max_iterations=max_iterations,
                executor=executor,
                source=source,
                progress=None if progress is None else progress(name),
                done=(resume or {}).get(name),
            )
        except Interrupted as exc:  # write what is done, and say so (raises Interrupted)
            sweeps[name] = exc.partial
            _write_partial(sweep_path, head, sweeps, built, resume)
    best = sweeps[next(iter(built))].best
    check = None
    files = {}
    record = {**head, **sweeps_to_dict(sweeps)}
    if resume is not None:  # each summary's time_s counts this run's part alone
        record["resumed"] = True
    if best is not None:
        p = problem.with_start_pose(best.start_pose)
        check = verify_plan(p, best.plan, expected_cost_mm=best.cost_mm)
    # all files or none: a report that cannot be written leaves the old sweep.json too
    with staged_outputs():
        files["sweep"] = write_json(sweep_path, record)
        if best is not None and plan_path is not None:
            files["plan"] = write_plan_json(
                plan_path,
                best,
                scenario=scenario_reference(source.scenario_path, plan_path),
                # the sweep chose the direction: `verify --any-start-direction` checks it
                start_direction="swept",
                check={"ok": check.ok, "violations": list(check.violations), **check.metrics},
            )
        if report_path is not None:
            files["report"] = _write_report(
                report_path,
                title or f"Effective puncture region: {sc.name}",
                sweeps,
                best,
                check,
                problem,
                options,
            )
    return SweepStudy(sweeps, best, check, files)


def _write_partial(sweep_path, head: dict, sweeps: dict, built: dict, resume) -> None:
    """The record of an interrupted sweep: every planner's finished directions (a planner
    not reached keeps what ``resume`` gave it), marked partial; the message says how much
    is done and how to carry on."""
    from needlekit.planning.steerable.sweep import SweepResult, sweep_stats

    first = next(iter(sweeps.values()))
    n = len(first.directions)
    for name in built:
        if name not in sweeps:
            res = list((resume or {}).get(name) or [None] * n)
            stats = sweep_stats(first.directions, first.effective, res)
            sweeps[name] = SweepResult(first.directions, first.effective, res, name, stats)
    written = write_partial_sweep(sweep_path, head, sweeps)
    total = int(first.effective.sum()) * len(built)
    done = sum(
        r is not None for s in sweeps.values() for i, r in enumerate(s.results) if s.effective[i]
    )
    raise Interrupted(
        f"{done} of {total} effective directions done ({', '.join(built)}); written to "
        f"{written} marked partial; the same command with --resume carries on",
        partial=sweeps,
    )


def write_partial_sweep(path, head: dict, sweeps: dict):
    """An interrupted sweep's record: ``head`` (:func:`sweep_settings` and the scenario),
    the sweeps so far as ``sweep.json`` holds them and every plan found so far, marked
    partial and signed (:func:`needlekit.io.partial.write_partial`), beside ``path``
    (``sweep.partial.json``); what :func:`read_partial_sweep` reads back.

    Parameters
    ----------
    path : path-like
        The complete sweep's file.
    head : dict
    sweeps : dict of str to SweepResult

    Returns
    -------
    Path
    """
    from needlekit.planning.steerable.sweep_result import solved_plans_to_dict, sweeps_to_dict

    record = {**head, **sweeps_to_dict(sweeps), "solved_plans": solved_plans_to_dict(sweeps)}
    return write_partial(path, record)


def sweep_settings(
    planners: dict, time_limit_s, max_iterations, seed, safety_margin_mm: float | None = None
) -> dict:
    """The settings a sweep record holds beside its directions (and a resumed run must
    share): ``time_limit_s``, ``max_iterations``, ``seed``, each planner's ``options``, and
    the ``safety_margin_mm`` the plans keep (when given).

    Parameters
    ----------
    planners : dict of str to Planner
        The built planners, by name.
    time_limit_s : float
    max_iterations : int or None
    seed : int or None
    safety_margin_mm : float, optional
        The problem's margin (the scenario's, or ``--safety-margin-mm``).

    Returns
    -------
    dict
    """
    out = {
        "time_limit_s": time_limit_s,
        "max_iterations": max_iterations,
        "seed": seed,
        "options": {name: _options_of(p) for name, p in planners.items()},
    }
    if safety_margin_mm is not None:
        out["safety_margin_mm"] = float(safety_margin_mm)
    return out


def read_partial_sweep(path, planners, directions, settings: dict | None = None) -> dict:
    """What an interrupted sweep finished, read back to carry on (``sweep --resume``):
    per planner, one result per direction (``None`` where still to do).

    Parameters
    ----------
    path : path-like
        The complete sweep's file (``sweep.json``); the record is read from beside it
        (``sweep.partial.json``, marked ``"partial": true`` and signed:
        :func:`needlekit.io.partial.write_partial`).
    planners : sequence of str
        The planners of the run to resume: the file's, in its order.
    directions : ndarray, shape (n, 3)
        The run's directions: the file's.
    settings : dict, optional
        The run's other settings (:func:`sweep_settings`): the file's.

    Returns
    -------
    dict of str to list

    Raises
    ------
    InvalidInputError
        (named ``--resume``) No such file, not a partial sweep, changed since it was
        written, or other planners, directions or settings than this run's.
    """
    from needlekit.planning.steerable.sweep_result import solved_plans_from_dict, sweeps_from_dict

    data = read_partial(path, "sweep", settings or {})
    sweeps = sweeps_from_dict(data, str(path))
    solved_plans_from_dict(sweeps, data.get("solved_plans") or {}, f"{path}: solved_plans")
    if list(sweeps) != list(planners):
        raise InvalidInputError(
            "--resume", f"{path} swept {', '.join(sweeps)}; this run asks for {', '.join(planners)}"
        )
    dirs = next(iter(sweeps.values())).directions
    if dirs.shape != np.shape(directions) or not np.allclose(dirs, directions, atol=1e-9):
        raise InvalidInputError(
            "--resume", f"{path} swept other directions ({len(dirs)}) than this run asks for"
        )
    return {name: list(s.results) for name, s in sweeps.items()}


def _options_of(planner) -> dict:
    """A built planner's options as it runs with them (JSON-ready)."""
    opts = getattr(planner, "options", None)
    if dataclasses.is_dataclass(opts) and not isinstance(opts, type):
        return dataclasses.asdict(opts)
    return {}


def _write_report(path, title: str, sweeps: dict, best, check, problem, options):
    from needlekit.report.sweep_report import sweep_study_sections, write_report_html

    sections = sweep_study_sections(sweeps, problem, options=options, best=best, check=check)
    return write_report_html(path, title=title, sections=sections)
