"""Is the goal connected to the start through free voxels? A proof of infeasibility.

The reference planner refuses a problem whose "reachable workspace is not connected" to the
goal (``docs/notes/steerable-reference-planner.md``, section 5, check 6). This is the same
idea made sound for the ``voxel_centres`` collision model. Take a valid path: curvature at
most ``1 / r``, every direction within ``H`` of the start direction ``d``, samples at most
``delta`` (the motion spacing) apart, each keeping ``m`` (``min_dist``) from every obstacle
voxel centre outside the start exclusion, the last within ``tau`` of the goal. Join its
samples by chords: a polyline from the start ``s`` to near the goal ``g``.

- Clearance of the polyline: a point ``x`` of the chord ``pq`` has
  ``|x - o|^2 >= m^2 - |p - q|^2 / 4`` for every such centre ``o``, so it keeps
  ``m' = sqrt(m^2 - delta^2 / 4)``.
- Voxels: the polyline is continuous, so the closed voxel cells it meets form a chain of
  face neighbours (6-connected; where it crosses an edge or a corner, every cell around it
  holds the crossing point). Each cell's centre lies within half a voxel diagonal ``h`` of
  a polyline point, so it keeps ``m' - h`` from those centres: it is *free*. The chain
  starts at the start's voxel and ends at a voxel within ``tau + h`` of the goal.
- Region: every point of a path (and of its chords) lies in each of these sets, so the
  voxel centres of the chain lie in them grown by ``h``:

  - the ellipsoid ``|x - s| + |x - g| <= L + tau`` (a path through ``x`` is at least
    that long; convex, so it holds the chords) -- the centre in the one grown by ``2 h``.
    ``L`` bounds the path's length: ``l_max``, or shorter by Schur's comparison theorem.
    A curve of length ``l <= 2 pi r`` whose curvature never exceeds ``1 / r`` has a chord
    at least ``2 r sin(l / (2 r))``, that of the arc of radius ``r`` as long (space curves
    included). The path's chord is at most ``D = |g - s| + tau``; so with ``D < 2 r`` its
    length is at most ``A = 2 r asin(D / (2 r))`` or at least ``2 pi r - A``, and when
    ``l_max < 2 pi r - A`` only the first is left: ``L = min(l_max, A)``
    (:func:`longest_path`). For a lung target 60 mm ahead at ``r = 50`` that is 64.4 mm
    instead of 150: the region shrinks from an ellipsoid 70 mm wide to one 12 mm wide;
  - with ``H <= 90`` deg, the cone ``K`` of half-angle ``H`` about ``d``: ``x - s`` is an
    integral of directions inside ``K``, so it lies in ``K``; likewise the path's end minus
    ``x``, so ``g - x`` lies within ``tau`` of ``K``. Both sets are convex;
  - with ``H <= 90`` deg, outside the start's horn torus: for a unit ``n`` normal to ``d``,
    write ``a = (x - s) . d`` and ``b = (x - s) . n``. The angle ``phi`` of the direction
    from ``d`` grows at most at the curvature, ``dphi/da <= 1 / (r cos phi)``, as on the
    circle of radius ``r`` through ``s`` tangent to ``d`` toward ``n``; so for ``a < r``
    the angle stays below the circle's, ``db/da <= tan phi`` stays below its slope, ``b``
    below its height, and ``x`` outside its disc. Over every ``n``: the distance from
    ``x`` to the circle of centres ``s + r n`` is at least ``r``. A chord dips at most
    ``r - sqrt(r^2 - delta^2 / 4)`` below that;
  - with ``H <= 90`` deg, a turn then straight: the part of the path up to a sample ``x``
    (outside the torus) is no shorter than the shortest curvature-bounded path from the
    start pose to ``x``, the turn on the circle of radius ``r`` then the tangent line
    (``needle.reachability``), and the rest no shorter than ``|x - g| - tau``; their sum is
    at most ``L``. A voxel centre lies within ``e = h + delta / 2`` of a sample, and where
    its ``e``-ball lies outside the torus the turn-then-straight length is 1-Lipschitz
    there (its gradient is the end's unit tangent): the centre's length minus ``e`` bounds
    the sample's.

So when no 6-connected chain of free voxels inside the grown region leads from the start's
voxel to a free voxel within ``tau + h`` of the goal, no valid path exists:
``INFEASIBLE``, proved.

Finer cells: nothing above needs the cells to be the voxels. With ``subdivide = f`` the
cells are ``f`` times narrower along each axis, their centres at index coordinates
``(I / f, J / f, K / f)`` (so cell ``(f i, f j, f k)`` is centred on voxel ``(i, j, k)``),
and ``h`` is their half-diagonal, ``f`` times smaller: a free cell keeps ``m' - h / f``
from the obstacle centres, which are still the voxels'. A gap one voxel wide, which a voxel
centre passes with ``m' - h`` (0.47 mm for the 1 mm needle on a Med-RAD lung) although the
needle needs ``m`` (1.02 mm), closes at ``f = 2`` (0.73 mm). The reference's own region (the start's trumpet and a spindle toward
the goal) and its 6-connected fill over the obstacle-free voxels with no start exclusion are
not such a proof; this module does not copy them.

Two greedy best-first fills search for the chain: one from the start toward the goal, one
from the goal's voxels toward the start. They take turns, each resuming where it stopped,
with a cap on the voxels each may queue that grows fourfold a round, so a connected goal is
found as fast as the start's fill heads there and a sealed pocket is closed as soon as the
smaller side is exhausted. The voxels the fills have reached sit in a hash set while they
are few (a connected goal is usually found within a few hundred); past ``DENSE_AFTER`` they
move to a flag per voxel of the grid, whose untouched pages the system never zeroes: a
sealed lung pocket (a few hundred thousand voxels) is proved in about half the hash set's
time. The verdict and the count do not depend on when the fills switch.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numba.extending import overload

from needlekit.anatomy.occupancy import VoxelObstacles, box_half_widths, voxel_centre
from needlekit.errors import InvalidInputError

__all__ = ["goal_connected", "warm_up"]


@numba.njit(cache=True, inline="always")
def _slot(keys, key):  # pragma: no cover - compiled
    """Open addressing: the slot holding ``key``, or the empty slot where it goes."""
    mask = keys.shape[0] - 1
    # Fibonacci hashing (0x9E3779B97F4A7C15), its high bits folded onto the low ones: the
    # low bits of a product depend only on the key's low bits, and keys that differ only
    # in their high bits (another slice of the grid) would all probe the same run
    x = key * -7046029254386353131
    h = (x ^ (x >> 32)) & mask
    while keys[h] != -1 and keys[h] != key:
        h = (h + 1) & mask
    return h


@numba.njit(cache=True)
def _grow(keys):  # pragma: no cover - compiled
    bigger = np.full(2 * keys.shape[0], -1, dtype=np.int64)
    for key in keys:
        if key != -1:
            bigger[_slot(bigger, key)] = key
    return bigger


#: The fills' first cap on reached voxels; each round multiplies it by four.
FIRST_CAP: int = 4096

#: Reached voxels (both fills) beyond which the fills keep a flag per voxel of the grid
#: instead of a hash set: a small fill touches few of the flags' pages (each first touch
#: of a page costs the system a fault), a large one probes the hash far more than that.
DENSE_AFTER: int = 8192

#: Slack (mm) on the region's tests: more than the plan check's angle and curvature
#: tolerances move a point within any l_max, far less than a voxel.
REGION_SLACK_MM: float = 1e-6

_CONNECTED, _SEALED, _CAPPED = 0, 1, 2
_FACES = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]])


@numba.njit(cache=True, inline="always")
def _cone_distance(vx, vy, vz, d, cos_h, sin_h):  # pragma: no cover - compiled
    """Distance (mm) from ``v`` to the cone of half-angle ``H`` about the unit ``d``."""
    a = vx * d[0] + vy * d[1] + vz * d[2]
    n2 = vx * vx + vy * vy + vz * vz
    b = math.sqrt(max(n2 - a * a, 0.0))
    if a * sin_h >= b * cos_h:
        return 0.0
    if a * cos_h + b * sin_h <= 0.0:
        return math.sqrt(n2)
    return b * cos_h - a * sin_h


@numba.njit(cache=True, inline="always")
def _turn_then_straight(a, b, r, reach):  # pragma: no cover - compiled
    """A lower bound on how far a path from the start must go to pass within ``reach`` of
    the point at axial ``a`` and radial ``b`` (module notes): the turn on the circle of
    radius ``r`` then straight, minus ``reach``, where the ball of that radius lies outside
    the horn torus; 0 elsewhere."""
    dc2 = a * a + (b - r) ** 2
    if r <= 0.0 or dc2 < (r + reach) ** 2:
        return 0.0
    ell = math.sqrt(dc2 - r * r)
    beta = math.atan2(b - r, a) + math.atan2(r, ell)
    if beta < 0.0:
        beta += 2.0 * math.pi
    return r * beta + ell - reach


@numba.njit(cache=True, inline="always")
def _in_region(x, y, z, start, d, goal, geo):  # pragma: no cover - compiled
    """Whether a voxel centre lies in the grown region (module notes). ``geo``: budget,
    use_cone, cos H, sin H, slack from s, slack from g, r (0: no torus), torus floor, the
    bound's r, its budget, its reach from a path point."""
    ds = math.sqrt((x - start[0]) ** 2 + (y - start[1]) ** 2 + (z - start[2]) ** 2)
    dg = math.sqrt((x - goal[0]) ** 2 + (y - goal[1]) ** 2 + (z - goal[2]) ** 2)
    if ds + dg > geo[0]:
        return False
    if geo[1] == 0.0:
        return True
    vx, vy, vz = x - start[0], y - start[1], z - start[2]
    if _cone_distance(vx, vy, vz, d, geo[2], geo[3]) > geo[4]:
        return False
    if _cone_distance(goal[0] - x, goal[1] - y, goal[2] - z, d, geo[2], geo[3]) > geo[5]:
        return False
    r = geo[6]
    if r > 0.0:
        a = vx * d[0] + vy * d[1] + vz * d[2]
        b = math.sqrt(max(vx * vx + vy * vy + vz * vz - a * a, 0.0))
        if a * a + (b - r) ** 2 < geo[7] * geo[7] and geo[7] > 0.0:
            return False
        if _turn_then_straight(a, b, geo[8], geo[10]) + dg > geo[9]:
            return False
    return True


