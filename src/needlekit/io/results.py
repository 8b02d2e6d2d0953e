"""Result files read back: which command wrote a JSON file, checked before any work.

The commands write their results as JSON (``plan.json``, ``sweep.json``, ``cfrw.json``,
``multi.json``, ``puncture.json``, the ``dynamic.json`` of ``plan --dynamic``, the
``scale.json`` of ``bench scale``);
``needlekit report`` draws any of them again. Here:

- :func:`result_kind`: the kind of a result document, from the fields that only that kind
  has (:data:`KIND_FIELDS`);
- :func:`read_result`, :func:`read_results`: a file read, its kind found, every field the
  report uses checked (the planning objects rebuilt by :mod:`needlekit.io.records`), and
  the scenario it names located and checked against the schema, all before any anatomy is
  loaded; errors name the file and the field, or the flag that fixes them.

A sweep file keeps each planner's best plan, not every direction's path; CFRW and
multi-needle files keep no blocking reason per direction nor entry points (the report
recomputes the maps from the scenario); a run among moving obstacles keeps the motions,
not the obstacles' shapes (the scenario gives them).
"""

from __future__ import annotations

import enum
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.files import read_json_object
from needlekit.io.records import (
    coverage_from_dict,
    dynamic_from_dict,
    entry_from_dict,
    field_of,
    goals_from_dict,
    multi_plan_from_dict,
    plan_result_from_dict,
    sweeps_from_dict,
)

__all__ = ["KIND_FIELDS", "ResultFile", "ResultKind", "read_result", "read_results", "result_kind"]


class ResultKind(enum.Enum):
    """What wrote a result file."""

    PLAN = "plan"  # needlekit plan, or sweep --plan
    GOALS = "goals"  # needlekit plan --goals
    SWEEP = "sweep"
    CFRW = "cfrw"
    MULTI = "multi"
    PUNCTURE = "puncture"
    DYNAMIC = "dynamic"  # needlekit plan --dynamic
    SCALE = "scale"  # needlekit bench scale

    @property
    def label(self) -> str:
        """The kind in words, with the command that writes it."""
        return _LABELS[self]

    @property
    def needs_scenario(self) -> bool:
        """Whether drawing it needs the scenario it was made from."""
        return self not in (ResultKind.PUNCTURE, ResultKind.SCALE)


_LABELS = {
    ResultKind.PLAN: "steerable-needle plan (needlekit plan)",
    ResultKind.GOALS: "plans to several targets (needlekit plan --goals)",
    ResultKind.SWEEP: "start-direction sweep (needlekit sweep)",
    ResultKind.CFRW: "collision-free reachable workspace (needlekit cfrw)",
    ResultKind.MULTI: "straight multi-needle plan (needlekit multi)",
    ResultKind.PUNCTURE: "puncture simulation study (needlekit puncture)",
    ResultKind.DYNAMIC: "re-planning among moving obstacles (needlekit plan --dynamic)",
    ResultKind.SCALE: "scaling curves (needlekit bench scale)",
}

#: The top-level fields that mark each kind, tried in this order (a sweep's best plans and
#: the targets of ``plan --goals`` hold plans, so those kinds come before the plan).
KIND_FIELDS: dict[ResultKind, tuple[str, ...]] = {
    ResultKind.PUNCTURE: ("per_trial", "paper", "options", "trials"),
    ResultKind.SWEEP: ("planners", "summary", "directions", "best_plans"),
    ResultKind.GOALS: ("targets", "mode", "planner"),
    ResultKind.MULTI: ("needles", "order", "gamma_mm"),
    ResultKind.CFRW: ("feasible", "theta_deg", "phi_deg", "world_T_sigma"),
    ResultKind.DYNAMIC: ("moving", "executed", "cycles", "settings"),
    ResultKind.PLAN: ("status", "primitives", "start_pose", "goal_mm"),
    ResultKind.SCALE: ("benchmark", "planning", "sweep", "study", "machine"),
}

#: Other needlekit records, named in the error when one is given.
_OTHER_RECORDS = (
    (("paa", "needlekit", "blocked"), "an approach analysis (`needlekit approach --report`)"),
    (("livers", "cases"), "a study record (`needlekit study`)"),
    (("machine", "versions"), "a benchmark record (`needlekit bench`)"),
)


