"""Result files read back: which command wrote a JSON file, every field checked by the
result types' own ``from_dict``, and the scenario it names located and checked, all before
any anatomy is loaded; errors name the file and the field, or the flag that fixes them.

:func:`read_result`, :func:`read_results` give :class:`~needlekit.io.results.ResultFile`
(whose kinds :mod:`needlekit.io.results` tells apart); :func:`read_plan_json` reads a
plan back to verify or export it. :class:`ResultScenarios` loads each scenario a report
needs once and builds its problems (what :mod:`needlekit.report.result_report` asks
for).

The command line reads result files before any anatomy or planner module (numba) is
loaded, so that a file it cannot read fails fast: the result types and the scenario
loading are imported by the functions that use them.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.files import read_json_object
from needlekit.io.results import FENG_GOAL_FILES, ResultFile, ResultKind, result_kind
from needlekit.io.scenario_schema import read_scenario_document
from needlekit.planning.straight.approach import ApproachAnalysis
from needlekit.records import field_of, trial_solved
from needlekit.scenario.dynamic import DYNAMIC_SETTINGS, dynamic_settings, moving_case
from needlekit.scenario.problems import problem_from_scenario
from needlekit.scenario.straight import multi_problem_from_scenario

__all__ = ["ResultScenarios", "read_plan_json", "read_result", "read_results"]


def read_plan_json(path: str | os.PathLike):
    """Read a plan file back: the plan and the goal it was made for.

    Parameters
    ----------
    path : path-like

    Returns
    -------
    plan : needlekit.planning.steerable.plan.SteerablePlan or None
        None when the file holds no plan (e.g. status ``timeout``).
    goal_mm : ndarray, shape (3,)
    data : dict
        The whole document.

    Raises
    ------
    InvalidInputError
        Missing file, bad JSON or a field not as the format says (named).
    """
    from needlekit.planning.steerable.plan import plan_from_dict

    p = Path(path)
    data = read_json_object(p, "plan")
    plan, goal = plan_from_dict(data, p.name)
    return plan, goal, data


def _check_cfrw(data: dict, where: str) -> None:
    from needlekit.planning.straight.entry import Entry

    for key in ("gamma_mm", "needle_radius_mm", "max_length_mm"):
        field_of(data, key, where)
    field_of(data, "target_mm", where, "point")
    field_of(data, "world_T_sigma", where, "pose")
    theta = np.asarray(field_of(data, "theta_deg", where, "list"), dtype=float)
    phi = np.asarray(field_of(data, "phi_deg", where, "list"), dtype=float)
    if theta.ndim != 1 or phi.ndim != 1 or not (len(theta) and len(phi)):
        raise InvalidInputError(f"{where}: theta_deg", "expected a grid of angles")
    feasible = np.asarray(field_of(data, "feasible", where, "list"))
    if feasible.shape != (len(theta), len(phi)):
        msg = f"expected a {len(theta)} x {len(phi)} grid (theta_deg by phi_deg)"
        raise InvalidInputError(f"{where}: feasible", msg)
    field_of(data, "counts", where, "dict")
    for h in field_of(data, "layers", where, "dict", optional=True) or {}:
        try:
            ok = float(h) > 0
        except ValueError:
            ok = False
        if not ok:
            raise InvalidInputError(f"{where}: layers", f"expected heights > 0 (mm), got {h!r}")
    for name, entry in (field_of(data, "best", where, "dict", optional=True) or {}).items():
        if entry is not None:
            Entry.from_dict(entry, f"{where}: best.{name}")
    field_of(data, "resolution_deg", where, optional=True)
    field_of(data, "target", where, "int", optional=True)


#: The series of an example trial's log that the puncture report draws.
_PUNCTURE_SERIES = (
    "t_s", "to_target_mm", "desired_to_target_mm", "to_line_mm", "measured_to_line_mm",
    "angle_deg", "measured_angle_deg", "base_error_mm", "base_rotation_error_deg",
    "needle_error_mm", "needle_rotation_error_deg", "tip_estimate_error_mm",
)  # fmt: skip


def _check_puncture(data: dict, where: str) -> None:
    for key in ("trials", "seed", "completed"):
        field_of(data, key, where, "int")
    aborted = field_of(data, "aborted", where, "dict")
    field_of(aborted, "count", f"{where}: aborted", "int")
    field_of(aborted, "trials", f"{where}: aborted", "list")
    paper = field_of(data, "paper", where, "dict")
    for key in ("position_error_mm", "angle_error_deg"):
        for source, stats in (
            (where, field_of(data, key, where, "dict")),
            (f"{where}: paper", field_of(paper, key, f"{where}: paper", "dict")),
        ):
            for name in ("mean", "sd", "min", "max"):
                field_of(stats, name, f"{source}.{key}", optional=source == where)
    v = field_of(data, "constraint_violations", where, "dict")
    at = f"{where}: constraint_violations"
    field_of(v, "total", at, "int")
    for key in ("position_mm", "angle_deg"):
        field_of(field_of(v, "tolerance", at, "dict"), key, f"{at}.tolerance")
    for key in ("guide_cylinder", "cone", "plane", "patient_cylinder"):
        field_of(field_of(v, key, at, "dict"), "count", f"{at}.{key}", "int")
        field_of(v[key], "trials", f"{at}.{key}", "list")
    field_of(data, "scenario", where, "dict")
    opts = field_of(data, "options", where, "dict")
    for key in ("exact_sensors", "stability_radius_mm", "history_keyframes", "guide_samples"):
        if key not in opts:
            raise InvalidInputError(f"{where}: options.{key}", "missing")
    for i, t in enumerate(field_of(data, "per_trial", where, "list")):
        at = f"{where}: per_trial[{i}]"
        field_of(t, "trial", at, "int")
        done = trial_solved(field_of(t, "status", at, "str"))
        phases = field_of(t, "phase_times_s", at, "dict")
        for key in ("position_error_mm", "angle_error_deg"):
            field_of(t, key, at, optional=not done)
        log = field_of(t, "log", at, "dict", optional=True)
        if log is None or "puncture" not in phases:
            continue  # not an example trial: no figure draws it
        field_of(phases, "puncture", f"{at}: phase_times_s")
        field_of(t, "octant", at, "int")
        n = len(field_of(log, "t_s", f"{at}: log", "list"))
        for key in _PUNCTURE_SERIES:
            if len(field_of(log, key, f"{at}: log", "list")) != n:
                raise InvalidInputError(f"{at}: log.{key}", f"expected {n} values, as t_s")
        if "tip_mm" in log:  # the neck figure carries the tip path onto the phantom
            field_of(t, "target_mm", at, "point")
            field_of(t, "guide_direction", at, "point")


#: Per series of a scale record: its list, and the numbers every entry of it holds.
_SCALE_SERIES = {
    "planning": ("rows", ("straight_distance_mm", "planner_wall_s")),
    "sweep": ("points", ("directions", "workers", "wall_s", "planner_s_sum", "prep_s")),
    "study": ("points", ("trials", "workers", "wall_s")),
}


def _check_scale(data: dict, where: str) -> None:
    """A ``needlekit bench scale`` record: its machine, and each series run (a series may be
    null: not run) with the numbers its figure draws."""
    if data.get("benchmark") != "scale":
        raise InvalidInputError(
            f"{where}: benchmark", f"expected 'scale', got {data.get('benchmark')!r}"
        )
    machine = field_of(data, "machine", where, "dict")
    field_of(machine, "load_average", f"{where}: machine", "list")
    for series, (key, numbers) in _SCALE_SERIES.items():
        block = field_of(data, series, where, "dict", optional=True)
        if block is None:
            continue
        field_of(block, "fits", f"{where}: {series}", "dict")
        for i, entry in enumerate(field_of(block, key, f"{where}: {series}", "list")):
            for name in numbers:
                field_of(entry, name, f"{where}: {series}.{key}[{i}]")


def _short(text: str, limit: int = 120) -> str:
    """A path from a file, quoted, at most ``limit`` characters (the rest elided)."""
    return repr(text if len(text) <= limit else text[: limit - 3] + "...")


def _check_execute(data: dict, where: str) -> None:
    """An ``execute.json``: the plan's motions, the summary the page tabulates and each
    trial that ran with its two paths."""
    prims = field_of(data, "plan_primitives", where, "list")
    if not prims or not all(isinstance(p, list) and len(p) == 3 for p in prims):
        raise InvalidInputError(
            f"{where}: plan_primitives", "expected a list of [spin, curvature, length]"
        )
    field_of(data, "seed", where, "int")
    field_of(data, "options", where, "dict")
    s = field_of(data, "summary", where, "dict")
    for key in ("trials", "margin_mm", "open_loop", "closed_loop", "crashed", "literature"):
        if key not in s:
            raise InvalidInputError(f"{where}: summary.{key}", "missing")
    for i, t in enumerate(field_of(data, "trials", where, "list")):
        at = f"{where}: trials[{i}]"
        field_of(t, "trial", at, "int")
        if "closed_loop" not in t:
            continue  # a trial that crashed: the summary lists it
        for loop in ("open_loop", "closed_loop"):
            run = field_of(t, loop, at, "dict")
            field_of(run, "points_mm", f"{at}.{loop}", "list")
            field_of(run, "final_error_mm", f"{at}.{loop}")
    field_of(data, "scenario_file", where, "str", optional=True)


def _check_execute_multi(data: dict, where: str) -> None:
    """A multi-needle ``execute.json``: the plan's needles and the summary the page draws."""
    for i, n in enumerate(field_of(data, "plan_needles", where, "list")):
        at = f"{where}: plan_needles[{i}]"
        field_of(n, "order", at, "int")
        field_of(n, "entry_mm", at, "point")
        field_of(n, "target_mm", at, "point")
    s = field_of(data, "summary", where, "dict")
    for key in ("trials", "crashed", "touched", "constraints"):
        if key not in s:
            raise InvalidInputError(f"{where}: summary.{key}", "missing")
    field_of(data, "trials", where, "list")
    field_of(data, "scenario_file", where, "str", optional=True)