@numba.njit(cache=True, inline="always")
def _inner_half_widths(affine, radius):  # pragma: no cover - compiled
    """Voxels to either side, per axis, that can hold a centre nearer than ``radius``
    (offset ``k`` along an axis puts a centre at least ``k`` spacings away)."""
    h0 = math.sqrt(affine[0, 0] ** 2 + affine[1, 0] ** 2 + affine[2, 0] ** 2)
    h1 = math.sqrt(affine[0, 1] ** 2 + affine[1, 1] ** 2 + affine[2, 1] ** 2)
    h2 = math.sqrt(affine[0, 2] ** 2 + affine[1, 2] ** 2 + affine[2, 2] ** 2)
    return max(int(radius / h0), 0), max(int(radius / h1), 0), max(int(radius / h2), 0)


@numba.njit(cache=True, inline="always")
def _free(occ, affine, i, j, k, start, excl_r, free_r):  # pragma: no cover - compiled
    """No obstacle centre (outside the start exclusion) closer than ``free_r`` to the point
    at index coordinates ``(i, j, k)`` (a voxel centre, or a finer cell's between them)."""
    ni, nj, nk = occ.shape
    r0, r1, r2 = _inner_half_widths(affine, free_r)
    x, y, z = voxel_centre(affine, i, j, k)
    i0, j0, k0 = int(math.floor(i)) - r0, int(math.floor(j)) - r1, int(math.floor(k)) - r2
    i1, j1, k1 = int(math.ceil(i)) + r0 + 1, int(math.ceil(j)) + r1 + 1, int(math.ceil(k)) + r2 + 1
    for a in range(max(i0, 0), min(i1, ni)):
        for b in range(max(j0, 0), min(j1, nj)):
            for c in range(max(k0, 0), min(k1, nk)):
                if not occ[a, b, c]:
                    continue
                cx, cy, cz = voxel_centre(affine, a, b, c)
                if (cx - x) ** 2 + (cy - y) ** 2 + (cz - z) ** 2 >= free_r * free_r:
                    continue
                if (cx - start[0]) ** 2 + (cy - start[1]) ** 2 + (cz - start[2]) ** 2 < excl_r**2:
                    continue
                return False
    return True


