"""Certified lower bounds on the clearance of a needle segment (mm).

Sphere tracing of any 1-Lipschitz signed distance (:func:`segment_clearance_bound`, its
runs of near steps sampled several at a time;
:func:`segment_clearance_bound_reference`, one sample a step, is the plain trace it is
held to, bit for bit), the tangent-line bound of a convex obstacle
(:func:`convex_segment_bound`), a placed needle's
tube and head (:func:`obstacle_segment_bound`), and the smallest over a problem's
obstacles (:func:`clearance_bound`); the argument for each is in
:mod:`needlekit.planning.straight.cfrw`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.needle_body import NeedleBody
from needlekit.anatomy.primitives import Capsule
from needlekit.constants import STRAIGHT_CAP_ABOVE_GAMMA_MM, STRAIGHT_NEAR_STEP_MM
from needlekit.geometry.segments import segment_distances
from needlekit.planning.straight.problem import StraightProblem

__all__ = [
    "clearance_bound",
    "convex_segment_bound",
    "obstacle_segment_bound",
    "segment_clearance_bound",
    "segment_clearance_bound_reference",
]


#: Largest step of the sphere tracing near obstacles (mm): the certified bound is at most
#: half of it below the sampled minimum (the straight planners' clearance rule, in
#: :mod:`needlekit.constants`).
NEAR_STEP_MM: float = STRAIGHT_NEAR_STEP_MM

#: Clearances above gamma by more than this are reported as this (mm): the map certifies
#: them as "at least"; it bounds the work of the sphere tracing.
CLEARANCE_CAP_ABOVE_GAMMA_MM: float = STRAIGHT_CAP_ABOVE_GAMMA_MM

#: Largest gap (mm) between a convex obstacle's certified bound along a segment and the
#: smallest distance sampled on it (:func:`convex_segment_bound`).
CONVEX_TOL_MM: float = 1e-3

#: Splits of a segment's bracket before :func:`convex_segment_bound` reports the bound so
#: far (each split keeps at most three quarters of the bracket: 200 mm shrink below 1e-3 mm
#: in 43).
CONVEX_MAX_ITER: int = 60

#: Most samples of one segment that :func:`segment_clearance_bound` asks the field for in
#: one round (a run of near steps; more only saves calls once a run is this long).
TRACE_MAX_AHEAD: int = 64

#: Most samples (segments x samples ahead) in one round: bounds the round's arrays to a
#: few tens of MB when many segments trace at once.
TRACE_MAX_SAMPLES: int = 1 << 20


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

    The samples and the arithmetic are those of
    :func:`segment_clearance_bound_reference`, bit for bit: the sphere tracing of every
    segment at once. A run of near steps (each ``step_mm`` long) has its positions known
    before the field is asked, so a segment inside one takes several samples a round (as
    many as its distance's trend promises, at most twice the last round's and
    :data:`TRACE_MAX_AHEAD`) and keeps those the trace takes: the field is asked once a
    round, for every segment's samples. The field must answer each point on its own (its
    value of a point does not depend on the other points asked with it) and in float64,
    as every field of needlekit does.

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
        Largest step where the distance is below the cap (> 0).

    Returns
    -------
    bound : ndarray, shape (n,)
        ``min(cap, lower bound of the distance over the segment) - error_bound``.
    at_mm : ndarray, shape (n,)
        Arc length of the sample with the smallest distance.
    """
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    L = np.ascontiguousarray(np.asarray(lengths, dtype=float).reshape(-1))
    n = len(o)
    cap, step = float(cap_mm), float(step_mm)
    # per segment: bound, best, at, t, d_prev, t_prev (the trace's state, as the reference's)
    state = np.zeros((6, n))
    state[0], state[1], state[4] = cap, np.inf, np.nan
    ahead = np.ones(n, dtype=np.int64)  # samples to take in the next round
    most = TRACE_MAX_AHEAD if step > 0 else 1
    active = np.arange(n)
    while active.size:
        limit = max(TRACE_MAX_SAMPLES // active.size, 1)
        size = int(np.minimum(ahead[active], limit).sum())
        pos, row = np.empty(size), np.empty(size, np.int64)
        start = np.empty(active.size + 1, np.int64)
        size = _plan_round(active, state[3], ahead, L, step, limit, pos, row, start)
        seg = active[row[:size]]
        d = field.capped_distance(o[seg] + pos[:size, None] * u[seg], cap_mm)
        done = np.zeros(active.size, dtype=np.bool_)
        _take_round(
            active, start, pos, np.asarray(d, dtype=float), L, cap, step, most, state, ahead, done
        )
        active = active[~done]
    return np.minimum(state[0], cap_mm) - float(field.error_bound_mm), state[2].copy()


@numba.njit(cache=True, error_model="numpy")
def _plan_round(k, t, ahead, L, step, limit, pos, row, start):  # pragma: no cover - compiled
    """Positions of this round's samples: from each segment's ``t``, ``min(t + step, L)``
    again and again (the trace's near steps) up to its ``ahead`` or the end; returns how
    many (rows of segment ``k[i]``: ``pos[start[i]:start[i + 1]]``)."""
    m = 0
    for i in range(k.size):
        s = k[i]
        start[i] = m
        c = t[s]
        for j in range(min(ahead[s], limit)):
            if j > 0:
                if not c < L[s]:  # the end was sampled: nothing further
                    break
                v = c + step
                c = v if (v < L[s] or v != v) else L[s]
            pos[m] = c
            row[m] = i
            m += 1
    start[k.size] = m
    return m


@numba.njit(cache=True, error_model="numpy")
def _take_round(
    k, start, pos, d, L, cap, step, most, state, ahead, done
):  # pragma: no cover - compiled
    """The reference's update for each sample, in order, while the trace takes them (a
    sample after a near step, not past the end); the next round's ``ahead``."""
    bound, best, at, t, d_prev, t_prev = state[0], state[1], state[2], state[3], state[4], state[5]
    for i in range(k.size):
        s = k[i]
        taken = 0
        near = False
        d_before = t_before = np.nan
        for q in range(start[i], start[i + 1]):
            tq, dq = pos[q], d[q]
            if math.isfinite(d_prev[s]):
                iv = 0.5 * (d_prev[s] + dq - (tq - t_prev[s]))
            else:
                iv = dq
            if iv < bound[s] or iv != iv:  # np.minimum: NaN wins
                bound[s] = iv
            if dq < best[s]:
                best[s] = dq
                at[s] = tq
            d_before, t_before = d_prev[s], t_prev[s]
            d_prev[s], t_prev[s] = dq, tq
            taken += 1
            x = dq - cap
            st = x if (x > step or x != x) else step  # np.maximum: NaN wins
            v = tq + st
            t[s] = v if (v < L[s] or v != v) else L[s]
            near = st == step
            if tq >= L[s]:
                done[i] = True
                break
            if not near:  # a far step: the samples planned after it are not the trace's
                break
        ahead[s] = 1
        if near and not done[i]:
            # a run of near steps lasts while the distance stays within step of the cap:
            # its trend over the last two samples says how long (at most twice as long)
            g = min(2 * taken, most)
            rise = (d_prev[s] - d_before) / (t_prev[s] - t_before) * step
            if rise > 0.0:
                left = 0.75 * (cap + step - d_prev[s]) / rise
                if left < g:
                    g = int(left)
            ahead[s] = max(g, 1)


def segment_clearance_bound_reference(
    field: DistanceField,
    origins: np.ndarray,
    directions: np.ndarray,
    lengths: np.ndarray,
    *,
    cap_mm: float,
    step_mm: float = NEAR_STEP_MM,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`segment_clearance_bound` one sample of every segment at a time: the plain
    sphere tracing it is held to (one call to the field per step).

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
