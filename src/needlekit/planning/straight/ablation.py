"""Ablation coverage coupled to the straight multi-needle planner.

From a tumour (a voxel mask, or any structure's distance field voxelised here) and an
ablation zone, :func:`choose_needle_targets` picks targets whose zones cover the tumour
plus a margin with few needles (:func:`~.coverage.choose_targets`), keeping only targets
a needle can reach: inside the body (the entry surface's inside) and clear of every
obstacle by the needle radius plus gamma. The planner (``liu_cfrw``) then plans one
trajectory per target, and :func:`planned_coverage` re-evaluates the coverage with each
planned needle's real insertion direction (entry to tip), which the zones follow.

Sign convention: :mod:`~.coverage` takes *insertion* directions (entry to tip); Sigma's
``up`` points from the target toward the entry (where the needle comes from), so the
direction assumed while choosing is ``-up`` (for a Med-RAD start pose: its z axis).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import Termination
from needlekit.planning.straight.coverage import (
    AblationZone,
    CoveragePlan,
    CoverageReport,
    CoverageStatus,
    TargetRegion,
    choose_targets,
    evaluate_coverage,
    fraction_text,
)
from needlekit.planning.straight.planner import MultiNeedleProblem
from needlekit.planning.straight.problem import StraightProblem
from needlekit.planning.straight.sequence import MultiNeedlePlan
from needlekit.records import field_of

__all__ = [
    "DEFAULT_VOXEL_MM",
    "MIN_TARGET_DEPTH_MM",
    "AblationOutcome",
    "choose_needle_targets",
    "clip_region",
    "plan_coverage",
    "plan_with_coverage",
    "planned_coverage",
    "voxelise",
]

#: Voxel size (mm) of a tumour given as a distance field (analytic shapes, phantoms): 1 mm
#: counts a 20 mm ball's volume to about 1 %, and a 50 mm region has ~10^5 voxels.
DEFAULT_VOXEL_MM: float = 1.0
#: A needle target must lie at least this deep (mm) inside the body: the planner's entry
#: search starts at the target and needs it strictly inside the entry surface.
MIN_TARGET_DEPTH_MM: float = 1.0


def voxelise(field: DistanceField, voxel_mm: float = DEFAULT_VOXEL_MM):
    """A structure's inside as a voxel mask: voxel centres where its signed distance <= 0.

    Parameters
    ----------
    field : DistanceField
        A bounded field (``bounds()`` finite), world RAS mm.
    voxel_mm : float
        Isotropic voxel size (mm).

    Returns
    -------
    mask : ndarray of bool, shape (i, j, k)
    affine : ndarray, shape (4, 4)
        Voxel index -> RAS (mm).

    Examples
    --------
    >>> from needlekit.anatomy.primitives import Sphere
    >>> mask, affine = voxelise(Sphere([0, 0, 0], 5.0), 1.0)
    >>> int(mask.sum())
    515
    """
    h = float(voxel_mm)
    if not (np.isfinite(h) and h > 0):
        raise InvalidInputError("voxel_mm", f"must be a number > 0, got {voxel_mm!r}")
    b = np.asarray(field.bounds(), dtype=float).reshape(2, 3)
    if not np.all(np.isfinite(b)):
        raise InvalidInputError("structure", "its field is unbounded: cannot voxelise it")
    lo = np.floor(b[0] / h) * h - h
    n = np.ceil((b[1] - lo) / h).astype(int) + 2
    if np.prod(n) > 5e7:
        raise InvalidInputError("voxel_mm", f"{h:g} mm gives {int(np.prod(n))} voxels: too many")
    axes = [lo[i] + h * np.arange(n[i]) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    mask = (field.signed_distance(pts) <= 0.0).reshape(tuple(n))
    affine = np.diag([h, h, h, 1.0])
    affine[:3, 3] = lo
    if not mask.any():
        raise InvalidInputError("structure", f"no voxel centre inside at {h:g} mm voxels")
    return mask, affine


def clip_region(region: TargetRegion, body: DistanceField) -> TargetRegion:
    """The region's voxels inside the body (the margin is organ tissue; beyond the organ's
    surface there is none to ablate). Tumour voxels are kept whatever the body says.

    Parameters
    ----------
    region : TargetRegion
    body : DistanceField
        Negative inside the organ.

    Returns
    -------
    TargetRegion
    """
    idx = np.argwhere(region.mask)
    pts = idx @ region.affine[:3, :3].T + region.affine[:3, 3]
    inside = body.signed_distance(pts) <= 0.0
    mask = np.zeros_like(region.mask)
    mask[tuple(idx[inside].T)] = True
    mask |= region.tumour
    return TargetRegion(mask, region.tumour, region.affine, region.margin_mm)


def _reachable(problem: StraightProblem):
    body = problem.scene[problem.entry_surface].field
    obstacles = problem.obstacle_field()
    need = problem.clearance_needed_mm + obstacles.error_bound_mm

    def allowed(targets: np.ndarray, _directions: np.ndarray) -> np.ndarray:
        deep = body.signed_distance(targets) <= -MIN_TARGET_DEPTH_MM
        clear = obstacles.signed_distance(targets) >= need
        return deep & clear

    return allowed


def choose_needle_targets(
    problem: StraightProblem,
    region: TargetRegion,
    zone: AblationZone,
    *,
    max_needles: int,
    coverage_goal: float,
    directions_from: MultiNeedlePlan | None = None,
) -> CoveragePlan:
    """Targets covering the region, each one a needle can reach.

    Candidates are kept when they lie :data:`MIN_TARGET_DEPTH_MM` inside the entry
    surface and clear of every obstacle by the needle radius plus gamma (a tip closer to a
    vessel is blocked in every direction). Every needle is assumed to come along ``-up``.

    Parameters
    ----------
    problem : StraightProblem
    region : TargetRegion
    zone : AblationZone
    max_needles : int
    coverage_goal : float
    directions_from : MultiNeedlePlan, optional
        A plan already made: each candidate then assumes the insertion direction of the
        planned needle whose target is nearest (a second round after the real directions
        lost coverage).

    Returns
    -------
    CoveragePlan
    """
    w = -np.asarray(problem.up, dtype=float)
    direction = w / np.linalg.norm(w)
    done = [n for n in (directions_from.needles if directions_from else ()) if n.entry is not None]
    if done:
        tips = np.array([n.planned_target_mm for n in done], dtype=float)
        dirs = np.array([n.target_mm - n.entry.entry_mm for n in done], dtype=float)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)

        def direction(centres: np.ndarray) -> np.ndarray:
            near = np.argmin(((centres[:, None, :] - tips[None]) ** 2).sum(-1), axis=1)
            return dirs[near]

    return choose_targets(
        region,
        zone,
        direction=direction,
        max_needles=max_needles,
        coverage_goal=coverage_goal,
        allowed=_reachable(problem),
    )


def planned_coverage(
    region: TargetRegion, zone: AblationZone, plan: MultiNeedlePlan
) -> CoverageReport:
    """Coverage of the planned needles, each zone along its real trajectory.

    A needle's tip is its planned target (in the tissue's rest frame: a deformation moves
    tissue and aimed target together) and its direction is entry to aimed target.
    Needles without a trajectory ablate nothing.

    Parameters
    ----------
    region : TargetRegion
    zone : AblationZone
    plan : MultiNeedlePlan

    Returns
    -------
    CoverageReport
    """
    tips, dirs = [], []
    for n in plan.needles:
        if n.entry is None:
            continue
        d = np.asarray(n.target_mm, float) - np.asarray(n.entry.entry_mm, float)
        tips.append(np.asarray(n.planned_target_mm, float))
        dirs.append(d / np.linalg.norm(d))
    if not tips:
        return evaluate_coverage(region, zone, np.zeros((0, 3)))
    return evaluate_coverage(region, zone, np.array(tips), np.array(dirs))


@dataclass(frozen=True)
class AblationOutcome:
    """Targets chosen, trajectories planned, coverage re-checked.

    Attributes
    ----------
    chosen : CoveragePlan
        The targets, chosen for the approach direction ``-up``.
    planned : CoverageReport or None
        Coverage with the planned trajectories' directions (None: nothing planned).
    ok : bool
        The targets reached the goal, every needle was planned, and the planned coverage
        reaches the goal.
    reason : str
        Why not ("" when ok).
    """

    chosen: CoveragePlan
    planned: CoverageReport | None
    ok: bool
    reason: str = ""

    @classmethod
    def of(cls, chosen: CoveragePlan, plan: MultiNeedlePlan | None, planned, max_needles: int):
        """Judge a run: the first failed step gives the reason.

        Parameters
        ----------
        chosen : CoveragePlan
        plan : MultiNeedlePlan or None
        planned : CoverageReport or None
        max_needles : int

        Returns
        -------
        AblationOutcome
        """
        goal = chosen.coverage_goal
        if chosen.status is not CoverageStatus.COVERED:
            reason = (
                f"coverage: {max_needles} needles reach {fraction_text(chosen.report.coverage)} "
                "of the "
                f"tumour plus margin, goal {goal:g} (reachable targets only; lower bound "
                f"{chosen.needles_lower_bound} needles)"
            )
            if chosen.needles == 0:
                reason = "coverage: no reachable target (all inside obstacles or outside the body)"
            return cls(chosen, planned, False, reason)
        if plan is not None and not plan.solved:
            return cls(chosen, planned, False, f"trajectories: {plan.reason}")
        if planned is not None and planned.coverage < goal - 1e-12:
            return cls(
                chosen,
                planned,
                False,
                f"coverage: {fraction_text(planned.coverage)} with the planned directions "
                f"({planned.uncovered_ml * 1000:.1f} uL of tumour plus margin uncovered), "
                f"goal {goal:g}",
            )
        return cls(chosen, planned, True, "")

    def to_dict(self) -> dict:
        """JSON-ready record (``multi.json``'s ``coverage``).

        Returns
        -------
        dict
        """
        z = self.chosen.zone
        rep = self.planned if self.planned is not None else self.chosen.report
        return {
            "status": "covered" if self.ok else "not_covered",
            "reason": self.reason,
            "coverage": rep.coverage,
            "tumour_coverage": rep.tumour_coverage,
            "needles": rep.needles,
            "healthy_ablated_ml": rep.healthy_ablated_ml,
            "ablated_outside_region_ml": rep.ablated_outside_region_ml,
            "tumour_volume_ml": rep.tumour_volume_ml,
            "region_volume_ml": rep.region_volume_ml,
            "zone": z.to_dict(),
            "coverage_goal": self.chosen.coverage_goal,
            "planned": None if self.planned is None else self.planned.to_dict(),
            "chosen": self.chosen.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: dict | None, where: str) -> AblationOutcome | None:
        """The ablation coverage of a multi-needle plan from its record (``multi.json``'s
        ``coverage``), as :meth:`to_dict` writes it.

        Parameters
        ----------
        data : dict or None
        where : str
            Names the record in messages.

        Returns
        -------
        AblationOutcome or None
            None when the record is null (the plan's targets were not chosen for coverage).

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named).
        """
        if data is None:
            return None
        zone = AblationZone.from_dict(field_of(data, "zone", where, "dict"), f"{where}: zone")
        chosen = CoveragePlan.from_dict(
            field_of(data, "chosen", where, "dict"), f"{where}: chosen", zone
        )
        planned = field_of(data, "planned", where, "dict", optional=True)
        if planned is not None:
            planned = CoverageReport.from_dict(planned, f"{where}: planned")
        ok = field_of(data, "status", where, "str") == "covered"
        reason = field_of(data, "reason", where, "str", optional=True) or ""
        return cls(chosen, planned, ok, reason)


def plan_with_coverage(
    problem: StraightProblem,
    region: TargetRegion,
    zone: AblationZone,
    solve,
    *,
    max_needles: int,
    coverage_goal: float,
    timings: dict | None = None,
) -> tuple[MultiNeedlePlan | None, AblationOutcome]:
    """Choose targets covering the region, plan them, re-check the coverage along the
    planned needles, and when their real directions lost it, choose once more along them
    and plan again (the better of the two rounds is kept).

    Parameters
    ----------
    problem : StraightProblem
    region : TargetRegion
        Tumour plus margin.
    zone : AblationZone
    solve : callable
        ``solve(targets_mm (k, 3)) -> MultiNeedlePlan`` (e.g. the ``liu_cfrw`` planner).
    max_needles : int
    coverage_goal : float
    timings : dict, optional
        Filled with the seconds of each step (``choose_targets_s``, ``trajectories_s``,
        ``coverage_check_s``, summed over rounds) and ``rounds``.

    Returns
    -------
    plan : MultiNeedlePlan or None
        None when no target could be chosen.
    outcome : AblationOutcome
    """
    steps = {} if timings is None else timings
    steps["rounds"] = 1

    def step(name, fn):
        t0 = time.perf_counter()
        out = fn()
        steps[name] = steps.get(name, 0.0) + time.perf_counter() - t0
        return out

    def choose(**kw):
        return step(
            "choose_targets_s",
            lambda: choose_needle_targets(
                problem, region, zone, max_needles=max_needles, coverage_goal=coverage_goal, **kw
            ),
        )

    chosen = choose()
    if chosen.needles == 0:
        return None, AblationOutcome.of(chosen, None, None, max_needles)
    plan = step("trajectories_s", lambda: solve(chosen.targets_mm))
    planned = step("coverage_check_s", lambda: planned_coverage(region, zone, plan))
    outcome = AblationOutcome.of(chosen, plan, planned, max_needles)
    if plan.solved and chosen.status is CoverageStatus.COVERED and not outcome.ok:
        steps["rounds"] = 2
        again = choose(directions_from=plan)
        if again.needles:
            plan2 = step("trajectories_s", lambda: solve(again.targets_mm))
            planned2 = step("coverage_check_s", lambda: planned_coverage(region, zone, plan2))
            outcome2 = AblationOutcome.of(again, plan2, planned2, max_needles)
            if outcome2.ok or (plan2.solved and planned2.coverage > planned.coverage):
                return plan2, outcome2
    return plan, outcome


def plan_coverage(
    multi: MultiNeedleProblem,
    planner,
    region: TargetRegion,
    settings: Mapping,
    *,
    time_limit_s: float,
    timings: dict | None = None,
) -> tuple[MultiNeedlePlan | None, AblationOutcome]:
    """The coverage pipeline of ``needlekit multi``, the liver study and the straight
    benchmark: :func:`plan_with_coverage` with ``planner`` solving each round's targets.

    Parameters
    ----------
    multi : MultiNeedleProblem
        Its problem is planned; its targets are replaced by the chosen ones.
    planner : Planner
        A straight multi-needle planner (``liu_cfrw``): ``planner.solve(multi,
        termination) -> MultiNeedlePlan``.
    region : TargetRegion
        Tumour plus margin.
    settings : mapping
        The scenario's coverage block: ``zone`` (AblationZone), ``max_needles`` (int) and
        ``coverage_goal`` (float in [0, 1]) are used
        (:func:`needlekit.scenario.straight.coverage_region` returns it).
    time_limit_s : float
        Budget of each round's planning (s); every round gets a fresh one.
    timings : dict, optional
        Filled as :func:`plan_with_coverage` fills it.

    Returns
    -------
    plan : MultiNeedlePlan or None
        None when no target could be chosen.
    outcome : AblationOutcome
    """
    return plan_with_coverage(
        multi.problem,
        region,
        settings["zone"],
        lambda targets: planner.solve(
            replace(multi, targets_mm=targets), Termination(time_limit_s)
        ),
        max_needles=settings["max_needles"],
        coverage_goal=settings["coverage_goal"],
        timings=timings,
    )
