"""Unions and intersections of atoms as distance fields (:class:`AtomField`), their plain
numpy references, and baking a phantom's structures onto voxel grids."""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Mapping

import numpy as np

from needlekit._validation import as_positive
from needlekit.anatomy.fields import ComplementField, DistanceField
from needlekit.anatomy.phantoms._atom_kernels import (
    ATOM_ERROR_BOUND_MM,
    BAKE_PADDING_MM,
    BALL_OUT,
    CELL_PADDING_MM,
    CELL_SIZE_MM,
    DIRECT_MAX_ATOMS,
    HALF_SPACE,
    MAX_BAKED_VOXELS,
    PARALLEL_MIN_POINTS,
    ROUND_CONE,
    _atom_bounds,
    _build_cells,
    _eval_grid,
    _eval_grid_cells,
    _eval_points,
    _eval_points_serial,
)
from needlekit.anatomy.voxel import VoxelSDF, grid_for_bounds
from needlekit.errors import InvalidInputError

# ----------------------------------------------------------------------------------------
# references (plain numpy, independent formulations)


def round_cone_distance_reference(points, a, b, ra: float, rb: float, *, n_angles: int = 4001):
    """Signed distance to the convex hull of two balls by its support function.

    The solid is one of revolution; in the half-plane (axial ``s``, radial ``w``) of a
    point its section is the convex hull ``K`` of two discs, and for a convex set
    ``sd(p) = max_n (n . p - h_K(n))`` over unit ``n``, with ``h_K(n) = max(n . c_a + ra,
    n . c_b + rb)``. The maximum over the angle of ``n`` is taken on a grid and refined by
    golden-section search: slow, independent of the closed form of the kernel.

    Parameters
    ----------
    points : array_like, shape (n, 3)
        World points (mm).
    a, b : array_like, shape (3,)
    ra, rb : float
    n_angles : int
        Grid of normal angles before refinement.

    Returns
    -------
    ndarray, shape (n,)
        Signed distances (mm).
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    axis = b - a
    length = float(np.linalg.norm(axis))
    u = axis / length if length > 0 else np.array([0.0, 0.0, 1.0])
    rel = p - a
    s = rel @ u
    w = np.linalg.norm(rel - s[:, None] * u, axis=1)

    def f(theta):
        ns, nw = np.cos(theta), np.sin(theta)
        return ns * s[..., None] + nw * w[..., None] - np.maximum(ra, ns * length + rb)

    grid = np.linspace(0.0, np.pi, n_angles)
    vals = f(grid[None, :])
    best = np.argmax(vals, axis=1)
    step = np.pi / (n_angles - 1)
    lo = np.maximum(grid[best] - step, 0.0)
    hi = np.minimum(grid[best] + step, np.pi)
    g = (math.sqrt(5.0) - 1.0) / 2.0

    def f1(t):
        return np.cos(t) * s + np.sin(t) * w - np.maximum(ra, np.cos(t) * length + rb)

    for _ in range(80):
        m1 = hi - g * (hi - lo)
        m2 = lo + g * (hi - lo)
        left = f1(m1) > f1(m2)
        hi = np.where(left, m2, hi)
        lo = np.where(left, lo, m1)
    return np.maximum(f1(0.5 * (lo + hi)), vals.max(axis=1))


def atom_distance_reference(kind: int, q: np.ndarray, points) -> np.ndarray:
    """Plain numpy signed distance of points to one atom (the oracle of the kernel).

    Parameters
    ----------
    kind : int
    q : ndarray, shape (16,)
        The atom's parameters (from :func:`round_cone`, :func:`plate`, ...).
    points : array_like, shape (n, 3)

    Returns
    -------
    ndarray, shape (n,)
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if kind == ROUND_CONE:
        if q[12] != 0.0:
            return np.linalg.norm(p - q[0:3], axis=1) - q[6]
        return round_cone_distance_reference(p, q[0:3], q[3:6], q[6], q[7])
    if kind == HALF_SPACE:
        return (p - q[0:3]) @ q[3:6]
    if kind == BALL_OUT:
        return q[3] - np.linalg.norm(p - q[0:3], axis=1)
    rel = p - q[0:3]
    s, t, h = rel @ q[3:6], rel @ q[6:9], rel @ q[9:12]
    # nearest point of the planar rounded rectangle: clamp to the inner rectangle, then
    # step out by at most the corner radius
    inner = np.stack(
        [np.clip(s, -(q[12] - q[15]), q[12] - q[15]), np.clip(t, -(q[13] - q[15]), q[13] - q[15])],
        axis=1,
    )
    off = np.stack([s, t], axis=1) - inner
    n = np.linalg.norm(off, axis=1, keepdims=True)
    near = inner + off * np.minimum(1.0, q[15] / np.where(n > 0, n, 1.0))
    planar = np.linalg.norm(np.stack([s, t], axis=1) - near, axis=1)
    return np.sqrt(planar**2 + h**2) - q[14]


