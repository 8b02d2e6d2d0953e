"""Plan costs as objectives (OMPL's ``OptimizationObjective``): path length, or the
integral of a clearance cost map along the path, or a user's own.

An objective gives the cost of one motion and declares an admissible lower bound: a
number ``b`` such that every motion costs at least ``b`` times its length
(:attr:`CostObjective.lower_bound_per_mm`). Resolution-optimal search needs it: RCS*
orders and prunes by ``g + b * (shortest connection length)`` and certifies its plan only
when the objective declares a bound (``None``: the search still runs, with no pruning by
the bound, and says why its result is not certified).

The clearance cost map charges every millimetre of insertion

    c(x) = 1 + w * max(0, 1 - d(x) / R)

where ``d(x)`` is the clearance of the tip at ``x`` (distance to the nearest obstacle
surface minus the needle radius and margin, from the scene's obstacle field), ``w`` the
weight and ``R`` the reach: paths pay up to ``1 + w`` per mm when they graze an obstacle
and exactly 1 per mm once they keep ``R`` away. A plan's cost is ``int c(x(s)) ds``
(trapezoid rule on samples every ``spacing_mm`` of each motion), in mm-equivalents. Since
``c >= 1``, its bound is 1 (the cost is never below the length); with ``w = 0`` the cost
is the length.

Examples
--------
An objective of one's own: a path that costs twice its length, with that bound declared.

>>> import numpy as np
>>> class Doubled:
...     name = "doubled"
...     lower_bound_per_mm = 2.0
...     def motion_cost(self, pose, spin, kappa, length, spacing_mm=COST_SPACING_MM):
...         return 2.0 * length
>>> isinstance(Doubled(), CostObjective)
True
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from needlekit.geometry.arcs import arc_end_unchecked, sample_arcs, samples_for_spacing

#: Integration step of cost maps (mm, largest; measured from each motion's start).
COST_SPACING_MM: float = 0.5

__all__ = [
    "COST_SPACING_MM",
    "ClearanceCostMap",
    "CostObjective",
    "PathLength",
    "chain_cost",
    "clearance_cost_rate",
    "motion_cost",
    "plan_cost",
]


@runtime_checkable
class CostObjective(Protocol):
    """What planners ask of a cost.

    Attributes
    ----------
    name : str
        Recorded in results.
    lower_bound_per_mm : float or None
        An admissible bound: every motion costs at least this times its length (> 0), or
        None when the objective declares none (RCS* then cannot certify optimality).
    """

    name: str
    lower_bound_per_mm: float | None

    def motion_cost(
        self, pose, spin: float, kappa: float, length: float, spacing_mm: float = ...
    ) -> float:
        """Cost of the motion ``(spin, kappa, length)`` from ``pose``.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        spin, kappa, length : float
        spacing_mm : float
            Largest spacing of integration samples, where the cost integrates a map.

        Returns
        -------
        float
            At least ``lower_bound_per_mm * length`` when a bound is declared.
        """


class PathLength:
    """Inserted length (mm): every mm costs 1, so the bound is 1 (exactly the length)."""

    name = "path_length"
    lower_bound_per_mm = 1.0
    exact_length = True  # the cost of a motion is its length: planners may skip the call

    def motion_cost(self, pose, spin, kappa, length, spacing_mm=COST_SPACING_MM) -> float:
        """The motion's length.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        spin, kappa, length : float
        spacing_mm : float
            Unused.

        Returns
        -------
        float
        """
        return float(length)


class ClearanceCostMap:
    """The clearance cost map ``1 + w * max(0, 1 - d / R)`` integrated along the motion
    (module notes); never below 1 per mm, so the bound is 1.

    Parameters
    ----------
    scene : Scene
        Its obstacle field gives the clearance ``d``.
    margin_mm : float
        Needle radius plus safety margin.
    weight : float
        ``w`` (>= 0).
    reach_mm : float
        ``R`` (> 0).
    """

    name = "clearance"
    lower_bound_per_mm = 1.0
    exact_length = False

    def __init__(self, scene, margin_mm: float, weight: float, reach_mm: float) -> None:
        self.scene, self.margin_mm = scene, float(margin_mm)
        self.weight, self.reach_mm = float(weight), float(reach_mm)

    def rate(self, points) -> np.ndarray:
        """The cost per mm at points (>= 1).

        Parameters
        ----------
        points : array_like, shape (n, 3)

        Returns
        -------
        ndarray, shape (n,)
        """
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        d = self.scene.clearance(pts, self.margin_mm)
        x = np.clip(1.0 - np.asarray(d, dtype=float) / self.reach_mm, 0.0, 1.0)
        return 1.0 + self.weight * x

    def motion_cost(self, pose, spin, kappa, length, spacing_mm=COST_SPACING_MM) -> float:
        """The trapezoid integral of the cost map along the motion.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        spin, kappa, length : float
        spacing_mm : float

        Returns
        -------
        float
        """
        if length <= 0.0:
            return float(length)
        m = samples_for_spacing(length, spacing_mm)
        rate = self.rate(sample_arcs(pose, spin, kappa, length, m))
        return float(length * (rate.sum() - 0.5 * (rate[0] + rate[-1])) / (m - 1))


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
    return ClearanceCostMap(
        problem.scene, problem.clearance_margin_mm, problem.cost_weight, problem.cost_reach_mm
    ).rate(points)


def motion_cost(
    problem, pose, spin: float, kappa: float, length: float, spacing_mm: float = COST_SPACING_MM
) -> float:
    """Cost of one motion ``(spin, kappa, length)`` from ``pose``, by the problem's
    objective.

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
    """
    return float(problem.objective.motion_cost(pose, spin, kappa, length, spacing_mm))


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
    objective = problem.objective
    total, g = 0.0, np.ascontiguousarray(pose, dtype=np.float64)
    for spin, kappa, length in np.asarray(primitives, dtype=float).reshape(-1, 3):
        total += float(objective.motion_cost(g, spin, kappa, length, spacing_mm))
        g = arc_end_unchecked(g, float(spin), float(kappa), float(length))
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
