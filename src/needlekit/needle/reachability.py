"""Which points a bevel-tip needle can reach from a tip pose, and how far it must go.

Frame-free coordinates of a point ``p`` seen from a tip at ``t`` with insertion axis
``e`` (the tip's z axis): ``axial = (p - t) . e`` and ``radial = |(p - t) - axial e|``.
(The lecture's ``P_z`` and ``sqrt(P_x^2 + P_y^2)`` when ``p`` is given in the tip frame.)

Single arc
    The arc from the tip through ``p`` lies in the plane of ``e`` and ``p``, with radius
    ``r = (axial^2 + radial^2) / (2 radial)`` and turning angle
    ``theta = 2 atan2(radial, axial)``. It respects a minimum radius ``r_min`` exactly when
    ``axial^2 + radial^2 >= 2 r_min radial``, i.e. ``p`` lies outside the horn torus
    swept by the circle of radius ``r_min`` tangent to the axis. Requiring a forward arc
    (``theta <= pi``, ``axial >= 0``) gives the lecture's condition
    ``P_z >= sqrt(2 r_min rho - rho^2)`` for ``rho <= 2 r_min`` (and ``P_z >= 0`` beyond).

Arc then straight line
    The shortest path with curvature at most ``1/r_min`` to a point outside the torus turns
    on the ``r_min`` circle until the tangent points at ``p``, then goes straight (a Dubins
    CS path, planar in the same plane): length ``r_min beta + sqrt(d^2 - r_min^2)`` where
    ``d`` is the distance from the circle's centre to ``p`` and ``beta`` the turn. Points
    inside the torus are not reachable by any arc-then-line path (every tangent line of a
    circle of radius >= r_min through the tip stays outside it). They are not out of reach
    for a needle that may spin mid-way: bending away first and back later (two arcs of
    opposite sides) reaches them, so "unreachable" here always means "by an arc then a
    line", and ``inf`` is not a lower bound on the length of such manoeuvres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_points, as_poses, as_positive, unbatch
from needlekit.constants import ON_AXIS_TOL_MM
from needlekit.errors import InvalidInputError

__all__ = [
    "ArcLinePath",
    "SingleArc",
    "is_reachable",
    "is_reachable_unchecked",
    "lecture_reachability_condition",
    "shortest_arc_line",
    "shortest_arc_line_unchecked",
    "single_arc_to",
    "tip_coordinates",
]


def _one_pose(world_T_tip) -> np.ndarray:
    g, single = as_poses(world_T_tip, "world_T_tip")
    if not single:
        raise InvalidInputError("world_T_tip", f"expected one tip pose (4, 4), got {g.shape[0]}")
    return g[0]


def tip_coordinates(world_T_tip, points):
    """Axial and radial coordinates of points relative to a tip (frame-free form).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
        Tip pose; its z axis is the insertion direction.
    points : array_like, shape (3,) or (n, 3)
        World points (mm).

    Returns
    -------
    axial, radial : ndarray, shape () or (n,)
        Distance along the insertion axis (signed) and from the axis (>= 0), mm.
    """
    g = _one_pose(world_T_tip)
    p, single = as_points(points, "points")
    d = p - g[:3, 3]
    e = g[:3, 2]
    axial = d @ e
    radial = np.linalg.norm(d - axial[:, None] * e, axis=1)
    return unbatch(axial, single), unbatch(radial, single)


@dataclass(frozen=True)
class SingleArc:
    """The unique single arc from a tip through each point (arrays of shape (n,)).

    Attributes
    ----------
    radius_mm : ndarray
        ``inf`` for points straight ahead; ``nan`` for points straight behind (no arc).
    turn_rad : ndarray
        Heading change along the arc, in [0, 2 pi].
    length_mm : ndarray
        Arc length (``inf`` where no arc exists).
    """

    radius_mm: np.ndarray
    turn_rad: np.ndarray
    length_mm: np.ndarray


def _single_arc(axial: np.ndarray, radial: np.ndarray) -> SingleArc:
    on_axis = radial <= ON_AXIS_TOL_MM
    safe = np.where(on_axis, 1.0, radial)
    finite_radius = (axial**2 + radial**2) / (2.0 * safe)
    turn = np.where(
        on_axis, np.where(axial >= 0.0, 0.0, 2.0 * np.pi), 2.0 * np.arctan2(radial, axial)
    )
    length = np.where(on_axis, np.where(axial >= 0.0, axial, np.inf), finite_radius * turn)
    radius = np.where(on_axis, np.where(axial >= 0.0, np.inf, np.nan), finite_radius)
    return SingleArc(radius, turn, length)


def single_arc_to(world_T_tip, points) -> SingleArc:
    """Radius, turning angle and length of the single arc through each point.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    points : array_like, shape (3,) or (n, 3)

    Returns
    -------
    SingleArc
        Arrays of shape (n,).
    """
    axial, radial = tip_coordinates(world_T_tip, np.atleast_2d(np.asarray(points, dtype=float)))
    return _single_arc(axial, radial)


def is_reachable(world_T_tip, points, r_min_mm, *, max_turn_rad: float = np.pi):
    """Whether a single arc with radius >= r_min and turn <= max_turn reaches each point.

    With the default ``max_turn_rad = pi`` this is the lecture's condition
    ``P_z >= sqrt(2 r_min rho - rho^2)`` (see :func:`lecture_reachability_condition`).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    points : array_like, shape (3,) or (n, 3)
    r_min_mm : float
        Minimum radius of curvature (> 0).
    max_turn_rad : float
        Largest heading change allowed along the arc, in (0, 2 pi].

    Returns
    -------
    bool or ndarray of bool, shape (n,)

    Examples
    --------
    >>> import numpy as np
    >>> is_reachable(np.eye(4), [[0, 10, 100], [0, 40, 10]], 50.0)
    array([ True, False])
    """
    r_min = as_positive(r_min_mm, "r_min_mm")
    if not (0.0 < max_turn_rad <= 2.0 * np.pi):
        raise InvalidInputError("max_turn_rad", f"must lie in (0, 2 pi], got {max_turn_rad}")
    axial, radial = tip_coordinates(world_T_tip, points)
    arc = _single_arc(np.atleast_1d(axial), np.atleast_1d(radial))
    with np.errstate(invalid="ignore"):
        ok = (arc.radius_mm >= r_min) & (arc.turn_rad <= max_turn_rad)
    return ok[0] if np.ndim(axial) == 0 else ok


def is_reachable_unchecked(origin, axis, point, r_min_mm: float) -> bool:
    """:func:`is_reachable` for one point with the default ``max_turn_rad = pi``, without
    input checks (the samplers' inner loops; checked entry points call it).

    A single arc turning at most pi reaches points on or ahead of the tip's normal plane
    (axial ``a >= 0``) whose arc radius ``(a^2 + rho^2) / (2 rho)`` is at least
    ``r_min``, and every point straight ahead.

    Parameters
    ----------
    origin, axis : sequence of float, length 3
        The tip's position (mm) and unit insertion direction.
    point : sequence of float, length 3
    r_min_mm : float

    Returns
    -------
    bool

    Examples
    --------
    >>> is_reachable_unchecked((0, 0, 0), (0, 0, 1), (0, 10, 100), 50.0)
    True
    >>> is_reachable_unchecked((0, 0, 0), (0, 0, 1), (0, 40, 10), 50.0)
    False
    """
    dx, dy, dz = point[0] - origin[0], point[1] - origin[1], point[2] - origin[2]
    a = dx * axis[0] + dy * axis[1] + dz * axis[2]
    if a < 0.0:  # behind the normal plane: the arc would turn more than pi
        return False
    rx, ry, rz = dx - a * axis[0], dy - a * axis[1], dz - a * axis[2]
    rho = math.sqrt(rx * rx + ry * ry + rz * rz)
    if rho <= ON_AXIS_TOL_MM:
        return True
    return (a * a + rho * rho) / (2.0 * rho) >= r_min_mm


def lecture_reachability_condition(points_tip, r_min_mm):
    """The lecture's test ``P_z >= sqrt(2 r_min rho - rho^2)`` on tip-frame points.

    Written literally (with ``P_z >= 0`` where the square root is of a negative number,
    ``rho > 2 r_min``); :func:`is_reachable` is the same test in frame-free form.

    Parameters
    ----------
    points_tip : array_like, shape (3,) or (n, 3)
        Points ``(P_x, P_y, P_z)`` in the tip frame (mm).
    r_min_mm : float

    Returns
    -------
    bool or ndarray of bool, shape (n,)
    """
    r_min = as_positive(r_min_mm, "r_min_mm")
    p, single = as_points(points_tip, "points_tip")
    rho = np.hypot(p[:, 0], p[:, 1])
    disc = 2.0 * r_min * rho - rho**2
    ok = p[:, 2] >= np.sqrt(np.maximum(disc, 0.0))
    return unbatch(ok, single)


@dataclass(frozen=True)
class ArcLinePath:
    """Shortest arc-then-straight path from a tip to each point (arrays of shape (n,)).

    Attributes
    ----------
    length_mm : ndarray
        Total length; ``inf`` where the point is unreachable.
    arc_length_mm : ndarray
        Length of the arc on the r_min circle.
    line_length_mm : ndarray
        Length of the straight part.
    turn_rad : ndarray
        Heading change along the arc, in [0, 2 pi).
    spin_rad : ndarray
        Rotation about the tip's z axis that puts the bending direction (the tip's -y
        axis, :mod:`needlekit.conventions`) toward the point; 0 for points on the axis.
    reachable : ndarray of bool
    """

    length_mm: np.ndarray
    arc_length_mm: np.ndarray
    line_length_mm: np.ndarray
    turn_rad: np.ndarray
    spin_rad: np.ndarray
    reachable: np.ndarray


def shortest_arc_line(world_T_tip, points, r_min_mm) -> ArcLinePath:
    """Shortest path of an r_min arc followed by a straight line to each point.

    Outside the r_min horn torus this is the shortest curvature-bounded path to the point
    (the Dubins CS path with free final heading), and so an admissible cost-to-go for
    planners there. Inside the torus no arc-then-line path exists (``inf``) although
    two-arc manoeuvres do; a planner's lower bound there must come from elsewhere.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    points : array_like, shape (3,) or (n, 3)
    r_min_mm : float

    Returns
    -------
    ArcLinePath

    Examples
    --------
    A point on the r_min circle is reached by a quarter circle alone (25 pi mm):

    >>> import numpy as np
    >>> p = shortest_arc_line(np.eye(4), [0.0, -50.0, 50.0], 50.0)
    >>> round(float(p.length_mm[0]), 6), round(float(p.line_length_mm[0]), 6)
    (78.539816, 0.0)
    """
    r = as_positive(r_min_mm, "r_min_mm")
    g = _one_pose(world_T_tip)
    p, _ = as_points(points, "points")
    local = (p - g[:3, 3]) @ g[:3, :3]
    return _arc_line(local, r)


def shortest_arc_line_unchecked(pose: np.ndarray, points: np.ndarray, r: float) -> ArcLinePath:
    """:func:`shortest_arc_line` without its checks, for a search's inner loop: ``pose`` a
    valid (4, 4) float64 pose, ``points`` float64 of shape (n, 3), ``r`` > 0. The same
    arithmetic, so the same answer to the bit.

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
    points : ndarray, shape (n, 3)
    r : float

    Returns
    -------
    ArcLinePath
    """
    return _arc_line((points - pose[:3, 3]) @ pose[:3, :3], r)


def _arc_line(local: np.ndarray, r: float) -> ArcLinePath:
    """Shortest r-arc-then-line paths to points given in tip frames, shape (n, 3)."""
    axial = local[:, 2]
    radial = np.hypot(local[:, 0], local[:, 1])
    on_axis = radial <= ON_AXIS_TOL_MM
    # bending direction -y rotated by spin must point at (x, y): (sin s, -cos s) ~ (x, y)
    spin = np.where(on_axis, 0.0, np.arctan2(local[:, 0], -local[:, 1]))
    # in the bending plane, lateral coordinate u = radial, circle centre at (u, z) = (r, 0)
    du, dz = radial - r, axial
    dist = np.hypot(du, dz)
    reachable = (dist >= r) & ~(on_axis & (axial < 0.0))
    tangent = np.sqrt(np.maximum(dist**2 - r * r, 0.0))
    gamma = np.arctan2(dz, du)
    turn = np.mod(np.arctan2(tangent, -r) - gamma, 2.0 * np.pi)
    # straight ahead: turn is 0 up to rounding; snap the 2 pi wrap-around back
    turn = np.where(turn > 2.0 * np.pi - 1e-12, 0.0, turn)
    arc_len = np.where(reachable, r * turn, np.inf)
    line_len = np.where(reachable, tangent, np.inf)
    return ArcLinePath(arc_len + line_len, arc_len, line_len, turn, spin, reachable)


def arc_line_lengths_from(poses, point, r_min_mm) -> np.ndarray:
    """Shortest arc-then-line length from each of many tip poses to one point.

    Parameters
    ----------
    poses : array_like, shape (n, 4, 4)
        Tip poses (world, mm).
    point : array_like, shape (3,)
    r_min_mm : float

    Returns
    -------
    ndarray, shape (n,)
        ``inf`` where the point lies inside a pose's r_min horn torus.
    """
    r = as_positive(r_min_mm, "r_min_mm")
    g, _ = as_poses(poses, "poses")
    q, _ = as_points(point, "point")
    return arc_line_lengths_from_unchecked(g, q[0], r)


def arc_line_lengths_from_unchecked(poses: np.ndarray, point: np.ndarray, r: float) -> np.ndarray:
    """:func:`arc_line_lengths_from` without its checks, for a search's inner loop (RRT's
    nearest node): ``poses`` valid float64 poses of shape (n, 4, 4), ``point`` float64 of
    shape (3,), ``r`` > 0. The same arithmetic, so the same lengths to the bit.

    Parameters
    ----------
    poses : ndarray, shape (n, 4, 4)
    point : ndarray, shape (3,)
    r : float

    Returns
    -------
    ndarray, shape (n,)
    """
    local = np.einsum("nji,nj->ni", poses[:, :3, :3], point - poses[:, :3, 3])
    return _arc_line(local, r).length_mm