def _check_feng_lungs(data: dict, where: str) -> None:
    """A ``feng_lungs.json``: the settings, Feng's figures and each target's tables and
    checks, what its page draws."""
    settings = field_of(data, "settings", where, "dict")
    at = f"{where}: settings"
    field_of(settings, "directions", at, "int")
    field_of(settings, "options", at, "dict")
    field_of(settings, "needle", at, "dict")
    if not all(isinstance(p, str) for p in field_of(settings, "planners", at, "list")):
        raise InvalidInputError(f"{at}.planners", "expected planner names")
    field_of(data, "case", where, "dict")
    field_of(field_of(data, "feng", where, "dict"), "table4", f"{where}: feng", "dict")
    goals = field_of(data, "goals", where, "dict")
    if not goals:
        raise InvalidInputError(f"{where}: goals", "expected the study's targets")
    for g, rec in goals.items():
        at = f"{where}: goals.{g}"
        field_of(rec, "goal_mm", at, "point")
        for name, t in field_of(rec, "table4", at, "dict").items():
            field_of(t, "n_solved", f"{at}.table4.{name}", "int")
        for name, c in field_of(rec, "checks", at, "dict").items():
            for key in ("passed", "solved"):
                field_of(c, key, f"{at}.checks.{name}", "int")


def _feng_lungs_files(data: dict, p: Path) -> None:
    """The scenario and sweep of each target the study wrote beside its record, read and
    checked (cheap: no anatomy is read); a sweep must keep every solved plan."""
    from needlekit.planning.steerable.sweep_result import solved_plans_from_dict, sweeps_from_dict

    for g in data["goals"]:
        scenario, sweep = (p.parent / g / name for name in FENG_GOAL_FILES)
        for f in (scenario, sweep):
            if not f.is_file():
                raise InvalidInputError(
                    str(p),
                    f"the study's {g}/{f.name} is not beside it ({_short(str(f))}): "
                    "`needlekit report` draws the record in the folder the study wrote",
                )
        read_scenario_document(scenario)
        doc = read_json_object(sweep, "sweep")
        where = f"{g}/{sweep.name}"
        if not isinstance(doc.get("solved_plans"), dict):
            raise InvalidInputError(
                f"{where}: solved_plans",
                "missing: the study was run before it kept every solved path, which its page "
                "draws (Fig. 7); run `needlekit study feng-lungs` again",
            )
        solved_plans_from_dict(sweeps_from_dict(doc, where), doc["solved_plans"], where)


