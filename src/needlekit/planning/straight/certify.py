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

from dataclasses import dataclass, replace

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

__all__ = [
    "NeedleCertificate",
    "certified_entry",
    "certify_needle",
    "certify_segment",
    "record_point",
]


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
    return certify_segment(
        problem.anatomy_field(), tip_mm, entry_mm, radius_mm=problem.needle.radius_mm,
        gamma_mm=problem.gamma_mm, extra_obstacles=tuple(problem.extra_obstacles),
        placed=placed, bodies=bodies,
    )  # fmt: skip


def certify_segment(
    field,
    tip_mm: np.ndarray,
    entry_mm: np.ndarray,
    *,
    radius_mm: float,
    gamma_mm: float,
    extra_obstacles: tuple = (),
    placed: tuple = (),
    bodies: tuple = (),
) -> NeedleCertificate:
    """:func:`certify_needle` given the obstacles' field instead of a problem (the same
    certificate: ``needlekit approach`` certifies its chosen line with it).

    Parameters
    ----------
    field : DistanceField or None
        The anatomy's obstacles (None: none).
    tip_mm, entry_mm : ndarray, shape (3,)
        The needle's target and entry as recorded (:func:`record_point`).
    radius_mm, gamma_mm : float
        Needle radius and safety distance (mm).
    extra_obstacles : sequence of DistanceField
        Obstacles counted one by one, as the CFRW map counts a problem's extra ones.
    placed, bodies : sequence
        As :func:`certify_needle`'s.

    Returns
    -------
    NeedleCertificate
    """
    tip = np.asarray(tip_mm, dtype=float).reshape(3)
    entry = np.asarray(entry_mm, dtype=float).reshape(3)
    axis = entry - tip
    length = float(np.linalg.norm(axis))
    o, u, L = tip[None], (axis / length)[None], np.array([length])
    r = float(radius_mm)
    cap = r + float(gamma_mm) + STRAIGHT_CAP_ABOVE_GAMMA_MM

    def traced(field, step):
        if field is None:
            return cap - r
        return float(segment_clearance_bound(field, o, u, L, cap_mm=cap, step_mm=step)[0][0]) - r

    def each(fields):  # the planner's bound of each obstacle on its own (CFRWMap._lowered)
        return min(
            float(obstacle_segment_bound(f, o, u, L, cap_mm=cap, step_mm=STRAIGHT_NEAR_STEP_MM)[0])
            for f in fields
        ) - r  # fmt: skip

    planner = traced(field, STRAIGHT_NEAR_STEP_MM)
    dense = traced(field, STRAIGHT_CHECK_STEP_MM)
    if extra_obstacles:  # obstacles the problem itself adds, as the map counts them
        planner = min(planner, each(extra_obstacles))
        dense = min(dense, traced(union(*extra_obstacles), STRAIGHT_CHECK_STEP_MM))
    planner_needles = dense_needles = float("inf")
    if bodies:
        planner_needles = each(bodies)
        axes = min(float(segment_distances(p, q, o, entry[None])[0]) for p, q in placed)
        dense_needles = min(axes - 2 * r, traced(union(*bodies), STRAIGHT_CHECK_STEP_MM))
    return NeedleCertificate(length, planner, dense, planner_needles, dense_needles)


def certified_entry(problem: StraightProblem, entry, placed: tuple = (), bodies: tuple = ()):
    """A trajectory as its record will hold it, if it passes the straight clearance rule.

    Its target and entry are rounded (:func:`record_point`) and certified
    (:func:`certify_needle`, the certificate ``verify_multi`` re-derives); it passes when
    the certificate proves each clearance at least gamma and the needle reaches.

    Parameters
    ----------
    problem : StraightProblem
        Anatomy (with any extra obstacles), needle and gamma.
    entry : Entry
        The trajectory (:class:`~needlekit.planning.straight.entry.Entry`).
    placed, bodies : sequence
        The needles placed before it (as :func:`certify_needle`'s).

    Returns
    -------
    (Entry or None, NeedleCertificate)
        The trajectory with its points rounded and its length and clearance the
        certificate's, or None when it fails; and the certificate.
    """
    tip, point = record_point(entry.target_mm), record_point(entry.entry_mm)
    cert = certify_needle(problem, tip, point, placed, bodies)
    if not (cert.passes(problem.gamma_mm) and cert.length_mm <= problem.needle.max_length_mm):
        return None, cert
    out = replace(
        entry, entry_mm=point, target_mm=tip, length_mm=cert.length_mm,
        clearance_mm=cert.clearance_mm,
    )  # fmt: skip
    return out, cert
