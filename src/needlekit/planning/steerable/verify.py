"""Independent check of a steerable-needle plan against its problem.

Every plan a planner reports passes this check first, and ``needlekit verify`` runs it on
plan files. It re-derives the path from the plan's primitives alone and checks:

- curvature: every primitive's ``|curvature| <= 1 / r_min``;
- length: total insertion ``<= l_max``;
- goal: the end lies within tau of the goal;
- heading: the angle between the start direction and every later direction (sampled
  densely) stays within the limit;
- puncture angle: the angle between the start direction and the entry surface (90 degrees
  minus the angle to its outward normal) is at least alpha;
- cost: when the caller states the plan's cost (a plan file's ``cost_mm``), it matches
  the cost recomputed from the primitives (path length, or the clearance cost map's
  integral);
- clearance: no sample of the path (every ``spacing_mm``) collides. With
  :class:`~needlekit.anatomy.occupancy.VoxelObstacles` this is the exact voxel-centre test
  with the start exclusion; otherwise the scene's obstacle field must keep the needle
  radius plus margin, outside the start exclusion ball.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from needlekit.anatomy.occupancy import VoxelObstacles
from needlekit.geometry.arcs import propagate_arcs, samples_for_spacing
from needlekit.planning.steerable.cost import plan_cost
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem

__all__ = ["Verification", "verify_approximate", "verify_plan"]

#: Slack on the checked limits (curvature, length, goal distance, angles): rounding only.
VERIFY_SLACK: float = 1e-9


@dataclass(frozen=True)
class Verification:
    """Outcome of :func:`verify_plan`.

    Attributes
    ----------
    ok : bool
        No violation.
    violations : tuple of str
        One line per broken rule, naming it and the measured value.
    metrics : dict
        ``cost`` (recomputed), ``length_mm``, ``goal_distance_mm``, ``max_curvature_per_mm``,
        ``max_heading_change_deg``, ``puncture_angle_deg`` (or None),
        ``min_clearance_mm`` (the obstacle field's, outside the start exclusion) and
        ``colliding_samples``.
    """

    ok: bool
    violations: tuple[str, ...]
    metrics: dict = field(default_factory=dict)


def _dense_poses(plan: SteerablePlan, spacing_mm: float) -> np.ndarray:
    poses = plan.poses()
    out = [poses[:1]]
    for i, (spin, kappa, length) in enumerate(plan.primitives):
        if length <= 0:
            continue
        m = samples_for_spacing(length, spacing_mm)
        s = np.linspace(0.0, length, m)[1:]
        out.append(propagate_arcs(poses[i], np.full(s.shape, spin), np.full(s.shape, kappa), s))
    return np.concatenate(out)


def verify_plan(
    problem: SteerableProblem,
    plan: SteerablePlan,
    *,
    obstacles: VoxelObstacles | None = None,
    spacing_mm: float = 0.25,
    expected_cost_mm: float | None = None,
) -> Verification:
    """Check a plan against every constraint of its problem.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan
    obstacles : VoxelObstacles, optional
        Exact voxel-centre collision test (with the start exclusion); without it, the
        scene's obstacle field is used.
    spacing_mm : float
        Spacing of the samples along the path.
    expected_cost_mm : float, optional
        The cost the plan claims; a violation when the recomputed cost differs by more
        than 1e-6 mm (relative 1e-9).

    Returns
    -------
    Verification
    """
    bad: list[str] = []
    prims = plan.primitives
    start = plan.start_pose
    kappa_max = problem.kappa_max_per_mm
    max_kappa = float(np.abs(prims[:, 1]).max()) if len(prims) else 0.0
    if max_kappa > kappa_max * (1 + VERIFY_SLACK) + VERIFY_SLACK:
        bad.append(f"curvature: {max_kappa:.6g} /mm exceeds 1 / r_min = {kappa_max:.6g} /mm")
    length = plan.length_mm
    if length > problem.max_length_mm + VERIFY_SLACK:
        bad.append(f"length: {length:.4f} mm exceeds l_max = {problem.max_length_mm:g} mm")
    poses = _dense_poses(plan, spacing_mm)
    end = poses[-1, :3, 3]
    goal_dist = float(np.linalg.norm(end - problem.goal_mm))
    if goal_dist > problem.goal_tolerance_mm + VERIFY_SLACK:
        bad.append(
            f"goal: ends {goal_dist:.4f} mm from the goal, tolerance {problem.goal_tolerance_mm:g} mm"
        )
    d0 = start[:3, 2]
    cosines = np.clip(poses[:, :3, 2] @ d0, -1.0, 1.0)
    heading = float(np.degrees(np.arccos(cosines.min())))
    if heading > problem.max_heading_change_deg + 1e-7:
        bad.append(
            f"heading: turns {heading:.3f} deg from the start direction, limit {problem.max_heading_change_deg:g} deg"
        )
    puncture = None
    if problem.entry_surface is not None:
        n = problem.scene.normal(start[:3, 3], problem.entry_surface)
        if np.all(np.isfinite(n)):
            puncture = float(np.degrees(np.arcsin(np.clip(d0 @ n, -1.0, 1.0))))
            if puncture < problem.min_puncture_angle_deg - 1e-7:
                bad.append(
                    f"puncture angle: {puncture:.3f} deg to the {problem.entry_surface} surface, "
                    f"minimum {problem.min_puncture_angle_deg:g} deg"
                )
    points = poses[:, :3, 3]
    far = np.linalg.norm(points - start[:3, 3], axis=1) >= problem.start_exclusion_mm
    field_clear = problem.scene.clearance(points[far]) if far.any() else np.array([np.inf])
    min_clear = float(field_clear.min())
    if obstacles is not None:
        hits = obstacles.collides(
            points, exclude_near=start[:3, 3], exclusion_mm=problem.start_exclusion_mm
        )
        n_hits = int(np.count_nonzero(hits))
        if n_hits:
            first = points[np.flatnonzero(hits)[0]]
            bad.append(
                f"collision: {n_hits} samples within {obstacles.min_distance_mm:.4f} mm of an "
                f"obstacle voxel centre, first at {np.round(first, 2).tolist()}"
            )
    else:
        n_hits = int(np.count_nonzero(field_clear < problem.clearance_margin_mm))
        if n_hits:
            bad.append(
                f"collision: clearance {min_clear:.4f} mm below the needle's "
                f"{problem.clearance_margin_mm:g} mm outside the start exclusion"
            )
    cost = plan_cost(problem, plan)
    if expected_cost_mm is not None and not (
        abs(float(expected_cost_mm) - cost) <= 1e-6 + 1e-9 * abs(cost)
    ):
        bad.append(f"cost: the plan claims {float(expected_cost_mm):.6f}, recomputed {cost:.6f}")
    metrics = {
        "cost": cost,
        "length_mm": length,
        "goal_distance_mm": goal_dist,
        "max_curvature_per_mm": max_kappa,
        "max_heading_change_deg": heading,
        "puncture_angle_deg": puncture,
        "min_clearance_mm": min_clear,
        "colliding_samples": n_hits,
    }
    return Verification(not bad, tuple(bad), metrics)


def verify_approximate(
    problem: SteerableProblem,
    plan: SteerablePlan,
    *,
    obstacles: VoxelObstacles | None = None,
    spacing_mm: float = 0.25,
) -> Verification:
    """Check a path that stops short of the goal (an approximate solution): every rule of
    :func:`verify_plan` except the goal tolerance, which becomes the distance it reaches.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan
    obstacles : VoxelObstacles, optional
    spacing_mm : float

    Returns
    -------
    Verification
        ``metrics["goal_distance_mm"]`` is how far from the goal the path ends.
    """
    from dataclasses import replace

    reached = float(np.linalg.norm(plan.end_pose()[:3, 3] - problem.goal_mm))
    relaxed = replace(
        problem,
        goal_tolerance_mm=max(problem.goal_tolerance_mm, reached),
        start_point_mm=None if problem.start_pose is not None else problem.start_point_mm,
    )
    return verify_plan(relaxed, plan, obstacles=obstacles, spacing_mm=spacing_mm)
