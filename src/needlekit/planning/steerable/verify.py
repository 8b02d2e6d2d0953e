"""Independent check of a steerable-needle plan against its problem.

Every plan a planner reports passes this check first, and ``needlekit verify`` runs it on
plan files. It re-derives the path from the plan's primitives alone and checks:

- start: the plan starts at the problem's start point (within :data:`START_TOLERANCE_MM`)
  and, when the problem has a start pose, in its insertion direction (within
  :data:`START_TOLERANCE_RAD`; the roll about the needle is free). A problem with only a
  start point (a sweep's) leaves the direction to the other rules (puncture angle);
- curvature: every primitive's ``|curvature| <= 1 / r_min``;
- length: total insertion ``<= l_max``;
- goal: the end lies within tau of the goal;
- heading: the angle between the start direction and every later direction stays within
  the limit (its largest value along each arc in closed form, as the searches check it,
  not only at samples);
- puncture angle: the angle between the start direction and the entry surface (90 degrees
  minus the angle to its outward normal) is at least alpha;
- cost: when the caller states the plan's cost (a plan file's ``cost_mm``), it matches
  the cost recomputed from the primitives (path length, or the clearance cost map's
  integral);
- clearance, certified, by the one rule the searches apply (:mod:`needlekit.constants`):
  ``certified_clearance_mm`` is a lower bound on the distance from the needle's surface to
  every obstacle outside the start exclusion (for ``voxel_centres``, to the obstacle voxel
  balls), for the whole path, not only its samples: the smallest sampled distance less half
  the sample gap, the model's stated error bound and the needle radius. The plan fails
  when it is below the safety margin. Two samplings certify it, and the path is clear when
  either does (each is a proof; the bound reported is the better one): the search's own
  samples, re-derived from the primitives (:func:`motion_samples`, every
  :data:`~needlekit.constants.MOTION_SPACING_MM` of each primitive), so that every plan a
  search accepted passes; and samples every ``spacing_mm``
  (:data:`~needlekit.constants.VERIFY_SPACING_MM` by default), which see between them.

A rule that cannot be checked (e.g. a puncture angle whose surface normal is undefined at
the start) counts as broken.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from needlekit.anatomy.collision import ClearanceCertificate
from needlekit.constants import MOTION_SPACING_MM, VERIFY_SPACING_MM
from needlekit.geometry.arcs import arc_points_unchecked, propagate_arcs, samples_for_spacing
from needlekit.geometry.so3 import angle_between
from needlekit.planning.result import Verification
from needlekit.planning.steerable.cost import plan_cost
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem

__all__ = [
    "START_TOLERANCE_MM",
    "START_TOLERANCE_RAD",
    "Verification",
    "motion_samples",
    "search_clearance_mm",
    "verify_approximate",
    "verify_plan",
]

#: Slack on the checked limits (curvature, length, goal distance, angles): rounding only.
VERIFY_SLACK: float = 1e-9

#: How far a plan may start from the problem's start point (mm) and turn from its start
#: direction (rad): a plan file stores its start pose to full precision, so only rounding.
START_TOLERANCE_MM: float = 1e-6
START_TOLERANCE_RAD: float = 1e-6


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


def motion_samples(plan: SteerablePlan, spacing_mm: float = MOTION_SPACING_MM) -> np.ndarray:
    """The collision samples a search tested along a plan: each primitive sampled as
    :meth:`~needlekit.planning.steerable.validity.MotionValidator.motion_valid` samples a
    motion (its start left out, the same count and kernel), the start point first.

    Parameters
    ----------
    plan : SteerablePlan
    spacing_mm : float
        The search's motion spacing.

    Returns
    -------
    ndarray, shape (k, 3), float64, C-contiguous
        World points (mm).
    """
    poses = plan.poses()
    chunks = [poses[0, :3, 3][None]]
    for i, (spin, kappa, length) in enumerate(plan.primitives):
        if length <= 0:
            continue
        m = samples_for_spacing(length, spacing_mm)
        pose = np.ascontiguousarray(poses[i])
        chunks.append(arc_points_unchecked(pose, float(spin), float(kappa), float(length), m)[1:])
    return np.ascontiguousarray(np.concatenate(chunks))


def search_clearance_mm(problem: SteerableProblem, plan: SteerablePlan) -> float:
    """The certified clearance of a plan by the search's own samples alone (every
    :data:`~needlekit.constants.MOTION_SPACING_MM` of each primitive, half of it lost to the
    gaps): the largest safety margin under which a search accepts this path's motions.
    :func:`verify_plan` reports the better of this and its dense certificate, so this is
    at most its ``certified_clearance_mm``.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan

    Returns
    -------
    float
        mm; -inf when a sample collides.
    """
    start = plan.start_pose
    own = not np.array_equal(start[:3, 3], problem.start_point_mm)
    source = replace(problem, start_pose=start, start_point_mm=None) if own else problem
    checker = source.collision_checker(MOTION_SPACING_MM)
    cert = checker.certify(motion_samples(plan, MOTION_SPACING_MM), MOTION_SPACING_MM)
    return float(cert.certified_clearance_mm)


def _certified_clearance(
    problem: SteerableProblem, start: np.ndarray, plan: SteerablePlan, dense: np.ndarray,
    spacing_mm: float,
) -> tuple[ClearanceCertificate, str, float]:
    """The better of the two certificates (module notes): the search's samples and the
    dense ones. Returns it, the checker's name and the smallest distance any sample saw."""
    own = not np.array_equal(start[:3, 3], problem.start_point_mm)
    source = replace(problem, start_pose=start, start_point_mm=None) if own else problem
    checker = source.collision_checker(MOTION_SPACING_MM)
    certs = [checker.certify(motion_samples(plan, MOTION_SPACING_MM), MOTION_SPACING_MM)]
    if float(spacing_mm) != MOTION_SPACING_MM:
        dense_checker = source.collision_checker(spacing_mm)
        certs.append(dense_checker.certify(dense, spacing_mm))
    best = max(certs, key=lambda c: (c.violation is None, c.certified_clearance_mm))
    return best, checker.name, min(c.sampled_clearance_mm for c in certs)


