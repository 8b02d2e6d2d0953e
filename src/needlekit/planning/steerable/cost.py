"""Plan costs: path length, or the integral of a clearance cost map along the path.

The clearance cost map charges every millimetre of insertion

    c(x) = 1 + w * max(0, 1 - d(x) / R)

where ``d(x)`` is the clearance of the tip at ``x`` (distance to the nearest obstacle
surface minus the needle radius and margin, from the scene's obstacle field), ``w`` the
weight and ``R`` the reach: paths pay up to ``1 + w`` per mm when they graze an obstacle
and exactly 1 per mm once they keep ``R`` away. A plan's cost is ``int c(x(s)) ds``
(trapezoid rule on samples every ``spacing_mm`` of each motion), in mm-equivalents. Since
``c >= 1``, the cost is never below the length, so length-based lower bounds (RCS*'s
turn-then-straight heuristic) stay admissible; with ``w = 0`` the cost is the length.
"""

from __future__ import annotations

import numpy as np

from needlekit.geometry.arcs import sample_arcs, samples_for_spacing

#: Integration step of cost maps (mm, largest; measured from each motion's start).
COST_SPACING_MM: float = 0.5

__all__ = ["COST_SPACING_MM", "chain_cost", "clearance_cost_rate", "motion_cost", "plan_cost"]


def clearance_cost_rate(problem, points) -> np.ndarray:
    """The clearance cost map at points: cost per mm of insertion there (>= 1).

    Parameters
    ----------
    problem : SteerableProblem
        Its cost weight and reach, scene and needle margin.
    points : array_like, shape (n, 3)

    Returns
    -------
    ndarray, shape (n,)
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    d = problem.scene.clearance(pts, problem.clearance_margin_mm)
    x = np.clip(1.0 - np.asarray(d, dtype=float) / problem.cost_reach_mm, 0.0, 1.0)
    return 1.0 + problem.cost_weight * x


def motion_cost(
    problem, pose, spin: float, kappa: float, length: float, spacing_mm: float = COST_SPACING_MM
) -> float:
    """Cost of one motion ``(spin, kappa, length)`` from ``pose``.

    Parameters
    ----------
    problem : SteerableProblem
    pose : ndarray, shape (4, 4)
    spin, kappa, length : float
    spacing_mm : float
        Largest spacing of the integration samples (measured from the motion's start).
        Plans are costed with :data:`COST_SPACING_MM`.

    Returns
    -------
    float
        ``length`` for path-length cost, else the trapezoid integral of the cost map.
    """
    from needlekit.planning.steerable.problem import CostKind

    if problem.cost is CostKind.PATH_LENGTH or length <= 0.0:
        return float(length)
    m = samples_for_spacing(length, spacing_mm)
    rate = clearance_cost_rate(problem, sample_arcs(pose, spin, kappa, length, m))
    return float(length * (rate.sum() - 0.5 * (rate[0] + rate[-1])) / (m - 1))


def chain_cost(problem, pose, primitives, spacing_mm: float = COST_SPACING_MM) -> float:
    """Cost of a chain of motions from ``pose``.

    Parameters
    ----------
    problem : SteerableProblem
    pose : ndarray, shape (4, 4)
    primitives : array_like, shape (k, 3)
        ``(spin, kappa, length)`` rows.
    spacing_mm : float

    Returns
    -------
    float
    """
    from needlekit.geometry.arcs import propagate_arcs

    total, g = 0.0, pose
    for spin, kappa, length in np.asarray(primitives, dtype=float).reshape(-1, 3):
        total += motion_cost(problem, g, spin, kappa, length, spacing_mm)
        g = propagate_arcs(g, spin, kappa, length)
    return total


def plan_cost(problem, plan, spacing_mm: float = COST_SPACING_MM) -> float:
    """Cost of a whole plan: the sum of its motions' costs.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan
    spacing_mm : float

    Returns
    -------
    float
    """
    return chain_cost(problem, plan.start_pose, plan.primitives, spacing_mm)