@numba.njit(cache=True, inline="always")
def _push(state, x, y, z, a, target, step):  # pragma: no cover - compiled
    """Queue voxel ``a`` (centre x, y, z) in the bucket of its distance to ``target``."""
    first, keys, queued, nxt, counts = state
    n_buckets = first.shape[0]
    if counts[1] == queued.shape[0]:
        queued = np.concatenate((queued, np.empty_like(queued)))
        nxt = np.concatenate((nxt, np.empty_like(nxt)))
    dt = math.sqrt((x - target[0]) ** 2 + (y - target[1]) ** 2 + (z - target[2]) ** 2)
    b = min(int(dt / step), n_buckets - 1)
    queued[counts[1]] = a
    nxt[counts[1]] = first[b]
    first[b] = counts[1]
    counts[1] += 1
    counts[2] = min(counts[2], b)
    return first, keys, queued, nxt, counts


@numba.njit(cache=True, inline="always")
def _mark_dense(state, a):  # pragma: no cover - compiled
    """Flag ``a`` as reached (the state's set is a flag per voxel); False when it was."""
    seen = state[1]
    if seen[a]:
        return False, state
    seen[a] = 1
    state[4][0] += 1
    return True, state


@numba.njit(cache=True)
def _to_dense(state, seen):  # pragma: no cover - compiled
    """The state with its reached set moved from the hash set into the flags ``seen``."""
    first, keys, queued, nxt, counts = state
    for key in keys:
        if key != -1:
            seen[key] = 1
    return first, seen, queued, nxt, counts


