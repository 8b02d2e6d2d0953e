"""Closest distances between straight segments (batch, exact)."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["closest_segment_params", "segment_distances"]


@numba.njit(cache=True, inline="always")
def closest_segment_params(rx, ry, rz, d1x, d1y, d1z, d2x, d2y, d2z):  # pragma: no cover
    """The closest points' parameters ``(s, t)`` in [0, 1] of the segments ``p0 + s d1``
    and ``q0 + t d2``, one pair (for the numba kernels, scalars in so that nothing is
    allocated; :func:`segment_distances` is the batch form): the unconstrained optimum
    clamped, then each re-optimised against the other's clamp. Either segment may have no
    length (a point); for parallel segments one of the closest pairs.

    Parameters
    ----------
    rx, ry, rz : float
        ``p0 - q0``.
    d1x, d1y, d1z, d2x, d2y, d2z : float
        The directions (ends minus starts).

    Returns
    -------
    s, t : float
    """
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    f = d2x * rx + d2y * ry + d2z * rz
    if a <= 1e-18 and e <= 1e-18:
        return 0.0, 0.0
    if a <= 1e-18:
        return 0.0, min(max(f / e, 0.0), 1.0)
    c = d1x * rx + d1y * ry + d1z * rz
    if e <= 1e-18:
        return min(max(-c / a, 0.0), 1.0), 0.0
    b = d1x * d2x + d1y * d2y + d1z * d2z
    denom = a * e - b * b
    s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 1e-12 * a * e else 0.0
    t = (b * s + f) / e
    if t < 0.0:
        t = 0.0
        s = min(max(-c / a, 0.0), 1.0)
    elif t > 1.0:
        t = 1.0
        s = min(max((b - c) / a, 0.0), 1.0)
    return s, t


def segment_distances(p0, p1, q0, q1) -> np.ndarray:
    """Distances between one segment ``p0-p1`` and many segments ``q0-q1``.

    The closest points minimise ``|p0 + s (p1 - p0) - q0 - t (q1 - q0)|`` over
    ``s, t in [0, 1]``: the unconstrained optimum clamped to the square, then each
    parameter re-optimised against the other's clamp (the standard closed form).

    Parameters
    ----------
    p0, p1 : ndarray, shape (3,)
    q0, q1 : ndarray, shape (m, 3)

    Returns
    -------
    ndarray, shape (m,)
        Exact closest distances (mm).
    """
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = float(d1 @ d1)
    e = np.einsum("ij,ij->i", d2, d2)
    f = np.einsum("ij,ij->i", d2, r)
    c = r @ d1
    b = d2 @ d1
    e_safe = np.where(e > 1e-18, e, 1.0)
    if a <= 1e-18:  # the first segment is a point
        t = np.clip(f / e_safe, 0.0, 1.0) * (e > 1e-18)
        s = np.zeros_like(t)
    else:
        denom = a * e - b * b
        s = np.where(
            denom > 1e-12 * a * e_safe,
            np.clip((b * f - c * e) / np.where(denom > 0, denom, 1.0), 0, 1),
            0.0,
        )
        t = (b * s + f) / e_safe
        low = t < 0.0
        high = t > 1.0
        s = np.where(
            low, np.clip(-c / a, 0.0, 1.0), np.where(high, np.clip((b - c) / a, 0.0, 1.0), s)
        )
        t = np.clip(t, 0.0, 1.0)
        point_q = e <= 1e-18
        s = np.where(point_q, np.clip(-c / a, 0.0, 1.0), s)
        t = np.where(point_q, 0.0, t)
    closest = (p0 + s[:, None] * d1) - (q0 + t[:, None] * d2)
    return np.linalg.norm(closest, axis=1)
