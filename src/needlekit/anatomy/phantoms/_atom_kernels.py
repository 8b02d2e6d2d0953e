"""Atoms of the phantoms (round cones, half-spaces, outsides of balls, plates): parameter
rows, numba kernels for their exact signed distances, and the acceleration cells."""

from __future__ import annotations

import math

import numba
import numpy as np

ROUND_CONE, HALF_SPACE, BALL_OUT, PLATE = 0, 1, 2, 3
_N_PARAMS = 16

#: Stated error (mm) of the exact atom fields: closed forms in double precision on
#: coordinates below ~10^3 mm lose at most ~1e-12 mm; the tests hold the kernels to an
#: independent reference (support functions) within 1e-7 mm.
ATOM_ERROR_BOUND_MM: float = 1e-9

#: Edge (mm) of the finest acceleration cell. A point's candidate atoms are those within
#: ``D + sqrt(3) * edge`` of the cell centre; 2 mm keeps ~3-4 candidates per cell (95 %
#: below 8) in the lung's trees with ~0.5 M cells (8 MB of lists), measured fastest to
#: build and bake on 2 cores among 1.25-3 mm.
CELL_SIZE_MM: float = 2.0

#: Margin (mm) of the acceleration cells around a union's box: covers the padding of
#: baked grids (:data:`BAKE_PADDING_MM`) so every voxel is answered from the cells.
CELL_PADDING_MM: float = 12.0

#: Padding (mm) of baked grids around a structure: above any needle radius plus safety
#: margin a planner uses (<= 5 mm), so the distances it compares with are interpolated,
#: not extrapolated (the outside-grid rule of VoxelSDF is conservative but looser).
BAKE_PADDING_MM: float = 6.0

#: Batches smaller than this use the serial kernel (starting numba's threads costs more).
PARALLEL_MIN_POINTS: int = 4096

#: Unions with at most this many atoms are evaluated directly (no cells).
DIRECT_MAX_ATOMS: int = 12

#: Largest grid (voxels) a phantom structure may be baked into: 1.2e8 float32 voxels are
#: 480 MB, beyond the "modest memory" the phantoms promise; a smaller voxel size than the
#: phantoms' range of validity is refused before it exhausts memory.
MAX_BAKED_VOXELS: int = 120_000_000


# ----------------------------------------------------------------------------------------
# atoms: parameter rows


def _row() -> np.ndarray:
    q = np.zeros(_N_PARAMS)
    q[13] = np.inf  # radius of a ball about the middle of q[0:3], q[3:6] holding the atom
    return q