def _mark_any(state, a):
    """:func:`_mark_dense` for a reached set of ``uint8`` flags, else :func:`_mark`: compiled,
    chosen once per state type (:func:`_mark_any_overload`), here for NUMBA_DISABLE_JIT."""
    return _mark_dense(state, a) if state[1].dtype == np.uint8 else _mark(state, a)


@overload(_mark_any, inline="always")
def _mark_any_overload(state, a):
    if state.types[1].dtype == numba.types.uint8:
        return lambda state, a: _mark_dense(state, a)
    return lambda state, a: _mark(state, a)


@numba.njit(cache=True, inline="always")
def _mark(state, a):  # pragma: no cover - compiled
    """Add ``a`` to the reached set; False when it was there already."""
    first, keys, queued, nxt, counts = state
    h = _slot(keys, a)
    if keys[h] == a:
        return False, state
    keys[h] = a
    counts[0] += 1
    if 2 * counts[0] > keys.shape[0]:
        keys = _grow(keys)
    return True, (first, keys, queued, nxt, counts)


@numba.njit(cache=True, inline="always")
def _cells(occ, f):  # pragma: no cover - compiled
    """The cell grid's shape: the voxels, or ``f`` cells to a voxel spacing along each axis
    with the voxel centres among the cell centres."""
    ni, nj, nk = occ.shape
    return (ni - 1) * f + 1, (nj - 1) * f + 1, (nk - 1) * f + 1


@numba.njit(cache=True, inline="always")
def _step(affine):  # pragma: no cover - compiled
    return min(
        math.sqrt(affine[0, 0] ** 2 + affine[1, 0] ** 2 + affine[2, 0] ** 2),
        math.sqrt(affine[0, 1] ** 2 + affine[1, 1] ** 2 + affine[2, 1] ** 2),
        math.sqrt(affine[0, 2] ** 2 + affine[1, 2] ** 2 + affine[2, 2] ** 2),
    )


