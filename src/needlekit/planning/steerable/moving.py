"""Obstacles that move during an insertion, and the check of a path against them.

Time is the insertion itself: the needle advances at a constant insertion speed ``v``
(mm/s), so the tip passes the point at arc length ``s`` at ``t = s / v``. A
:class:`MovingObstacle` is a distance field moved rigidly by a :class:`Motion`, a constant
drift plus an optional sinusoid (breathing),

    offset(t) = velocity t + amplitude (sin(2 pi t / period + phase) - sin(phase)),

so that the field as given is the obstacle at ``t = 0``. A planner sees a moving obstacle
as a static field: where it is at one time (:meth:`MovingObstacle.at`), everywhere it goes
over a time span (:class:`SweptField`), or, point by point, wherever it may be when the tip
can pass that point (:class:`ArrivalField`).

:func:`certify_execution` is the independent check of an executed path. It runs
:func:`~needlekit.planning.steerable.verify.verify_plan` against the static anatomy
(curvature, length, goal, heading, puncture angle, certified clearance) and checks every
moving obstacle at the times the tip passed: samples ``h`` apart in arc length, sample
``i`` against the obstacle at ``t_i = s_i / v``. The distance to a translated field is
1-Lipschitz in the point and changes by at most ``max_speed * dt`` over a time ``dt``, so
the smallest sampled clearance less ``h / 2``, ``max_speed * h / (2 v)`` and the field's
error bound is a lower bound for the whole path, at every instant the tip passes. A
clearance that cannot be evaluated (not finite) counts as a violation.

The tip is what is checked, as in the lecture's planner; the shaft left behind is not (the
tissue around it is taken to carry it): ``shaft_clearance_mm`` reports, for information,
how close the moving obstacles come to the inserted needle until the insertion ends.

The motions, the moving obstacles and the fields a planner sees of them
(:class:`Motion`, :class:`MovingObstacle`, :class:`SweptField`, :class:`ArrivalField`) are
defined in :mod:`needlekit.planning.steerable.moving_obstacles`; this module re-exports
them and holds the check.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from needlekit._validation import as_positive
from needlekit.anatomy.fields import DistanceField, union
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import propagate_arcs, samples_for_spacing
from needlekit.planning.result import Verification
from needlekit.planning.steerable.moving_obstacles import (  # re-exported (they lived here)
    ARRIVAL_MAX_GROWTH,
    SWEEP_STEP_MM,
    ArrivalField,
    Motion,
    MovingObstacle,
    SweptField,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.verify import verify_approximate, verify_plan

__all__ = [
    "ARRIVAL_MAX_GROWTH",
    "CHECK_SPACING_MM",
    "SWEEP_STEP_MM",
    "ArrivalField",
    "Motion",
    "MovingObstacle",
    "SweptField",
    "certify_execution",
    "check_moving",
    "moving_clearance",
    "path_samples",
    "scene_with",
]

#: Arc-length spacing (mm) of the samples at which executed paths are checked (as verify).
CHECK_SPACING_MM: float = 0.25


def check_moving(problem: SteerableProblem, moving) -> list[MovingObstacle]:
    """Moving obstacles checked against a problem: named apart from its structures, a
    start pose and the field collision model.

    Parameters
    ----------
    problem : SteerableProblem
    moving : sequence of MovingObstacle

    Returns
    -------
    list of MovingObstacle

    Raises
    ------
    InvalidInputError
        Naming the obstacle, ``start_pose`` or ``collision_model``.
    """
    moving = list(moving)
    names = set(problem.scene.names)
    for i, m in enumerate(moving):
        if not isinstance(m, MovingObstacle):
            raise InvalidInputError(
                f"moving[{i}]", f"expected a MovingObstacle, got {type(m).__name__}"
            )
        if m.name in names:
            raise InvalidInputError(
                f"moving[{i}].name", f"{m.name!r} is already a structure of the scene"
            )
        names.add(m.name)
    if not getattr(problem.collision_checker(), "reads_scene", False):
        raise InvalidInputError(
            "collision_model",
            "moving obstacles are distance fields added to the scene: use a collision model "
            "that reads the scene's obstacle field (e.g. field)",
        )
    if problem.start_pose is None:
        raise InvalidInputError("start_pose", "planning among moving obstacles needs a start pose")
    return moving


def scene_with(scene: Scene, fields: Mapping[str, DistanceField], colors=None) -> Scene:
    """The static scene plus obstacles (e.g. moving ones placed at a time).

    Parameters
    ----------
    scene : Scene
    fields : mapping of str to DistanceField
    colors : mapping of str to str, optional

    Returns
    -------
    Scene
    """
    colors = colors or {}
    extra = [Structure(n, Role.OBSTACLE, f, colors.get(n), "moving") for n, f in fields.items()]
    try:
        base = scene.obstacle_field(0.0)
    except InvalidInputError:  # no static obstacle: the moving ones alone
        base = None
    combined = None if base is None else union(base, *fields.values()) if fields else base
    return Scene([*scene.structures, *extra], name=scene.name, obstacle_field=combined)


def path_samples(plan: SteerablePlan, spacing_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along a plan at most ``spacing_mm`` apart in arc length, ends included.

    Parameters
    ----------
    plan : SteerablePlan
    spacing_mm : float

    Returns
    -------
    points : ndarray, shape (n, 3)
    arcs_mm : ndarray, shape (n,)
        Their arc lengths from the plan's start.
    """
    poses = plan.poses()
    pts, arcs, s0 = [poses[0, :3, 3][None]], [np.zeros(1)], 0.0
    for i, (spin, kappa, length) in enumerate(plan.primitives):
        if length <= 0:
            continue
        s = np.linspace(0.0, length, samples_for_spacing(length, spacing_mm))[1:]
        ends = propagate_arcs(poses[i], np.full(s.shape, spin), np.full(s.shape, kappa), s)
        pts.append(ends[:, :3, 3])
        arcs.append(s0 + s)
        s0 += length
    return np.concatenate(pts), np.concatenate(arcs)


