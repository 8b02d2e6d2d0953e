"""Exact collision tests against obstacle voxels: distances to voxel centres, no interpolation.

A segmentation's obstacles are its obstacle voxels. :class:`VoxelObstacles` answers, for a
point ``p``, whether some obstacle voxel centre lies closer than ``min_distance_mm`` (the
needle radius plus half a voxel diagonal, plus any safety margin), or whether ``p`` is
outside the image. This is the collision model of the reference steerable-needle planner
used for the Med-RAD benchmarks (``docs/notes/steerable-reference-planner.md``, section 7):
its certified plans clear the threshold by as little as a micrometre, so planners that must
reproduce its verdicts use these exact distances, while :class:`~needlekit.anatomy.voxel.VoxelSDF`
(interpolated, with an error bound) serves clearance figures and figures.

Obstacle centres closer than ``exclusion_mm`` to an exclusion point (the needle's start on
the airway wall) are ignored: the needle leaves the airway through its wall.

The kernel visits only the voxels of the box of half-width ``min_distance_mm`` around each
query point; :func:`nearest_obstacle_distance_reference` (a KD-tree over all obstacle
centres) is the test oracle.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit._validation import as_points, as_positive, unbatch
from needlekit.anatomy.grids import _orthogonal_affine
from needlekit.errors import InvalidInputError

__all__ = [
    "VoxelObstacles",
    "BLOCK_VOXELS",
    "any_collides_unchecked",
    "box_half_widths",
    "colliding_samples",
    "nearest_obstacle_distance_reference",
    "occupied_blocks",
    "voxel_centre",
]


@numba.njit(cache=True, inline="always")
def box_half_widths(affine, radius):  # pragma: no cover - compiled
    """Voxels to either side, per axis, of a box holding every centre within ``radius``
    of a point (the search box of the voxel-centre kernels)."""
    h0 = math.sqrt(affine[0, 0] ** 2 + affine[1, 0] ** 2 + affine[2, 0] ** 2)
    h1 = math.sqrt(affine[0, 1] ** 2 + affine[1, 1] ** 2 + affine[2, 1] ** 2)
    h2 = math.sqrt(affine[0, 2] ** 2 + affine[1, 2] ** 2 + affine[2, 2] ** 2)
    return math.ceil(radius / h0), math.ceil(radius / h1), math.ceil(radius / h2)


@numba.njit(cache=True, inline="always")
def voxel_centre(affine, i, j, k):  # pragma: no cover - compiled
    """World position (mm) of voxel ``(i, j, k)``'s centre."""
    x = affine[0, 0] * i + affine[0, 1] * j + affine[0, 2] * k + affine[0, 3]
    y = affine[1, 0] * i + affine[1, 1] * j + affine[1, 2] * k + affine[1, 3]
    z = affine[2, 0] * i + affine[2, 1] * j + affine[2, 2] * k + affine[2, 3]
    return x, y, z


#: Edge (voxels) of the blocks of :attr:`VoxelObstacles.blocks`: a point whose search box
#: meets only empty blocks is clear after a few block reads instead of a read of every
#: voxel in its box (7 x 7 x 7 on a Med-RAD lung with the certified threshold).
BLOCK_VOXELS: int = 4


