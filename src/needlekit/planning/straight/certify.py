"""The certified clearance of one straight needle, as a plan records it.

The straight planners' clearance rule (:mod:`needlekit.constants`, "the clearance rule of
the straight planners") applied to a needle given by its two recorded points: the planner
(:func:`~needlekit.planning.straight.sequence.plan_needles`) certifies each needle so
before it accepts it, and :func:`~needlekit.planning.straight.verify.verify_multi`
re-derives the same certificate from the record. Both go through :func:`record_point` and
:func:`certify_needle` with the same numbers, so they compute the same bound, bit for bit.

Two certificates of each clearance, the better one counts (each is a lower bound):

- the planner's own samples: sphere tracing with :data:`~needlekit.constants.STRAIGHT_NEAR_STEP_MM`
  near obstacles, capped as the CFRW map caps (the map's figure for that segment);
- dense samples every :data:`~needlekit.constants.STRAIGHT_CHECK_STEP_MM`, and for the
  placed needles the closed-form distance between the axes besides their heads traced
  densely.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.anatomy.fields import union
from needlekit.constants import (
    RECORD_DECIMALS,
    STRAIGHT_CAP_ABOVE_GAMMA_MM,
    STRAIGHT_CHECK_STEP_MM,
    STRAIGHT_NEAR_STEP_MM,
)
from needlekit.geometry.segments import segment_distances
from needlekit.planning.straight.cfrw import obstacle_segment_bound, segment_clearance_bound
from needlekit.planning.straight.problem import StraightProblem

__all__ = ["NeedleCertificate", "certify_needle", "record_point"]


def record_point(point) -> np.ndarray:
    """A point as a plan record holds it: rounded to :data:`~needlekit.constants.RECORD_DECIMALS`.

    Rounding twice gives the same floats, and JSON keeps a float exactly, so a point read
    back from the record equals the one the planner certified.

    Parameters
    ----------
    point : array_like, shape (3,)
        World point (mm).

    Returns
    -------
    ndarray, shape (3,)

    Examples
    --------
    >>> record_point([1.23456789, 0.0, -2.0000004]).tolist()
    [1.234568, 0.0, -2.0]
    """
    return np.round(np.asarray(point, dtype=float).reshape(3), RECORD_DECIMALS)


@dataclass(frozen=True)
class NeedleCertificate:
    """Certified clearances of one needle (mm; the needle's surface, radius subtracted).

    Attributes
    ----------
    length_mm : float
        Distance from the target to the entry.
    planner_clearance_mm, dense_clearance_mm : float
        To the anatomy, by the planner's samples and by the dense ones (up to gamma plus
        the cap).
    planner_needle_clearance_mm, dense_needle_clearance_mm : float
        To the needles placed before it (``inf`` when none).
    """

    length_mm: float
    planner_clearance_mm: float
    dense_clearance_mm: float
    planner_needle_clearance_mm: float = float("inf")
    dense_needle_clearance_mm: float = float("inf")

    @property
    def clearance_mm(self) -> float:
        """The better certificate of the clearance to the anatomy (mm)."""
        return max(self.planner_clearance_mm, self.dense_clearance_mm)

    @property
    def needle_clearance_mm(self) -> float:
        """The better certificate of the clearance to the placed needles (mm)."""
        return max(self.planner_needle_clearance_mm, self.dense_needle_clearance_mm)

    def passes(self, gamma_mm: float) -> bool:
        """Whether either certificate proves each clearance at least ``gamma_mm``.

        Parameters
        ----------
        gamma_mm : float
            The safety distance (mm).

        Returns
        -------
        bool
        """
        return self.clearance_mm >= gamma_mm and self.needle_clearance_mm >= gamma_mm


def certify_needle(
    problem: StraightProblem,
    tip_mm: np.ndarray,
    entry_mm: np.ndarray,
    placed: tuple = (),
    bodies: tuple = (),
) -> NeedleCertificate:
    """Both certificates of a needle's clearance, to the anatomy and to placed needles.

    Parameters
    ----------
    problem : StraightProblem
        Anatomy (with any extra obstacles it holds), needle and gamma (its target is
        ignored).
    tip_mm, entry_mm : ndarray, shape (3,)
        The needle's target and entry as recorded (:func:`record_point`).
    placed : sequence of (ndarray (3,), ndarray (3,))
        The needles placed before it, ``(tip, entry)``.
    bodies : sequence of DistanceField
        Their bodies (tube and head), in the same order.

    Returns
    -------
    NeedleCertificate
    """
    tip = np.asarray(tip_mm, dtype=float).reshape(3)
    entry = np.asarray(entry_mm, dtype=float).reshape(3)
    axis = entry - tip
    length = float(np.linalg.norm(axis))
    o, u, L = tip[None], (axis / length)[None], np.array([length])
    r = problem.needle.radius_mm
    cap = problem.clearance_needed_mm + STRAIGHT_CAP_ABOVE_GAMMA_MM

    def traced(field, step):
        if field is None:
            return cap - r
        return float(segment_clearance_bound(field, o, u, L, cap_mm=cap, step_mm=step)[0][0]) - r

    def each(fields):  # the planner's bound of each obstacle on its own (CFRWMap._lowered)
        return min(
            float(obstacle_segment_bound(f, o, u, L, cap_mm=cap, step_mm=STRAIGHT_NEAR_STEP_MM)[0])
            for f in fields
        ) - r  # fmt: skip

    planner = traced(problem.anatomy_field(), STRAIGHT_NEAR_STEP_MM)
    dense = traced(problem.anatomy_field(), STRAIGHT_CHECK_STEP_MM)
    if problem.extra_obstacles:  # obstacles the problem itself adds, as the map counts them
        planner = min(planner, each(problem.extra_obstacles))
        dense = min(dense, traced(union(*problem.extra_obstacles), STRAIGHT_CHECK_STEP_MM))
    planner_needles = dense_needles = float("inf")
    if bodies:
        planner_needles = each(bodies)
        axes = min(float(segment_distances(p, q, o, entry[None])[0]) for p, q in placed)
        dense_needles = min(axes - 2 * r, traced(union(*bodies), STRAIGHT_CHECK_STEP_MM))
    return NeedleCertificate(length, planner, dense, planner_needles, dense_needles)
