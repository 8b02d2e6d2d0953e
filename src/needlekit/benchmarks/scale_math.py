"""The arithmetic of ``needlekit bench scale``: least-squares fits with R^2 and the share of
obstacle voxels around a start-goal segment.

Pure functions over arrays, no clocks: the tests check them on synthetic data with known
answers (a power law's exponent, a half-filled grid).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CAPSULE_RADIUS_MM", "capsule_obstacle_fraction", "linear_fit", "loglog_fit"]

#: Radius of the capsule around the start-goal segment in which the obstacle density is
#: measured (mm): about the room a curved needle of r_min 50 mm uses to bend around what
#: lies on the straight line over 50-60 mm (its arc leaves the chord by at most ~9 mm).
CAPSULE_RADIUS_MM: float = 10.0


def _fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float] | None:
    """Slope, intercept and R^2 of the least-squares line y = intercept + slope * x."""
    if len(x) < 2 or np.ptp(x) == 0.0:
        return None
    slope, intercept = np.polyfit(x, y, 1)
    pred = intercept + slope * x
    ss_res = float(np.sum((y - pred) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0.0 else (1.0 if ss_res == 0.0 else 0.0)
    return float(slope), float(intercept), float(r2)


def linear_fit(x, y, *, at=None) -> dict | None:
    """Least-squares line ``y = intercept + slope * x`` with its R^2.

    Parameters
    ----------
    x, y : array_like, shape (n,)
        Finite values (pairs with a non-finite value are left out).
    at : float, optional
        Also give the line's value there (an extrapolation when outside ``x``'s range).

    Returns
    -------
    dict or None
        ``slope``, ``intercept``, ``r2``, ``n`` and, with ``at``, ``at`` and
        ``predicted``; None with fewer than two distinct ``x``.

    Examples
    --------
    >>> f = linear_fit([1, 2, 5, 10], [3.0, 5.0, 11.0, 21.0], at=100)
    >>> round(f["slope"], 6), round(f["intercept"], 6), round(f["predicted"], 6), f["r2"]
    (2.0, 1.0, 201.0, 1.0)
    """
    xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(xa) & np.isfinite(ya)
    fit = _fit(xa[keep], ya[keep])
    if fit is None:
        return None
    out = {"slope": fit[0], "intercept": fit[1], "r2": fit[2], "n": int(keep.sum())}
    if at is not None:
        out |= {"at": float(at), "predicted": fit[1] + fit[0] * float(at)}
    return out


def loglog_fit(x, y) -> dict | None:
    """Power law ``y = coefficient * x ** exponent``, fitted as a line in log-log.

    Parameters
    ----------
    x, y : array_like, shape (n,)
        Pairs where either is not a finite positive number are left out (a log needs
        one) and counted in ``left_out``.

    Returns
    -------
    dict or None
        ``exponent`` (the log-log slope), ``coefficient``, ``r2`` (of the log-log line),
        ``n`` and ``left_out``; None with fewer than two distinct positive ``x``.

    Examples
    --------
    >>> f = loglog_fit([1.0, 2.0, 4.0, 8.0, 0.0], [3.0, 3 * 2**1.5, 24.0, 3 * 8**1.5, 1.0])
    >>> round(f["exponent"], 9), round(f["coefficient"], 9), f["r2"], f["left_out"]
    (1.5, 3.0, 1.0, 1)
    """
    xa, ya = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(xa) & np.isfinite(ya) & (xa > 0) & (ya > 0)
    fit = _fit(np.log(xa[keep]), np.log(ya[keep]))
    if fit is None:
        return None
    return {
        "exponent": fit[0],
        "coefficient": math.exp(fit[1]),
        "r2": fit[2],
        "n": int(keep.sum()),
        "left_out": int((~keep).sum()),
    }


def capsule_obstacle_fraction(
    occupancy, affine, a_mm, b_mm, radius_mm: float = CAPSULE_RADIUS_MM
) -> dict:
    """The share of obstacle voxels among the voxels whose centres lie within
    ``radius_mm`` of the segment from ``a_mm`` to ``b_mm`` (a capsule).

    Parameters
    ----------
    occupancy : ndarray of bool, shape (i, j, k)
        True at obstacle voxels (a Med-RAD case's cached ``occupancy``: everything that is
        not free space).
    affine : array_like, shape (4, 4)
        Voxel index -> RAS mm.
    a_mm, b_mm : array_like, shape (3,)
        The segment's ends (RAS mm).
    radius_mm : float

    Returns
    -------
    dict
        ``fraction`` (None when no voxel centre of the grid lies in the capsule),
        ``voxels`` (the capsule's voxels inside the grid; those outside are not counted),
        ``obstacle_voxels`` and ``radius_mm``.

    Examples
    --------
    >>> occ = np.zeros((40, 40, 40), dtype=bool)
    >>> occ[20:] = True  # x >= 20 mm is obstacle
    >>> d = capsule_obstacle_fraction(occ, np.eye(4), [19.5, 20, 5], [19.5, 20, 35], 5.0)
    >>> d["fraction"]
    0.5
    """
    occ = np.asarray(occupancy)
    aff = np.asarray(affine, dtype=float)
    a, b = np.asarray(a_mm, dtype=float), np.asarray(b_mm, dtype=float)
    r = float(radius_mm)
    lo, hi = np.minimum(a, b) - r, np.maximum(a, b) + r
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])  # fmt: skip
    idx = (np.linalg.inv(aff) @ corners.T)[:3].T
    first = np.maximum(np.floor(idx.min(axis=0)).astype(int), 0)
    last = np.minimum(np.ceil(idx.max(axis=0)).astype(int), np.asarray(occ.shape) - 1)
    empty = {"fraction": None, "voxels": 0, "obstacle_voxels": 0, "radius_mm": r}
    if np.any(last < first):
        return empty
    axes = [np.arange(f, t + 1) for f, t in zip(first, last, strict=True)]
    ii, jj, kk = np.meshgrid(*axes, indexing="ij")
    ijk = np.stack([ii.ravel(), jj.ravel(), kk.ravel()], axis=1)
    pts = ijk @ aff[:3, :3].T + aff[:3, 3]
    ab = b - a
    denom = float(ab @ ab)
    t = np.zeros(len(pts)) if denom == 0.0 else np.clip((pts - a) @ ab / denom, 0.0, 1.0)
    inside = np.linalg.norm(pts - (a + t[:, None] * ab), axis=1) <= r
    n = int(inside.sum())
    if n == 0:
        return empty
    sub = occ[first[0] : last[0] + 1, first[1] : last[1] + 1, first[2] : last[2] + 1]
    hits = int(np.count_nonzero(sub.ravel()[inside]))
    return {"fraction": hits / n, "voxels": n, "obstacle_voxels": hits, "radius_mm": r}
