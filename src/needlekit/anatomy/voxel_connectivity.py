"""Is the goal connected to the start through free voxels? A proof of infeasibility.

The reference planner refuses a problem whose "reachable workspace is not connected" to the
goal (``docs/notes/steerable-reference-planner.md``, section 5, check 6). This is the same
idea made sound for the ``voxel_centres`` collision model:

- a valid path's samples (every ``spacing`` mm) each keep ``min_dist`` from every obstacle
  voxel centre outside the start exclusion; the voxel centre nearest a sample lies within
  half a voxel diagonal ``h`` of it, so that voxel keeps ``min_dist - h`` from them: it is
  *free*;
- consecutive samples are closer than the smallest voxel spacing, so their nearest voxels
  are 26-neighbours;
- every sample lies in the ellipsoid ``|p - s| + |p - g| <= l_max + tau`` (a path through
  ``p`` is at least that long), so its voxel centre lies in the one grown by ``2 h``;
- the last sample lies within ``tau`` of the goal, its voxel centre within ``tau + h``.

So when no 26-connected chain of free voxels inside that ellipsoid leads from the start's
voxel to within ``tau + h`` of the goal, no valid path exists: ``INFEASIBLE``, proved. The
fill (a greedy best-first search in a numba kernel, nearest the goal first) stops as soon
as it reaches the goal.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit.anatomy.occupancy import VoxelObstacles, box_half_widths, voxel_centre

__all__ = ["goal_connected"]


@numba.njit(cache=True, inline="always")
def _slot(keys, key):  # pragma: no cover - compiled
    """Open addressing: the slot holding ``key``, or the empty slot where it goes."""
    mask = keys.shape[0] - 1
    h = (key * -7046029254386353131) & mask  # Fibonacci hashing (0x9E3779B97F4A7C15)
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


@numba.njit(cache=True)
def _fill(occ, affine, inv, start, goal, excl_r, free_r, reach, budget):  # pragma: no cover
    ni, nj, nk = occ.shape
    r0, r1, r2 = box_half_widths(affine, free_r)
    fr2, ex2, reach2 = free_r * free_r, excl_r * excl_r, reach * reach

    def centre(i, j, k):
        return voxel_centre(affine, i, j, k)

    def free(i, j, k):
        # no obstacle centre (outside the start exclusion) closer than free_r
        x, y, z = centre(i, j, k)
        for a in range(max(i - r0, 0), min(i + r0 + 1, ni)):
            for b in range(max(j - r1, 0), min(j + r1 + 1, nj)):
                for c in range(max(k - r2, 0), min(k + r2 + 1, nk)):
                    if not occ[a, b, c]:
                        continue
                    cx, cy, cz = centre(a, b, c)
                    if (cx - x) ** 2 + (cy - y) ** 2 + (cz - z) ** 2 >= fr2:
                        continue
                    if (cx - start[0]) ** 2 + (cy - start[1]) ** 2 + (cz - start[2]) ** 2 < ex2:
                        continue
                    return False
        return True

    def inside(x, y, z):
        ds = math.sqrt((x - start[0]) ** 2 + (y - start[1]) ** 2 + (z - start[2]) ** 2)
        dg = math.sqrt((x - goal[0]) ** 2 + (y - goal[1]) ** 2 + (z - goal[2]) ** 2)
        return ds + dg <= budget

    # greedy best-first: voxels wait in buckets by their distance to the goal (in steps of
    # the smallest spacing), the nearest bucket first; when the goal is reachable the fill
    # heads straight for it, and when it is not, it exhausts the region all the same.
    # Memory grows with the voxels reached (a hash set of visited voxels and a list of
    # queued ones), not with the region's box.
    step = min(
        math.sqrt(affine[0, 0] ** 2 + affine[1, 0] ** 2 + affine[2, 0] ** 2),
        math.sqrt(affine[0, 1] ** 2 + affine[1, 1] ** 2 + affine[2, 1] ** 2),
        math.sqrt(affine[0, 2] ** 2 + affine[1, 2] ** 2 + affine[2, 2] ** 2),
    )
    n_buckets = int(math.ceil(budget / step)) + 2
    first = np.full(n_buckets, -1, dtype=np.int64)
    keys = np.full(4096, -1, dtype=np.int64)  # visited voxels (linear index), a hash set
    n_keys = 0
    queued = np.empty(1024, dtype=np.int64)  # queued voxels' linear index ...
    nxt = np.empty(1024, dtype=np.int64)  # ... and the next entry of their bucket
    u = inv[0, 0] * start[0] + inv[0, 1] * start[1] + inv[0, 2] * start[2] + inv[0, 3]
    v = inv[1, 0] * start[0] + inv[1, 1] * start[1] + inv[1, 2] * start[2] + inv[1, 3]
    w = inv[2, 0] * start[0] + inv[2, 1] * start[1] + inv[2, 2] * start[2] + inv[2, 3]
    si, sj, sk = int(round(u)), int(round(v)), int(round(w))
    q0 = (si * nj + sj) * nk + sk
    keys[_slot(keys, q0)] = q0
    n_keys = 1
    x, y, z = centre(si, sj, sk)
    b0 = min(
        int(math.sqrt((x - goal[0]) ** 2 + (y - goal[1]) ** 2 + (z - goal[2]) ** 2) / step),
        n_buckets - 1,
    )
    queued[0] = q0
    nxt[0] = -1
    first[b0] = 0
    n_queued = 1
    low = b0
    seen = 1
    while low < n_buckets:
        if first[low] < 0:
            low += 1
            continue
        e = first[low]
        first[low] = nxt[e]
        q = queued[e]
        gi = q // (nj * nk)
        gj = (q // nk) % nj
        gk = q % nk
        x, y, z = centre(gi, gj, gk)
        if (x - goal[0]) ** 2 + (y - goal[1]) ** 2 + (z - goal[2]) ** 2 <= reach2:
            return True, seen
        for di in range(-1, 2):
            for dj in range(-1, 2):
                for dk in range(-1, 2):
                    ci, cj, ck = gi + di, gj + dj, gk + dk
                    if ci < 0 or cj < 0 or ck < 0 or ci >= ni or cj >= nj or ck >= nk:
                        continue
                    a = (ci * nj + cj) * nk + ck
                    h = _slot(keys, a)
                    if keys[h] == a:
                        continue
                    keys[h] = a
                    n_keys += 1
                    if 2 * n_keys > keys.shape[0]:
                        keys = _grow(keys)
                    cx, cy, cz = centre(ci, cj, ck)
                    if not inside(cx, cy, cz) or not free(ci, cj, ck):
                        continue
                    seen += 1
                    if n_queued == queued.shape[0]:
                        queued = np.concatenate((queued, np.empty_like(queued)))
                        nxt = np.concatenate((nxt, np.empty_like(nxt)))
                    dg = math.sqrt((cx - goal[0]) ** 2 + (cy - goal[1]) ** 2 + (cz - goal[2]) ** 2)
                    b = min(int(dg / step), n_buckets - 1)
                    queued[n_queued] = a
                    nxt[n_queued] = first[b]
                    first[b] = n_queued
                    n_queued += 1
                    if b < low:
                        low = b
    return False, seen


def goal_connected(
    obstacles: VoxelObstacles,
    start_mm: np.ndarray,
    goal_mm: np.ndarray,
    *,
    max_length_mm: float,
    goal_tolerance_mm: float,
    exclusion_mm: float,
    spacing_mm: float,
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

    Returns
    -------
    connected : bool or None
        False proves that no valid path exists; None when the argument does not apply
        (samples as far apart as the voxels, or a start outside the image).
    visited : int
        Voxels the fill reached.
    """
    if spacing_mm >= float(np.min(obstacles.spacing_mm)):
        return None, 0
    start = np.ascontiguousarray(start_mm, dtype=np.float64).reshape(3)
    goal = np.ascontiguousarray(goal_mm, dtype=np.float64).reshape(3)
    h = obstacles.voxel_radius_mm
    budget = max_length_mm + goal_tolerance_mm + 2.0 * h
    s_ijk = np.rint(obstacles.inv_affine[:3, :3] @ start + obstacles.inv_affine[:3, 3])
    if np.any(s_ijk < 0) or np.any(s_ijk > np.array(obstacles.occupancy.shape) - 1):
        return None, 0
    free_r = obstacles.min_distance_mm - h
    connected, n = _fill(
        obstacles.occupancy,
        obstacles.affine,
        obstacles.inv_affine,
        start,
        goal,
        float(exclusion_mm),
        float(free_r),
        float(goal_tolerance_mm + h),
        float(budget),
    )
    return bool(connected), int(n)