# ----------------------------------------------------------------------------------------
# the field


class AtomField(DistanceField):
    """Exact signed distance to a union or intersection of atoms (module notes).

    Parameters
    ----------
    atoms : sequence of (int, ndarray)
        ``(kind, params)`` pairs from :func:`round_cone`, :func:`half_space`,
        :func:`ball_outside`, :func:`plate`.
    op : {"union", "intersection"}
        ``min`` (exact outside) or ``max`` (exact inside) of the atoms' distances.

    Examples
    --------
    >>> from needlekit.anatomy.phantoms._atom_kernels import round_cone
    >>> f = AtomField([round_cone([0, 0, 0], [0, 0, 30], 4.0, 2.0)])
    >>> f.signed_distance([[10.0, 0.0, 15.0], [0.0, 0.0, 35.0]]).round(6).tolist()
    [6.977753, 3.0]
    """

    error_bound_mm = ATOM_ERROR_BOUND_MM

    def __init__(self, atoms, op: str = "union") -> None:
        if op not in ("union", "intersection"):
            raise InvalidInputError("op", f"expected 'union' or 'intersection', got {op!r}")
        if len(atoms) == 0:
            raise InvalidInputError("atoms", "needs at least one atom")
        self.kinds = np.array([k for k, _ in atoms], dtype=np.int64)
        self.params = np.ascontiguousarray(np.stack([q for _, q in atoms]), dtype=np.float64)
        self.kinds.flags.writeable = False
        self.params.flags.writeable = False
        self.op = op
        self._is_max = op == "intersection"
        boxes = np.stack([_atom_bounds(k, q) for k, q in atoms])
        if self._is_max:
            self._box = np.stack([boxes[:, 0].max(axis=0), boxes[:, 1].min(axis=0)])
        else:
            self._box = np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
        self._cells = None

    def __len__(self) -> int:
        return len(self.kinds)

    def __repr__(self) -> str:
        return f"AtomField({len(self)} atoms, op={self.op!r})"

    def content_key(self) -> tuple:
        """A key of the field's contents: equal for two fields only when they give the
        same distances (the same atoms in the same order, the same operation).

        Returns
        -------
        tuple
            Hashable: the operation and a SHA-256 of the atoms' kinds and parameters.
        """
        digest = hashlib.sha256(np.ascontiguousarray(self.kinds).view(np.uint8))
        digest.update(np.ascontiguousarray(self.params).view(np.uint8))
        return ("AtomField", self.op, self.params.shape, digest.digest())

    @property
    def atoms(self) -> list:
        """The ``(kind, params)`` pairs."""
        return list(zip(self.kinds.tolist(), self.params, strict=True))

    @classmethod
    def union_of(cls, fields) -> AtomField:
        """One union of the atoms of several union fields (their common acceleration
        cells keep candidate lists short where one structure is far and another near).

        Parameters
        ----------
        fields : sequence of AtomField
            Unions.

        Returns
        -------
        AtomField
        """
        if any(f.op != "union" for f in fields):
            raise InvalidInputError("fields", "only unions can be merged")
        return cls([a for f in fields for a in f.atoms])

    def bounds(self) -> np.ndarray:
        """Box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm) holding the solid.

        Returns
        -------
        ndarray, shape (2, 3)
        """
        return self._box.copy()

    def _acceleration(self, cover=None):
        """Cells (module notes) covering the solid's box plus :data:`CELL_PADDING_MM`
        and, if given, the box ``cover``; empty arrays when evaluated directly."""
        if self._is_max or len(self) <= DIRECT_MAX_ATOMS:
            return (
                np.zeros(3),
                1.0,
                np.ones(3, dtype=np.int64),
                np.zeros(0, np.int64),
                np.zeros(0, np.int32),
            )
        box = self._box + np.array([[-CELL_PADDING_MM], [CELL_PADDING_MM]])
        if cover is not None:
            box = np.stack([np.minimum(box[0], cover[0]), np.maximum(box[1], cover[1])])
        if self._cells is not None:
            origin, h, shape = self._cells[:3]
            if np.all(origin <= box[0]) and np.all(origin + h * shape >= box[1]):
                return self._cells
            box = np.stack([np.minimum(box[0], origin), np.maximum(box[1], origin + h * shape)])
        self._cells = _build_cells(self.kinds, self.params, box, CELL_SIZE_MM)
        return self._cells

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        out = np.empty(points.shape[0])
        origin, h, shape, offsets, items = self._acceleration()
        kernel = _eval_points if points.shape[0] >= PARALLEL_MIN_POINTS else _eval_points_serial
        kernel(
            self.kinds,
            self.params,
            self._is_max,
            origin,
            h,
            shape,
            offsets,
            items,
            np.ascontiguousarray(points),
            out,
        )
        return out

    def sample_grid(self, affine, shape, *, out=None, negate_max: bool = False) -> np.ndarray:
        """The field at the voxel centres of an axis-aligned grid.

        Parameters
        ----------
        affine : ndarray, shape (4, 4)
            Voxel->RAS affine with a diagonal isotropic spacing (from
            :func:`~needlekit.anatomy.voxel.grid_for_bounds`).
        shape : tuple of int
            Grid shape ``(i, j, k)``.
        out : ndarray of float32, shape ``shape``, optional
            Array to write (or combine) into.
        negate_max : bool
            Combine as ``out = max(out, -d)`` (the free space left by an obstacle)
            instead of storing ``d``.

        Returns
        -------
        ndarray of float32, shape ``shape``
            Signed distances (mm).
        """
        a = np.asarray(affine, dtype=np.float64)
        h = float(a[0, 0])
        if not np.allclose(a[:3, :3], h * np.eye(3)) or h <= 0:
            raise InvalidInputError("affine", "expected a diagonal isotropic voxel->RAS affine")
        shp = tuple(int(v) for v in shape)
        if int(np.prod(shp, dtype=np.int64)) > MAX_BAKED_VOXELS:
            raise InvalidInputError(
                "voxel_size_mm",
                f"{h:g} mm would need a grid of {shp} voxels (> {MAX_BAKED_VOXELS:.1e}); "
                "use a larger voxel size",
            )
        if out is None:
            if negate_max:
                raise InvalidInputError("out", "negate_max needs an array to combine into")
            out = np.full(shp, np.nan, dtype=np.float32)  # a voxel left out fails loudly
        grid_box = np.stack([a[:3, 3] - h, a[:3, 3] + h * np.array(shp)])  # one voxel more
        origin, ch, cshape, offsets, items = self._acceleration(cover=grid_box)
        if offsets.shape[0] > 0:
            _eval_grid_cells(
                self.kinds,
                self.params,
                origin,
                ch,
                cshape,
                offsets,
                items,
                a[:3, 3].copy(),
                h,
                negate_max,
                out,
            )
        else:
            _eval_grid(self.kinds, self.params, self._is_max, a[:3, 3].copy(), h, negate_max, out)
        return out

    def bake_on(self, affine, shape) -> VoxelSDF:
        """:meth:`sample_grid` as a :class:`~needlekit.anatomy.voxel.VoxelSDF`.

        Parameters
        ----------
        affine : ndarray, shape (4, 4)
        shape : tuple of int

        Returns
        -------
        VoxelSDF
            Value error 0 (exact samples): ``error_bound_mm`` is the half voxel diagonal
            plus float32 rounding, on the measured side (module notes).
        """
        return VoxelSDF(self.sample_grid(affine, shape), affine, value_error_mm=0.0)

    def bake(self, voxel_size_mm: float, padding_mm: float = BAKE_PADDING_MM) -> VoxelSDF:
        """Bake the field on an axis-aligned grid around :meth:`bounds`.

        Parameters
        ----------
        voxel_size_mm : float
            Isotropic spacing (mm), > 0.
        padding_mm : float
            Margin (mm) of the grid around the solid.

        Returns
        -------
        VoxelSDF
        """
        h = as_positive(voxel_size_mm, "voxel_size_mm")
        affine, shape = grid_for_bounds(self._box, h, padding_mm)
        return self.bake_on(affine, shape)

    def release_cells(self) -> None:
        """Drop the acceleration cells (rebuilt on the next query) to free memory.

        Returns
        -------
        None
        """
        self._cells = None