def _locate_scenario(data: dict, path: Path, flag: str, key: str = "scenario") -> Path:
    """The scenario a result names, relative to the result's own folder (as the commands
    write it: :func:`needlekit.io.results.scenario_reference`), never to the working
    folder: the same result file reads the same scenario wherever the report runs."""
    named = data.get(key)
    if not isinstance(named, str) or not named or "\0" in named:
        if key == "scenario_file":
            raise InvalidInputError(
                flag,
                f"{path}: the execution names no scenario file (written before needlekit "
                f"kept it); give the scenario with {flag} (a steerable one: or draw it with "
                "its plan.json)",
            )
        raise InvalidInputError(flag, f"{path}: the result names no scenario; give it with {flag}")
    located = path.parent / named  # an absolute path stays itself
    if located.is_file():
        return located
    raise InvalidInputError(
        flag,
        f"{path} names the scenario {_short(named)} (relative to the result: "
        f"{_short(str(located))}), which is not there; give its path with {flag}",
    )


def _check_kind(kind: ResultKind, data: dict, where: str) -> None:
    """Every field of a result checked by its type's ``from_dict`` (or, for kinds with no
    type, here)."""
    from needlekit.planning.steerable.dynamic_record import DynamicRecord
    from needlekit.planning.steerable.result import PlanResult, goals_from_dict
    from needlekit.planning.steerable.sweep_result import sweeps_from_dict
    from needlekit.planning.straight.ablation import AblationOutcome
    from needlekit.planning.straight.sequence import MultiNeedlePlan

    if kind is ResultKind.PLAN:
        PlanResult.from_dict(data, where)
    elif kind is ResultKind.GOALS:
        goals_from_dict(data, where)
    elif kind is ResultKind.SWEEP:
        sweeps_from_dict(data, where)
        field_of(data, "options", where, "dict", optional=True)
    elif kind is ResultKind.CFRW:
        _check_cfrw(data, where)
    elif kind is ResultKind.MULTI:
        MultiNeedlePlan.from_dict(data, where)
        AblationOutcome.from_dict(data.get("coverage"), f"{where}: coverage")
        field_of(data, "resolution_deg", where, optional=True)
    elif kind is ResultKind.DYNAMIC:
        DynamicRecord.from_dict(data, where)
    elif kind is ResultKind.SCALE:
        _check_scale(data, where)
    elif kind is ResultKind.EXECUTE:
        _check_execute(data, where)
    elif kind is ResultKind.EXECUTE_MULTI:
        _check_execute_multi(data, where)
    elif kind is ResultKind.APPROACH:
        ApproachAnalysis.from_dict(data, where)
        field_of(data, "max_cells", where, "int", optional=True)
    elif kind is ResultKind.FENG_LUNGS:
        _check_feng_lungs(data, where)
    else:
        _check_puncture(data, where)