def round_cone(a, b, ra: float, rb: float) -> tuple[int, np.ndarray]:
    """Atom: convex hull of the balls ``(a, ra)`` and ``(b, rb)`` (a tapered tube).

    Parameters
    ----------
    a, b : array_like, shape (3,)
        Centres of the end balls (world RAS, mm).
    ra, rb : float
        Their radii (mm), > 0.

    Returns
    -------
    kind : int
    params : ndarray, shape (16,)
        Centres, radii and precomputed constants of the closed form.
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    q = _row()
    ba = b - a
    l2 = float(ba @ ba)
    rr = float(ra) - float(rb)
    q[0:3], q[3:6], q[6], q[7] = a, b, ra, rb
    if l2 <= rr * rr or l2 == 0.0:  # one ball holds the other: the larger ball
        big = (a, ra) if ra >= rb else (b, rb)
        q[0:3], q[3:6], q[6], q[12], q[13] = big[0], big[0], big[1], 1.0, big[1]
        return ROUND_CONE, q
    q[8], q[9], q[10], q[11] = l2, rr, l2 - rr * rr, 1.0 / l2
    q[13] = 0.5 * np.sqrt(l2) + max(ra, rb)
    return ROUND_CONE, q


def half_space(point, normal) -> tuple[int, np.ndarray]:
    """Atom: the half-space ``(p - point) . n <= 0`` (``n`` the unit outward normal).

    Parameters
    ----------
    point : array_like, shape (3,)
        A point of the plane (mm).
    normal : array_like, shape (3,)
        Outward normal (normalised here).

    Returns
    -------
    kind : int
    params : ndarray, shape (16,)
    """
    q = _row()
    n = np.asarray(normal, dtype=np.float64)
    q[0:3], q[3:6] = point, n / np.linalg.norm(n)
    return HALF_SPACE, q


def ball_outside(center, radius: float) -> tuple[int, np.ndarray]:
    """Atom: the outside of a ball, ``|p - center| >= radius`` (e.g. below a dome).

    Parameters
    ----------
    center : array_like, shape (3,)
    radius : float
        (mm), > 0.

    Returns
    -------
    kind : int
    params : ndarray, shape (16,)
    """
    q = _row()
    q[0:3], q[3] = center, radius
    return BALL_OUT, q


def plate(
    center, e1, e2, half_extents, half_thickness: float, *, corner_mm: float = 0.0
) -> tuple[int, np.ndarray]:
    """Atom: points within ``half_thickness`` of the rectangle
    ``center + s e1 + t e2``, ``|s| <= hx``, ``|t| <= hy``, its corners rounded with
    radius ``corner_mm`` (a thin sheet).

    Parameters
    ----------
    center : array_like, shape (3,)
    e1, e2 : array_like, shape (3,)
        In-plane axes (orthonormalised here, ``e2`` made perpendicular to ``e1``).
    half_extents : array_like, shape (2,)
        ``(hx, hy)`` (mm), >= 0.
    half_thickness : float
        (mm), > 0.
    corner_mm : float
        Corner radius (mm), in ``[0, min(hx, hy)]``.

    Returns
    -------
    kind : int
    params : ndarray, shape (16,)
    """
    u = np.asarray(e1, dtype=np.float64)
    u = u / np.linalg.norm(u)
    v = np.asarray(e2, dtype=np.float64)
    v = v - (v @ u) * u
    v = v / np.linalg.norm(v)
    q = _row()
    q[0:3], q[3:6], q[6:9], q[9:12] = center, u, v, np.cross(u, v)
    q[12], q[13], q[14], q[15] = half_extents[0], half_extents[1], half_thickness, corner_mm
    return PLATE, q


def _atom_bounds(kind: int, q: np.ndarray) -> np.ndarray:
    if kind == ROUND_CONE:
        if q[12] != 0.0:
            return np.stack([q[0:3] - q[6], q[0:3] + q[6]])
        lo = np.minimum(q[0:3] - q[6], q[3:6] - q[7])
        hi = np.maximum(q[0:3] + q[6], q[3:6] + q[7])
        return np.stack([lo, hi])
    if kind == PLATE:
        half = np.abs(q[3:6]) * q[12] + np.abs(q[6:9]) * q[13] + q[14]
        return np.stack([q[0:3] - half, q[0:3] + half])
    box = np.array([[-np.inf] * 3, [np.inf] * 3])
    if kind == HALF_SPACE and np.count_nonzero(q[3:6]) == 1:  # axis-aligned: one face
        i = int(np.flatnonzero(q[3:6])[0])
        box[0 if q[3 + i] < 0 else 1, i] = q[i]
    return box


# ----------------------------------------------------------------------------------------
# numba kernels


@numba.njit(cache=True, inline="always")
def _sign(v):  # pragma: no cover - compiled
    return 1.0 if v > 0.0 else (-1.0 if v < 0.0 else 0.0)


@numba.njit(cache=True, inline="always")
def _atom_sd(kind, q, x, y, z):  # pragma: no cover - compiled
    """Signed distance of one point to one atom (see the module table)."""
    if kind == 0:
        px = x - q[0]
        py = y - q[1]
        pz = z - q[2]
        if q[12] != 0.0:
            return math.sqrt(px * px + py * py + pz * pz) - q[6]
        # round cone: closed form with one square root (I. Quilez, "sdRoundCone")
        bax = q[3] - q[0]
        bay = q[4] - q[1]
        baz = q[5] - q[2]
        l2 = q[8]
        rr = q[9]
        a2 = q[10]
        il2 = q[11]
        yy = px * bax + py * bay + pz * baz
        zz = yy - l2
        cx = px * l2 - bax * yy
        cy = py * l2 - bay * yy
        cz = pz * l2 - baz * yy
        x2 = cx * cx + cy * cy + cz * cz
        y2 = yy * yy * l2
        z2 = zz * zz * l2
        k = _sign(rr) * rr * rr * x2
        if _sign(zz) * a2 * z2 > k:
            return math.sqrt(x2 + z2) * il2 - q[7]
        if _sign(yy) * a2 * y2 < k:
            return math.sqrt(x2 + y2) * il2 - q[6]
        return (math.sqrt(x2 * a2 * il2) + yy * rr) * il2 - q[6]
    if kind == 1:
        return (x - q[0]) * q[3] + (y - q[1]) * q[4] + (z - q[2]) * q[5]
    if kind == 2:
        px = x - q[0]
        py = y - q[1]
        pz = z - q[2]
        return q[3] - math.sqrt(px * px + py * py + pz * pz)
    # plate
    px = x - q[0]
    py = y - q[1]
    pz = z - q[2]
    s = px * q[3] + py * q[4] + pz * q[5]
    t = px * q[6] + py * q[7] + pz * q[8]
    h = px * q[9] + py * q[10] + pz * q[11]
    # planar distance to the rounded rectangle, then to the sheet around it
    ds = abs(s) - q[12] + q[15]
    dt = abs(t) - q[13] + q[15]
    mx = max(ds, 0.0)
    my = max(dt, 0.0)
    d2 = math.sqrt(mx * mx + my * my) - q[15]
    d2 = max(d2, 0.0)
    return math.sqrt(d2 * d2 + h * h) - q[14]


@numba.njit(cache=True, inline="always")
def _cannot_beat(q, x, y, z, best):  # pragma: no cover - compiled
    """True when the atom's bounding ball shows its distance is >= ``best``."""
    t = best + q[13]
    if not t < np.inf:
        return False
    if t <= 0.0:
        return True
    mx = x - 0.5 * (q[0] + q[3])
    my = y - 0.5 * (q[1] + q[4])
    mz = z - 0.5 * (q[2] + q[5])
    return mx * mx + my * my + mz * mz >= t * t


