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

Convex obstacles and placed needles. The clearance of a union is the smallest of its
parts', so each placed needle is bounded on its own (:func:`obstacle_segment_bound`,
:func:`clearance_bound`). Its tube is a capsule: the distance between the candidate
segment and the tube's axis, less the radius, is exact in closed form. Its head (Eq. 4's
superquadric, every exponent >= 2) is convex, and the signed distance to a convex solid is
a convex function, so along a segment its tangent lines lie below it:
:func:`convex_segment_bound` keeps a bracket where the slope changes sign, bounds the
minimum by where the two end tangents meet (or by the 1-Lipschitz bound, whichever is
higher), and splits until the bound and the best sample differ by at most
:data:`CONVEX_TOL_MM`; each slope is widened by its error (the projection's error over the
distance) and each part let go keeps its tangent's bound, so the result stays a lower
bound. Segments farther than the cap from the head's enclosing capsule (closed form) are
certified at the cap without evaluating the head, and a segment found inside the head gets
the head's depth bound. :meth:`CFRWMap.with_obstacles` adds placed needles to a map of the
anatomy without searching the entries or tracing the anatomy again; the result equals
:func:`cfrw_map` of the problem with them, number for number.

Entry points. From the target, each ray marches in steps of ``|d| / L`` (``L`` the entry
surface field's Lipschitz bound: 1 for exact distances, computed from the grid for voxel
fields), so no sign change of the field is stepped over (but for parts shorter than
:data:`ENTRY_MIN_STEP_MM`), then bisects the crossing to :data:`ENTRY_TOL_MM`.

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
from dataclasses import dataclass, replace

import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.errors import InvalidInputError
from needlekit.geometry.segments import segment_distances
from needlekit.planning.straight.problem import StraightProblem, directions_of

__all__ = [
    "BOUNDARY_TOL_MM",
    "Blocked",
    "CFRWMap",
    "cfrw_map",
    "clearance_bound",
    "convex_segment_bound",
    "entry_points",
    "inside_polylines",
    "obstacle_segment_bound",
    "segment_clearance_bound",
]

#: Largest step of the sphere tracing near obstacles (mm): the certified bound is at most
#: half of it below the sampled minimum.
NEAR_STEP_MM: float = 0.5
#: Clearances above gamma by more than this are reported as this (mm): the map certifies
#: them as "at least"; it bounds the work of the sphere tracing.
CLEARANCE_CAP_ABOVE_GAMMA_MM: float = 10.0
#: Largest gap (mm) between a convex obstacle's certified bound along a segment and the
#: smallest distance sampled on it (:func:`convex_segment_bound`).
CONVEX_TOL_MM: float = 1e-3
#: Splits of a segment's bracket before :func:`convex_segment_bound` reports the bound so
#: far (each split keeps at most three quarters of the bracket: 200 mm shrink below 1e-3 mm
#: in 43).
CONVEX_MAX_ITER: int = 60
#: Boundary trajectories clear the obstacles by gamma to within this (mm).
BOUNDARY_TOL_MM: float = 0.01
#: Sampling step (mm) of the fine clearance that boundary refinement uses.
FINE_STEP_MM: float = 0.02
#: Entry points are located to within this (mm) along the ray.
ENTRY_TOL_MM: float = 1e-4
#: Smallest step (mm) of the march toward the entry surface: a part of the ray outside
#: the body shorter than this, before the first crossing found, can be stepped over.
ENTRY_MIN_STEP_MM: float = 0.05


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