@numba.njit(cache=True)
def _seed(
    occ, affine, inv, start, d, goal, s_key, excl_r, free_r, reach, geo, f, from_goal
):  # pragma: no cover
    """A fill's initial state: the start's cell, or the free cells of the region within
    ``reach`` of the goal. The state: buckets (a list per step of distance to the fill's
    target), the reached cells (a hash set of linear indices), the queued cells and the
    next entry of their bucket, and (reached, queued, lowest bucket). Cells: ``f`` to a
    voxel spacing (:func:`_cells`)."""
    ni, nj, nk = _cells(occ, f)
    step = _step(affine) / f
    n_buckets = int(math.ceil(geo[0] / step)) + 2
    state = (
        np.full(n_buckets, -1, dtype=np.int64),
        np.full(4096, -1, dtype=np.int64),
        np.empty(1024, dtype=np.int64),
        np.empty(1024, dtype=np.int64),
        np.array([0, 0, n_buckets], dtype=np.int64),
    )
    target = start if from_goal else goal
    if not from_goal:
        i, j, k = s_key // (nj * nk), (s_key // nk) % nj, s_key % nk
        _, state = _mark(state, s_key)
        x, y, z = voxel_centre(affine, i / f, j / f, k / f)
        return _push(state, x, y, z, s_key, target, step)
    g0, g1, g2 = goal[0], goal[1], goal[2]
    gi = int(round(f * (inv[0, 0] * g0 + inv[0, 1] * g1 + inv[0, 2] * g2 + inv[0, 3])))
    gj = int(round(f * (inv[1, 0] * g0 + inv[1, 1] * g1 + inv[1, 2] * g2 + inv[1, 3])))
    gk = int(round(f * (inv[2, 0] * g0 + inv[2, 1] * g1 + inv[2, 2] * g2 + inv[2, 3])))
    r0, r1, r2 = box_half_widths(affine, reach)
    r0, r1, r2 = (r0 + 1) * f, (r1 + 1) * f, (r2 + 1) * f
    for i in range(max(gi - r0, 0), min(gi + r0 + 1, ni)):
        for j in range(max(gj - r1, 0), min(gj + r1 + 1, nj)):
            for k in range(max(gk - r2, 0), min(gk + r2 + 1, nk)):
                a = (i * nj + j) * nk + k
                x, y, z = voxel_centre(affine, i / f, j / f, k / f)
                if (x - goal[0]) ** 2 + (y - goal[1]) ** 2 + (z - goal[2]) ** 2 > reach * reach:
                    continue
                if a != s_key and not (
                    _in_region(x, y, z, start, d, goal, geo)
                    and _free(occ, affine, i / f, j / f, k / f, start, excl_r, free_r)
                ):
                    continue
                _, state = _mark(state, a)
                state = _push(state, x, y, z, a, target, step)
    return state


@numba.njit(cache=True)
def _fill(
    occ, affine, start, d, goal, s_key, excl_r, free_r, reach, geo, f, from_goal, state, cap
):  # pragma: no cover
    """Run one greedy best-first fill (6-connected, free cells of the region) from its
    state until it is done or has queued ``cap`` cells: from the start it is done when it
    pops a cell within ``reach`` of the goal, from the goal when it pops the start's
    cell. Returns (connected / sealed / capped, state)."""
    ni, nj, nk = _cells(occ, f)
    step = _step(affine) / f
    target = start if from_goal else goal
    while state[4][2] < state[0].shape[0]:
        first, counts = state[0], state[4]
        low = counts[2]
        if first[low] < 0:
            counts[2] = low + 1
            continue
        e = first[low]
        first[low] = state[3][e]
        q = state[2][e]
        qi, qj, qk = q // (nj * nk), (q // nk) % nj, q % nk
        x, y, z = voxel_centre(affine, qi / f, qj / f, qk / f)
        if from_goal and q == s_key:
            return _CONNECTED, state
        if (
            not from_goal
            and (x - goal[0]) ** 2 + (y - goal[1]) ** 2 + (z - goal[2]) ** 2 <= reach * reach
        ):
            return _CONNECTED, state
        if counts[1] > cap:
            # put it back: the next round pops it first
            state[3][e] = first[low]
            first[low] = e
            return _CAPPED, state
        for face in range(6):
            ci, cj, ck = qi + _FACES[face, 0], qj + _FACES[face, 1], qk + _FACES[face, 2]
            if ci < 0 or cj < 0 or ck < 0 or ci >= ni or cj >= nj or ck >= nk:
                continue
            a = (ci * nj + cj) * nk + ck
            new, state = _mark_any(state, a)
            if not new:
                continue
            cx, cy, cz = voxel_centre(affine, ci / f, cj / f, ck / f)
            if a != s_key and not (
                _in_region(cx, cy, cz, start, d, goal, geo)
                and _free(occ, affine, ci / f, cj / f, ck / f, start, excl_r, free_r)
            ):
                continue
            state = _push(state, cx, cy, cz, a, target, step)
    return _SEALED, state