@numba.njit(cache=True, inline="always")
def _combine_all(kinds, params, is_max, x, y, z):  # pragma: no cover - compiled
    best = -np.inf if is_max else np.inf
    for a in range(kinds.shape[0]):
        d = _atom_sd(kinds[a], params[a], x, y, z)
        if is_max:
            best = max(best, d)
        else:
            best = min(best, d)
    return best


@numba.njit(cache=True, inline="always")
def _union_cells(kinds, params, origin, h, shape, offsets, items, x, y, z):
    # pragma: no cover - compiled
    i = math.floor((x - origin[0]) / h)
    j = math.floor((y - origin[1]) / h)
    k = math.floor((z - origin[2]) / h)
    if i < 0 or j < 0 or k < 0 or i >= shape[0] or j >= shape[1] or k >= shape[2]:
        return _combine_all(kinds, params, False, x, y, z)
    c = (int(i) * shape[1] + int(j)) * shape[2] + int(k)
    best = np.inf
    for t in range(offsets[c], offsets[c + 1]):
        a = items[t]
        if not _cannot_beat(params[a], x, y, z, best):
            best = min(best, _atom_sd(kinds[a], params[a], x, y, z))
    return best


@numba.njit(cache=True, inline="always")
def _eval_one(kinds, params, is_max, origin, h, shape, offsets, items, x, y, z):
    # pragma: no cover - compiled
    if offsets.shape[0] > 0:
        return _union_cells(kinds, params, origin, h, shape, offsets, items, x, y, z)
    return _combine_all(kinds, params, is_max, x, y, z)


@numba.njit(cache=True, parallel=True)
def _eval_points(kinds, params, is_max, origin, h, shape, offsets, items, points, out):
    # pragma: no cover - compiled
    """Field at world points (n, 3); cells when ``offsets`` is non-empty (unions)."""
    for n in numba.prange(points.shape[0]):
        out[n] = _eval_one(
            kinds,
            params,
            is_max,
            origin,
            h,
            shape,
            offsets,
            items,
            points[n, 0],
            points[n, 1],
            points[n, 2],
        )