def convex_segment_bound(
    field,
    origins: np.ndarray,
    directions: np.ndarray,
    lengths: np.ndarray,
    *,
    cap_mm: float,
    tol_mm: float = CONVEX_TOL_MM,
) -> np.ndarray:
    """Certified lower bound of a convex solid's signed distance along segments, within
    ``tol_mm`` of the true minimum (module notes: convex obstacles).

    Parameters
    ----------
    field : DistanceField
        A convex solid with ``value_and_gradient(points) -> (sd (n,), unit grad (n, 3))``
        and ``max_depth_mm`` (a :class:`~needlekit.anatomy.primitives.Superquadric`:
        every exponent >= 2).
    origins, directions : ndarray, shape (n, 3)
    lengths : ndarray, shape (n,)
    cap_mm : float
        Bounds above this are reported as this.
    tol_mm : float
        Largest gap between the bound and the smallest distance sampled.

    Returns
    -------
    ndarray, shape (n,)
        ``min(cap, lower bound) - error_bound``. A segment found inside the solid (a
        sampled distance <= 0) gets ``-max_depth_mm - error_bound``: the field must state
        how deep its solid goes (``max_depth_mm``), the one bound that needs no search.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    L = np.asarray(lengths, dtype=float).reshape(-1)
    n = len(o)
    err = float(field.error_bound_mm)
    cap = float(cap_mm)
    out = np.full(n, cap)

    def sample(idx, t):
        f, g = field.value_and_gradient(o[idx] + t[:, None] * u[idx])
        # a slope from a closest point off by err (mm) is off by at most err / f
        return f, np.einsum("ij,ij->i", g, u[idx]), err / np.maximum(f, 1e-12)

    idx = np.arange(n)
    a, b = np.zeros(n), L.copy()
    fa, sa, ea = sample(idx, a)
    fb, sb, eb = sample(idx, b)
    floor = np.full(n, np.inf)  # lower bound over the parts of the segment let go
    inside = np.zeros(n, dtype=bool)
    for it in range(CONVEX_MAX_ITER + 1):
        dips = (fa <= 0.0) | (fb <= 0.0)
        inside[idx[dips]] = True
        lo_a, hi_b = sa - ea, sb + eb  # slopes widened by their error: tangents stay below
        w = b - a
        with np.errstate(divide="ignore", invalid="ignore"):
            t_meet = np.clip((fb - fa + lo_a * a - hi_b * b) / (lo_a - hi_b), a, b)
            tangent = fa + lo_a * (t_meet - a)
        lower = np.maximum(np.where(np.isfinite(tangent), tangent, -np.inf), 0.5 * (fa + fb - w))
        lower = np.where(lo_a >= 0.0, fa, np.where(hi_b <= 0.0, fb, lower))  # monotone
        lower = np.minimum(lower, floor)
        upper = np.minimum(fa, fb)
        done = dips | (lower >= cap) | (upper - lower <= tol_mm) | (w <= 0.0) | (lo_a >= 0.0)
        done |= (hi_b <= 0.0) | (it == CONVEX_MAX_ITER)  # the last: the bound so far
        fin = done & ~dips
        out[idx[fin]] = np.minimum(lower[fin], cap)
        keep = ~done
        if not keep.any():
            break
        idx, a, b, fa, sa, ea, fb, sb, eb, t_meet, w, floor = (
            v[keep] for v in (idx, a, b, fa, sa, ea, fb, sb, eb, t_meet, w, floor)
        )
        # split near where the tangents meet, never nearer an end than a quarter
        m = np.clip(t_meet, a + 0.25 * w, b - 0.25 * w)
        fm, sm, em = sample(idx, m)
        right = sm < 0.0  # falling at m: the minimum lies right of m, up to the slope error
        # the part let go is bounded by m's tangent, its slope widened toward the part
        floor = np.minimum(
            floor,
            np.where(
                right,
                fm - np.maximum(sm + em, 0.0) * (m - a),
                fm + np.minimum(sm - em, 0.0) * (b - m),
            ),
        )
        a = np.where(right, m, a)
        b = np.where(right, b, m)
        fa, sa, ea = (np.where(right, x, y) for x, y in ((fm, fa), (sm, sa), (em, ea)))
        fb, sb, eb = (np.where(right, y, x) for x, y in ((fm, fb), (sm, sb), (em, eb)))
    # a segment through the solid: no point of it lies deeper than the solid's depth
    out[inside] = -float(field.max_depth_mm)
    return out - err


def obstacle_segment_bound(
    field: DistanceField,
    origins: np.ndarray,
    directions: np.ndarray,
    lengths: np.ndarray,
    *,
    cap_mm: float,
    step_mm: float = NEAR_STEP_MM,
) -> np.ndarray:
    """Certified lower bound of one obstacle's distance along segments, in closed form
    where the obstacle allows it.

    - a :class:`~needlekit.anatomy.primitives.Capsule` (a placed needle's tube): exact,
      the distance between the capsule's axis and each segment less its radius
      (:func:`~needlekit.geometry.segments.segment_distances`);
    - a :class:`~needlekit.anatomy.needle_body.NeedleBody`: its tube so, and its head
      sphere-traced (:func:`segment_clearance_bound`) only along the segments that come
      within the cap of the head's enclosing capsule (closed form); the others are
      certified at the cap;
    - any other field: :func:`segment_clearance_bound`.

    Parameters
    ----------
    field : DistanceField
    origins, directions : ndarray, shape (n, 3)
        Segment starts and unit directions (world, mm).
    lengths : ndarray, shape (n,)
    cap_mm : float
        Bounds above this are reported as this.
    step_mm : float
        Sphere-tracing step near the obstacle, where one is traced.

    Returns
    -------
    ndarray, shape (n,)
        ``min(cap, lower bound of the distance over the segment) - error_bound`` (the
        closed forms state no error).
    """
    from needlekit.anatomy.needle_body import NeedleBody
    from needlekit.anatomy.primitives import Capsule

    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    L = np.asarray(lengths, dtype=float).reshape(-1)
    if isinstance(field, Capsule):
        return np.minimum(_capsule_segment_distance(field, o, u, L), float(cap_mm))
    if isinstance(field, NeedleBody):
        out = np.minimum(_capsule_segment_distance(field.tube, o, u, L), float(cap_mm))
        if field.head_field is not None:
            near = np.flatnonzero(_capsule_segment_distance(field.head_bound, o, u, L) < cap_mm)
            if near.size:
                head = convex_segment_bound(
                    field.head_field, o[near], u[near], L[near], cap_mm=cap_mm
                )
                out[near] = np.minimum(out[near], head)
        return out
    return segment_clearance_bound(field, o, u, L, cap_mm=cap_mm, step_mm=step_mm)[0]


def _capsule_segment_distance(capsule, o: np.ndarray, u: np.ndarray, L: np.ndarray):
    """Exact signed distance from a capsule to each segment ``o + t u``, ``t in [0, L]``."""
    p0, p1 = capsule.p0_mm, capsule.p1_mm
    if capsule._posed:
        p0 = capsule._rot @ p0 + capsule._trans
        p1 = capsule._rot @ p1 + capsule._trans
    return segment_distances(p0, p1, o, o + L[:, None] * u) - capsule.radius_mm


def clearance_bound(
    problem: StraightProblem,
    origins: np.ndarray,
    directions: np.ndarray,
    lengths: np.ndarray,
    *,
    cap_mm: float,
    step_mm: float = NEAR_STEP_MM,
) -> np.ndarray:
    """Certified lower bound of the distance from segments to every obstacle of a problem:
    the anatomy's union sphere-traced at once, each extra obstacle (a placed needle) on its
    own by :func:`obstacle_segment_bound`; the minimum of the parts.

    Parameters
    ----------
    problem : StraightProblem
    origins, directions : ndarray, shape (n, 3)
    lengths : ndarray, shape (n,)
    cap_mm, step_mm : float
        As :func:`segment_clearance_bound`.

    Returns
    -------
    ndarray, shape (n,)
        Distance of the segment's axis (the needle radius not subtracted).
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    L = np.asarray(lengths, dtype=float).reshape(-1)
    anatomy = problem.anatomy_field()
    if anatomy is None:
        out = np.full(len(o), float(cap_mm))
    else:
        out, _ = segment_clearance_bound(anatomy, o, u, L, cap_mm=cap_mm, step_mm=step_mm)
    for f in problem.extra_obstacles:
        np.minimum(out, obstacle_segment_bound(f, o, u, L, cap_mm=cap_mm, step_mm=step_mm), out=out)
    return out


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
    lip = body.lipschitz_bound
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
        # no sign change of the field within |d| / L; without L, of the true surface
        # within |d| - err
        safe = -d / lip if lip is not None else -d - err
        step = np.maximum(safe, ENTRY_MIN_STEP_MM)
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
        intersection of this map's CFRW with the new obstacles' (issue 11, point 2).

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
        blocked[(blocked == Blocked.FREE) & ~(clearance >= pr.gamma_mm)] = Blocked.PLACED_NEEDLE
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
    blocked[(blocked == 0) & ~(clearance >= problem.gamma_mm)] = Blocked.CLEARANCE
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