def goal_connected(
    obstacles: VoxelObstacles,
    start_mm: np.ndarray,
    goal_mm: np.ndarray,
    *,
    max_length_mm: float,
    goal_tolerance_mm: float,
    exclusion_mm: float,
    spacing_mm: float,
    start_direction: np.ndarray | None = None,
    r_min_mm: float | None = None,
    max_heading_change_deg: float | None = None,
    dense_after: int = DENSE_AFTER,
    subdivide: int = 1,
    max_cells: int | None = None,
) -> tuple[bool | None, int]:
    """Whether free voxels connect the start to the goal (module notes).

    Parameters
    ----------
    obstacles : VoxelObstacles
    start_mm, goal_mm : ndarray, shape (3,)
    max_length_mm, goal_tolerance_mm, exclusion_mm : float
        The problem's l_max, tau and start exclusion.
    spacing_mm : float
        The collision samples' spacing along paths.
    start_direction : ndarray, shape (3,), optional
        The start's insertion direction (unit). With a heading limit of at most 90 deg,
        the region is cut to the heading cones and, with ``r_min_mm``, to outside the
        start's horn torus; without it, the ellipsoid alone.
    r_min_mm : float, optional
        The smallest radius of curvature.
    max_heading_change_deg : float, optional
        The heading limit H.
    dense_after : int
        Reached voxels after which the fills flag voxels in an array over the grid instead
        of a hash set (:data:`DENSE_AFTER`; -1: from the start, as the warm-up runs it).
        Finer cells always keep the hash set.
    subdivide : int
        Cells to a voxel spacing along each axis (module notes, finer cells): 1, the
        voxels; 2, cells half as wide, whose smaller half-diagonal leaves more room for the
        needle's clearance to seal narrow gaps.
    max_cells : int, optional
        Cells the two fills may queue before the answer is None (no limit by default).

    Returns
    -------
    connected : bool or None
        False proves that no valid path exists; None when the argument does not apply
        (samples as far apart as the voxels, or a start outside the image) or the fills
        reached ``max_cells``.
    visited : int
        Cells the two fills queued.
    """
    if spacing_mm >= float(np.min(obstacles.spacing_mm)):
        return None, 0
    start = np.ascontiguousarray(start_mm, dtype=np.float64).reshape(3)
    goal = np.ascontiguousarray(goal_mm, dtype=np.float64).reshape(3)
    f = int(subdivide)
    if f < 1:
        raise InvalidInputError("subdivide", f"must be a whole number >= 1, got {subdivide}")
    shape = (np.array(obstacles.occupancy.shape) - 1) * f + 1
    s_ijk = np.rint(f * (obstacles.inv_affine[:3, :3] @ start + obstacles.inv_affine[:3, 3]))
    if np.any(s_ijk < 0) or np.any(s_ijk > shape - 1):
        return None, 0
    s_key = int((s_ijk[0] * shape[1] + s_ijk[1]) * shape[2] + s_ijk[2])
    h, tau, m = obstacles.voxel_radius_mm / f, float(goal_tolerance_mm), obstacles.min_distance_mm
    half_gap2 = 0.25 * float(spacing_mm) ** 2
    free_r = math.sqrt(max(m * m - half_gap2, 0.0)) - h
    geo = _region(
        start_direction, r_min_mm, max_heading_change_deg, max_length_mm, tau, h, half_gap2,
        chord_mm=float(np.linalg.norm(goal - start)),
    )  # fmt: skip
    d = np.zeros(3) if start_direction is None else np.asarray(start_direction, dtype=np.float64)
    d = np.ascontiguousarray(d / max(float(np.linalg.norm(d)), 1e-300))
    occ, affine = obstacles.occupancy, obstacles.affine
    args = (start, d, goal, s_key, float(exclusion_mm), float(free_r), float(tau + h), geo, f)
    states = [_seed(occ, affine, obstacles.inv_affine, *args, side) for side in (False, True)]
    cap = FIRST_CAP
    dense = f > 1  # finer cells keep the hash set: a flag per cell would be f^3 the grid
    limit = math.inf if max_cells is None else int(max_cells)
    while True:
        if states[0][4][1] + states[1][4][1] > limit:
            return None, int(states[0][4][1] + states[1][4][1])
        if not dense and states[0][4][0] + states[1][4][0] > dense_after:
            # numpy's zeros are the system's zeroed pages: only the touched ones cost
            states = [_to_dense(st, np.zeros(occ.size, np.uint8)) for st in states]
            dense = True
        for side in (0, 1):
            status, states[side] = _fill(
                occ, affine, *args, bool(side), states[side], min(cap, limit)
            )
            if status != _CAPPED:
                return status == _CONNECTED, int(states[0][4][1] + states[1][4][1])
        cap *= 4


#: The array types (occupancy, affine, inverse) whose flag-array kernels have been run in
#: this process (:func:`warm_up`).
_DENSE_WARMED: set = set()