# ----------------------------------------------------------------------------------------
# baking a phantom's structures on one grid


def _union_box(boxes) -> np.ndarray:
    b = np.stack(list(boxes))
    return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])


def bake_structures(
    exact: Mapping[str, AtomField],
    *,
    bake,
    voxel_size_mm: float,
    region: str | None = None,
    obstacles=(),
    own_grids: bool = False,
    padding_mm: float = BAKE_PADDING_MM,
):
    """Bake structures on one grid and build the scene's combined obstacle field.

    Parameters
    ----------
    exact : mapping of str to AtomField
        Exact geometry by structure name.
    bake : sequence of str
        Structures to bake into :class:`~needlekit.anatomy.voxel.VoxelSDF` grids.
    voxel_size_mm : float
    region : str, optional
        The allowed region: the combined field is then the complement of the free space
        ``max(region, -obstacle_1, ...)`` (exact inside the free space); without one, it
        is the union of the obstacles.
    obstacles : sequence of str
        Obstacles in the combined field (those that can meet the free space).
    own_grids : bool
        Bake each structure on a grid around itself (small structures far apart)
        instead of on the combined field's grid.
    padding_mm : float

    Returns
    -------
    baked : dict of str to VoxelSDF
    combined : DistanceField
        For :class:`~needlekit.anatomy.scene.Scene`'s ``obstacle_field``: one voxel
        lookup instead of one per structure, same error bound.
    timings : dict of str to float
        Seconds per step.
    """
    names = list(bake) + ([region] if region else []) + list(obstacles)
    affine, shape = grid_for_bounds(
        _union_box(exact[n].bounds() for n in names), voxel_size_mm, padding_mm
    )
    baked: dict[str, VoxelSDF] = {}
    timings: dict[str, float] = {}
    for name in bake:
        t0 = time.perf_counter()
        baked[name] = (
            exact[name].bake(voxel_size_mm, padding_mm)
            if own_grids
            else exact[name].bake_on(affine, shape)
        )
        exact[name].release_cells()
        timings[name] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if region is not None:
        vals = exact[region].sample_grid(affine, shape)
        for name in obstacles:
            if name in baked and not own_grids:  # max(vals, -baked), slab by slab
                src = baked[name].values
                for i in range(0, shape[0], 16):
                    np.maximum(vals[i : i + 16], -src[i : i + 16], out=vals[i : i + 16])
            else:
                exact[name].sample_grid(affine, shape, out=vals, negate_max=True)
        combined = ComplementField(VoxelSDF(vals, affine, value_error_mm=0.0))
    else:
        union = AtomField.union_of([exact[name] for name in obstacles])
        combined = VoxelSDF(union.sample_grid(affine, shape), affine, value_error_mm=0.0)
    timings["combined"] = time.perf_counter() - t0
    return baked, combined, timings