@numba.njit(cache=True)
def _eval_points_serial(kinds, params, is_max, origin, h, shape, offsets, items, points, out):
    # pragma: no cover - compiled
    """:func:`_eval_points` on one thread (small batches: no thread start-up)."""
    for n in range(points.shape[0]):
        out[n] = _eval_one(
            kinds,
            params,
            is_max,
            origin,
            h,
            shape,
            offsets,
            items,
            points[n, 0],
            points[n, 1],
            points[n, 2],
        )


@numba.njit(cache=True, parallel=True)
def _eval_grid(kinds, params, is_max, g_origin, g_h, negate_max, out):
    # pragma: no cover - compiled
    """Field ``d`` (all atoms, direct) at the voxel centres ``g_origin + (i, j, k) g_h``
    of ``out`` (float32): stored, or with ``negate_max`` combined as ``max(out, -d)``."""
    ni, nj, nk = out.shape
    for i in numba.prange(ni):
        x = g_origin[0] + i * g_h
        for j in range(nj):
            y = g_origin[1] + j * g_h
            for k in range(nk):
                d = _combine_all(kinds, params, is_max, x, y, g_origin[2] + k * g_h)
                if negate_max:
                    out[i, j, k] = max(out[i, j, k], -d)
                else:
                    out[i, j, k] = d


@numba.njit(cache=True, inline="always")
def _first_voxel(c_origin, h, c, g_origin, g_h, n):  # pragma: no cover - compiled
    """Index of the first voxel at or above the lower face of cell ``c`` (clamped)."""
    v = math.ceil((c_origin + c * h - g_origin) / g_h - 1e-9)
    return min(max(v, 0), n)


@numba.njit(cache=True, parallel=True)
def _eval_grid_cells(
    kinds, params, origin, h, shape, offsets, items, g_origin, g_h, negate_max, out
):
    # pragma: no cover - compiled
    """Union field on a grid, cell by cell: each cell's voxels against its candidate
    list. The cells must cover the grid (with a margin); voxel ranges of consecutive
    cells use the same boundary function and the last cell takes the rest, so every
    voxel belongs to exactly one cell."""
    ni, nj, nk = out.shape
    for ci in numba.prange(shape[0]):
        i0 = _first_voxel(origin[0], h, ci, g_origin[0], g_h, ni)
        i1 = ni if ci == shape[0] - 1 else _first_voxel(origin[0], h, ci + 1, g_origin[0], g_h, ni)
        if i0 >= i1:
            continue
        for cj in range(shape[1]):
            j0 = _first_voxel(origin[1], h, cj, g_origin[1], g_h, nj)
            j1 = (
                nj
                if cj == shape[1] - 1
                else _first_voxel(origin[1], h, cj + 1, g_origin[1], g_h, nj)
            )
            if j0 >= j1:
                continue
            for ck in range(shape[2]):
                k0 = _first_voxel(origin[2], h, ck, g_origin[2], g_h, nk)
                k1 = (
                    nk
                    if ck == shape[2] - 1
                    else _first_voxel(origin[2], h, ck + 1, g_origin[2], g_h, nk)
                )
                if k0 >= k1:
                    continue
                c = (ci * shape[1] + cj) * shape[2] + ck
                lo = offsets[c]
                hi = offsets[c + 1]
                for i in range(i0, i1):
                    x = g_origin[0] + i * g_h
                    for j in range(j0, j1):
                        y = g_origin[1] + j * g_h
                        for k in range(k0, k1):
                            z = g_origin[2] + k * g_h
                            d = np.inf
                            for t in range(lo, hi):
                                a = items[t]
                                if not _cannot_beat(params[a], x, y, z, d):
                                    d = min(d, _atom_sd(kinds[a], params[a], x, y, z))
                            if negate_max:
                                out[i, j, k] = max(out[i, j, k], -d)
                            else:
                                out[i, j, k] = d