def _check_dynamic_scenario(data: dict, p: Path, located: Path, doc: dict, where: str) -> None:
    """The scenario of a run among moving obstacles has moving structures, and its
    ``dynamic`` block goes with the run's settings (cheap: no anatomy is read)."""
    if not any(isinstance(s, dict) and "moving" in s for s in doc.get("structures", [])):
        msg = f"{located} has no moving structure; {p.name} was made from another scenario"
        raise InvalidInputError(where, msg)
    try:
        dynamic_settings(located, {k: data["settings"].get(k) for k in DYNAMIC_SETTINGS})
    except InvalidInputError as exc:
        msg = f"the run's settings do not go with the dynamic block of {located}: {exc}"
        raise InvalidInputError(where, msg) from None


def read_result(
    path: str | os.PathLike, *, scenario: str | os.PathLike | None = None, flag: str = "scenario"
) -> ResultFile:
    """Read a result file, find its kind, check its fields and locate its scenario.

    Nothing heavy happens here (no anatomy is loaded): every error a file can cause is
    raised before a report starts its work. The scenario file is read and checked against
    the schema.

    Parameters
    ----------
    path : path-like
    scenario : path-like, optional
        The scenario to use instead of the one the file names (it moved).
    flag : str
        How messages name the way to give ``scenario`` (``"--scenario"`` on the command line).

    Returns
    -------
    ResultFile

    Raises
    ------
    InvalidInputError
        A missing file, not JSON, a document of no known kind, a field not as its kind
        writes it (named), or a scenario that cannot be found or is invalid.
    """
    p = Path(path)
    return _read(p, read_json_object(p, "result"), scenario, flag)