def result_kind(data: dict, where: str) -> ResultKind:
    """The kind of a result document.

    Parameters
    ----------
    data : dict
        The document's top level.
    where : str
        Names it in messages (the file).

    Returns
    -------
    ResultKind

    Raises
    ------
    InvalidInputError
        No kind's fields are all there.

    Examples
    --------
    >>> result_kind({"status": "solved", "primitives": [], "start_pose": None,
    ...              "goal_mm": [0, 0, 0]}, "plan.json").value
    'plan'
    """
    for kind, keys in KIND_FIELDS.items():
        if all(k in data for k in keys):
            return kind
    known = ", ".join(k.value for k in ResultKind)
    for keys, what in _OTHER_RECORDS:
        if all(k in data for k in keys):
            raise InvalidInputError(where, f"is {what}; `needlekit report` reads {known} results")
    raise InvalidInputError(where, f"not a result of a known kind ({known})")


def _check_cfrw(data: dict, where: str) -> None:
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
            entry_from_dict(entry, f"{where}: best.{name}")
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
        done = field_of(t, "status", at, "str") == "completed"
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


# ---------------------------------------------------------------------------------------
# files


@dataclass(frozen=True)
class ResultFile:
    """A result file, read and checked.

    Attributes
    ----------
    path : Path
    kind : ResultKind
    data : dict
        The whole document.
    scenario : Path or None
        The scenario it was made from, located (None for kinds that need none).
    """

    path: Path
    kind: ResultKind
    data: dict
    scenario: Path | None = None


def _locate_scenario(data: dict, path: Path, flag: str) -> Path:
    """The scenario a result names: as written (relative to the working folder), else
    relative to the result's folder."""
    named = data.get("scenario")
    if not isinstance(named, str) or not named:
        raise InvalidInputError(flag, f"{path}: the result names no scenario; give it with {flag}")
    first = Path(named)
    candidates = [first] if first.is_absolute() else [first, path.parent / first]
    for c in candidates:
        if c.is_file():
            return c
    raise InvalidInputError(
        flag, f"{path} names the scenario {named}, which is not there; give its path with {flag}"
    )


def _check_kind(kind: ResultKind, data: dict, where: str) -> None:
    if kind is ResultKind.PLAN:
        plan_result_from_dict(data, where)
    elif kind is ResultKind.GOALS:
        goals_from_dict(data, where)
    elif kind is ResultKind.SWEEP:
        sweeps_from_dict(data, where)
        field_of(data, "options", where, "dict", optional=True)
    elif kind is ResultKind.CFRW:
        _check_cfrw(data, where)
    elif kind is ResultKind.MULTI:
        multi_plan_from_dict(data, where)
        coverage_from_dict(data.get("coverage"), f"{where}: coverage")
        field_of(data, "resolution_deg", where, optional=True)
    elif kind is ResultKind.DYNAMIC:
        dynamic_from_dict(data, where)
    elif kind is ResultKind.SCALE:
        _check_scale(data, where)
    else:
        _check_puncture(data, where)


def _check_dynamic_scenario(data: dict, p: Path, located: Path, doc: dict, where: str) -> None:
    """The scenario of a run among moving obstacles has moving structures, and its
    ``dynamic`` block goes with the run's settings (cheap: no anatomy is read)."""
    from needlekit.io.problems import DYNAMIC_SETTINGS, dynamic_settings

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
    from needlekit.io.scenario import read_scenario_document

    kind = result_kind(data, str(p))
    _check_kind(kind, data, p.name)
    located = None
    if kind.needs_scenario:
        located = Path(scenario) if scenario is not None else _locate_scenario(data, p, flag)
        doc = read_scenario_document(located)
        if kind in (ResultKind.CFRW, ResultKind.MULTI) and not doc.get("straight"):
            msg = f"{located} has no straight block; {p.name} was made from another scenario"
            raise InvalidInputError(flag if scenario is not None else str(p), msg)
        if kind is ResultKind.DYNAMIC:
            where = flag if scenario is not None else str(p)
            _check_dynamic_scenario(data, p, located, doc, where)
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
    return [_read(p, d, chosen[i], flag) for i, (p, d) in enumerate(docs)]
