"""The collision-free reachable workspace (CFRW) of a straight needle (Liu et al. 2016).

For a fixed target, a trajectory is a direction ``u(theta, phi)`` (target toward entry,
:mod:`~needlekit.planning.straight.problem`). :func:`cfrw_map` evaluates a dense grid of
directions and keeps, for each, the entry point (where the ray leaves the body through the
entry surface), the insertion length, the angle to the surface's inward normal, and the
**certified clearance**: a lower bound on the distance from the needle's surface (the
capsule of the needle's radius around the segment target-entry) to every obstacle.

Certified clearance along a segment. A signed distance ``d`` is 1-Lipschitz, so between
two samples ``t_i < t_j`` of the segment the distance is at least
``(d_i + d_j - (t_j - t_i)) / 2``. The samples are taken by sphere tracing: far from
obstacles the step is the distance itself less a cap (so whole stretches are certified to
clear the cap at once), near them at most :data:`NEAR_STEP_MM`; the bound over all
intervals, less the field's stated error bound and the needle radius, is the certified
clearance (reported up to ``cap``). A direction belongs to the CFRW when that clearance is
at least gamma (the paper's safety distance), and the other limits hold.

The CFRW's boundary is drawn, as in the paper's Fig. 11, in layered planes ``z = h`` of
Sigma: each direction meets the plane at ``h tan(theta) (cos phi, sin phi)``. Boundary
points are found on the grid (marching squares over ``clearance - gamma``) and refined by
bisection in ``theta`` on a finely sampled clearance, so that trajectories on the boundary
clear the obstacles by gamma to within :data:`BOUNDARY_TOL_MM`. The paper's ray-casting
test (step 3 of its entry search) decides whether a point of a layer lies inside the
closed boundary polylines, holes included (:func:`inside_polylines`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.problem import StraightProblem, directions_of

__all__ = [
    "BOUNDARY_TOL_MM",
    "Blocked",
    "CFRWMap",
    "cfrw_map",
    "entry_points",
    "inside_polylines",
    "segment_clearance_bound",
]

#: Largest step of the sphere tracing near obstacles (mm): the certified bound is at most
#: half of it below the sampled minimum.
NEAR_STEP_MM: float = 0.5
#: Clearances above gamma by more than this are reported as this (mm): the map certifies
#: them as "at least"; it bounds the work of the sphere tracing.
CLEARANCE_CAP_ABOVE_GAMMA_MM: float = 10.0
#: Boundary trajectories clear the obstacles by gamma to within this (mm).
BOUNDARY_TOL_MM: float = 0.01
#: Sampling step (mm) of the fine clearance that boundary refinement uses.
FINE_STEP_MM: float = 0.02
#: Entry points are located to within this (mm) along the ray.
ENTRY_TOL_MM: float = 1e-4


class Blocked(enum.IntEnum):
    """Why a direction is not in the CFRW (0: it is)."""

    FREE = 0
    ANGLE_LIMIT = 1  # outside Eq. 2's box, or the approach cone
    NO_ENTRY = 2  # the ray does not leave the body within the needle's length
    TOO_LONG = 3
    NORMAL_ANGLE = 4  # too oblique to the entry surface
    CLEARANCE = 5  # closer than gamma to an obstacle


def segment_clearance_bound(
    field: DistanceField,
    origins: np.ndarray,
    directions: np.ndarray,
    lengths: np.ndarray,
    *,
    cap_mm: float,
    step_mm: float = NEAR_STEP_MM,
) -> tuple[np.ndarray, np.ndarray]:
    """Certified lower bound of a field's distance along segments (module notes).

    Parameters
    ----------
    field : DistanceField
    origins, directions : ndarray, shape (n, 3)
        Segment starts and unit directions (world, mm).
    lengths : ndarray, shape (n,)
        Segment lengths (mm, >= 0).
    cap_mm : float
        Bounds above this are reported as this.
    step_mm : float
        Largest step where the distance is below the cap.

    Returns
    -------
    bound : ndarray, shape (n,)
        ``min(cap, lower bound of the distance over the segment) - error_bound``.
    at_mm : ndarray, shape (n,)
        Arc length of the sample with the smallest distance.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    L = np.asarray(lengths, dtype=float).reshape(-1)
    n = len(o)
    bound = np.full(n, float(cap_mm))
    best = np.full(n, np.inf)
    at = np.zeros(n)
    t = np.zeros(n)
    d_prev = np.full(n, np.nan)
    t_prev = np.zeros(n)
    active = np.arange(n)
    while active.size:
        p = o[active] + t[active, None] * u[active]
        d = field.capped_distance(p, cap_mm)  # exact below the cap, a lower bound above
        k = active
        seen = np.isfinite(d_prev[k])
        gap = t[k] - t_prev[k]
        interval = np.where(seen, 0.5 * (d_prev[k] + d - gap), d)
        bound[k] = np.minimum(bound[k], interval)
        closer = d < best[k]
        best[k] = np.where(closer, d, best[k])
        at[k] = np.where(closer, t[k], at[k])
        d_prev[k], t_prev[k] = d, t[k]
        done = t[k] >= L[k]
        # beyond the cap a whole step of d - cap is certified to clear it; nearer, step_mm
        step = np.maximum(d - cap_mm, step_mm)
        t[k] = np.minimum(t[k] + step, L[k])
        active = k[~done]
    return np.minimum(bound, cap_mm) - float(field.error_bound_mm), at