@numba.njit(cache=True, parallel=True)
def _refine_count(kinds, params, origin, h, shape, pshape, shift, poff, pitems, reach, counts):
    # pragma: no cover - compiled
    """Candidate counts of the cells of one level from their parents' lists."""
    nj = shape[1]
    nk = shape[2]
    for c in numba.prange(shape[0] * nj * nk):
        i = c // (nj * nk)
        j = (c // nk) % nj
        k = c % nk
        x = origin[0] + (i + 0.5) * h
        y = origin[1] + (j + 0.5) * h
        z = origin[2] + (k + 0.5) * h
        pc = ((i >> shift) * pshape[1] + (j >> shift)) * pshape[2] + (k >> shift)
        lo = poff[pc]
        hi = poff[pc + 1]
        d = np.empty(hi - lo)
        best = np.inf
        for t in range(lo, hi):
            a = pitems[t]
            d[t - lo] = _atom_sd(kinds[a], params[a], x, y, z)
            best = min(best, d[t - lo])
        n = 0
        for t in range(hi - lo):
            if d[t] <= best + reach:
                n += 1
        counts[c] = n


@numba.njit(cache=True, parallel=True)
def _refine_fill(
    kinds, params, origin, h, shape, pshape, shift, poff, pitems, reach, offsets, items
):
    # pragma: no cover - compiled
    """Candidate lists of the cells of one level, nearest (at the centre) first."""
    nj = shape[1]
    nk = shape[2]
    for c in numba.prange(shape[0] * nj * nk):
        i = c // (nj * nk)
        j = (c // nk) % nj
        k = c % nk
        x = origin[0] + (i + 0.5) * h
        y = origin[1] + (j + 0.5) * h
        z = origin[2] + (k + 0.5) * h
        pc = ((i >> shift) * pshape[1] + (j >> shift)) * pshape[2] + (k >> shift)
        lo = poff[pc]
        hi = poff[pc + 1]
        d = np.empty(hi - lo)
        keys = np.empty(hi - lo, dtype=np.int64)
        best = np.inf
        for t in range(lo, hi):
            a = pitems[t]
            d[t - lo] = _atom_sd(kinds[a], params[a], x, y, z)
            best = min(best, d[t - lo])
        w0 = offsets[c]
        w = w0
        for t in range(hi - lo):
            if d[t] <= best + reach:
                # insertion by distance at the centre: nearest first (pruning works best)
                m = w
                while m > w0 and d[keys[m - 1 - w0]] > d[t]:
                    items[m] = items[m - 1]
                    keys[m - w0] = keys[m - 1 - w0]
                    m -= 1
                items[m] = pitems[lo + t]
                keys[m - w0] = t
                w += 1


def _build_cells(kinds, params, box: np.ndarray, cell_mm: float):
    """Candidate lists on cubic cells of edge ``cell_mm`` covering ``box`` (see the module
    notes). Returns ``origin (3,), h, shape (3,) int64, offsets, items``."""
    origin = box[0].astype(np.float64)
    shape_f = np.maximum(np.ceil((box[1] - box[0]) / cell_mm).astype(np.int64), 1)
    levels = 1
    while shape_f.max() > 4 * 2 ** (levels - 1):
        levels += 1
    poff = np.array([0, len(kinds)], dtype=np.int64)
    pitems = np.arange(len(kinds), dtype=np.int32)
    pshape = np.ones(3, dtype=np.int64)
    shift = 62  # the first level's parent is one cell holding every atom
    for lev in range(levels):
        scale = 2 ** (levels - 1 - lev)
        shape = -(-shape_f // scale)
        h = cell_mm * scale
        reach = math.sqrt(3.0) * h * (1.0 + 1e-12) + 1e-9
        counts = np.empty(int(np.prod(shape)), dtype=np.int64)
        _refine_count(kinds, params, origin, h, shape, pshape, shift, poff, pitems, reach, counts)
        offsets = np.zeros(len(counts) + 1, dtype=np.int64)
        np.cumsum(counts, out=offsets[1:])
        items = np.empty(int(offsets[-1]), dtype=np.int32)
        _refine_fill(
            kinds, params, origin, h, shape, pshape, shift, poff, pitems, reach, offsets, items
        )
        poff, pitems, pshape, shift = offsets, items, shape, 1
    return origin, float(cell_mm), pshape, poff, pitems