def _read(p: Path, data: dict, scenario, flag: str) -> ResultFile:
    kind = result_kind(data, str(p))
    _check_kind(kind, data, p.name)
    located = None
    if kind.needs_scenario:
        executions = (ResultKind.EXECUTE, ResultKind.EXECUTE_MULTI)
        key = "scenario_file" if kind in executions else "scenario"
        located = Path(scenario) if scenario is not None else _locate_scenario(data, p, flag, key)
        doc = read_scenario_document(located)
        straight = (
            ResultKind.CFRW,
            ResultKind.MULTI,
            ResultKind.EXECUTE_MULTI,
            ResultKind.APPROACH,
        )
        if kind in straight and not doc.get("straight"):
            msg = f"{located} has no straight block; {p.name} was made from another scenario"
            raise InvalidInputError(flag if scenario is not None else str(p), msg)
        if kind is ResultKind.DYNAMIC:
            where = flag if scenario is not None else str(p)
            _check_dynamic_scenario(data, p, located, doc, where)
    if kind is ResultKind.FENG_LUNGS:
        _feng_lungs_files(data, p)
    return ResultFile(p, kind, data, located)


def read_results(
    paths: Sequence[str | os.PathLike],
    scenarios: Sequence[str | os.PathLike] = (),
    *,
    flag: str = "scenario",
) -> list[ResultFile]:
    """Read several result files (:func:`read_result`), with scenario overrides.

    Parameters
    ----------
    paths : sequence of path-like
    scenarios : sequence of path-like
        None: each result's own scenario. One: for every result that needs a scenario.
        Several: one per such result, in order.
    flag : str
        How messages name the scenario overrides.

    Returns
    -------
    list of ResultFile

    Raises
    ------
    InvalidInputError
        As :func:`read_result`, or a number of scenarios that matches neither rule.
    """
    paths = [Path(p) for p in paths]
    if not paths:
        raise InvalidInputError("results", "expected one or more result files")
    docs = [(p, read_json_object(p, "result")) for p in paths]
    needing = [i for i, (p, d) in enumerate(docs) if result_kind(d, str(p)).needs_scenario]
    scenarios = list(scenarios)
    if scenarios and not needing:
        raise InvalidInputError(flag, "given, but none of the results reads a scenario")
    if len(scenarios) > 1 and len(scenarios) != len(needing):
        raise InvalidInputError(
            flag,
            f"given {len(scenarios)} times for {len(needing)} results that read a scenario; "
            "give it once (for all) or once per such result, in order",
        )
    chosen: dict[int, Path | None] = {i: None for i in range(len(paths))}
    for k, i in enumerate(needing):
        if scenarios:
            chosen[i] = Path(scenarios[k if len(scenarios) > 1 else 0])
    for i, (p, d) in enumerate(docs):  # an execution that names no scenario file: its plan's
        if chosen[i] is None and result_kind(d, str(p)) is ResultKind.EXECUTE:
            if not d.get("scenario_file"):
                chosen[i] = _plan_scenario(d, docs, flag)
    return [_read(p, d, chosen[i], flag) for i, (p, d) in enumerate(docs)]


