"""The CFRW of one target on a grid of directions: :class:`CFRWMap`.

Per direction its entry, length, angle to the surface normal, certified clearance and why
it is blocked (:class:`Blocked`); the boundary in layered planes of Sigma, refined to
:data:`BOUNDARY_TOL_MM`, and the paper's ray-casting test of a layer point against the
closed boundary polylines (:func:`inside_polylines`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.constants import RECORD_ROUNDING_ALLOWANCE_MM
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.cfrw.bounds import (
    CLEARANCE_CAP_ABOVE_GAMMA_MM,
    NEAR_STEP_MM,
    clearance_bound,
    obstacle_segment_bound,
)
from needlekit.planning.straight.cfrw.entries import entry_points
from needlekit.planning.straight.problem import StraightProblem, directions_of

__all__ = ["BOUNDARY_TOL_MM", "Blocked", "CFRWMap", "inside_polylines"]


#: Boundary trajectories clear the obstacles by gamma to within this (mm).
BOUNDARY_TOL_MM: float = 0.01

#: Sampling step (mm) of the fine clearance that boundary refinement uses.
FINE_STEP_MM: float = 0.02


class Blocked(enum.IntEnum):
    """Why a direction is not in the CFRW (0: it is)."""

    FREE = 0
    ANGLE_LIMIT = 1  # outside Eq. 2's box, or the approach cone
    NO_ENTRY = 2  # the ray does not leave the body within the needle's length
    TOO_LONG = 3
    NORMAL_ANGLE = 4  # too oblique to the entry surface
    CLEARANCE = 5  # closer than gamma to the anatomy (a vessel, a scene obstacle)
    PLACED_NEEDLE = 6  # clear of the anatomy, closer than gamma to a needle placed before


#: Each reason a direction within the angle limits is blocked, in words.
_BLOCKED_WORDS = {
    Blocked.NO_ENTRY: "without an entry within reach",
    Blocked.TOO_LONG: "too long",
    Blocked.NORMAL_ANGLE: "too oblique to the entry surface",
    Blocked.CLEARANCE: "closer than gamma to the anatomy",
    Blocked.PLACED_NEEDLE: "closer than gamma to a needle placed before",
}


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

    def blocking_summary(self) -> str:
        """What keeps the directions within the angle limits out of the CFRW, in words.

        Returns
        -------
        str
            e.g. ``"of 16560 directions within the angle limits (of 32760), 444 free,
            16116 closer than gamma to the anatomy; most blocked: closer than gamma to the
            anatomy"``.
        """
        c = self.counts()
        n = int(self.blocked.size)
        within = n - c["angle_limit"]
        if within == 0:
            return f"all {n} directions lie outside the angle limits"
        parts = [f"{c['free']} free"] + [
            f"{c[b.name.lower()]} {_BLOCKED_WORDS[b]}" for b in _BLOCKED_WORDS if c[b.name.lower()]
        ]
        head = f"of {within} directions within the angle limits (of {n}), " + ", ".join(parts)
        blocked = [(c[b.name.lower()], -int(b), b) for b in _BLOCKED_WORDS]
        count, _, most = max(blocked)
        return head + (f"; most blocked: {_BLOCKED_WORDS[most]}" if count else "")

    def with_obstacles(self, *fields: DistanceField, step_mm: float = NEAR_STEP_MM) -> CFRWMap:
        """The CFRW once more obstacles are in place (the needles placed so far): the
        intersection of this map's CFRW with the new obstacles'.

        Directions, entries, lengths and normal angles are this map's (the entry surface
        is unchanged); each clearance is lowered to each new obstacle's certified bound
        (:func:`obstacle_segment_bound`), and directions that lose gamma become blocked by
        clearance. The result is the map :func:`cfrw_map` makes of
        ``problem.with_obstacles(*fields)`` with the same step, number for number, without
        searching the entries or tracing the anatomy again.

        Parameters
        ----------
        *fields : DistanceField
        step_mm : float
            Sphere-tracing step near the new obstacles (as :func:`cfrw_map`'s).

        Returns
        -------
        CFRWMap
        """
        return self._lowered(self.problem.with_obstacles(*fields), fields, step_mm)

    def _lowered(self, pr: StraightProblem, fields, step_mm: float) -> CFRWMap:
        """This map for the problem ``pr``, its clearances lowered to ``fields``'."""
        clearance = self.clearance_mm.reshape(-1).copy()
        check = np.flatnonzero(np.isfinite(clearance))
        if check.size and fields:
            cap = pr.clearance_needed_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
            o = np.broadcast_to(pr.target_mm, (check.size, 3))
            u = self.directions.reshape(-1, 3)[check]
            L = self.length_mm.reshape(-1)[check]
            for f in fields:
                b = obstacle_segment_bound(f, o, u, L, cap_mm=cap, step_mm=step_mm)
                np.minimum(clearance[check], b - pr.needle.radius_mm, out=b)
                clearance[check] = b
        blocked = self.blocked.reshape(-1).copy()
        accept = pr.gamma_mm + RECORD_ROUNDING_ALLOWANCE_MM  # as cfrw_map's
        blocked[(blocked == Blocked.FREE) & ~(clearance >= accept)] = Blocked.PLACED_NEEDLE
        shape = self.blocked.shape
        return replace(
            self, problem=pr, clearance_mm=clearance.reshape(shape), blocked=blocked.reshape(shape)
        )

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
            b = clearance_bound(
                pr,
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
        by_clearance = (self.blocked == Blocked.CLEARANCE) | (self.blocked == Blocked.PLACED_NEEDLE)
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
            # JSON has no NaN: a direction without a value (not evaluated) is null
            return np.where(np.isfinite(a), np.round(a, digits), None).tolist()

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