def warm_up(obstacles: VoxelObstacles, start_mm: np.ndarray, exclusion_mm: float,
            spacing_mm: float) -> None:  # fmt: skip
    """Run the fills' kernels once on these obstacles' array types, so that numba loads
    (or compiles) them before a planner's clock starts: the hash-set kernels on every
    call (a tiny fill), the flag-array ones once per process and array types (their flags
    over the whole grid cost a fraction of a millisecond, which a solve should not pay
    each time).

    Parameters
    ----------
    obstacles : VoxelObstacles
    start_mm : ndarray, shape (3,)
    exclusion_mm, spacing_mm : float

    Returns
    -------
    None
    """
    key = tuple(
        str(numba.typeof(a)) for a in (obstacles.occupancy, obstacles.affine, obstacles.inv_affine)
    )
    for dense_after in (DENSE_AFTER, -1) if key not in _DENSE_WARMED else (DENSE_AFTER,):
        goal_connected(
            obstacles, start_mm, start_mm, max_length_mm=0.0, goal_tolerance_mm=0.0,
            exclusion_mm=exclusion_mm, spacing_mm=spacing_mm,
            start_direction=np.array([0.0, 0.0, 1.0]), r_min_mm=1.0,
            max_heading_change_deg=90.0, dense_after=dense_after,
        )  # fmt: skip
    _DENSE_WARMED.add(key)


def longest_path(
    max_length_mm: float, r_min_mm: float | None, chord_mm: float | None, tau_mm: float
) -> float:
    """The longest a valid path can be (module notes): ``l_max``, or Schur's arc over the
    chord when that is shorter and applies.

    Parameters
    ----------
    max_length_mm : float
        ``l_max``.
    r_min_mm : float or None
        The smallest radius of curvature (None or 0: no bound from it).
    chord_mm : float or None
        ``|g - s|`` (None: no bound from it).
    tau_mm : float
        The goal tolerance.

    Returns
    -------
    float
        At least the length of every path the plan check accepts (its curvature and length
        slacks included).

    Examples
    --------
    >>> round(longest_path(150.0, 50.0, 60.0, 0.0), 2)  # 100 asin(0.6), and the slacks
    64.35
    >>> longest_path(150.0, 25.0, 60.0, 0.0)  # the goal is past the diameter: no bound
    150.0
    """
    l_max = float(max_length_mm)
    if not r_min_mm or r_min_mm <= 0.0 or chord_mm is None:
        return l_max
    # the check accepts curvature up to (1 + 1e-9) / r + 1e-9: a diameter a little shorter
    diameter = 2.0 * float(r_min_mm) / (1.0 + 1e-6 * (1.0 + float(r_min_mm)))
    reach = float(chord_mm) + float(tau_mm) + REGION_SLACK_MM
    if reach >= diameter:
        return l_max
    arc = diameter * math.asin(reach / diameter)
    if l_max + REGION_SLACK_MM >= math.pi * diameter - arc:
        return l_max  # a path could be a loop longer than pi r
    return min(l_max, arc + REGION_SLACK_MM)


def _region(
    direction, r_min, heading_deg, max_length_mm, tau, h, half_gap2, chord_mm=None
) -> np.ndarray:
    """The region's figures for the kernel (its ``geo``; module notes)."""
    slack = REGION_SLACK_MM
    geo = np.zeros(11)
    longest = longest_path(max_length_mm, r_min, chord_mm, tau)
    geo[0] = longest + tau + 2.0 * h + slack
    if direction is None or heading_deg is None or heading_deg > 90.0:
        return geo
    hr = math.radians(float(heading_deg))
    geo[1:6] = 1.0, math.cos(hr), math.sin(hr), h + slack, tau + h + slack
    if r_min is not None and r_min > 0.0:
        r = float(r_min)
        dip = r - math.sqrt(max(r * r - half_gap2, 0.0))  # a chord's dip into the torus
        geo[6], geo[7] = r, r - dip - h - slack
        # the turn-then-straight bound: a centre lies within h + delta / 2 of a path point
        reach = h + 0.5 * math.sqrt(4.0 * half_gap2) + slack
        geo[8] = r / (1.0 + 1e-6 * (1.0 + r))  # the check's curvature slack
        geo[9], geo[10] = longest + tau + reach + slack, reach
    return geo