def moving_clearance(problem, moving, points, arcs, speed, t0_s, spacing_mm) -> dict:
    """The tip's clearance to each moving obstacle as it passes points (module notes).

    Parameters
    ----------
    problem : SteerableProblem
        Needle, margin and start exclusion (around its start point).
    moving : sequence of MovingObstacle
    points : ndarray, shape (n, 3)
        Samples of the tip path, at most ``spacing_mm`` apart in arc length.
    arcs : ndarray, shape (n,)
        Their arc lengths (mm) from where the tip was at ``t0_s``.
    speed : float
        Insertion speed (mm/s).
    t0_s : float
    spacing_mm : float

    Returns
    -------
    dict
        Per obstacle name: ``(sampled, certified, first)``, the smallest sampled clearance
        of the needle's surface (NaN when not finite), its certified lower bound for the
        whole stretch, and the first sample in (time, point) whose sampled clearance less
        the error bound is below the margin, or None.
    """
    radius = 0.5 * problem.needle_diameter_mm
    far = np.linalg.norm(points - problem.start_pose[:3, 3], axis=1) >= problem.start_exclusion_mm
    times = t0_s + arcs / speed
    out = {}
    for m in moving:
        if not far.any():
            out[m.name] = (np.inf, np.inf, None)
            continue
        p, t = points[far], times[far]
        d = m.field.signed_distance(p - m.motion.offset_mm(t)) - radius
        err = float(m.field.error_bound_mm)
        slack = 0.5 * spacing_mm * (1.0 + m.motion.max_speed_mm_s / speed) + err
        sampled = float(np.min(d)) if np.all(np.isfinite(d)) else math.nan
        hits = np.flatnonzero(d - err < problem.safety_margin_mm)
        first = None if len(hits) == 0 else (float(t[hits[0]]), p[hits[0]].tolist())
        out[m.name] = (sampled, sampled - slack, first)
    return out