def entry_points(
    body: DistanceField, target_mm: np.ndarray, directions: np.ndarray, max_length_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Where rays from the target leave the body through its surface.

    Parameters
    ----------
    body : DistanceField
        The entry surface's structure (negative inside the body).
    target_mm : ndarray, shape (3,)
    directions : ndarray, shape (n, 3)
        Unit directions from the target.
    max_length_mm : float
        Rays are followed this far (plus a small slack to report "too long").

    Returns
    -------
    length_mm : ndarray, shape (n,)
        Distance from the target to the first crossing (``inf`` where none within the
        search length).
    entry_mm : ndarray, shape (n, 3)
        The crossing points (NaN where none).
    """
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    n = len(u)
    reach = float(max_length_mm) * 1.25 + 5.0
    err = float(body.error_bound_mm)
    t = np.zeros(n)
    lo = np.zeros(n)
    hi = np.full(n, np.inf)
    active = np.arange(n)
    while active.size:
        d = body.signed_distance(target_mm + t[active, None] * u[active])
        out = d >= 0.0
        hi[active[out]] = t[active[out]]
        lo[active[~out]] = t[active[~out]]
        step = np.maximum(-d - err, 0.05)
        t[active] = t[active] + step
        keep = ~out & (t[active] <= reach)
        active = active[keep]
    found = np.isfinite(hi)
    idx = np.flatnonzero(found)
    a, b = lo[idx], hi[idx]
    while idx.size and np.max(b - a) > ENTRY_TOL_MM:
        m = 0.5 * (a + b)
        d = body.signed_distance(target_mm + m[:, None] * u[idx])
        a = np.where(d < 0, m, a)
        b = np.where(d < 0, b, m)
    length = np.full(n, np.inf)
    length[idx] = b
    entry = np.full((n, 3), np.nan)
    entry[idx] = target_mm + b[:, None] * u[idx]
    return length, entry


@dataclass(frozen=True)
class CFRWMap:
    """The CFRW of one target on a grid of directions.

    Attributes
    ----------
    problem : StraightProblem
    theta_rad : ndarray, shape (m,)
    phi_rad : ndarray, shape (k,)
        Grid of Sigma angles (``phi`` spans the problem's range; a full circle wraps).
    directions : ndarray, shape (m, k, 3)
        Unit world directions, target toward entry.
    entry_mm : ndarray, shape (m, k, 3)
        Entry points (NaN where the ray does not leave the body within reach).
    length_mm : ndarray, shape (m, k)
    clearance_mm : ndarray, shape (m, k)
        Certified clearance of the needle's surface (up to gamma + the cap; NaN where not
        evaluated: outside the angle limits or without an entry).
    normal_angle_deg : ndarray, shape (m, k)
        Angle between the insertion direction and the entry surface's inward normal.
    blocked : ndarray of int, shape (m, k)
        :class:`Blocked` code of each direction (0: in the CFRW).
    """

    problem: StraightProblem
    theta_rad: np.ndarray
    phi_rad: np.ndarray
    directions: np.ndarray
    entry_mm: np.ndarray
    length_mm: np.ndarray
    clearance_mm: np.ndarray
    normal_angle_deg: np.ndarray
    blocked: np.ndarray

    @property
    def feasible(self) -> np.ndarray:
        """Directions in the CFRW, shape (m, k) bool."""
        return self.blocked == Blocked.FREE

    @property
    def margin_mm(self) -> np.ndarray:
        """Certified clearance less gamma (>= 0 in the CFRW), shape (m, k)."""
        return self.clearance_mm - self.problem.gamma_mm

    @property
    def full_circle(self) -> bool:
        """Whether ``phi`` spans the whole circle (the grid wraps around)."""
        lo, hi = self.problem.phi_range_deg
        return hi - lo >= 360.0 - 1e-9

    def counts(self) -> dict:
        """How many directions each reason blocks.

        Returns
        -------
        dict
            ``Blocked`` name (lower case) -> count.
        """
        return {b.name.lower(): int(np.count_nonzero(self.blocked == b)) for b in Blocked}

    def clearance_of(
        self, theta_rad, phi_rad, *, step_mm: float = FINE_STEP_MM, cap_mm: float | None = None
    ) -> np.ndarray:
        """Certified clearance of single directions, sampled finely (NaN where the ray has
        no entry within reach).

        Parameters
        ----------
        theta_rad, phi_rad : array_like, shape (n,)
        step_mm : float
            Sampling step near obstacles (the bound is at most half of it low).
        cap_mm : float, optional
            Clearances above this come back as this (default: gamma plus the map's cap);
            a cap just above gamma makes a yes/no question fast.

        Returns
        -------
        ndarray, shape (n,)
        """
        pr = self.problem
        u = directions_of(theta_rad, phi_rad, pr.world_T_sigma).reshape(-1, 3)
        length, _ = entry_points(
            pr.scene[pr.entry_surface].field, pr.target_mm, u, pr.needle.max_length_mm
        )
        out = np.full(len(u), np.nan)
        ok = np.isfinite(length)
        if ok.any():
            cap = pr.gamma_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM if cap_mm is None else cap_mm
            b, _ = segment_clearance_bound(
                pr.obstacle_field(),
                np.broadcast_to(pr.target_mm, (int(ok.sum()), 3)),
                u[ok],
                length[ok],
                cap_mm=cap + pr.needle.radius_mm,
                step_mm=step_mm,
            )
            out[ok] = b - pr.needle.radius_mm
        return out

    def _level(self) -> np.ndarray:
        """Positive inside the CFRW, negative outside; follows ``clearance - gamma`` where
        the clearance decides, so that contours of it sit near the gamma boundary."""
        level = np.full(self.blocked.shape, -1.0)
        margin = self.margin_mm
        free = self.feasible
        level[free] = np.maximum(margin[free], 1e-9)
        by_clearance = self.blocked == Blocked.CLEARANCE
        level[by_clearance] = np.minimum(margin[by_clearance], -1e-9)
        return level

    def _level_at(self, theta, phi, level) -> np.ndarray:
        """Bilinear interpolation of the level on the grid (phi periodic when the grid
        spans the circle); -1 outside the grid."""
        th, ph = self.theta_rad, self.phi_rad
        m, k = level.shape
        dth = (th[-1] - th[0]) / (m - 1) if m > 1 else 1.0
        x = (theta - th[0]) / dth
        if self.full_circle:
            dph = 2 * np.pi / k
            y = np.mod(phi - ph[0], 2 * np.pi) / dph
        else:
            dph = (ph[-1] - ph[0]) / (k - 1) if k > 1 else 1.0
            y = (phi - ph[0]) / dph
        out = np.full(np.shape(theta), -1.0)
        ok = (x >= 0) & (x <= m - 1) & (y >= 0) & ((y <= k - 1) | self.full_circle)
        x0 = np.clip(np.floor(x[ok]).astype(int), 0, max(m - 2, 0))
        y0 = np.floor(y[ok]).astype(int)
        fx, fy = x[ok] - x0, y[ok] - y0
        x1 = np.minimum(x0 + 1, m - 1)
        if self.full_circle:
            y0, y1 = y0 % k, (y0 + 1) % k
        else:
            y0 = np.clip(y0, 0, max(k - 2, 0))
            fy = y[ok] - y0
            y1 = np.minimum(y0 + 1, k - 1)
        v = (
            level[x0, y0] * (1 - fx) * (1 - fy)
            + level[x1, y0] * fx * (1 - fy)
            + level[x0, y1] * (1 - fx) * fy
            + level[x1, y1] * fx * fy
        )
        out[ok] = v
        return out

    def layer(self, h_mm: float, *, refine: bool = True, max_theta_deg: float = 85.0):
        """The CFRW's boundary in the plane ``z = h`` of Sigma (the paper's Fig. 11).

        Parameters
        ----------
        h_mm : float
            Height of the plane above the target along Sigma's z (> 0).
        refine : bool
            Move each vertex where the clearance decides the boundary along its ray
            (bisection in theta on :meth:`clearance_of`) to where the clearance is gamma,
            to within :data:`BOUNDARY_TOL_MM`; vertices on another limit (an angle limit,
            the entry surface, the length) stay as the grid gives them.
        max_theta_deg : float
            Directions beyond this from Sigma's z are left out of the plane (they meet it
            far away, or never).

        Returns
        -------
        list of ndarray, shape (n_i, 2)
            Closed polylines (last vertex = first), ``(x, y)`` in Sigma (mm); the CFRW's
            part of the plane is their inside by the even-odd rule (holes included).
        """
        from skimage import measure

        if not (np.isfinite(h_mm) and h_mm > 0):
            raise InvalidInputError("h_mm", f"must be a finite number > 0, got {h_mm!r}")
        top = np.radians(min(max_theta_deg, float(np.degrees(self.theta_rad[-1]))))
        radius = h_mm * np.tan(top)
        dth = (self.theta_rad[-1] - self.theta_rad[0]) / max(len(self.theta_rad) - 1, 1)
        cell = max(h_mm * dth / 2.0, 1e-3)  # about half a grid step at the pole
        n = min(int(np.ceil(2 * radius / cell)) + 1, 1201)
        xs = np.linspace(-radius, radius, n)
        X, Y = np.meshgrid(xs, xs, indexing="ij")
        r = np.hypot(X, Y)
        theta = np.arctan2(r, h_mm)
        phi = np.arctan2(Y, X)
        level = self._level_at(theta, phi, self._level())
        level[theta > top] = -1.0
        grid = np.pad(level, 1, constant_values=-1.0)
        out = []
        step = xs[1] - xs[0]
        for c in measure.find_contours(grid, 0.0):
            xy = xs[0] + (c - 1.0) * step
            if refine:
                xy = self._refine_layer(xy, h_mm)
            if not np.allclose(xy[0], xy[-1]):
                xy = np.vstack([xy, xy[:1]])
            out.append(xy)
        return out

    def _refine_layer(self, xy: np.ndarray, h_mm: float) -> np.ndarray:
        """Bisection toward clearance = gamma: along the vertex's ray (in theta), or, where
        the boundary runs along the ray, across it (in phi)."""
        theta = np.arctan2(np.hypot(xy[:, 0], xy[:, 1]), h_mm)
        phi = np.arctan2(xy[:, 1], xy[:, 0])
        step = (self.theta_rad[-1] - self.theta_rad[0]) / max(len(self.theta_rad) - 1, 1)
        top = 0.5 * np.pi - 1e-9
        done = np.zeros(len(xy), dtype=bool)
        for along_theta in (True, False):
            todo = np.flatnonzero(~done)
            if not todo.size:
                break
            t, f = theta[todo], phi[todo]
            if along_theta:
                a0, b0 = np.clip(t - step, 0, top), np.clip(t + step, 0, top)
                ends = ((a0, f), (b0, f))
            else:
                w = step / np.maximum(np.sin(t), 1e-6)  # the same arc across the ray
                a0, b0 = f - w, f + w
                ends = ((t, a0), (t, b0))
            moved = self._bisect(ends, along_theta)
            if moved is None:
                continue
            ok, tt, ff = moved
            theta[todo[ok]], phi[todo[ok]] = tt, ff
            done[todo[ok]] = True
        r = h_mm * np.tan(theta)
        out = xy.copy()
        out[done] = np.column_stack([r * np.cos(phi), r * np.sin(phi)])[done]
        return out

    def _bisect(self, ends, along_theta: bool):
        gamma = self.problem.gamma_mm
        cap = gamma + 2 * BOUNDARY_TOL_MM
        (ta, fa), (tb, fb) = ends
        ca = self.clearance_of(ta, fa, cap_mm=cap)
        cb = self.clearance_of(tb, fb, cap_mm=cap)
        ok = ((ca >= gamma) != (cb >= gamma)) & np.isfinite(ca) & np.isfinite(cb)
        if not ok.any():
            return None
        swap = ca[ok] < gamma
        # a: the clear end, b: the blocked one (the moving coordinate only)
        a = np.where(swap, (tb if along_theta else fb)[ok], (ta if along_theta else fa)[ok])
        b = np.where(swap, (ta if along_theta else fa)[ok], (tb if along_theta else fb)[ok])
        fixed = (fa if along_theta else ta)[ok]
        while np.max(np.abs(b - a)) * 200.0 > 1e-6:  # 200 mm lever: 1e-6 mm at the entry
            m = 0.5 * (a + b)
            c = (
                self.clearance_of(m, fixed, cap_mm=cap)
                if along_theta
                else self.clearance_of(fixed, m, cap_mm=cap)
            )
            clear = c >= gamma
            a, b = np.where(clear, m, a), np.where(clear, b, m)
        return (ok, a, fixed) if along_theta else (ok, fixed, a)

    def to_dict(self) -> dict:
        """JSON-ready summary and grids (the ``cfrw.json`` format).

        Returns
        -------
        dict
        """

        def grid(a, digits=4):
            return np.where(np.isfinite(a), np.round(a, digits), np.nan).tolist()

        pr = self.problem
        return {
            "target_mm": pr.target_mm.tolist(),
            "gamma_mm": pr.gamma_mm,
            "needle_radius_mm": pr.needle.radius_mm,
            "max_length_mm": pr.needle.max_length_mm,
            "world_T_sigma": pr.world_T_sigma.tolist(),
            "theta_deg": np.degrees(self.theta_rad).round(6).tolist(),
            "phi_deg": np.degrees(self.phi_rad).round(6).tolist(),
            "counts": self.counts(),
            "feasible": self.feasible.astype(int).tolist(),
            "clearance_mm": grid(self.clearance_mm),
            "length_mm": grid(self.length_mm),
            "normal_angle_deg": grid(self.normal_angle_deg, 3),
        }


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
    m = int(round((t1 - t0) / np.radians(res))) + 1
    theta = np.linspace(t0, t1, m)
    if p1 - p0 >= 2 * np.pi - 1e-9:
        k = int(round(2 * np.pi / np.radians(res)))
        phi = p0 + np.arange(k) * (2 * np.pi / k)
    else:
        k = int(round((p1 - p0) / np.radians(res))) + 1
        phi = np.linspace(p0, p1, k)
    T, P = np.meshgrid(theta, phi, indexing="ij")
    u = directions_of(T, P, problem.world_T_sigma)
    flat = u.reshape(-1, 3)
    n = len(flat)
    blocked = np.zeros(n, dtype=np.int64)
    if problem.approach_direction is not None and problem.approach_cone_deg < 180.0:
        off = np.degrees(np.arccos(np.clip(flat @ problem.approach_direction, -1.0, 1.0)))
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
        normal_angle[has] = np.degrees(np.arccos(np.clip(np.sum(flat[has] * g, axis=1), -1, 1)))
    blocked[(blocked == 0) & (normal_angle > problem.max_normal_angle_deg + 1e-9)] = (
        Blocked.NORMAL_ANGLE
    )
    clearance = np.full(n, np.nan)
    check = np.isfinite(length) & (length <= problem.needle.max_length_mm)
    check &= (blocked == 0) | (blocked == Blocked.NORMAL_ANGLE)
    if check.any():
        cap = problem.clearance_needed_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
        b, _ = segment_clearance_bound(
            problem.obstacle_field(),
            np.broadcast_to(problem.target_mm, (int(check.sum()), 3)),
            flat[check],
            length[check],
            cap_mm=cap,
            step_mm=step_mm,
        )
        clearance[check] = b - problem.needle.radius_mm
    blocked[(blocked == 0) & ~(clearance >= problem.gamma_mm)] = Blocked.CLEARANCE
    shape = (m, k)
    return CFRWMap(
        problem,
        theta,
        phi,
        u,
        entry.reshape(m, k, 3),
        length.reshape(shape),
        clearance.reshape(shape),
        normal_angle.reshape(shape),
        blocked.reshape(shape),
    )


def inside_polylines(points_xy, polylines) -> np.ndarray:
    """The paper's ray-casting test: points inside closed polylines (even-odd rule, so
    holes count), by the number of crossings of a ray toward +x.

    Parameters
    ----------
    points_xy : array_like, shape (n, 2)
    polylines : list of array_like, shape (m_i, 2)
        Closed polylines (the last vertex may repeat the first).

    Returns
    -------
    ndarray of bool, shape (n,)

    Examples
    --------
    >>> square = [[0, 0], [2, 0], [2, 2], [0, 2], [0, 0]]
    >>> hole = [[0.5, 0.5], [1.5, 0.5], [1.5, 1.5], [0.5, 1.5], [0.5, 0.5]]
    >>> inside_polylines([[0.25, 1.0], [1.0, 1.0], [3.0, 1.0]], [square, hole]).tolist()
    [True, False, False]
    """
    p = np.asarray(points_xy, dtype=float).reshape(-1, 2)
    crossings = np.zeros(len(p), dtype=np.int64)
    for poly in polylines:
        v = np.asarray(poly, dtype=float).reshape(-1, 2)
        a, b = v, np.roll(v, -1, axis=0)
        ya, yb = a[:, 1][None], b[:, 1][None]
        py = p[:, 1][:, None]
        straddle = (ya > py) != (yb > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            x_at = a[:, 0][None] + (py - ya) * (b[:, 0] - a[:, 0])[None] / (yb - ya)
        crossings += np.count_nonzero(straddle & (x_at > p[:, 0][:, None]), axis=1)
    return crossings % 2 == 1