def _plan_scenario(execution: dict, docs, flag: str) -> Path | None:
    """The scenario of the plan, among ``docs``, whose motions the execution carried out
    (None when no plan there has them)."""
    prims = np.asarray(execution.get("plan_primitives") or [], dtype=float)
    for p, d in docs:
        if result_kind(d, str(p)) is not ResultKind.PLAN:
            continue
        keys = ("rotation_rad", "curvature_per_mm", "length_mm")
        try:
            theirs = np.array([[m[k] for k in keys] for m in d.get("primitives") or []], float)
        except (KeyError, TypeError, ValueError):
            continue  # its reader names what is wrong
        if theirs.shape == prims.shape and np.allclose(theirs, prims, rtol=0.0, atol=1e-9):
            return _locate_scenario(d, p, flag)
    return None


class ResultScenarios:
    """The scenarios of the results a report draws, each loaded once (a Med-RAD patient
    takes tens of seconds), and the problems built from them: what
    :func:`needlekit.report.result_report.write_result_report` asks its ``scenarios`` for.

    Parameters
    ----------
    cache_dir : path-like, optional
        Prepared-anatomy cache of Med-RAD scenarios (default: the user cache).
    use_cache : bool
    """

    def __init__(self, cache_dir: str | os.PathLike | None = None, use_cache: bool = True):
        self.cache_dir, self.use_cache, self.loaded = cache_dir, use_cache, {}

    def __call__(self, path: str | os.PathLike):
        """The scenario of ``path``, loaded once.

        Parameters
        ----------
        path : path-like

        Returns
        -------
        needlekit.scenario.loading.Scenario
        """
        from needlekit.scenario.loading import load_scenario

        key = os.path.realpath(path)
        if key not in self.loaded:
            self.loaded[key] = load_scenario(
                path, cache_dir=self.cache_dir, use_cache=self.use_cache
            )
        return self.loaded[key]

    def steerable_problem(self, scenario, **overrides):
        """:func:`~needlekit.scenario.problems.problem_from_scenario`.

        Parameters
        ----------
        scenario : Scenario
        **overrides
            Problem attributes (the result's start pose and goal).

        Returns
        -------
        SteerableProblem
        """
        return problem_from_scenario(scenario, **overrides)

    def multi_problem(self, scenario):
        """:func:`~needlekit.scenario.straight.multi_problem_from_scenario`.

        Parameters
        ----------
        scenario : Scenario

        Returns
        -------
        tuple
            ``(MultiNeedleProblem, options)``.
        """
        return multi_problem_from_scenario(scenario)

    def moving_case(self, scenario, problem):
        """The scenario's moving case (:func:`~needlekit.scenario.dynamic.moving_case`)
        from a scenario and problem already built.

        Parameters
        ----------
        scenario : Scenario
        problem : SteerableProblem
            Its steerable problem (from :meth:`steerable_problem`).

        Returns
        -------
        tuple
            ``(scenario, static problem, moving obstacles)``.
        """
        return moving_case(_Loaded(scenario, problem))


class _Loaded:
    """A loaded scenario and its problem, handed to :func:`moving_case` as a
    :class:`~needlekit.scenario.problems.ScenarioSource` hands them."""

    def __init__(self, scenario, problem) -> None:
        self.scenario, self.problem = scenario, problem

    def load(self, document=None):  # loaded already: the document is not needed
        return self.scenario, self.problem