def _shaft_clearance(problem, moving, points, arcs, speed, spacing_mm) -> float:
    """Certified clearance of the inserted needle to the moving obstacles, each sample from
    when it is inserted until the insertion ends (information; module notes)."""
    t_end = float(arcs[-1]) / speed
    lead = 0.5 * spacing_mm / speed  # a point between samples is inserted this much earlier
    far = np.linalg.norm(points - problem.start_pose[:3, 3], axis=1) >= problem.start_exclusion_mm
    best = math.inf
    for m in moving:
        vmax = m.motion.max_speed_mm_s
        n = max(2, math.ceil(vmax * t_end / SWEEP_STEP_MM) + 1)
        grid = np.linspace(0.0, t_end, n)
        low = math.inf
        for p, t_in in zip(points[far], arcs[far] / speed, strict=True):
            ts = np.concatenate([[max(0.0, t_in - lead)], grid[grid > t_in - lead]])
            low = min(low, float(m.field.signed_distance(p - m.motion.offset_mm(ts)).min()))
        slack = 0.5 * spacing_mm + 0.5 * vmax * t_end / (n - 1) + m.field.error_bound_mm
        best = min(best, low - slack)
    return best - 0.5 * problem.needle_diameter_mm


def certify_execution(
    problem: SteerableProblem,
    moving: Sequence[MovingObstacle],
    executed: SteerablePlan,
    insertion_speed_mm_s: float,
    *,
    spacing_mm: float = CHECK_SPACING_MM,
    require_goal: bool = True,
) -> Verification:
    """Check a path executed from the problem's start at ``t = 0`` (module notes).

    Parameters
    ----------
    problem : SteerableProblem
        The static anatomy, start, goal and limits.
    moving : sequence of MovingObstacle
    executed : SteerablePlan
        The path, from the problem's start pose.
    insertion_speed_mm_s : float
        The tip passes arc length ``s`` at ``s / insertion_speed_mm_s``.
    spacing_mm : float
        Largest sample spacing along the path.
    require_goal : bool
        False checks every rule but the goal (a path stopped on the way).

    Returns
    -------
    Verification
        ``metrics`` as :func:`verify_plan`'s (``certified_clearance_mm`` is to the static
        anatomy) plus ``moving_clearance_mm`` and ``certified_moving_clearance_mm`` (the
        smallest over the moving obstacles, at the times the tip passed),
        ``per_obstacle`` (each obstacle's figures and its first sampled contact
        ``[time_s, point_mm]``), ``shaft_clearance_mm`` (information) and ``duration_s``.
    """
    speed = as_positive(insertion_speed_mm_s, "insertion_speed_mm_s")
    moving = check_moving(problem, moving)
    if not np.allclose(executed.start_pose, problem.start_pose, atol=1e-9):
        raise InvalidInputError("executed", "the path does not start at the problem's start pose")
    check = verify_plan if require_goal else verify_approximate
    static = check(problem, executed, spacing_mm=spacing_mm)
    bad = list(static.violations)
    metrics = dict(static.metrics)
    points, arcs = path_samples(executed, spacing_mm)
    per = moving_clearance(problem, moving, points, arcs, speed, 0.0, spacing_mm)
    for name, (sampled, certified, first) in per.items():
        if math.isnan(sampled):
            bad.append(f"moving obstacle {name!r}: clearance could not be evaluated")
        elif certified < problem.safety_margin_mm:
            where = (
                ""
                if first is None
                else (f"; first contact at t = {first[0]:.2f} s, {np.round(first[1], 2).tolist()}")
            )
            bad.append(
                f"moving obstacle {name!r}: certified clearance {certified:.4f} mm at the times "
                f"the tip passed (sampled {sampled:.4f} mm) below the safety margin "
                f"{problem.safety_margin_mm:g} mm{where}"
            )
    finite = [v for v in per.values() if math.isfinite(v[0])]
    metrics.update(
        moving_clearance_mm=min((v[0] for v in finite), default=None),
        certified_moving_clearance_mm=min((v[1] for v in finite), default=None),
        per_obstacle={
            n: {"clearance_mm": v[0], "certified_clearance_mm": v[1], "first_contact": v[2]}
            for n, v in per.items()
        },
        shaft_clearance_mm=_shaft_clearance(problem, moving, points, arcs, speed, spacing_mm)
        if moving and len(points) > 1
        else None,
        duration_s=executed.length_mm / speed,
    )
    return Verification(not bad, tuple(bad), metrics)
