"""Compiled kernels of the shaft's solve: the one linear solve and the channel's sampling.

Each kernel does in one compiled loop what a numpy reference does in many small array
operations (:func:`needlekit.mechanics.shaft.solve_linear_reference`,
:meth:`needlekit.mechanics.channel.Channel.sample_reference`,
:func:`needlekit.mechanics.shaft.node_positions_reference`); tests hold each kernel to
its reference. Compiled with ``cache=True``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "foundation_kernel",
    "node_positions_kernel",
    "offsets_kernel",
    "reference_kernel",
    "rod_solve_kernel",
    "sample_channel_kernel",
]


@numba.njit(cache=True)
def foundation_kernel(s, gap, support_end, k, k_by_mm):  # pragma: no cover - compiled
    """The foundation's modulus per element of nodes ``s``: ``k`` where the element's
    middle lies in ``(gap, support_end)``, times ``k_by_mm[int(middle - gap)]`` (the last
    entry beyond its end; an empty array: no factor); 0 elsewhere."""
    n = s.size - 1
    out = np.zeros(n)
    m = k_by_mm.size
    for e in range(n):
        mid = 0.5 * (s[e] + s[e + 1])
        if gap < mid < support_end:
            f = 1.0
            if m > 0:
                i = int(mid - gap)
                f = k_by_mm[min(max(i, 0), m - 1)]
            out[e] = k * f
    return out


@numba.njit(cache=True)
def node_positions_kernel(gap, depth, breaks, h, min_fraction):  # pragma: no cover - compiled
    """:func:`needlekit.mechanics.shaft.node_positions_reference` in one loop, the same
    floating-point operations in the same order (the same bits)."""
    tip = gap + depth
    n_gap = max(1, math.ceil(gap / h - 1e-9)) if gap > 0 else 0
    m_in = max(1, math.ceil(depth / h)) - 1  # inner nodes gap + h i, i = 1 .. m_in
    must = np.empty(1 + breaks.size)
    must[0] = tip
    n_must = 1
    for b in breaks:
        if gap < b < tip - 1e-9:
            must[n_must] = b
            n_must += 1
    cand = np.empty(n_gap + 1 + m_in + n_must)
    n = 0
    if n_gap:  # numpy's linspace(0, gap, n_gap + 1): i * step + 0, its last exactly gap
        step = gap / n_gap
        for i in range(n_gap + 1):
            cand[n] = (i / n_gap * gap if step == 0.0 else i * step) + 0.0
            n += 1
        cand[n - 1] = gap
    else:
        cand[n] = 0.0
        n += 1
    tol = 0.3 * h
    for i in range(1, m_in + 1):
        x = gap + h * i
        ok = x < tip
        for j in range(n_must):
            ok = ok and abs(x - must[j]) >= tol
        if ok:
            cand[n] = x
            n += 1
    for j in range(n_must):
        cand[n] = must[j]
        n += 1
    srt = np.sort(cand[:n])
    s = np.empty(n)  # unique, below the tip
    m = 0
    for x in srt:
        if x < tip and (m == 0 or x != s[m - 1]):
            s[m] = x
            m += 1
    min_len = min_fraction * h
    out = np.empty(m + 1)
    k = 0
    for i in range(m):
        if i == 0 or (s[i] - s[i - 1] >= min_len and tip - s[i] >= min_len):
            out[k] = s[i]
            k += 1
    out[k] = tip
    return out[: k + 1]


@numba.njit(cache=True)
def _element(length, ei, k, kb, kf):  # pragma: no cover - compiled
    c = ei / length**3
    l1, l2 = length, length * length
    kb[0, 0], kb[0, 1], kb[0, 2], kb[0, 3] = 12.0 * c, 6.0 * l1 * c, -12.0 * c, 6.0 * l1 * c
    kb[1, 1], kb[1, 2], kb[1, 3] = 4.0 * l2 * c, -6.0 * l1 * c, 2.0 * l2 * c
    kb[2, 2], kb[2, 3] = 12.0 * c, -6.0 * l1 * c
    kb[3, 3] = 4.0 * l2 * c
    f = k * length / 420.0
    kf[0, 0], kf[0, 1], kf[0, 2], kf[0, 3] = 156.0 * f, 22.0 * l1 * f, 54.0 * f, -13.0 * l1 * f
    kf[1, 1], kf[1, 2], kf[1, 3] = 4.0 * l2 * f, 13.0 * l1 * f, -3.0 * l2 * f
    kf[2, 2], kf[2, 3] = 156.0 * f, -22.0 * l1 * f
    kf[3, 3] = 4.0 * l2 * f
    for a in range(4):
        for b in range(a):
            kb[a, b] = kb[b, a]
            kf[a, b] = kf[b, a]


@numba.njit(cache=True)
def rod_solve_kernel(lengths, ei, k_e, ref, fx, fy):  # pragma: no cover - compiled
    """Clamped rod on its foundation, pulled off its reference, with a tip force.

    Parameters
    ----------
    lengths : ndarray, shape (e,)
        Element lengths (mm).
    ei : float
        Flexural rigidity (N mm^2).
    k_e : ndarray, shape (e,)
        Foundation modulus per element (N/mm^2).
    ref : ndarray, shape (e, 4, 2)
        Each element's reference offsets (minus a rest shape) in both planes.
    fx, fy : float
        Tip force in the two planes (N).

    Returns
    -------
    sol : ndarray, shape (2 (e + 1), 2)
        Deflections and slopes, zero at the clamped first node.
    nodal : ndarray, shape (e + 1, 2)
        The foundation's consistent nodal forces on the rod (N).
    ok : bool
        False when the matrix was not positive definite.
    """
    ne = lengths.size
    n = 2 * (ne + 1)
    band = np.zeros((n, 4))  # band[i, d] = K[i, i - d]
    rhs = np.zeros((n, 2))
    kb = np.empty((4, 4))
    kf = np.empty((4, 4))
    for e in range(ne):
        _element(lengths[e], ei, k_e[e], kb, kf)
        base = 2 * e
        for a in range(4):
            for b in range(a + 1):
                band[base + a, a - b] += kb[a, b] + kf[a, b]
            for p in range(2):
                acc = 0.0
                for b in range(4):
                    acc += kb[a, b] * ref[e, b, p]
                rhs[base + a, p] -= acc
    rhs[n - 2, 0] += fx
    rhs[n - 2, 1] += fy
    # banded Cholesky of the system without the clamped unknowns 0 and 1
    low = np.zeros((n, 4))
    for i in range(2, n):
        for d in range(min(3, i - 2), -1, -1):
            j = i - d
            s = band[i, d]
            for m in range(max(2, i - 3), j):
                s -= low[i, i - m] * low[j, j - m]
            if d == 0:
                if not s > 0.0:
                    return np.zeros((n, 2)), np.zeros((ne + 1, 2)), False
                low[i, 0] = math.sqrt(s)
            else:
                low[i, d] = s / low[j, 0]
    y = np.zeros((n, 2))
    for i in range(2, n):
        for p in range(2):
            s = rhs[i, p]
            for m in range(max(2, i - 3), i):
                s -= low[i, i - m] * y[m, p]
            y[i, p] = s / low[i, 0]
    x = np.zeros((n, 2))
    for i in range(n - 1, 1, -1):
        for p in range(2):
            s = y[i, p]
            for m in range(i + 1, min(n, i + 4)):
                s -= low[m, m - i] * x[m, p]
            x[i, p] = s / low[i, 0]
    nodal = np.zeros((ne + 1, 2))
    for e in range(ne):
        if k_e[e] == 0.0:
            continue
        _element(lengths[e], ei, k_e[e], kb, kf)
        base = 2 * e
        for p in range(2):
            for a in (0, 2):
                acc = 0.0
                for b in range(4):
                    acc += kf[a, b] * x[base + b, p]
                nodal[e + a // 2, p] -= acc
    return x, nodal, True


@numba.njit(cache=True)
def sample_channel_kernel(depth, pos, tan, ex, q):  # pragma: no cover - compiled
    """Hermite samples of a channel at depths ``q`` (see ``Channel.sample``).

    Parameters
    ----------
    depth : ndarray, shape (m,)
        The channel's increasing depths (m >= 2).
    pos, tan, ex : ndarray, shape (m, 3)
        Points, unit tangents, transported unit normals.
    q : ndarray, shape (k,)
        Depths to sample, clipped to the channel.

    Returns
    -------
    tuple of ndarray, each shape (k, 3)
        Points, unit tangents, unit normals perpendicular to them.
    """
    m = depth.size
    k = q.size
    out_p = np.empty((k, 3))
    out_t = np.empty((k, 3))
    out_e = np.empty((k, 3))
    for r in range(k):
        d = min(max(q[r], 0.0), depth[m - 1])
        i = np.searchsorted(depth, d, side="right") - 1
        i = min(max(i, 0), m - 2)
        h = depth[i + 1] - depth[i]
        tau = (d - depth[i]) / h
        t2 = tau * tau
        t3 = t2 * tau
        h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + tau, -2 * t3 + 3 * t2, t3 - t2
        g00, g10, g01, g11 = (
            6 * t2 - 6 * tau,
            3 * t2 - 4 * tau + 1,
            -6 * t2 + 6 * tau,
            3 * t2 - 2 * tau,
        )
        nt = 0.0
        for c in range(3):
            m0 = h * tan[i, c]
            m1 = h * tan[i + 1, c]
            out_p[r, c] = h00 * pos[i, c] + h10 * m0 + h01 * pos[i + 1, c] + h11 * m1
            v = g00 * pos[i, c] + g10 * m0 + g01 * pos[i + 1, c] + g11 * m1
            out_t[r, c] = v
            nt += v * v
        nt = math.sqrt(nt)
        dot = 0.0
        for c in range(3):
            out_t[r, c] /= nt
            out_e[r, c] = (1.0 - tau) * ex[i, c] + tau * ex[i + 1, c]
            dot += out_e[r, c] * out_t[r, c]
        ne = 0.0
        for c in range(3):
            out_e[r, c] -= dot * out_t[r, c]
            ne += out_e[r, c] * out_e[r, c]
        ne = math.sqrt(ne)
        for c in range(3):
            out_e[r, c] /= ne
    return out_p, out_t, out_e


@numba.njit(cache=True)
def reference_kernel(s, gap, g_pos, g_tan, g_ex, depth, pos, tan, ex):  # pragma: no cover - compiled
    """The shaft's reference at nodes ``s`` (``needlekit.mechanics.shaft._reference``,
    the same operations): the guide's line up to ``gap``, the channel (at least two
    points, :func:`sample_channel_kernel`) beyond; and ``e_y = t x e_x``."""
    n = s.size
    out_p, out_t, out_x = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    m = 0
    for i in range(n):
        if s[i] <= gap:
            for c in range(3):
                out_p[i, c] = g_pos[c] + s[i] * g_tan[c]
                out_t[i, c] = g_tan[c]
                out_x[i, c] = g_ex[c]
        else:
            m += 1
    if m:
        q = np.empty(m)
        rows = np.empty(m, dtype=np.int64)
        j = 0
        for i in range(n):
            if s[i] > gap:
                q[j] = s[i] - gap
                rows[j] = i
                j += 1
        cp, ct, cx = sample_channel_kernel(depth, pos, tan, ex, q)
        for j in range(m):
            for c in range(3):
                out_p[rows[j], c] = cp[j, c]
                out_t[rows[j], c] = ct[j, c]
                out_x[rows[j], c] = cx[j, c]
    ey = np.empty((n, 3))
    for i in range(n):
        t, x = out_t[i], out_x[i]
        ey[i, 0] = t[1] * x[2] - t[2] * x[1]
        ey[i, 1] = t[2] * x[0] - t[0] * x[2]
        ey[i, 2] = t[0] * x[1] - t[1] * x[0]
    return out_p, out_t, out_x, ey


@numba.njit(cache=True)
def offsets_kernel(s, pos, tan, ex, ey, cx, cy, rest_length, bend_start):  # pragma: no cover - compiled
    """Element lengths and each element's reference end offsets in its first node's frame,
    less a pre-bent tip's rest shape (``needlekit.mechanics.shaft._offsets_numpy``, the
    same operations)."""
    e = s.size - 1
    lengths = np.empty(e)
    ref = np.zeros((e, 4, 2))
    start = max(bend_start, 0.0)
    for i in range(e):
        lengths[i] = s[i + 1] - s[i]
        c0, c1, c2 = pos[i + 1, 0] - pos[i, 0], pos[i + 1, 1] - pos[i, 1], pos[i + 1, 2] - pos[i, 2]
        t0, t1, t2 = tan[i + 1, 0], tan[i + 1, 1], tan[i + 1, 2]
        ref[i, 2, 0] = c0 * ex[i, 0] + c1 * ex[i, 1] + c2 * ex[i, 2]
        ref[i, 3, 0] = t0 * ex[i, 0] + t1 * ex[i, 1] + t2 * ex[i, 2]
        ref[i, 2, 1] = c0 * ey[i, 0] + c1 * ey[i, 1] + c2 * ey[i, 2]
        ref[i, 3, 1] = t0 * ey[i, 0] + t1 * ey[i, 1] + t2 * ey[i, 2]
        if rest_length > 0.0 and 0.5 * (s[i + 1] + s[i]) > start:
            li = lengths[i]
            ref[i, 2, 0] -= 0.5 * cx * (li * li)
            ref[i, 3, 0] -= cx * li
            ref[i, 2, 1] -= 0.5 * cy * (li * li)
            ref[i, 3, 1] -= cy * li
    return lengths, ref
