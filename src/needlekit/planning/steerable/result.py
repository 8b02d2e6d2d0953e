"""What the steerable-needle planners return (``solve(problem, budget) -> PlanResult``)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from needlekit.constants import DEFAULT_SAMPLE_SPACING_MM
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.plan import SteerablePlan, plan_from_dict
from needlekit.records import Status, enum_of, field_of, number_or_inf

__all__ = ["PlanResult", "goals_from_dict"]


@dataclass(frozen=True)
class PlanResult:
    """Outcome of a planning run.

    Attributes
    ----------
    status : PlanStatus
    planner : str
        ``"rrt"``, ``"rcs"`` or ``"rcs_star"``.
    plan : SteerablePlan or None
        The best plan (it passed :func:`needlekit.planning.steerable.verify.verify_plan`).
    cost_mm : float
        Its cost (``inf`` without a plan).
    time_s : float
        Wall-clock time of the search (excluding the problem's set-up).
    goal_mm : ndarray, shape (3,)
    stats : dict
        ``iterations``, ``nodes``, ``certified`` (the search space was exhausted at the
        finest resolution), ``reason`` (why the run ended), and planner-specific counts.
    start_pose : ndarray, shape (4, 4) or None
        The problem's start pose (recorded also when there is no plan).
    """

    status: PlanStatus
    planner: str
    plan: SteerablePlan | None
    cost_mm: float
    time_s: float
    goal_mm: np.ndarray
    stats: dict = field(default_factory=dict)
    start_pose: np.ndarray | None = None

    @property
    def length_mm(self) -> float:
        """Inserted length of the plan (``inf`` without one)."""
        return self.plan.length_mm if self.plan is not None else float("inf")

    def to_dict(self, spacing_mm: float = DEFAULT_SAMPLE_SPACING_MM) -> dict:
        """JSON-ready record (the ``plan.json`` format).

        Parameters
        ----------
        spacing_mm : float
            Largest spacing of ``points_mm`` along the tip path.

        Returns
        -------
        dict
            ``status``, ``planner``, ``cost_mm``, ``length_mm``, ``time_s``, ``primitives``,
            ``points_mm``, ``start_pose``, ``goal_mm`` and ``stats`` (``None`` for missing
            numbers).
        """

        def num(x):
            return None if x is None or not np.isfinite(x) else float(x)

        out = {
            "status": self.status.value,
            "planner": self.planner,
            "cost_mm": num(self.cost_mm),
            "length_mm": num(self.length_mm),
            "time_s": float(self.time_s),
            "goal_mm": np.asarray(self.goal_mm, dtype=float).tolist(),
            "stats": {
                k: v
                for k, v in self.stats.items()
                if isinstance(v, (int, float, str, bool, type(None)))
            },
        }
        if self.plan is not None:
            out.update(self.plan.to_dict())
            out["points_mm"] = np.round(self.plan.points_mm(spacing_mm), 6).tolist()
        else:
            start = None if self.start_pose is None else np.asarray(self.start_pose).tolist()
            out.update({"primitives": [], "points_mm": [], "start_pose": start})
        return out

    @classmethod
    def from_dict(cls, data: dict, where: str) -> PlanResult:
        """A planner result from its ``plan.json`` record, as :meth:`to_dict` writes it.

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.

        Returns
        -------
        PlanResult
            ``stats`` as recorded (the JSON-ready ones only).

        Raises
        ------
        InvalidInputError
            A field not as the format says, or a status with a plan but no motions.
        """
        status = enum_of(Status, field_of(data, "status", where, "str"), f"{where}: status")
        planner = field_of(data, "planner", where, "str")
        plan, goal = plan_from_dict(data, where)
        if status.has_plan and plan is None:
            msg = f"status {status.value} without motions"
            raise InvalidInputError(f"{where}: primitives", msg)
        start = field_of(data, "start_pose", where, "pose", optional=True)
        stats = field_of(data, "stats", where, "dict", optional=True) or {}
        time_s = field_of(data, "time_s", where, optional=True) or 0.0
        cost = number_or_inf(data, "cost_mm", where)
        return cls(status, planner, plan, cost, float(time_s), goal, dict(stats), start)


def goals_from_dict(data: dict, where: str) -> list[PlanResult]:
    """The results of ``needlekit plan --goals`` from its record, one per target.

    Parameters
    ----------
    data : dict
        ``planner``, ``mode`` (``per-target`` or ``one-tree``) and ``targets`` (plan
        records).
    where : str
        Names the record in messages.

    Returns
    -------
    list of PlanResult

    Raises
    ------
    InvalidInputError
        A field not as the format says (named).
    """
    field_of(data, "planner", where, "str")
    mode = field_of(data, "mode", where, "str")
    if mode not in ("per-target", "one-tree"):
        raise InvalidInputError(f"{where}: mode", f"expected per-target or one-tree, got {mode!r}")
    targets = field_of(data, "targets", where, "list")
    if not targets:
        raise InvalidInputError(f"{where}: targets", "expected one or more plans")
    return [PlanResult.from_dict(t, f"{where}: targets[{i}]") for i, t in enumerate(targets)]
