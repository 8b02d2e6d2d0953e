"""Planning objects rebuilt from their JSON records (the files the commands write).

- :func:`plan_result_from_dict`, :func:`goals_from_dict`: steerable-needle plans
  (``plan.json``, ``needlekit plan --goals``);
- :func:`sweeps_from_dict`: the sweeps of ``sweep.json`` (each effective direction's
  status, cost and time; the best plans with their motions);
- :func:`multi_plan_from_dict`, :func:`coverage_from_dict`: a straight multi-needle plan
  and its ablation coverage (``multi.json``);
- :func:`dynamic_from_dict`: a run among moving obstacles (``needlekit plan --dynamic``):
  the executed path, every cycle with the plan it followed, the plan made once at
  ``t = 0``, the motions and settings (the checks are left to run again).

Every field is checked as it is read: a record that does not hold what its writer writes
raises :class:`~needlekit.errors.InvalidInputError` naming the record and the field.
:mod:`needlekit.io.results` reads whole result files with these.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = [
    "DynamicRecord",
    "coverage_from_dict",
    "dynamic_from_dict",
    "entry_from_dict",
    "field_of",
    "goals_from_dict",
    "multi_plan_from_dict",
    "plan_result_from_dict",
    "sweeps_from_dict",
]


def field_of(data: dict, key: str, where: str, kind: str = "number", *, optional: bool = False):
    """One field of a record, checked.

    Parameters
    ----------
    data : dict
        The record (anything else is refused, naming ``where``).
    key : str
    where : str
        Names the record in messages (``"plan.json"``, ``"sweep.json: directions[3]"``).
    kind : str
        ``number`` (finite), ``int``, ``str``, ``bool``, ``list``, ``dict``, ``point``
        (three finite numbers) or ``pose`` (a 4x4 matrix of finite numbers).
    optional : bool
        A missing or null field gives None instead of an error.

    Returns
    -------
    object
        The value; an ndarray of shape (3,) or (4, 4) for ``point`` and ``pose``.

    Raises
    ------
    InvalidInputError
        ``"<where>: <key>: ..."``: missing, null, or not of ``kind``.
    """
    name = f"{where}: {key}"
    if not isinstance(data, dict):
        raise InvalidInputError(where, "expected a JSON object")
    value = data.get(key)
    if value is None:
        if optional:
            return None
        raise InvalidInputError(
            name, "missing" if key not in data else "expected a value, got null"
        )
    if kind in ("point", "pose"):
        shape = (3,) if kind == "point" else (4, 4)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            arr = None
        if arr is None or arr.shape != shape or not np.all(np.isfinite(arr)):
            what = "three finite numbers" if kind == "point" else "a 4x4 matrix of finite numbers"
            raise InvalidInputError(name, f"expected {what}")
        return arr
    numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
    ok = {
        "number": numeric and np.isfinite(value),
        "int": isinstance(value, int) and not isinstance(value, bool),
        "str": isinstance(value, str),
        "bool": isinstance(value, bool),
        "list": isinstance(value, list),
        "dict": isinstance(value, dict),
    }[kind]
    if not ok:
        what = {"number": "a finite number", "int": "a whole number", "str": "text"}
        what |= {"bool": "true or false", "list": "a list", "dict": "an object"}
        raise InvalidInputError(name, f"expected {what[kind]}, got {value!r:.60}")
    return value


def _number_or_inf(data: dict, key: str, where: str) -> float:
    value = field_of(data, key, where, optional=True)
    return float("inf") if value is None else float(value)


def _status(value, where: str):
    from needlekit.planning.result import PlanStatus

    try:
        return PlanStatus(value)
    except ValueError:
        known = ", ".join(s.value for s in PlanStatus)
        raise InvalidInputError(where, f"expected one of {known}, got {value!r:.40}") from None


# ---------------------------------------------------------------------------------------
# steerable results


def plan_result_from_dict(data: dict, where: str):
    """A planner result from its ``plan.json`` record.

    Parameters
    ----------
    data : dict
        As :meth:`PlanResult.to_dict <needlekit.planning.steerable.result.PlanResult.to_dict>`
        writes it.
    where : str
        Names the record in messages.

    Returns
    -------
    PlanResult

    Raises
    ------
    InvalidInputError
        A field not as the format says, or a status with a plan but no motions.
    """
    from needlekit.io.plans import plan_from_dict
    from needlekit.planning.steerable.result import PlanResult

    status = _status(field_of(data, "status", where, "str"), f"{where}: status")
    planner = field_of(data, "planner", where, "str")
    plan, goal = plan_from_dict(data, where)
    if status.has_plan and plan is None:
        raise InvalidInputError(f"{where}: primitives", f"status {status.value} without motions")
    start = field_of(data, "start_pose", where, "pose", optional=True)
    stats = field_of(data, "stats", where, "dict", optional=True) or {}
    time_s = field_of(data, "time_s", where, optional=True) or 0.0
    cost = _number_or_inf(data, "cost_mm", where)
    return PlanResult(status, planner, plan, cost, float(time_s), goal, dict(stats), start)


def goals_from_dict(data: dict, where: str) -> list:
    """The results of ``needlekit plan --goals`` from its record, one per target.

    Parameters
    ----------
    data : dict
        ``planner``, ``mode`` and ``targets`` (plan records).
    where : str

    Returns
    -------
    list of PlanResult
    """
    field_of(data, "planner", where, "str")
    mode = field_of(data, "mode", where, "str")
    if mode not in ("per-target", "one-tree"):
        raise InvalidInputError(f"{where}: mode", f"expected per-target or one-tree, got {mode!r}")
    targets = field_of(data, "targets", where, "list")
    if not targets:
        raise InvalidInputError(f"{where}: targets", "expected one or more plans")
    return [plan_result_from_dict(t, f"{where}: targets[{i}]") for i, t in enumerate(targets)]


def sweeps_from_dict(data: dict, where: str, goal_mm=None) -> dict:
    """The sweeps of a ``sweep.json`` record, one per planner.

    Every effective direction gets a result with its status, cost and time; only the best
    direction's carries a plan (the file keeps no other path).

    Parameters
    ----------
    data : dict
        As :func:`~needlekit.planning.steerable.sweep.sweeps_to_dict` writes it.
    where : str
    goal_mm : array_like, shape (3,), optional
        The goal of the results without a plan (default: a best plan's goal, else NaN).

    Returns
    -------
    dict of str to SweepResult
        In the file's planner order.
    """
    from needlekit.planning.steerable.result import PlanResult
    from needlekit.planning.steerable.sweep import SweepResult

    planners = field_of(data, "planners", where, "list")
    if not planners or not all(isinstance(p, str) for p in planners):
        raise InvalidInputError(f"{where}: planners", "expected one or more planner names")
    rows = field_of(data, "directions", where, "list")
    summary = field_of(data, "summary", where, "dict")
    bests = field_of(data, "best_plans", where, "dict")
    best = {}
    for name in planners:
        b = bests.get(name)
        best[name] = None if b is None else plan_result_from_dict(b, f"{where}: best_plans.{name}")
    if goal_mm is None:
        found = [b.goal_mm for b in best.values() if b is not None]
        goal_mm = found[0] if found else np.full(3, np.nan)
    goal = np.asarray(goal_mm, dtype=float)
    dirs, eff = np.zeros((len(rows), 3)), np.zeros(len(rows), dtype=bool)
    for i, row in enumerate(rows):
        at = f"{where}: directions[{i}]"
        if field_of(row, "index", at, "int") != i:
            raise InvalidInputError(f"{at}: index", f"expected {i} (rows in sweep order)")
        dirs[i] = field_of(row, "direction", at, "point")
        eff[i] = field_of(row, "effective", at, "bool")
    out = {}
    for name in planners:
        stats = field_of(summary, name, f"{where}: summary", "dict")
        best_index = field_of(stats, "best_index", f"{where}: summary.{name}", "int", optional=True)
        results: list = [None] * len(rows)
        for i in np.flatnonzero(eff):
            at = f"{where}: directions[{i}]"
            status = _status(
                field_of(row := rows[i], "status", at, "dict").get(name), f"{at}: status"
            )
            cost = _number_or_inf(field_of(row, "cost_mm", at, "dict"), name, f"{at}: cost_mm")
            t = field_of(field_of(row, "time_s", at, "dict"), name, f"{at}: time_s", optional=True)
            results[i] = PlanResult(status, name, None, cost, float(t or 0.0), goal)
        b = best[name]
        if best_index is not None:
            if not 0 <= best_index < len(rows) or results[best_index] is None:
                msg = f"{best_index} is not an effective direction"
                raise InvalidInputError(f"{where}: summary.{name}.best_index", msg)
            if b is None or b.plan is None:
                raise InvalidInputError(f"{where}: best_plans.{name}", "missing the best plan")
            results[best_index] = b
        out[name] = SweepResult(dirs, eff, results, name, dict(stats))
    return out


# ---------------------------------------------------------------------------------------
# straight results


def entry_from_dict(row: dict, where: str):
    """A straight trajectory from its record (a needle of ``multi.json``, a best entry of
    ``cfrw.json``).

    Parameters
    ----------
    row : dict
        ``entry_mm`` (None: no trajectory), ``target_mm``, ``theta_deg``, ``phi_deg``,
        ``length_mm``, ``clearance_mm``, ``normal_angle_deg``.
    where : str

    Returns
    -------
    Entry or None
    """
    from needlekit.planning.straight.entry import Entry

    entry = field_of(row, "entry_mm", where, "point", optional=True)
    if entry is None:
        return None
    return Entry(
        entry,
        field_of(row, "target_mm", where, "point"),
        float(np.radians(field_of(row, "theta_deg", where))),
        float(np.radians(field_of(row, "phi_deg", where))),
        float(field_of(row, "length_mm", where)),
        float(field_of(row, "clearance_mm", where)),
        float(field_of(row, "normal_angle_deg", where)),
    )


def multi_plan_from_dict(data: dict, where: str):
    """A multi-needle plan from its ``multi.json`` record (without its CFRW maps).

    Parameters
    ----------
    data : dict
        As :meth:`MultiNeedlePlan.to_dict
        <needlekit.planning.straight.sequence.MultiNeedlePlan.to_dict>` writes it.
    where : str

    Returns
    -------
    MultiNeedlePlan
        Solved when every needle has a trajectory.
    """
    from needlekit.planning.straight.sequence import MultiNeedlePlan, NeedleRecord

    needles = []
    for i, row in enumerate(field_of(data, "needles", where, "list")):
        at = f"{where}: needles[{i}]"
        blocked = field_of(row, "blocked", at, "dict")
        if not all(isinstance(v, int) and not isinstance(v, bool) for v in blocked.values()):
            raise InvalidInputError(f"{at}: blocked", "expected whole-number counts")
        nc = field_of(row, "needle_clearance_mm", at, optional=True)
        needles.append(
            NeedleRecord(
                field_of(row, "order", at, "int"),
                field_of(row, "target_index", at, "int"),
                field_of(row, "planned_target_mm", at, "point"),
                field_of(row, "target_mm", at, "point"),
                entry_from_dict(row, at),
                float("inf") if nc is None else float(nc),
                dict(blocked),
            )
        )
    order = field_of(data, "order", where, "list")
    if not all(isinstance(k, int) and not isinstance(k, bool) for k in order):
        raise InvalidInputError(f"{where}: order", "expected target indices")
    solved = bool(needles) and all(n.entry is not None for n in needles)
    return MultiNeedlePlan(
        tuple(needles),
        tuple(order),
        solved,
        field_of(data, "orders_tried", where, "int"),
        float(field_of(data, "gamma_mm", where)),
        float(field_of(data, "needle_radius_mm", where)),
        "" if solved else str(field_of(data, "reason", where, "str", optional=True) or ""),
    )


def _coverage_report(data: dict, where: str):
    from needlekit.planning.straight.coverage import CoverageReport

    fields = CoverageReport.__dataclass_fields__
    values = {k: field_of(data, k, where, "int" if k == "needles" else "number") for k in fields}
    return CoverageReport(**values)


def coverage_from_dict(data: dict | None, where: str):
    """The ablation coverage of a multi-needle plan from its record (``multi.json``'s
    ``coverage``).

    Parameters
    ----------
    data : dict or None
    where : str

    Returns
    -------
    AblationOutcome or None
        None when the plan's targets were not chosen for coverage.
    """
    if data is None:
        return None
    from needlekit.planning.straight.ablation import AblationOutcome
    from needlekit.planning.straight.coverage import AblationZone, CoveragePlan, CoverageStatus

    z = field_of(data, "zone", where, "dict")
    at = f"{where}: zone"
    try:
        zone = AblationZone(
            field_of(z, "kind", at, "str"),
            field_of(z, "length_mm", at),
            field_of(z, "diameter_mm", at),
            field_of(z, "tip_offset_mm", at),
        )
    except InvalidInputError as exc:
        raise InvalidInputError(f"{at}.{exc.field}", exc.reason) from None
    c = field_of(data, "chosen", where, "dict")
    at = f"{where}: chosen"
    try:
        status = CoverageStatus(field_of(c, "status", at, "str"))
    except ValueError:
        raise InvalidInputError(f"{at}: status", "expected covered or partial") from None
    arrays = []
    for key in ("targets_mm", "centres_mm", "directions"):
        a = np.asarray(field_of(c, key, at, "list"), dtype=float).reshape(-1, 3)
        if not np.all(np.isfinite(a)):
            raise InvalidInputError(f"{at}: {key}", "expected finite points (k, 3)")
        arrays.append(a)
    chosen = CoveragePlan(
        status,
        *arrays,
        zone,
        _coverage_report(field_of(c, "report", at, "dict"), f"{at}: report"),
        float(field_of(c, "coverage_goal", at)),
        field_of(c, "candidates", at, "int"),
        float(field_of(c, "candidate_spacing_mm", at)),
        field_of(c, "greedy_needles", at, "int"),
        field_of(c, "needles_lower_bound", at, "int"),
    )
    planned = field_of(data, "planned", where, "dict", optional=True)
    planned = None if planned is None else _coverage_report(planned, f"{where}: planned")
    ok = field_of(data, "status", where, "str") == "covered"
    reason = field_of(data, "reason", where, "str", optional=True) or ""
    return AblationOutcome(chosen, planned, ok, reason)


# ---------------------------------------------------------------------------------------
# a run among moving obstacles


@dataclass(frozen=True)
class DynamicRecord:
    """A run among moving obstacles as its record holds it (``needlekit plan --dynamic``'s
    file), without the obstacles' shapes (the scenario's) and with the checks as recorded.

    Attributes
    ----------
    status : DynamicStatus
    reason : str
    settings : dict
        ``planner``, ``insertion_speed_mm_s``, ``step_mm``, ``predict``, ``lookahead_s``.
    motions : dict of str to Motion
        Each moving obstacle's motion by name, in the file's order.
    executed : SteerablePlan
        The path inserted, from the run's start pose.
    cycles : tuple of Cycle
        Each with the plan it followed.
    static : PlanResult or None
        The plan made once at ``t = 0`` (None: not asked for).
    checks : dict
        The checks as recorded: ``executed`` and ``static`` (None: none), each a dict with
        ``ok``, ``violations`` (tuple of str) and ``metrics``.
    """

    status: object
    reason: str
    settings: dict
    motions: dict
    executed: object
    cycles: tuple
    static: object
    checks: dict

    @property
    def goal_mm(self) -> np.ndarray | None:
        """The goal the run planned for (as its plans record it; None without a plan
        record)."""
        results = [c.result for c in self.cycles]
        if self.static is not None:
            results.append(self.static)
        return np.asarray(results[0].goal_mm, dtype=float) if results else None


def _dynamic_status(value, where: str):
    from needlekit.planning.steerable.dynamic import DynamicStatus

    try:
        return DynamicStatus(value)
    except ValueError:
        known = ", ".join(s.value for s in DynamicStatus)
        raise InvalidInputError(where, f"expected one of {known}, got {value!r:.40}") from None


def _dynamic_settings(data: dict, where: str) -> dict:
    from needlekit.planning.steerable.dynamic import check_settings

    at = f"{where}: settings"
    s = field_of(data, "settings", where, "dict")
    out = {
        "planner": field_of(s, "planner", at, "str"),
        "insertion_speed_mm_s": float(field_of(s, "insertion_speed_mm_s", at)),
        "step_mm": float(field_of(s, "step_mm", at)),
        "predict": field_of(s, "predict", at, "str"),
        "lookahead_s": field_of(s, "lookahead_s", at, optional=True),
    }
    try:
        check_settings(out["insertion_speed_mm_s"], out["step_mm"], out["predict"],
                       out["lookahead_s"])  # fmt: skip
    except InvalidInputError as exc:
        raise InvalidInputError(f"{at}: {exc.field}", exc.reason) from None
    return out


def _motions(data: dict, where: str) -> dict:
    from needlekit.planning.steerable.moving import Motion

    out = {}
    for i, m in enumerate(field_of(data, "moving", where, "list")):
        at = f"{where}: moving[{i}]"
        name = field_of(m, "name", at, "str")
        if name in out:
            raise InvalidInputError(f"{at}: name", f"{name!r} is given twice")
        amplitude = field_of(m, "amplitude_mm", at, "point", optional=True)
        try:
            out[name] = Motion(
                field_of(m, "velocity_mm_s", at, "point"),
                np.zeros(3) if amplitude is None else amplitude,
                field_of(m, "period_s", at, optional=True),
                field_of(m, "phase_deg", at, optional=True) or 0.0,
            )
        except InvalidInputError as exc:
            raise InvalidInputError(f"{at}: {exc.field}", exc.reason) from None
    return out


def _path(data: dict, where: str):
    """A path from its start pose and primitives (none: nothing inserted)."""
    from needlekit.planning.steerable.plan import SteerablePlan

    start = field_of(data, "start_pose", where, "pose")
    rows = []
    for i, q in enumerate(field_of(data, "primitives", where, "list")):
        at = f"{where}: primitives[{i}]"
        rows.append([field_of(q, k, at) for k in ("rotation_rad", "curvature_per_mm", "length_mm")])
    try:
        return SteerablePlan(start, np.array(rows, dtype=float).reshape(-1, 3))
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc.field}", exc.reason) from None


def _recorded_check(data: dict, where: str, *, optional: bool = False) -> dict | None:
    check = field_of(data, "check", where, "dict", optional=optional)
    if check is None:
        return None
    at = f"{where}: check"
    ok = field_of(check, "ok", at, "bool")
    violations = field_of(check, "violations", at, "list")
    if not all(isinstance(v, str) for v in violations):
        raise InvalidInputError(f"{at}: violations", "expected lines of text")
    if ok == bool(violations):
        msg = f"is {str(ok).lower()} with {len(violations)} violations"
        raise InvalidInputError(f"{at}: ok", msg)
    metrics = field_of(check, "metrics", at, "dict")
    field_of(metrics, "certified_moving_clearance_mm", f"{at}: metrics", optional=True)
    return {"ok": ok, "violations": tuple(violations), "metrics": metrics}


def _dynamic_cycles(data: dict, where: str, names) -> tuple:
    from needlekit.planning.steerable.dynamic import Cycle

    out = []
    for i, c in enumerate(field_of(data, "cycles", where, "list")):
        at = f"{where}: cycles[{i}]"
        if field_of(c, "index", at, "int") != i:
            raise InvalidInputError(f"{at}: index", f"expected {i} (cycles in order)")
        window = field_of(c, "window_s", at, "list")
        if len(window) != 2 or not all(
            isinstance(w, (int, float)) and not isinstance(w, bool) and np.isfinite(w)
            for w in window
        ):
            raise InvalidInputError(f"{at}: window_s", "expected two finite times (s)")
        offsets = field_of(c, "obstacle_offsets_mm", at, "dict")
        if set(offsets) != set(names):
            msg = f"expected the moving obstacles {sorted(names)}, got {sorted(offsets)}"
            raise InvalidInputError(f"{at}: obstacle_offsets_mm", msg)
        offsets = {
            k: field_of(offsets, k, f"{at}: obstacle_offsets_mm", "point").tolist() for k in offsets
        }
        source = field_of(c, "source", at, "str")
        if source not in ("planned", "kept"):
            raise InvalidInputError(
                f"{at}: source", f"expected planned or kept, got {source!r:.40}"
            )
        out.append(
            Cycle(
                i,
                float(field_of(c, "t_s", at)),
                float(field_of(c, "inserted_mm", at)),
                field_of(c, "tip_pose", at, "pose"),
                offsets,
                (float(window[0]), float(window[1])),
                plan_result_from_dict(field_of(c, "plan", at, "dict"), f"{at}: plan"),
                source,
                float(field_of(c, "advanced_mm", at)),
            )
        )
    return tuple(out)


def dynamic_from_dict(data: dict, where: str) -> DynamicRecord:
    """A run among moving obstacles from its record (``needlekit plan --dynamic``'s file).

    The plans (the path executed, each cycle's, the one made at ``t = 0``) are rebuilt
    from their motions; the moving obstacles' shapes are not in the record (the scenario
    gives them), and the checks are kept as recorded, to be run again.

    Parameters
    ----------
    data : dict
        As :meth:`DynamicResult.to_dict
        <needlekit.planning.steerable.dynamic.DynamicResult.to_dict>` writes it.
    where : str
        Names the record in messages.

    Returns
    -------
    DynamicRecord

    Raises
    ------
    InvalidInputError
        A field not as the format says, or plans that do not start where the run started
        or aim at different goals (named).
    """
    status = _dynamic_status(field_of(data, "status", where, "str"), f"{where}: status")
    reason = field_of(data, "reason", where, "str")
    settings = _dynamic_settings(data, where)
    motions = _motions(data, where)
    at = f"{where}: executed"
    executed = _path(field_of(data, "executed", where, "dict"), at)
    checks = {"executed": _recorded_check(data, where), "static": None}
    cycles = _dynamic_cycles(data, where, motions)
    static = field_of(data, "static", where, "dict", optional=True)
    if static is not None:
        checks["static"] = _recorded_check(static, f"{where}: static", optional=True)
        static = plan_result_from_dict(
            field_of(static, "plan", f"{where}: static", "dict"), f"{where}: static: plan"
        )
    starts = [(f"{where}: cycles[0]: tip_pose", cycles[0].tip_pose)] if cycles else []
    if static is not None and static.plan is not None:
        starts.append((f"{where}: static: plan: start_pose", static.plan.start_pose))
    for name, pose in starts:
        if not np.allclose(pose, executed.start_pose, rtol=0.0, atol=1e-9):
            raise InvalidInputError(name, "differs from executed.start_pose (the run's start)")
    goals = [(f"{where}: cycles[{c.index}]: plan: goal_mm", c.result.goal_mm) for c in cycles]
    if static is not None:
        goals.append((f"{where}: static: plan: goal_mm", static.goal_mm))
    for name, goal in goals[1:]:
        if not np.allclose(goal, goals[0][1], rtol=0.0, atol=1e-9):
            raise InvalidInputError(name, f"differs from the goal of {goals[0][0]}")
    return DynamicRecord(status, reason, settings, motions, executed, cycles, static, checks)