@numba.njit(cache=True)
def _mark_blocks(occ, out):  # pragma: no cover - compiled
    b = BLOCK_VOXELS
    ni, nj, nk = occ.shape
    for i in range(ni):
        for j in range(nj):
            for k in range(nk):
                if occ[i, j, k]:
                    out[i // b, j // b, k // b] = True


def occupied_blocks(occupancy: np.ndarray) -> np.ndarray:
    """Whether each block of :data:`BLOCK_VOXELS` voxels a side holds an obstacle voxel
    (one pass over the mask: 0.05 s for a Med-RAD lung's 84 M voxels).

    Parameters
    ----------
    occupancy : ndarray of bool, shape (i, j, k), C-contiguous

    Returns
    -------
    ndarray of bool, shape (ceil(i / 4), ceil(j / 4), ceil(k / 4)), C-contiguous

    Examples
    --------
    >>> occ = np.zeros((5, 4, 4), bool); occ[4, 0, 0] = True
    >>> occupied_blocks(occ)[:, 0, 0].tolist()
    [False, True]
    """
    b = BLOCK_VOXELS
    out = np.zeros(tuple(-(-n // b) for n in occupancy.shape), dtype=np.bool_)
    _mark_blocks(occupancy, out)
    return out


@numba.njit(cache=True, inline="always")
def _blocks_empty(blocks, i0, i1, j0, j1, k0, k1):  # pragma: no cover - compiled
    """Whether every block meeting voxels ``[i0, i1) x [j0, j1) x [k0, k1)`` is empty."""
    b = BLOCK_VOXELS
    for bi in range(i0 // b, (i1 - 1) // b + 1):
        for bj in range(j0 // b, (j1 - 1) // b + 1):
            for bk in range(k0 // b, (k1 - 1) // b + 1):
                if blocks[bi, bj, bk]:
                    return False
    return True


@numba.njit(cache=True)
def _collides(occ, blocks, inv, affine, min_dist, excl_point, excl_r, points, out):  # pragma: no cover
    ni, nj, nk = occ.shape
    # the box of voxels around a point that can hold a centre within min_dist
    r0, r1, r2 = box_half_widths(affine, min_dist)
    md2 = min_dist * min_dist
    ex2 = excl_r * excl_r
    for n in range(points.shape[0]):
        x, y, z = points[n, 0], points[n, 1], points[n, 2]
        u = inv[0, 0] * x + inv[0, 1] * y + inv[0, 2] * z + inv[0, 3]
        v = inv[1, 0] * x + inv[1, 1] * y + inv[1, 2] * z + inv[1, 3]
        w = inv[2, 0] * x + inv[2, 1] * y + inv[2, 2] * z + inv[2, 3]
        # outside the image: a negative index, or one that rounds past the last voxel
        if u < 0.0 or v < 0.0 or w < 0.0 or round(u) >= ni or round(v) >= nj or round(w) >= nk:
            out[n] = True
            continue
        ci, cj, ck = int(round(u)), int(round(v)), int(round(w))
        i0, i1 = max(ci - r0, 0), min(ci + r0 + 1, ni)
        j0, j1 = max(cj - r1, 0), min(cj + r1 + 1, nj)
        k0, k1 = max(ck - r2, 0), min(ck + r2 + 1, nk)
        hit = False
        if _blocks_empty(blocks, i0, i1, j0, j1, k0, k1):
            out[n] = hit
            continue
        for i in range(i0, i1):
            for j in range(j0, j1):
                for k in range(k0, k1):
                    if not occ[i, j, k]:
                        continue
                    cx, cy, cz = voxel_centre(affine, i, j, k)
                    d2 = (cx - x) ** 2 + (cy - y) ** 2 + (cz - z) ** 2
                    if d2 >= md2:
                        continue
                    e2 = (
                        (cx - excl_point[0]) ** 2
                        + (cy - excl_point[1]) ** 2
                        + (cz - excl_point[2]) ** 2
                    )
                    if e2 < ex2:
                        continue
                    hit = True
                    break
                if hit:
                    break
            if hit:
                break
        out[n] = hit


@numba.njit(cache=True)
def any_collides_unchecked(
    occ, blocks, inv, affine, min_dist, excl_point, excl_r, points
):  # pragma: no cover
    """Whether any of the points collides (:meth:`VoxelObstacles.collides` ``.any()``,
    stopping at the first hit, without checks): the search loops' call.

    Parameters
    ----------
    occ, blocks, inv, affine, min_dist
        A :class:`VoxelObstacles`' ``occupancy``, ``blocks``, ``inv_affine``, ``affine``
        and a threshold (its ``min_distance_mm``, or the certified rule's).
    excl_point : ndarray, shape (3,)
    excl_r : float
        Obstacle centres closer than this to ``excl_point`` are ignored.
    points : ndarray, shape (n, 3), float64, C-contiguous

    Returns
    -------
    bool
    """
    out = np.empty(1, dtype=np.bool_)
    for n in range(points.shape[0]):
        _collides(occ, blocks, inv, affine, min_dist, excl_point, excl_r, points[n : n + 1], out)
        if out[0]:
            return True
    return False


def colliding_samples(
    obstacles: VoxelObstacles, points: np.ndarray, min_distance_mm: float, excl_point, excl_r
) -> np.ndarray:
    """Which points lie closer than ``min_distance_mm`` to an obstacle voxel centre (beyond
    the exclusion), or outside the image: :meth:`VoxelObstacles.collides` at another
    threshold (the certified rule's, which adds half the sample gap).

    Parameters
    ----------
    obstacles : VoxelObstacles
    points : ndarray, shape (n, 3), float64, C-contiguous
    min_distance_mm : float
    excl_point : ndarray, shape (3,)
    excl_r : float

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    o = obstacles
    out = np.empty(points.shape[0], dtype=np.bool_)
    ex = np.ascontiguousarray(excl_point, dtype=np.float64).reshape(3)
    args = (o.occupancy, o.blocks, o.inv_affine, o.affine, float(min_distance_mm))
    _collides(*args, ex, float(excl_r), points, out)
    return out


def _read_only(a: np.ndarray) -> np.ndarray:
    """A read-only view of ``a`` (the caller's array keeps its own flag)."""
    view = a.view()
    view.flags.writeable = False
    return view


class VoxelObstacles:
    """Obstacle voxels of a segmentation, for exact point collision tests.

    Parameters
    ----------
    occupancy : array_like of bool, shape (i, j, k)
        True where a voxel is an obstacle (e.g. airway, vessels, fissures and everything
        outside the pleura).
    affine : array_like, shape (4, 4)
        Voxel index -> RAS (mm) affine with orthogonal axes.
    needle_diameter_mm : float
        The needle's diameter; half of it is kept from the obstacle voxels.
    safety_margin_mm : float
        Extra clearance.

    Attributes
    ----------
    min_distance_mm : float
        ``needle_diameter_mm / 2 + half voxel diagonal + safety_margin_mm``: a point closer
        than this to an obstacle voxel centre collides.

    Examples
    --------
    >>> occ = np.zeros((10, 10, 10), bool); occ[5, 5, 5] = True
    >>> obs = VoxelObstacles(occ, np.eye(4), needle_diameter_mm=1.0)
    >>> round(obs.min_distance_mm, 4)   # 0.5 + sqrt(3) / 2
    1.366
    >>> obs.collides([[5.0, 5.0, 6.3], [5.0, 5.0, 6.4], [-1.0, 0.0, 0.0]]).tolist()
    [True, False, True]
    """

    def __init__(
        self, occupancy, affine, *, needle_diameter_mm: float, safety_margin_mm: float = 0.0
    ):
        occ = np.asarray(occupancy)
        if occ.ndim != 3:
            raise InvalidInputError("occupancy", f"expected a 3-D mask, got shape {occ.shape}")
        # read-only views, whether the caller's arrays are (a prepared patient's, from the
        # cache) or not: numba compiles a kernel once per array type, and a writable and a
        # read-only array are two (about 2 s each for the connectivity proof's fills)
        self.occupancy = _read_only(np.ascontiguousarray(occ, dtype=np.bool_))
        self._blocks = None
        a, spacing, _ = _orthogonal_affine(affine, "affine")
        self.affine = _read_only(np.ascontiguousarray(a))
        self.inv_affine = _read_only(np.ascontiguousarray(np.linalg.inv(a)))
        self.spacing_mm = spacing
        d = as_positive(needle_diameter_mm, "needle_diameter_mm")
        m = float(safety_margin_mm)
        if not (np.isfinite(m) and m >= 0):
            raise InvalidInputError(
                "safety_margin_mm", f"must be a finite number >= 0, got {safety_margin_mm}"
            )
        self.voxel_radius_mm = 0.5 * float(np.linalg.norm(spacing))
        self.min_distance_mm = 0.5 * d + self.voxel_radius_mm + m

    @property
    def blocks(self) -> np.ndarray:
        """:func:`occupied_blocks` of the occupancy (built on first use)."""
        if self._blocks is None:
            self._blocks = occupied_blocks(self.occupancy)
        return self._blocks

    def collides(self, points, *, exclude_near=None, exclusion_mm: float = 0.0):
        """Whether points collide with the obstacle voxels (or lie outside the image).

        Parameters
        ----------
        points : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).
        exclude_near : array_like, shape (3,), optional
            Obstacle voxels whose centres lie closer than ``exclusion_mm`` to this point are
            ignored (the start of a transbronchial needle).
        exclusion_mm : float

        Returns
        -------
        bool or ndarray of bool, shape (n,)
        """
        p, single = as_points(points, "points")
        ex = (
            np.zeros(3)
            if exclude_near is None
            # contiguous: a pose's column (``pose[:3, 3]``) would compile the kernel again
            else np.ascontiguousarray(exclude_near, dtype=np.float64).reshape(3)
        )
        r = 0.0 if exclude_near is None else float(exclusion_mm)
        out = np.empty(p.shape[0], dtype=np.bool_)
        args = (self.occupancy, self.blocks, self.inv_affine, self.affine, self.min_distance_mm)
        _collides(*args, ex, r, p, out)
        return unbatch(out, single)


def nearest_obstacle_distance_reference(
    obstacles: VoxelObstacles, points, *, exclude_near=None, exclusion_mm=0.0
):
    """Distance from points to the nearest (non-excluded) obstacle voxel centre, by a
    KD-tree over all obstacle centres: the oracle of :meth:`VoxelObstacles.collides`.

    Parameters
    ----------
    obstacles : VoxelObstacles
    points : array_like, shape (n, 3)
    exclude_near : array_like, shape (3,), optional
    exclusion_mm : float

    Returns
    -------
    ndarray, shape (n,)
        ``inf`` where no obstacle centre remains.
    """
    from scipy.spatial import cKDTree

    p, _ = as_points(points, "points")
    idx = np.argwhere(obstacles.occupancy)
    centres = idx @ obstacles.affine[:3, :3].T + obstacles.affine[:3, 3]
    if exclude_near is not None:
        keep = (
            np.linalg.norm(centres - np.asarray(exclude_near, dtype=float), axis=1) >= exclusion_mm
        )
        centres = centres[keep]
    if len(centres) == 0:
        return np.full(p.shape[0], np.inf)
    d, _ = cKDTree(centres).query(p)
    return d
