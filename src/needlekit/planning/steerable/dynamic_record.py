"""A run among moving obstacles as its record holds it (``needlekit plan --dynamic``'s
file): :class:`DynamicRecord`, with ``to_dict`` and ``from_dict`` side by side.

The record keeps the executed path, every cycle with the plan it followed, the plan made
once at ``t = 0``, the motions and the settings, and the checks as they were run; it does
not keep the moving obstacles' shapes (the scenario gives them), so a
:class:`~needlekit.planning.steerable.dynamic.DynamicResult` cannot be rebuilt from it
alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.dynamic import (
    Cycle,
    DynamicStatus,
    check_settings,
    json_ready,
)
from needlekit.planning.steerable.moving import Motion
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.result import PlanResult
from needlekit.records import enum_of, field_of

__all__ = ["DynamicRecord", "dynamic_from_dict"]


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

    status: DynamicStatus
    reason: str
    settings: dict
    motions: dict
    executed: SteerablePlan
    cycles: tuple
    static: PlanResult | None
    checks: dict

    @property
    def goal_mm(self) -> np.ndarray | None:
        """The goal the run planned for (as its plans record it; None without a plan
        record)."""
        results = [c.result for c in self.cycles]
        if self.static is not None:
            results.append(self.static)
        return np.asarray(results[0].goal_mm, dtype=float) if results else None

    def to_dict(self) -> dict:
        """The record again, as :meth:`DynamicResult.to_dict
        <needlekit.planning.steerable.dynamic.DynamicResult.to_dict>` wrote it.

        Returns
        -------
        dict
        """
        out = {
            "status": self.status.value,
            "reason": self.reason,
            "settings": dict(self.settings),
            "moving": [{"name": k, **m.to_dict()} for k, m in self.motions.items()],
            "executed": {
                **self.executed.to_dict(),
                "length_mm": self.executed.length_mm,
                "points_mm": np.round(self.executed.points_mm(0.5), 6).tolist(),
            },
            "check": _check_record(self.checks["executed"]),
            "cycles": [c.to_dict() for c in self.cycles],
            "static": None,
        }
        if self.static is not None:
            check = _check_record(self.checks["static"])
            out["static"] = {"plan": self.static.to_dict(), "check": check}
        return json_ready(out)

    @classmethod
    def from_dict(cls, data: dict, where: str) -> DynamicRecord:
        """A run among moving obstacles from its record (``needlekit plan --dynamic``'s
        file).

        The plans (the path executed, each cycle's, the one made at ``t = 0``) are rebuilt
        from their motions; the moving obstacles' shapes are not in the record (the
        scenario gives them), and the checks are kept as recorded, to be run again.

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
            A field not as the format says, or plans that do not start where the run
            started or aim at different goals (named).
        """
        return _from_dict(data, where)


def _check_record(check: dict | None) -> dict | None:
    if check is None:
        return None
    return {**check, "violations": list(check["violations"])}


def _dynamic_settings(data: dict, where: str) -> dict:
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
                PlanResult.from_dict(field_of(c, "plan", at, "dict"), f"{at}: plan"),
                source,
                float(field_of(c, "advanced_mm", at)),
            )
        )
    return tuple(out)


def _from_dict(data: dict, where: str) -> DynamicRecord:
    """:meth:`DynamicRecord.from_dict`."""
    status = enum_of(DynamicStatus, field_of(data, "status", where, "str"), f"{where}: status")
    reason = field_of(data, "reason", where, "str")
    settings = _dynamic_settings(data, where)
    motions = _motions(data, where)
    at = f"{where}: executed"
    executed = SteerablePlan.from_dict(field_of(data, "executed", where, "dict"), at)
    checks = {"executed": _recorded_check(data, where), "static": None}
    cycles = _dynamic_cycles(data, where, motions)
    static = field_of(data, "static", where, "dict", optional=True)
    if static is not None:
        checks["static"] = _recorded_check(static, f"{where}: static", optional=True)
        static = PlanResult.from_dict(
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


def dynamic_from_dict(data: dict, where: str) -> DynamicRecord:
    """A run among moving obstacles from its record: :meth:`DynamicRecord.from_dict`.

    Parameters
    ----------
    data : dict
    where : str

    Returns
    -------
    DynamicRecord
    """
    return DynamicRecord.from_dict(data, where)
