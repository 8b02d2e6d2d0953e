"""Steering back to the plan: the plan as a reference path, and pure pursuit.

Between re-plans the needle follows its plan by feedback. The law is pure pursuit, the
path-following rule of mobile robots (Coulter 1992) on the needle's own means: from the
estimated tip, take the point of the plan ``lookahead_mm`` further along than the point
nearest the tip (the goal once that lies closer), and steer the one arc that runs through
it. In the tip frame that point ``q`` asks for curvature ``2 |q_lateral| / |q|^2`` in the
plane of ``q``: the tip spins so that its -y axis faces ``q_lateral`` and inserts at that
curvature, capped at ``1 / r_min`` (less is duty-cycled spinning; a point behind the tip
asks for the cap). On the plan with no error it gives the plan's curvature back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.plan import SteerablePlan

__all__ = ["PlanReference", "PurePursuit", "pure_pursuit", "pure_pursuit_law"]

#: Spacing of the reference's points along the plan (mm).
REFERENCE_SPACING_MM: float = 0.25


@dataclass(frozen=True)
class PlanReference:
    """A plan's path as points at known arc length, and where the tip has got to.

    Attributes
    ----------
    points_mm : ndarray, shape (n, 3)
    arc_mm : ndarray, shape (n,)
        Arc length of each point from the plan's start.
    goal_mm : ndarray, shape (3,)
    """

    points_mm: np.ndarray
    arc_mm: np.ndarray
    goal_mm: np.ndarray

    @classmethod
    def of_plan(cls, plan: SteerablePlan, goal_mm) -> PlanReference:
        """The reference of a plan.

        Parameters
        ----------
        plan : SteerablePlan
        goal_mm : array_like, shape (3,)

        Returns
        -------
        PlanReference
        """
        pts = plan.points_mm(REFERENCE_SPACING_MM)
        step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(step)])
        goal = np.asarray(goal_mm, dtype=np.float64)
        if goal.shape != (3,) or not np.all(np.isfinite(goal)):
            raise InvalidInputError("goal_mm", "expected three finite numbers")
        return cls(pts, arc, goal)

    def nearest(self, point, start: int = 0, window_mm: float = 20.0) -> int:
        """Index of the reference point nearest ``point``, looking from ``start`` on
        (the tip only moves forward) within ``window_mm`` of arc length.

        Parameters
        ----------
        point : array_like, shape (3,)
        start : int
        window_mm : float

        Returns
        -------
        int
        """
        stop = int(np.searchsorted(self.arc_mm, self.arc_mm[start] + window_mm, "right"))
        d = np.linalg.norm(self.points_mm[start:stop] - np.asarray(point), axis=1)
        return start + int(np.argmin(d))

    def ahead(self, index: int, lookahead_mm: float) -> np.ndarray:
        """The point ``lookahead_mm`` along the plan from point ``index`` (the goal past
        the plan's end).

        Parameters
        ----------
        index : int
        lookahead_mm : float

        Returns
        -------
        ndarray, shape (3,)
        """
        s = self.arc_mm[index] + lookahead_mm
        if s >= self.arc_mm[-1]:
            return self.goal_mm
        j = int(np.searchsorted(self.arc_mm, s))
        return self.points_mm[j]


def pure_pursuit(pose, target_mm, kappa_max_per_mm: float) -> tuple[float, float]:
    """The spin and curvature whose arc runs from the tip through ``target_mm``.

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
        The (estimated) tip pose.
    target_mm : array_like, shape (3,)
    kappa_max_per_mm : float
        ``1 / r_min``.

    Returns
    -------
    (float, float)
        ``(spin_rad, kappa_per_mm)``: spin the tip by ``spin_rad`` about its axis, then
        insert at ``kappa_per_mm``.

    Examples
    --------
    A point 50 mm to the -y side and 50 mm ahead lies on the quarter circle of radius 50:

    >>> import numpy as np
    >>> spin, kappa = pure_pursuit(np.eye(4), [0.0, -50.0, 50.0], 0.05)
    >>> round(spin, 12), round(1 / kappa, 9)
    (0.0, 50.0)
    """
    q = pose[:3, :3].T @ (np.asarray(target_mm, dtype=np.float64) - pose[:3, 3])
    lateral = math.hypot(q[0], q[1])
    if lateral < 1e-9:
        return 0.0, 0.0
    # the spun tip's -y axis, (sin s, -cos s), faces the lateral offset
    spin = math.atan2(q[0], -q[1])
    if q[2] <= 0.0:
        return spin, kappa_max_per_mm
    kappa = 2.0 * lateral / float(q @ q)
    return spin, min(kappa, kappa_max_per_mm)


class PurePursuit:
    """The ``pure_pursuit`` feedback law (:data:`needlekit.execute.plugins.FEEDBACK_LAWS`):
    :func:`pure_pursuit` toward the plan's point ``lookahead_mm`` ahead of the nearest.

    Parameters
    ----------
    lookahead_mm : float
    kappa_max_per_mm : float
    """

    def __init__(self, lookahead_mm: float, kappa_max_per_mm: float) -> None:
        self.lookahead_mm = float(lookahead_mm)
        self.kappa_max_per_mm = float(kappa_max_per_mm)

    def __call__(self, pose, reference: PlanReference, index: int) -> tuple[float, float]:
        """The command from the estimated tip.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        reference : PlanReference
        index : int
            The reference point nearest the tip.

        Returns
        -------
        (float, float)
            ``(spin_rad, kappa_per_mm)``.
        """
        return pure_pursuit(pose, reference.ahead(index, self.lookahead_mm), self.kappa_max_per_mm)


def pure_pursuit_law(setup) -> PurePursuit:
    """The ``pure_pursuit`` law of a run: its look-ahead, the needle's ``1 / r_min``.

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    PurePursuit
    """
    return PurePursuit(setup.settings.lookahead_mm, 1.0 / setup.r_min_mm)


pure_pursuit_law.parameters = lambda settings: {"lookahead_mm": settings.lookahead_mm}