def verify_plan(
    problem: SteerableProblem,
    plan: SteerablePlan,
    *,
    spacing_mm: float = VERIFY_SPACING_MM,
    expected_cost_mm: float | None = None,
) -> Verification:
    """Check a plan against every constraint of its problem.

    Parameters
    ----------
    problem : SteerableProblem
        Its collision model decides the clearance rule.
    plan : SteerablePlan
    spacing_mm : float
        Largest spacing of the dense samples along the path (their certificate subtracts
        half); the search's own samples are certified besides.
    expected_cost_mm : float, optional
        The cost the plan claims; a violation when the recomputed cost differs by more
        than 1e-6 mm (relative 1e-9).

    Returns
    -------
    Verification
    """
    prims = plan.primitives
    start = plan.start_pose
    bad = _start_violations(problem, start)
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
    heading = _heading_deg(plan)
    if heading > problem.max_heading_change_deg + 1e-7:
        bad.append(
            f"heading: turns {heading:.3f} deg from the start direction, limit {problem.max_heading_change_deg:g} deg"
        )
    puncture, why = _puncture_angle(problem, start)
    if puncture is None and problem.min_puncture_angle_deg > 0:
        bad.append(f"puncture angle: could not be checked ({why})")
    elif puncture is not None and puncture < problem.min_puncture_angle_deg - 1e-7:
        bad.append(
            f"puncture angle: {puncture:.3f} deg to the {problem.entry_surface or 'entry'} surface, "
            f"minimum {problem.min_puncture_angle_deg:g} deg"
        )
    points = np.ascontiguousarray(poses[:, :3, 3])
    # the problem's collision checker, bound to the plan's own start (its exclusion)
    cert, model, sampled = _certified_clearance(problem, start, plan, points, spacing_mm)
    if cert.violation is not None:
        bad.append(cert.violation)
    certified, n_hits = cert.certified_clearance_mm, cert.colliding_samples
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
        "min_clearance_mm": sampled,
        "certified_clearance_mm": certified,
        "collision_model": model,
        "colliding_samples": n_hits,
    }
    return Verification(not bad, tuple(bad), metrics)


def _heading_deg(plan: SteerablePlan) -> float:
    """The largest angle (deg) between the start direction and the tangent anywhere along
    the plan: along an arc ``tangent . d0 = A sin(phi) + B cos(phi)`` (``phi = kappa s``),
    whose minimum is ``-hypot(A, B)`` where ``phi = atan2(A, B) + pi (mod 2 pi)`` falls
    within the arc, else at an end."""
    poses = plan.poses()
    d0 = plan.start_pose[:3, 2]
    lowest = 1.0
    for pose, (spin, kappa, length) in zip(poses[:-1], plan.primitives, strict=True):
        if length <= 0:
            continue
        bend = pose[:3, :2] @ np.array([np.sin(spin), -np.cos(spin)])
        a, b = float(bend @ d0), float(pose[:3, 2] @ d0)
        end = float(kappa * length)
        lowest = min(lowest, b, a * np.sin(end) + b * np.cos(end))
        psi = np.arctan2(a, b)
        turns = np.ceil((min(0.0, end) - psi - np.pi) / (2 * np.pi))
        if psi + np.pi + 2 * np.pi * turns <= max(0.0, end):
            lowest = min(lowest, -float(np.hypot(a, b)))
    return float(np.degrees(np.arccos(np.clip(lowest, -1.0, 1.0))))


def _start_violations(problem: SteerableProblem, start: np.ndarray) -> list[str]:
    """Where the plan starts against the problem's start point and direction."""
    bad = []
    moved = float(np.linalg.norm(start[:3, 3] - problem.start_point_mm))
    if not moved <= START_TOLERANCE_MM:
        bad.append(f"start: the plan starts {moved:.4f} mm from the problem's start point")
    if problem.start_pose is not None:
        turned = float(angle_between(start[:3, 2], problem.start_pose[:3, 2]))
        if not turned <= START_TOLERANCE_RAD:
            bad.append(
                f"start: the plan's insertion direction is {np.degrees(turned):.4f} deg from "
                "the problem's start direction"
            )
    return bad


def _puncture_angle(problem: SteerableProblem, start: np.ndarray) -> tuple[float | None, str]:
    """The angle (deg) between the start direction and the entry surface, or None and why."""
    n, why = problem.tissue_normal(start[:3, 3])
    if n is None:
        return None, why
    return float(np.degrees(np.arcsin(np.clip(start[:3, 2] @ n, -1.0, 1.0)))), ""


def verify_approximate(
    problem: SteerableProblem,
    plan: SteerablePlan,
    *,
    spacing_mm: float = VERIFY_SPACING_MM,
) -> Verification:
    """Check a path that stops short of the goal (an approximate solution): every rule of
    :func:`verify_plan` except the goal tolerance, which becomes the distance it reaches.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan
    spacing_mm : float

    Returns
    -------
    Verification
        ``metrics["goal_distance_mm"]`` is how far from the goal the path ends.
    """
    reached = float(np.linalg.norm(plan.end_pose()[:3, 3] - problem.goal_mm))
    # only the tolerance changes (a finite distance, at least the problem's): nothing near
    # the start is built again
    relaxed = problem.with_goal_tolerance(max(problem.goal_tolerance_mm, reached))
    return verify_plan(relaxed, plan, spacing_mm=spacing_mm)
