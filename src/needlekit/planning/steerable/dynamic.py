"""Planning among moving obstacles: re-plan from the current tip, cycle after cycle.

The lecture's RRT plans "in a dynamic environment with dynamic obstacles".
:func:`replan_among_moving` runs that loop, with time taken from the insertion (the needle
advances at a constant speed ``v``; :mod:`needlekit.planning.steerable.moving`) and
planning taken to cost no time (it runs while the needle advances). Each cycle

1. poses the problem from the current tip (:func:`continuation_problem`). After the first
   cycle the needle is inside the tissue: the start punctures no surface
   (``start_inside``: no entry surface, no puncture angle, no start exclusion), the length
   left is ``l_max`` less what is inserted, and the heading limit shrinks by the angle
   already turned, so that the whole path stays within the limit around the first start
   direction (angles between directions obey the triangle inequality);
2. places the moving obstacles as the prediction says (``predict``):

   - ``"arrival"`` (default): each point against the obstacle wherever it may be when
     the tip can pass that point (:class:`~needlekit.planning.steerable.moving.ArrivalField`;
     the obstacles' motion is taken as known);
   - ``"swept"``: everywhere the obstacle goes while the next advance runs (or over
     ``lookahead_s``; :class:`~needlekit.planning.steerable.moving.SweptField`);
   - ``"snapshot"``: where the obstacle is now;

   and plans with a registered planner (RRT by default, the lecture's). When the rest of
   the previous cycle's plan still passes the check against this cycle's problem and the
   new search found nothing cheaper (or nothing), the rest is kept (``source = "kept"``);
3. advances ``step_mm`` along the plan (the whole plan when it is shorter) and checks the
   advance against the obstacles as they moved meanwhile;

until the tip is within the goal tolerance, a cycle finds no plan, or an advance is unsafe.
The whole executed path is then certified
(:func:`~needlekit.planning.steerable.moving.certify_execution`). :func:`plan_static` is
the baseline a user compares with: one plan at ``t = 0``, with the obstacles where they are
then, executed open-loop while they move.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_positive
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus, Verification
from needlekit.planning.steerable.continuation import (
    continuation_from_pose,
    continuation_problem,
)
from needlekit.planning.steerable.moving import (
    CHECK_SPACING_MM,
    ArrivalField,
    MovingObstacle,
    certify_execution,
    check_moving,
    moving_clearance,
    path_samples,
    scene_with,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.solve import solve
from needlekit.planning.steerable.verify import verify_plan

__all__ = [
    "DEFAULT_STEP_MM",
    "PREDICTIONS",
    "Cycle",
    "DynamicResult",
    "DynamicStatus",
    "check_settings",
    "continuation_from_pose",
    "continuation_problem",
    "json_ready",
    "plan_static",
    "replan_among_moving",
]
#: A motion that ends within this (mm) past an advance's end is advanced whole: rounding.
SPLIT_SLACK_MM: float = 1e-9
#: Default advance between re-plans (mm): a tenth of a 50 mm insertion, 2.5 s at 2 mm/s.
DEFAULT_STEP_MM: float = 5.0
#: What a cycle plans against (the first is the default): each obstacle wherever it may be when the tip can pass a
#: point, swept over the next advance, or where it is now.
PREDICTIONS: tuple[str, ...] = ("arrival", "swept", "snapshot")


class DynamicStatus(enum.Enum):
    """How a run among moving obstacles ended.

    REACHED
        The tip reached the goal and the executed path passed the check.
    NO_PLAN
        A cycle found no plan from the current tip (its status and reason are recorded),
        or nothing was left of the length or heading budget.
    UNSAFE
        An advance came closer to a moving obstacle than the margin allows, certified (as
        the obstacle moved during it); the run stops there.
    CHECK_FAILED
        The tip reached the goal but the executed path failed the check.
    """

    REACHED = "reached"
    NO_PLAN = "no_plan"
    UNSAFE = "unsafe"
    CHECK_FAILED = "check_failed"


@dataclass(frozen=True)
class Cycle:
    """One planning cycle.

    Attributes
    ----------
    index : int
        From 0.
    t_s : float
        When it planned (inserted length over insertion speed).
    inserted_mm : float
    tip_pose : ndarray, shape (4, 4)
        Where it planned from.
    obstacle_offsets_mm : dict of str to list
        Each moving obstacle's displacement from its ``t = 0`` position at ``t_s``.
    window_s : tuple of float
        The times the obstacles were planned against: ``(t_s, t_s)`` for a snapshot, the
        sweep's span, or the arrival window at the goal.
    result : PlanResult
        The plan followed (the search's, or the kept rest of the previous one).
    source : str
        ``"planned"`` (this cycle's search) or ``"kept"``.
    advanced_mm : float
        How far the needle advanced along the plan (0 without a plan).
    """

    index: int
    t_s: float
    inserted_mm: float
    tip_pose: np.ndarray
    obstacle_offsets_mm: dict
    window_s: tuple
    result: PlanResult
    source: str = "planned"
    advanced_mm: float = 0.0

    def to_dict(self) -> dict:
        """JSON-ready record (the plan as ``PlanResult.to_dict`` gives it).

        Returns
        -------
        dict
        """
        return {
            "index": self.index,
            "t_s": self.t_s,
            "inserted_mm": self.inserted_mm,
            "tip_pose": np.asarray(self.tip_pose).tolist(),
            "obstacle_offsets_mm": self.obstacle_offsets_mm,
            "window_s": list(self.window_s),
            "source": self.source,
            "advanced_mm": self.advanced_mm,
            "plan": self.result.to_dict(),
        }


@dataclass(frozen=True)
class DynamicResult:
    """What :func:`replan_among_moving` did.

    Attributes
    ----------
    status : DynamicStatus
    reason : str
    executed : SteerablePlan
        The path inserted, from the original start pose.
    check : Verification
        :func:`~needlekit.planning.steerable.moving.certify_execution` of ``executed``
        (the goal is not required of a run that stopped on the way).
    cycles : tuple of Cycle
    settings : dict
        ``planner``, ``insertion_speed_mm_s``, ``step_mm``, ``predict``, ``lookahead_s``.
    moving : tuple of MovingObstacle
    static : tuple (PlanResult, Verification or None) or None
        The baseline (:func:`plan_static`) when it was asked for.
    """

    status: DynamicStatus
    reason: str
    executed: SteerablePlan
    check: Verification
    cycles: tuple
    settings: dict
    moving: tuple
    static: tuple | None = None

    @property
    def reached(self) -> bool:
        """Whether the goal was reached by a certified path."""
        return self.status is DynamicStatus.REACHED

    def to_dict(self) -> dict:
        """JSON-ready record.

        Returns
        -------
        dict
            ``status``, ``reason``, ``settings``, ``moving`` (name and motion),
            ``executed`` (primitives, ``points_mm``, ``length_mm``), ``check`` (``ok``,
            ``violations``, ``metrics``), ``cycles`` and ``static`` (its plan and check).
        """
        out = {
            "status": self.status.value,
            "reason": self.reason,
            "settings": dict(self.settings),
            "moving": [{"name": m.name, **m.motion.to_dict()} for m in self.moving],
            "executed": {
                **self.executed.to_dict(),
                "length_mm": self.executed.length_mm,
                "points_mm": np.round(self.executed.points_mm(0.5), 6).tolist(),
            },
            "check": _check_dict(self.check),
            "cycles": [c.to_dict() for c in self.cycles],
            "static": None,
        }
        if self.static is not None:
            res, check = self.static
            out["static"] = {"plan": res.to_dict(), "check": _check_dict(check)}
        return json_ready(out)


def _check_dict(check: Verification | None) -> dict | None:
    if check is None:
        return None
    return {"ok": check.ok, "violations": list(check.violations), "metrics": check.metrics}


def json_ready(value):
    """Plain JSON values: numpy numbers as Python ones, non-finite numbers as None.

    Parameters
    ----------
    value : object
        Mappings, sequences, arrays and numbers, nested.

    Returns
    -------
    object
        The same structure with plain Python values.
    """
    if isinstance(value, Mapping):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [json_ready(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    return value


def _split(plan: SteerablePlan, length_mm: float) -> tuple[SteerablePlan, SteerablePlan]:
    """The first ``length_mm`` of a plan and the rest (a motion cut where it passes)."""
    head, tail, left = [], [], float(length_mm)
    for spin, kappa, length in plan.primitives:
        if left >= length - SPLIT_SLACK_MM:  # no sliver of a motion left over
            head.append([spin, kappa, length])
        elif left > 0.0:
            head.append([spin, kappa, left])
            tail.append([0.0, kappa, length - left])  # same arc, no new spin
        else:
            tail.append([spin, kappa, length])
        left -= length
    first = SteerablePlan(plan.start_pose, np.array(head).reshape(-1, 3))
    return first, SteerablePlan(first.end_pose(), np.array(tail).reshape(-1, 3))


def _solve(problem, planner, budget) -> PlanResult:
    return solve(problem, planner, **budget)


def _kept(problem: SteerableProblem, rest: SteerablePlan | None, res: PlanResult):
    """The rest of the previous plan when it still passes this cycle's check and the new
    search found nothing cheaper, as a result; else None."""
    if rest is None or len(rest.primitives) == 0:
        return None
    check = verify_plan(problem, rest)
    cost = check.metrics["cost"]
    if not check.ok or (res.status is PlanStatus.SOLVED and res.cost_mm < cost - 1e-9):
        return None
    stats = {
        "reason": "the rest of the previous plan, re-checked against this cycle",
        "search_status": res.status.value,
        "certified_clearance_mm": check.metrics["certified_clearance_mm"],
    }
    return PlanResult(PlanStatus.SOLVED, "kept", rest, cost, 0.0, problem.goal_mm, stats,
                      problem.start_pose)  # fmt: skip


def plan_static(
    problem: SteerableProblem,
    moving: Sequence[MovingObstacle],
    insertion_speed_mm_s: float,
    *,
    planner: str = "rrt",
    time_limit_s: float | None = None,
    max_iterations: int | None = None,
    seed: int | None = 0,
    options=None,
) -> tuple[PlanResult, Verification | None]:
    """The baseline: plan once at ``t = 0`` (the obstacles where they are then) and execute
    the plan open-loop while they move.

    Parameters
    ----------
    problem : SteerableProblem
        The static anatomy, start, goal and limits.
    moving : sequence of MovingObstacle
    insertion_speed_mm_s : float
    planner, time_limit_s, max_iterations, seed, options
        As :func:`needlekit.planning.steerable.solve.solve`.

    Returns
    -------
    result : PlanResult
    check : Verification or None
        :func:`~needlekit.planning.steerable.moving.certify_execution` of the plan
        executed (None without a plan).
    """
    speed = as_positive(insertion_speed_mm_s, "insertion_speed_mm_s")
    moving = check_moving(problem, moving)
    scene = scene_with(problem.scene, {m.name: m.field for m in moving})
    budget = {"time_limit_s": time_limit_s, "max_iterations": max_iterations, "seed": seed}
    res = _solve(continuation_problem(problem, _nothing(problem), scene), planner,
                 {**budget, "options": options})  # fmt: skip
    if res.plan is None:
        return res, None
    return res, certify_execution(
        problem, moving, res.plan, speed, require_goal=res.status is PlanStatus.SOLVED
    )


def _nothing(problem: SteerableProblem) -> SteerablePlan:
    return SteerablePlan(problem.start_pose, np.zeros((0, 3)))


def check_settings(
    insertion_speed_mm_s, step_mm, predict: str, lookahead_s=None
) -> tuple[float, float, float]:
    """The run's settings checked (cheap: callers check them before loading anatomy).

    Parameters
    ----------
    insertion_speed_mm_s, step_mm : float
        > 0.
    predict : str
        One of :data:`PREDICTIONS`.
    lookahead_s : float, optional
        >= 0, only with ``"swept"``.

    Returns
    -------
    speed, step, lookahead : float
        The lookahead defaults to the advance's time.

    Raises
    ------
    InvalidInputError
        Naming the setting.
    """
    speed = as_positive(insertion_speed_mm_s, "insertion_speed_mm_s")
    step = as_positive(step_mm, "step_mm")
    if predict not in PREDICTIONS:
        raise InvalidInputError(
            "predict", f"expected one of {', '.join(PREDICTIONS)}, got {predict!r}"
        )
    if lookahead_s is not None and predict != "swept":
        raise InvalidInputError("lookahead_s", f"only goes with predict='swept', not {predict!r}")
    ahead = step / speed if lookahead_s is None else float(lookahead_s)
    if not (math.isfinite(ahead) and ahead >= 0.0):
        raise InvalidInputError("lookahead_s", f"must be a finite number >= 0, got {lookahead_s!r}")
    return speed, step, ahead


def replan_among_moving(
    problem: SteerableProblem,
    moving: Sequence[MovingObstacle],
    *,
    insertion_speed_mm_s: float,
    step_mm: float = DEFAULT_STEP_MM,
    predict: str = "arrival",
    lookahead_s: float | None = None,
    planner: str = "rrt",
    time_limit_s: float | None = None,
    max_iterations: int | None = None,
    seed: int | None = 0,
    options=None,
    compare_static: bool = True,
) -> DynamicResult:
    """Plan, advance ``step_mm``, and plan again from the tip, among moving obstacles
    (module notes).

    Parameters
    ----------
    problem : SteerableProblem
        The static anatomy (without the moving obstacles), start pose, goal and limits;
        field collision model.
    moving : sequence of MovingObstacle
    insertion_speed_mm_s : float
        Constant insertion speed (mm/s): time is inserted length over it.
    step_mm : float
        How far the needle advances along each cycle's plan before planning again.
    predict : {"arrival", "swept", "snapshot"}
        What each cycle plans against (module notes).
    lookahead_s : float, optional
        With ``"swept"``: how long to sweep (default the advance's time,
        ``step_mm / insertion_speed_mm_s``).
    planner : str
        A registered steerable planner (default ``"rrt"``, the lecture's).
    time_limit_s, max_iterations, options
        Each cycle's budget and planner options.
    seed : int, optional
        Cycle ``k`` plans with ``seed + k`` (randomised planners).
    compare_static : bool
        Also run :func:`plan_static` (same planner, budget and seed).

    Returns
    -------
    DynamicResult

    Raises
    ------
    InvalidInputError
        A bad setting (named), a problem without a start pose or with the
        ``voxel_centres`` model, or a moving obstacle whose name the scene already has.
    """
    speed, step, ahead = check_settings(insertion_speed_mm_s, step_mm, predict, lookahead_s)
    moving = check_moving(problem, moving)
    budget = {"time_limit_s": time_limit_s, "max_iterations": max_iterations, "options": options}
    colors = {m.name: m.color for m in moving}
    executed, rest = _nothing(problem), None
    cycles: list[Cycle] = []
    status, reason, k = None, "", 0
    while status is None:
        t = executed.length_mm / speed
        fields, window = _predicted(problem, moving, predict, executed, speed, ahead)
        try:
            scene = scene_with(problem.scene, fields, colors)
            cycle_problem = continuation_problem(problem, executed, scene)
        except InvalidInputError as exc:
            status, reason = DynamicStatus.NO_PLAN, f"cycle {k + 1}: {exc.reason}"
            break
        res = _solve(cycle_problem, planner, {**budget, "seed": None if seed is None else seed + k})
        kept = _kept(cycle_problem, rest, res)
        row = {
            "index": k,
            "t_s": t,
            "inserted_mm": executed.length_mm,
            "tip_pose": cycle_problem.start_pose,
            "obstacle_offsets_mm": {m.name: m.motion.offset_mm(t).tolist() for m in moving},
            "window_s": window,
            "result": res if kept is None else kept,
            "source": "planned" if kept is None else "kept",
        }
        plan = row["result"].plan
        if row["result"].status is not PlanStatus.SOLVED:
            cycles.append(Cycle(**row))
            why = res.stats.get("reason", "")
            status = DynamicStatus.NO_PLAN
            reason = f"cycle {k + 1}: no plan from the tip ({res.status.value}: {why})"
            break
        piece, rest = _split(plan, step)
        cycles.append(Cycle(**row, advanced_mm=piece.length_mm))
        executed = SteerablePlan(
            problem.start_pose, np.vstack([executed.primitives, piece.primitives])
        )
        advance = _advance_check(problem, moving, piece, t, speed)
        if advance is not None:
            status, reason = DynamicStatus.UNSAFE, f"cycle {k + 1}: {advance}"
        elif len(rest.primitives) == 0:
            status, reason = DynamicStatus.REACHED, f"goal reached in {k + 1} cycles"
        k += 1
    check = certify_execution(
        problem, moving, executed, speed, require_goal=status is DynamicStatus.REACHED
    )
    if status is DynamicStatus.REACHED and not check.ok:
        status, reason = DynamicStatus.CHECK_FAILED, "; ".join(check.violations)
    static = None
    if compare_static:
        static = plan_static(problem, moving, speed, planner=planner, seed=seed, **budget)
    settings = {
        "planner": planner,
        "insertion_speed_mm_s": speed,
        "step_mm": step,
        "predict": predict,
        "lookahead_s": ahead if predict == "swept" else None,
    }
    return DynamicResult(
        status, reason, executed, check, tuple(cycles), settings, tuple(moving), static
    )


def _predicted(problem, moving, predict, executed, speed, ahead):
    """The moving obstacles a cycle plans against, and the times they stand for."""
    t = executed.length_mm / speed
    if predict == "snapshot":
        return {m.name: m.at(t) for m in moving}, (t, t)
    if predict == "swept":
        return {m.name: m.swept(t, t + ahead) for m in moving}, (t, t + ahead)
    tip = executed.end_pose()[:3, 3]
    left = problem.max_length_mm - executed.length_mm
    if left <= 0.0:
        return {m.name: m.at(t) for m in moving}, (t, t)  # the continuation refuses it
    fields = {
        m.name: ArrivalField(m.field, m.motion, t, tip, speed, problem.r_min_mm, left)
        for m in moving
    }
    if not fields:
        return fields, (t, t)
    lo, hi = next(iter(fields.values())).window_s(problem.goal_mm)
    return fields, (float(lo[0]), float(hi[0]))


def _advance_check(problem, moving, piece: SteerablePlan, t0_s: float, speed: float) -> str | None:
    """Why an advance is unsafe against the moving obstacles as they moved, or None."""
    points, arcs = path_samples(piece, CHECK_SPACING_MM)
    # the original problem's start exclusion, as the final check applies it
    per = moving_clearance(problem, moving, points, arcs, speed, t0_s, CHECK_SPACING_MM)
    for name, (sampled, certified, first) in per.items():
        if math.isnan(sampled) or certified < problem.safety_margin_mm:
            when = "" if first is None else f", first contact at t = {first[0]:.2f} s"
            return (
                f"the advance came within {certified:.3f} mm (certified) of the moving "
                f"obstacle {name!r} as it moved{when}"
            )
    return None
