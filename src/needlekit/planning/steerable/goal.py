"""Connecting a tip pose to the goal: turn at r_min, then go straight, stopping tau short.

This is the connection resolution-optimal search tries from every node, and its length is
the admissible cost-to-go (the shortest curvature-bounded path to a point outside the r_min
horn torus, :func:`needlekit.needle.reachability.shortest_arc_line`, less the tolerance):

- goal ahead and outside the turning circle: an r_min arc until the heading points at the
  goal, then a straight segment that ends ``tau`` before the goal (or no segment when the
  arc already ends within ``tau``);
- goal inside the turning circle by at most ``tau``: an r_min arc alone, to the circle point
  nearest the goal;
- otherwise (behind the tip, or deeper inside the torus): no connection.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from needlekit._validation import as_points, as_poses, as_positive
from needlekit.constants import ON_AXIS_TOL_MM
from needlekit.errors import InvalidInputError
from needlekit.needle.reachability import shortest_arc_line_unchecked

__all__ = [
    "GoalConnection",
    "connection_length_unchecked",
    "goal_connection",
    "goal_connection_unchecked",
    "single_arc_connection",
    "single_arc_connection_unchecked",
]


@dataclass(frozen=True)
class GoalConnection:
    """An arc (then maybe a line) from a tip pose to within tau of the goal.

    Attributes
    ----------
    primitives : ndarray, shape (k, 3)
        ``(rotation_rad, curvature_per_mm, length_mm)`` rows: the arc, then the line if any.
    length_mm : float
    end_distance_mm : float
        Distance from the connection's end to the goal (<= tau).
    """

    primitives: np.ndarray
    length_mm: float
    end_distance_mm: float


def goal_connection(
    world_T_tip, goal_mm, r_min_mm: float, tolerance_mm: float
) -> GoalConnection | None:
    """The shortest arc-then-line connection from a tip pose to within tau of the goal.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    goal_mm : array_like, shape (3,)
    r_min_mm : float
        Radius of the arc.
    tolerance_mm : float
        tau.

    Returns
    -------
    GoalConnection or None
        None when no such connection exists (goal behind the tip, or more than tau inside
        the r_min horn torus).

    Examples
    --------
    A goal 50 mm to the side of a 50 mm turning circle's quarter point:

    >>> import numpy as np
    >>> c = goal_connection(np.eye(4), [0.0, -50.0, 100.0], 50.0, 1.0)
    >>> round(c.length_mm, 4), c.primitives.shape  # 30 deg arc (26.18) + 86.60 - 1 line
    (111.7825, (2, 3))
    """
    g, single = as_poses(world_T_tip, "world_T_tip")
    if not single:
        raise InvalidInputError("world_T_tip", "expected one 4x4 pose")
    p, single = as_points(goal_mm, "goal_mm")
    if not single:
        raise InvalidInputError("goal_mm", "expected one point (3,)")
    r = as_positive(r_min_mm, "r_min_mm")
    tau = float(tolerance_mm)
    if not (np.isfinite(tau) and tau >= 0):
        raise InvalidInputError("tolerance_mm", f"must be a finite number >= 0, got {tolerance_mm}")
    return goal_connection_unchecked(g[0], p[0], r, tau)


def goal_connection_unchecked(
    pose: np.ndarray, goal: np.ndarray, r: float, tau: float
) -> GoalConnection | None:
    """:func:`goal_connection` without its checks, for a search's inner loop: ``pose`` a
    valid (4, 4) float64 pose, ``goal`` float64 of shape (3,), ``r`` > 0, ``tau`` >= 0.

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
    goal : ndarray, shape (3,)
    r, tau : float

    Returns
    -------
    GoalConnection or None
    """
    g, p = pose[None], goal[None]
    path = shortest_arc_line_unchecked(pose, p, r)
    kappa = 1.0 / r
    spin = float(path.spin_rad[0])
    if path.reachable[0]:
        arc = float(path.arc_length_mm[0])
        line = float(path.line_length_mm[0])
        if line > tau:
            rows = [[spin, kappa, arc], [0.0, 0.0, line - tau]]
            return GoalConnection(np.array(rows), arc + line - tau, tau)
        return GoalConnection(np.array([[spin, kappa, arc]]), arc, line)
    # inside the torus: the arc to the circle point nearest the goal, if within tau
    local = (p[0] - g[0, :3, 3]) @ g[0, :3, :3]
    axial = local[2]
    radial = float(np.hypot(local[0], local[1]))
    if axial < 0.0:
        return None
    depth = r - float(np.hypot(radial - r, axial))  # how far inside the circle
    if depth > tau:
        return None
    turn = float(np.arctan2(axial, r - radial))  # goal's angle seen from the centre
    return GoalConnection(np.array([[spin, kappa, r * turn]]), r * turn, depth)


@numba.njit(cache=True)
def connection_length_unchecked(pose, goal, r, tau):  # pragma: no cover - compiled
    """``goal_connection(pose, goal, r, tau).length_mm`` (``inf`` for None), without its
    checks: the cost-to-go of resolution-optimal search, once per node.

    Parameters
    ----------
    pose : ndarray, shape (4, 4), float64
    goal : ndarray, shape (3,), float64
    r, tau : float
        r_min (> 0) and the tolerance (>= 0).

    Returns
    -------
    float
    """
    l0 = l1 = l2 = 0.0
    for i in range(3):
        d = goal[i] - pose[i, 3]
        l0 += d * pose[i, 0]
        l1 += d * pose[i, 1]
        l2 += d * pose[i, 2]
    axial = l2
    radial = math.hypot(l0, l1)
    du = radial - r
    dist = math.hypot(du, axial)
    if dist >= r and not (radial <= ON_AXIS_TOL_MM and axial < 0.0):
        tangent = math.sqrt(max(dist * dist - r * r, 0.0))
        turn = (math.atan2(tangent, -r) - math.atan2(axial, du)) % (2.0 * math.pi)
        if turn > 2.0 * math.pi - 1e-12:
            turn = 0.0
        arc = r * turn
        if tangent > tau:
            return arc + tangent - tau
        return arc
    if axial < 0.0:
        return math.inf
    if r - math.hypot(radial - r, axial) > tau:
        return math.inf
    return r * math.atan2(axial, r - radial)


def single_arc_connection(
    world_T_tip, goal_mm, r_min_mm: float, tolerance_mm: float
) -> GoalConnection | None:
    """One constant-curvature arc from a tip pose to the goal itself (RCS and RRT's
    connection): radius ``max(r_min, radius needed)``; when the goal needs a tighter arc,
    the r_min arc to the circle point nearest the goal, accepted within tau.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    goal_mm : array_like, shape (3,)
    r_min_mm, tolerance_mm : float

    Returns
    -------
    GoalConnection or None
    """
    g, _ = as_poses(world_T_tip, "world_T_tip")
    p, _ = as_points(goal_mm, "goal_mm")
    r = as_positive(r_min_mm, "r_min_mm")
    return single_arc_connection_unchecked(g[0], p[0], r, float(tolerance_mm))


def single_arc_connection_unchecked(
    pose: np.ndarray, goal: np.ndarray, r: float, tau: float
) -> GoalConnection | None:
    """:func:`single_arc_connection` without its checks, for a search's inner loop (the
    arguments as :func:`goal_connection_unchecked` takes them).

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
    goal : ndarray, shape (3,)
    r, tau : float

    Returns
    -------
    GoalConnection or None
    """
    local = (goal - pose[:3, 3]) @ pose[:3, :3]
    axial = float(local[2])
    radial = float(np.hypot(local[0], local[1]))
    if axial < 0.0 and radial <= 1e-12:
        return None
    spin = 0.0 if radial <= 1e-12 else float(np.arctan2(local[0], -local[1]))
    if radial <= 1e-12:
        return GoalConnection(np.array([[0.0, 0.0, axial]]), axial, 0.0)
    needed = (axial**2 + radial**2) / (2.0 * radial)
    turn = 2.0 * float(np.arctan2(radial, axial))
    if turn > np.pi:  # the goal is behind: no forward arc reaches it
        return None
    if needed >= r:
        return GoalConnection(np.array([[spin, 1.0 / needed, needed * turn]]), needed * turn, 0.0)
    depth = r - float(np.hypot(radial - r, axial))
    if depth > tau:
        return None
    t = float(np.arctan2(axial, r - radial))
    return GoalConnection(np.array([[spin, 1.0 / r, r * t]]), r * t, depth)
