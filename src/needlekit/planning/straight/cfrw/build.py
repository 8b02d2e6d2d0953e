"""Building the CFRW map of a straight-needle problem: :func:`cfrw_map`.

The grid of directions is evaluated in one batch: the angle limits, the entry points,
length and surface angle, then the certified clearance of the directions still open.
"""

from __future__ import annotations

import numpy as np

from needlekit.constants import RECORD_ROUNDING_ALLOWANCE_MM
from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import angle_between
from needlekit.planning.straight.angle_grid import grid_shape
from needlekit.planning.straight.cfrw.bounds import (
    CLEARANCE_CAP_ABOVE_GAMMA_MM,
    NEAR_STEP_MM,
    segment_clearance_bound,
)
from needlekit.planning.straight.cfrw.entries import entry_points
from needlekit.planning.straight.cfrw.map import Blocked, CFRWMap
from needlekit.planning.straight.problem import StraightProblem, directions_of

__all__ = ["cfrw_map"]


def cfrw_map(
    problem: StraightProblem,
    *,
    resolution_deg: float = 1.0,
    step_mm: float = NEAR_STEP_MM,
) -> CFRWMap:
    """Evaluate every direction of a grid over the problem's angle box.

    Parameters
    ----------
    problem : StraightProblem
    resolution_deg : float
        Grid step in theta and phi.
    step_mm : float
        Largest sphere-tracing step near obstacles (the certified bound is at most half of
        it below the sampled minimum).

    Returns
    -------
    CFRWMap

    Raises
    ------
    InvalidInputError
        The target lies outside the body, or a bad resolution.
    """
    res = float(resolution_deg)
    if not (np.isfinite(res) and 0 < res <= 45):
        raise InvalidInputError("resolution_deg", f"must lie in (0, 45], got {resolution_deg!r}")
    body = problem.scene[problem.entry_surface].field
    if float(body.signed_distance(problem.target_mm)) >= 0:
        raise InvalidInputError(
            "target_mm",
            f"{np.round(problem.target_mm, 3).tolist()} lies outside the "
            f"{problem.entry_surface} surface: there is no entry to it",
        )
    t0, t1 = np.radians(problem.theta_range_deg)
    p0, p1 = np.radians(problem.phi_range_deg)
    m, k = grid_shape(problem.theta_range_deg, problem.phi_range_deg, res)
    theta = np.linspace(t0, t1, m)
    if p1 - p0 >= 2 * np.pi - 1e-9:
        phi = p0 + np.arange(k) * (2 * np.pi / k)
    else:
        phi = np.linspace(p0, p1, k)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    u = directions_of(T, P, problem.world_T_sigma)
    flat = u.reshape(-1, 3)
    n = len(flat)
    blocked = np.zeros(n, dtype=np.int64)
    if problem.approach_direction is not None and problem.approach_cone_deg < 180.0:
        off = np.degrees(angle_between(flat, problem.approach_direction))
        blocked[off > problem.approach_cone_deg + 1e-9] = Blocked.ANGLE_LIMIT
    free = blocked == 0
    length = np.full(n, np.inf)
    entry = np.full((n, 3), np.nan)
    length[free], entry[free] = entry_points(
        body, problem.target_mm, flat[free], problem.needle.max_length_mm
    )
    blocked[free & ~np.isfinite(length)] = Blocked.NO_ENTRY
    blocked[(blocked == 0) & (length > problem.needle.max_length_mm)] = Blocked.TOO_LONG
    normal_angle = np.full(n, np.nan)
    has = np.isfinite(length)
    if has.any():
        g = body.gradient(entry[has])
        g = g / np.linalg.norm(g, axis=1, keepdims=True)
        # the needle goes in along -u; the inward normal is -g: the angle between them
        normal_angle[has] = np.degrees(angle_between(flat[has], g))
    blocked[(blocked == 0) & (normal_angle > problem.max_normal_angle_deg + 1e-9)] = (
        Blocked.NORMAL_ANGLE
    )
    clearance = np.full(n, np.nan)
    check = np.isfinite(length) & (length <= problem.needle.max_length_mm)
    check &= (blocked == 0) | (blocked == Blocked.NORMAL_ANGLE)
    if check.any():
        cap = problem.clearance_needed_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
        anatomy = problem.anatomy_field()
        b = np.full(int(check.sum()), cap)
        if anatomy is not None:
            b, _ = segment_clearance_bound(
                anatomy,
                np.broadcast_to(problem.target_mm, (int(check.sum()), 3)),
                flat[check],
                length[check],
                cap_mm=cap,
                step_mm=step_mm,
            )
        clearance[check] = b - problem.needle.radius_mm
    # the record rounds the chosen points: keep the allowance above gamma (constants.py)
    accept = problem.gamma_mm + RECORD_ROUNDING_ALLOWANCE_MM
    blocked[(blocked == 0) & ~(clearance >= accept)] = Blocked.CLEARANCE
    shape = (m, k)
    anatomy_map = CFRWMap(
        problem,  # its clearance, for now, the anatomy's alone
        theta,
        phi,
        u,
        entry.reshape(m, k, 3),
        length.reshape(shape),
        clearance.reshape(shape),
        normal_angle.reshape(shape),
        blocked.reshape(shape),
    )
    # the placed needles after the anatomy, so that what they block is told apart
    return anatomy_map._lowered(problem, problem.extra_obstacles, step_mm)
