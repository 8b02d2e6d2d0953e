"""Distance from points to the nearest obstacle voxel centre, within a cap.

The clearance figure of the ``voxel_centres`` collision model
(:class:`~needlekit.anatomy.occupancy.VoxelObstacles`): a needle sample at ``p`` keeps
``distance(p) - voxel_radius - needle radius`` from every obstacle voxel ball. The kernel
visits the box of half-width ``cap_mm`` around each point only, so distances beyond the cap
come back as the cap; :func:`~needlekit.anatomy.occupancy.nearest_obstacle_distance_reference`
(a KD-tree over every obstacle centre) is its oracle.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit._validation import as_points, as_positive
from needlekit.anatomy.occupancy import VoxelObstacles, box_half_widths, voxel_centre

__all__ = ["nearest_obstacle_distance", "smallest_obstacle_distance"]


@numba.njit(cache=True, inline="always")
def _nearest_in_box(occ, inv, affine, x, y, z, cap, excl_point, ex2):  # pragma: no cover
    """Squared distance from ``(x, y, z)`` to the nearest obstacle centre closer than
    ``cap`` (outside the exclusion), else ``cap**2``; -1 outside the image."""
    ni, nj, nk = occ.shape
    u = inv[0, 0] * x + inv[0, 1] * y + inv[0, 2] * z + inv[0, 3]
    v = inv[1, 0] * x + inv[1, 1] * y + inv[1, 2] * z + inv[1, 3]
    w = inv[2, 0] * x + inv[2, 1] * y + inv[2, 2] * z + inv[2, 3]
    if u < 0.0 or v < 0.0 or w < 0.0 or round(u) >= ni or round(v) >= nj or round(w) >= nk:
        return -1.0
    ci, cj, ck = int(round(u)), int(round(v)), int(round(w))
    r0, r1, r2 = box_half_widths(affine, cap)
    best = cap * cap
    for i in range(max(ci - r0, 0), min(ci + r0 + 1, ni)):
        for j in range(max(cj - r1, 0), min(cj + r1 + 1, nj)):
            for k in range(max(ck - r2, 0), min(ck + r2 + 1, nk)):
                if not occ[i, j, k]:
                    continue
                cx, cy, cz = voxel_centre(affine, i, j, k)
                d2 = (cx - x) ** 2 + (cy - y) ** 2 + (cz - z) ** 2
                if d2 >= best:
                    continue
                e2 = (
                    (cx - excl_point[0]) ** 2
                    + (cy - excl_point[1]) ** 2
                    + (cz - excl_point[2]) ** 2
                )
                if e2 < ex2:
                    continue
                best = d2
    return best


@numba.njit(cache=True)
def _nearest(occ, inv, affine, cap, excl_point, excl_r, points, out):  # pragma: no cover
    ex2 = excl_r * excl_r
    for n in range(points.shape[0]):
        d2 = _nearest_in_box(
            occ, inv, affine, points[n, 0], points[n, 1], points[n, 2], cap, excl_point, ex2
        )
        out[n] = -math.inf if d2 < 0.0 else math.sqrt(d2)  # outside the image: a collision


@numba.njit(cache=True)
def _smallest(occ, inv, affine, cap, excl_point, excl_r, points):  # pragma: no cover
    # the smallest distance over all points: each point's search box shrinks to the
    # smallest distance found so far, so only the first points near an obstacle pay for
    # a wide box
    ex2 = excl_r * excl_r
    best = cap * cap
    for n in range(points.shape[0]):
        r = math.sqrt(best)
        d2 = _nearest_in_box(
            occ, inv, affine, points[n, 0], points[n, 1], points[n, 2], r, excl_point, ex2
        )
        if d2 < 0.0:
            return -math.inf  # outside the image: a collision in this model
        if d2 < best:
            best = d2
    return math.sqrt(best)


#: The first pass of :func:`smallest_obstacle_distance` looks this far (mm) beyond the
#: given floor; only when nothing lies within it does a second pass look up to the cap.
_NEAR_PASS_MM: float = 2.0


def smallest_obstacle_distance(
    obstacles: VoxelObstacles,
    points: np.ndarray,
    *,
    cap_mm: float,
    near_mm: float = 0.0,
    exclude_near=None,
    exclusion_mm: float = 0.0,
) -> float:
    """The smallest distance from any of the points to an obstacle voxel centre, capped:
    ``min(nearest_obstacle_distance(...))`` without each point's own distance.

    Parameters
    ----------
    obstacles : VoxelObstacles
    points : ndarray, shape (n, 3), float64
        World points (RAS, mm); checked by the caller (finite, C-contiguous).
    cap_mm : float
        The answer is at most this.
    near_mm : float
        Where the answer is expected to lie above (e.g. the collision threshold): a first
        pass looks up to ``near_mm + 2`` mm only, a second up to the cap when the first
        finds nothing.
    exclude_near : array_like, shape (3,), optional
    exclusion_mm : float

    Returns
    -------
    float
        ``-inf`` when a point lies outside the image; ``cap_mm`` for no points.

    Examples
    --------
    >>> occ = np.zeros((10, 10, 10), bool); occ[5, 5, 5] = True
    >>> obs = VoxelObstacles(occ, np.eye(4), needle_diameter_mm=1.0)
    >>> smallest_obstacle_distance(obs, np.array([[5.0, 5.0, 7.0], [1.0, 1.0, 1.0]]), cap_mm=3.0)
    2.0
    """
    cap = float(cap_mm)
    ex = (
        np.zeros(3)
        if exclude_near is None
        else np.ascontiguousarray(exclude_near, dtype=np.float64).reshape(3)
    )
    r = 0.0 if exclude_near is None else float(exclusion_mm)
    args = (obstacles.occupancy, obstacles.inv_affine, obstacles.affine)
    first = min(cap, float(near_mm) + _NEAR_PASS_MM)
    d = _smallest(*args, first, ex, r, points)
    if d < first or first >= cap:
        return d
    return _smallest(*args, cap, ex, r, points)


def nearest_obstacle_distance(
    obstacles: VoxelObstacles,
    points,
    *,
    cap_mm: float,
    exclude_near=None,
    exclusion_mm: float = 0.0,
) -> np.ndarray:
    """Distance from points to the nearest obstacle voxel centre, capped.

    Parameters
    ----------
    obstacles : VoxelObstacles
    points : array_like, shape (n, 3)
        World points (RAS, mm).
    cap_mm : float
        Distances beyond this come back as ``cap_mm``.
    exclude_near : array_like, shape (3,), optional
        Obstacle centres closer than ``exclusion_mm`` to this point are ignored.
    exclusion_mm : float

    Returns
    -------
    ndarray, shape (n,)
        ``-inf`` for points outside the image (a collision in this model).

    Examples
    --------
    >>> occ = np.zeros((10, 10, 10), bool); occ[5, 5, 5] = True
    >>> obs = VoxelObstacles(occ, np.eye(4), needle_diameter_mm=1.0)
    >>> nearest_obstacle_distance(obs, [[5.0, 5.0, 7.0], [1.0, 1.0, 1.0]], cap_mm=3.0).tolist()
    [2.0, 3.0]
    """
    p, _ = as_points(points, "points")
    cap = as_positive(cap_mm, "cap_mm")
    ex = (
        np.zeros(3)
        if exclude_near is None
        else np.asarray(exclude_near, dtype=np.float64).reshape(3)
    )
    r = 0.0 if exclude_near is None else float(exclusion_mm)
    out = np.empty(p.shape[0])
    _nearest(obstacles.occupancy, obstacles.inv_affine, obstacles.affine, cap, ex, r, p, out)
    return out
