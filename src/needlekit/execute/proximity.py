"""The closed loop's last line of defence: stop inserting when the estimated tip comes too
close to an obstacle.

Re-planning keeps the tip near a plan certified clear of every obstacle by the plan's
margin, but a re-plan can be refused (the goal outside the reachable set late in an
insertion), and the loop then follows a plan the tip has drifted from. On Med-RAD lung 3
(checkpoints, ``--cross-track-mm 0.25``, 100 trials) one run followed its last adopted
plan for 60 mm while the tip drifted 1.6 mm from it, three times the plan's margin, and
crossed the chest wall's obstacle voxels 3.55 mm short of the target, its estimate 0.04 mm
from the true tip all the while: the loop knew where the tip was, and nothing stopped it.

:class:`ProximityStop` asks the anatomy without the margin (the judge the executed paths
are certified against) for the estimated tip's clearance, and the loop stops the
insertion once it falls below the stop distance: ``min(stop_clearance_mm, margin / 2)``,
so that a plan followed within half its margin is never stopped (a plan with no margin is
stopped only where the estimate lies inside an obstacle). The run then ends short of the
target, its record says where and why (``stopped_near_obstacle``), and the trial's status
is ``approximate`` (or ``infeasible`` if the true tip had crossed already).

The clearance is the checker's certified bound (:meth:`CollisionChecker.certify
<needlekit.anatomy.collision.CollisionChecker.certify>`), a lower bound of the needle
surface's distance to the obstacles, taken as the judge will take it from the recorded
true path: a sample of a path recorded every ``record_mm``, less half that gap (on lung 3
the stop first fired on the point's own clearance, 0.15 mm, and the recorded path, judged
with its 0.34 mm gap, still crossed by 0.04 mm). A clearance that cannot be bounded (the
tip outside the image, NaN) stops the insertion. Distance is 1-Lipschitz, so a point within
``c - stop`` of a point of certified clearance ``c`` keeps at least ``stop``: the checker
is asked again only once the estimate has moved that far (a few times per millimetre near
an obstacle, once per millimetres away from one), whatever the estimate's jumps.

The estimate is checked against the anatomy as planned: under a deforming truth the
obstacles move with the tissue and the loop does not know by how much (it sees the target
only), which the stop shares with the plan it follows.
"""

from __future__ import annotations

import math

import numpy as np

from needlekit.constants import STOP_CLEARANCE_MM

__all__ = ["STOP_CLEARANCE_MM", "ProximityStop", "stop_distance_mm"]


def stop_distance_mm(stop_clearance_mm: float, margin_mm: float) -> float:
    """The clearance (mm) below which the loop stops: the setting, at most half the plan's
    margin.

    Parameters
    ----------
    stop_clearance_mm : float
        ``ExecutionSettings.stop_clearance_mm``.
    margin_mm : float
        The plan's safety margin.

    Returns
    -------
    float

    Examples
    --------
    >>> stop_distance_mm(0.1, 0.5), stop_distance_mm(0.1, 0.1), stop_distance_mm(0.1, 0.0)
    (0.1, 0.05, 0.0)
    """
    return min(float(stop_clearance_mm), 0.5 * float(margin_mm))


class ProximityStop:
    """The estimated tip's clearance against a checker, and whether it is below the stop.

    Parameters
    ----------
    checker : CollisionChecker
        The anatomy without the margin.
    stop_mm : float
        Stop once the certified clearance is below this.
    spacing_mm : float
        The gap of the recorded path the run will be judged on: the estimated tip's
        clearance is certified as a sample of that path is (less half the gap).

    Attributes
    ----------
    checks : int
        The checker's calls so far.
    """

    def __init__(self, checker, stop_mm: float, spacing_mm: float) -> None:
        self.checker, self.stop_mm, self.spacing_mm = checker, float(stop_mm), float(spacing_mm)
        self.checks = 0
        self._at: tuple[float, float, float] | None = None
        self._clear = -math.inf

    def breached(self, tip_mm: np.ndarray) -> float | None:
        """The certified clearance (mm) of the needle at ``tip_mm`` when it is below the
        stop distance, else None.

        Parameters
        ----------
        tip_mm : ndarray, shape (3,)
            The estimated tip.

        Returns
        -------
        float or None
        """
        at = (float(tip_mm[0]), float(tip_mm[1]), float(tip_mm[2]))
        if self._at is not None and self._clear - math.dist(at, self._at) >= self.stop_mm:
            return None
        c = float(self.checker.certify(np.array([at, at]), self.spacing_mm).certified_clearance_mm)
        self.checks += 1
        # no bound (within the start's exclusion, say): ask again at the next step
        self._at, self._clear = (at, c) if math.isfinite(c) else (None, -math.inf)
        return None if c >= self.stop_mm else c  # NaN (not checked) stops too
