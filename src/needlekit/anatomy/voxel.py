"""Signed distance grids over voxels: the fast distance field for segmented anatomy.

A :class:`VoxelSDF` stores signed distances (mm, negative inside) at the voxel centres of a
grid placed in the world by a voxel->RAS affine with orthogonal axes (flips and axis
permutations allowed, shear refused), and answers queries by trilinear interpolation in a
numba kernel (:func:`_trilinear`), held by the tests to the numpy reference
:func:`trilinear_reference` and to ``scipy.ndimage.map_coordinates(order=1)``.

Error bound (``h`` = voxel spacings, ``r = |h| / 2`` the half voxel diagonal)
    If the stored values are within ``e`` of the true signed distance ``D`` at every voxel
    centre, the interpolant ``I(x) = sum_k w_k v_k`` is within ``e + r`` of ``D(x)``:
    ``|I - D| <= sum_k w_k |v_k - D(c_k)| + sum_k w_k |D(c_k) - D(x)|`` and, ``D`` being
    1-Lipschitz, the last sum is at most ``sum_k w_k |c_k - x| <= sqrt(sum_k w_k |c_k -
    x|^2) = sqrt(sum_i h_i^2 t_i (1 - t_i)) <= r`` (``t_i`` the cell coordinates; equality
    at a cell centre, e.g. for a structure of zero size there). Add float32 storage
    rounding (``max |v| 2^-24``) and, for affines orthogonal only to
    :data:`AFFINE_ORTHOGONALITY_TOL`, the defect times the grid diagonal.

Surface of a mask (:meth:`VoxelSDF.from_mask`)
    Each voxel owns its box (the grid cell centred on its centre). The mask's surface is
    the boundary of the union ``U`` of the boxes of the set voxels; voxels beyond the array
    count as unset. The boxes are the Voronoi cells of the centres, so this is also the
    surface halfway between set and unset centres. For an unset centre ``c`` with nearest
    set centre at EDT distance ``d``, the nearest box ``B_v`` lies between the balls of
    radius ``h_min / 2`` and ``r`` about ``v``, so ``d - r <= D(c) <= d - h_min / 2``
    (symmetrically inside, with the EDT of the unset voxels). Storing ``d - a`` with
    ``a = (r + h_min / 2) / 2`` (capped at :data:`MASK_OFFSET_MAX_FRACTION` ``* h_min``)
    gives ``e = max(a - h_min / 2, r - a)``, i.e. ``(r - h_min / 2) / 2``: 0.183 h for
    isotropic voxels, 0.124 mm for the Med-RAD lungs (0.55 x 0.55 x 0.7 mm), whose whole
    bound ``e + r`` is 0.65 mm.

Points outside the grid
    The grid must hold the whole structure (constructors check it; masks are padded). For
    ``x`` outside the box of voxel centres with projection ``p`` onto it, every structure
    point ``s`` satisfies ``|x - s|^2 >= |x - p|^2 + |p - s|^2``, so the field returns
    ``sqrt(|x - p|^2 + max(I(p), 0)^2)``: never more than ``D(x) + error_bound_mm`` and
    at least ``(D(x) - error_bound_mm) / sqrt(2)``, i.e. conservative (a clearance may be
    underestimated there, never overestimated beyond the bound).
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np

from needlekit._validation import as_scalar
from needlekit.anatomy._trilinear import (
    FEW_POINTS,
    PARALLEL_MIN_POINTS,
    _trilinear,
    _trilinear_gradient,
    _trilinear_gradient_serial,
    _trilinear_serial,
    trilinear_few,
    trilinear_reference,
)
from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.grids import (
    AFFINE_ORTHOGONALITY_TOL,
    DEFAULT_MASK_PADDING_MM,
    MASK_OFFSET_MAX_FRACTION,
    _bbox,
    _mask_and_affine,
    _orthogonal_affine,
    _window,
    crop_mask,
    downsample_mask,
    grid_for_bounds,
    mask_edt,
    mask_surface_offset,
)
from needlekit.errors import InvalidInputError

__all__ = [
    "AFFINE_ORTHOGONALITY_TOL",
    "DEFAULT_MASK_PADDING_MM",
    "MASK_OFFSET_MAX_FRACTION",
    "VoxelSDF",
    "crop_mask",
    "downsample_mask",
    "grid_error_bounds",
    "grid_for_bounds",
    "mask_surface_offset",
    "trilinear_reference",
]

#: Relative rounding of a float32 grid value (half an ulp).
FLOAT32_REL_ROUNDING: float = 2.0**-24

#: Points per chunk when sampling a function on a grid (24 MB of float64 points).
SAMPLE_CHUNK_POINTS: int = 1 << 20


# ----------------------------------------------------------------------------------------
# the field


def _index_box_to_world(affine: np.ndarray, lo, hi) -> np.ndarray:
    """World box ``(2, 3)`` around an index box (corners mapped through the affine)."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])  # fmt: skip
    world = corners @ affine[:3, :3].T + affine[:3, 3]
    return np.stack([world.min(axis=0), world.max(axis=0)])


def grid_error_bounds(values: np.ndarray, spacing, defect: float, value_error_mm: float):
    """The value error (with float32 rounding) and the whole error bound of a grid of
    signed distances (module notes).

    Parameters
    ----------
    values : ndarray of float32, shape (i, j, k)
    spacing : ndarray, shape (3,)
        Voxel spacings (mm).
    defect : float
        The affine's orthogonality defect.
    value_error_mm : float
        Largest ``|values - D|`` at the voxel centres before rounding.

    Returns
    -------
    value_error_mm, error_bound_mm : float
    """
    vmax = max(float(values.max()), -float(values.min()))  # max |v| without a temporary
    extent = float(np.linalg.norm(spacing * (np.array(values.shape) - 1)))
    value_error = value_error_mm + vmax * FLOAT32_REL_ROUNDING
    interpolation = 0.5 * float(np.linalg.norm(spacing))
    return value_error, value_error + interpolation + defect * (extent + vmax)


class _MaskGrid:
    """The grid :meth:`VoxelSDF.from_mask` transforms: the set voxels' index box, the
    padding around it, the window ``lo..hi`` and the structure's world box (one place, so
    that :meth:`VoxelSDF.mask_bounds` gives the very numbers of a built field)."""

    def __init__(self, shape, set_box, affine, padding_mm, crop) -> None:
        a, self.spacing, _ = _orthogonal_affine(np.asarray(affine, dtype=np.float64), "affine")
        pad_mm = as_scalar(padding_mm, "padding_mm")
        if pad_mm < 0:
            raise InvalidInputError("padding_mm", f"must be >= 0, got {pad_mm}")
        if set_box is None:
            raise InvalidInputError("mask", "no voxel is set: the structure is empty")
        self.box = (np.asarray(set_box[0]), np.asarray(set_box[1]))
        self.offset, self.value_error = mask_surface_offset(self.spacing)
        r = 0.5 * float(np.linalg.norm(self.spacing))
        # enough unset layers that boundary centres pass _check_structure_inside
        min_pad = np.ceil((self.value_error + r + self.offset) / self.spacing).astype(np.int64) + 1
        pad = np.maximum(np.ceil(pad_mm / self.spacing - 1e-9).astype(np.int64), min_pad)
        lo, hi = self.box[0] - pad, self.box[1] + pad
        if not crop:
            lo = np.minimum(lo, 0)
            hi = np.maximum(hi, np.array(shape) - 1)
        self.lo, self.hi, self.affine = lo, hi, a

    def box_world(self) -> np.ndarray:
        shifted = self.affine.copy()  # the window's affine, as grids._window makes it
        shifted[:3, 3] = self.affine[:3, :3] @ self.lo + self.affine[:3, 3]
        return _index_box_to_world(
            shifted, self.box[0] - self.lo - 0.5, self.box[1] - self.lo + 0.5
        )


class VoxelSDF(DistanceField):
    """Signed distance field sampled at the voxel centres of an orthogonal grid.

    Parameters
    ----------
    values : array_like, shape (i, j, k)
        Signed distances (mm, negative inside) at voxel centres; stored as float32,
        read-only. At least 2 voxels along every axis.
    affine : array_like, shape (4, 4)
        Voxel index -> RAS (mm) affine; orthogonal axes (flips, permutations allowed).
    value_error_mm : float
        Largest ``|values - D|`` at the voxel centres (``D`` the true signed distance).
        :attr:`error_bound_mm` adds interpolation (half voxel diagonal), float32
        rounding and the affine's orthogonality defect (module notes).

    Raises
    ------
    InvalidInputError
        Bad shapes, NaN, sheared affine, or a structure reaching the grid boundary (a
        boundary value ``<= value_error_mm +`` half voxel diagonal): the outside-grid rule
        needs the whole structure inside the grid.

    Examples
    --------
    >>> affine, shape = grid_for_bounds([[-10, -10, -10], [10, 10, 10]], 1.0, 3.0)
    >>> sdf = VoxelSDF.from_function(lambda p: np.linalg.norm(p, axis=1) - 8.0, affine, shape)
    >>> abs(float(sdf.signed_distance([3.0, 0.2, 0.0])) + 4.8) <= sdf.error_bound_mm
    True
    >>> round(sdf.error_bound_mm, 3)  # half diagonal of a 1 mm voxel (+ rounding)
    0.866
    """

    def __init__(
        self, values, affine, *, value_error_mm: float = 0.0, _box: np.ndarray | None = None
    ) -> None:
        vals = np.asarray(values)
        if vals.ndim != 3 or min(vals.shape) < 2:
            raise InvalidInputError(
                "values", f"expected a 3-D grid with >= 2 voxels per axis, got {vals.shape}"
            )
        vals = np.ascontiguousarray(vals, dtype=np.float32)
        # ``_box`` (private: from_mask, whose distance transforms give finite values and
        # know the structure's box) skips the finiteness pass and the box pass
        if _box is None and not np.all(np.isfinite(vals)):
            raise InvalidInputError("values", "must be finite, got NaN or infinity")
        a, spacing, defect = _orthogonal_affine(affine, "affine")
        e = as_scalar(value_error_mm, "value_error_mm")
        if e < 0:
            raise InvalidInputError("value_error_mm", f"must be >= 0, got {e}")
        vals.flags.writeable = False
        a.flags.writeable = False
        self.values = vals
        self.affine = a
        self.inv_affine = np.linalg.inv(a)
        self.spacing_mm = spacing
        self.shape = vals.shape
        #: Interpolation error of a 1-Lipschitz function on this grid: the half voxel
        #: diagonal (module notes).
        self.interpolation_error_mm = 0.5 * float(np.linalg.norm(spacing))
        #: Largest |stored value - true distance| at voxel centres (incl. float32 rounding).
        self.value_error_mm, self.error_bound_mm = grid_error_bounds(vals, spacing, defect, e)
        self._check_structure_inside()
        self._box = self._structure_box() if _box is None else _box

    # -- construction ---------------------------------------------------------------------

    def _boundary_min(self) -> float:
        v = self.values
        return float(
            min(v[0].min(), v[-1].min(), v[:, 0].min(), v[:, -1].min(), v[:, :, 0].min(),
                v[:, :, -1].min())
        )  # fmt: skip

    def _check_structure_inside(self) -> None:
        # any boundary-face point lies within r of a boundary centre c, where
        # D >= v(c) - value_error - r: this keeps the structure off the grid boundary
        need = self.value_error_mm + self.interpolation_error_mm
        low = self._boundary_min()
        if not low > need:
            raise InvalidInputError(
                "values",
                f"the structure reaches the grid boundary (a boundary voxel holds {low:.3f} mm"
                f" <= {need:.3f} mm = value error + half voxel diagonal); pad the grid",
            )

    def _structure_box(self) -> np.ndarray:
        # a structure point y lies in the box of some centre c with D(c) <= r, so
        # v(c) <= r + value_error: the union of those boxes holds the structure
        sel = self.values <= self.interpolation_error_mm + self.value_error_mm
        box = _bbox(sel)
        if box is None:
            return np.full((2, 3), np.nan)
        return self._index_box_to_world(box[0] - 0.5, box[1] + 0.5)

    def _index_box_to_world(self, lo, hi) -> np.ndarray:
        return _index_box_to_world(self.affine, lo, hi)

    @classmethod
    def from_mask(
        cls,
        mask,
        affine=None,
        *,
        crop: bool = True,
        padding_mm: float = DEFAULT_MASK_PADDING_MM,
        n_threads: int | None = None,
    ) -> VoxelSDF:
        """Signed distance to a binary mask's surface by two Euclidean distance transforms.

        Parameters
        ----------
        mask : array_like of bool, shape (i, j, k), or an object with ``data`` and
            ``affine`` attributes (e.g. :class:`needlekit.io.volumes.Mask`)
            Set voxels mark the structure (0/1 numbers are accepted).
        affine : array_like, shape (4, 4), optional
            Voxel->RAS affine (mm), orthogonal axes; taken from ``mask`` when it has one.
        crop : bool
            Crop the grid to the structure plus ``padding_mm`` before the EDT (less memory
            and time); the field outside the grid is the conservative extrapolation.
        padding_mm : float
            Margin (mm) kept around the structure when cropping. Whatever ``crop``, the
            grid is zero-padded where needed so the structure stays inside it.
        n_threads : int, optional
            Threads of the EDT (default: all CPUs).

        Returns
        -------
        VoxelSDF
            ``value_error_mm`` from :func:`mask_surface_offset`; the surface is the
            boundary of the union of the set voxels' boxes (module notes).

        Examples
        --------
        >>> m = np.zeros((20, 20, 20), bool); m[5:15, 5:15, 5:15] = True
        >>> sdf = VoxelSDF.from_mask(m, np.diag([0.5, 0.5, 0.5, 1.0]))
        >>> d = float(sdf.signed_distance([2.0, 3.0, 3.0]))  # surface at x = 2.25 mm
        >>> abs(d - 0.25) <= sdf.error_bound_mm
        True
        """
        m, a = _mask_and_affine(mask, affine)
        g = _MaskGrid(m.shape, _bbox(m), a, padding_mm, crop)
        m, a = _window(m, g.affine, g.lo, g.hi)
        threads = int(n_threads) if n_threads else (os.cpu_count() or 1)
        values = mask_edt(~m, g.spacing, threads)
        values -= np.float32(g.offset)
        inside = mask_edt(m, g.spacing, threads)
        np.subtract(np.float32(g.offset), inside, out=values, where=m)
        del inside
        return cls(values, a, value_error_mm=g.value_error, _box=g.box_world())

    @staticmethod
    def mask_bounds(
        mask,
        affine,
        *,
        offset=None,
        shape=None,
        crop: bool = True,
        padding_mm: float = DEFAULT_MASK_PADDING_MM,
        tight: bool = False,
    ) -> np.ndarray:
        """What :meth:`bounds` of ``from_mask(mask, affine, crop=crop,
        padding_mm=padding_mm)`` returns, bit for bit, without the distance transforms:
        for a structure built lazily that is only drawn or boxed (one pass over the mask).

        Parameters
        ----------
        mask : array_like of bool, shape (i, j, k)
            The structure's voxels, or a crop of them holding every set voxel.
        affine : array_like, shape (4, 4)
            Voxel->RAS affine (mm) of the whole grid.
        offset : array_like of int, shape (3,), optional
            Index of the crop's first voxel in the whole grid (default: none).
        shape : tuple of int, optional
            The whole grid's shape (default: the mask's).
        crop, padding_mm :
            As :meth:`from_mask`.
        tight : bool, optional
            The mask is cut to its set voxels (a stored mask): its box is its shape, unread.

        Returns
        -------
        ndarray, shape (2, 3)
            ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (RAS, mm).

        Examples
        --------
        >>> m = np.zeros((20, 20, 20), bool); m[5:15, 5:15, 5:15] = True
        >>> a = np.diag([0.5, 0.5, 0.5, 1.0])
        >>> bool(np.array_equal(VoxelSDF.mask_bounds(m, a), VoxelSDF.from_mask(m, a).bounds()))
        True
        """
        m = np.asarray(mask, dtype=bool)
        tight = tight and m.size > 1  # a one-voxel crop may be an empty mask's
        box = (np.zeros(3, np.intp), np.array(m.shape, np.intp) - 1) if tight else _bbox(m)
        if box is not None and offset is not None:
            off = np.asarray(offset, dtype=np.int64).reshape(3)
            box = (box[0] + off, box[1] + off)
        full = m.shape if shape is None else tuple(int(v) for v in shape)
        return _MaskGrid(full, box, affine, padding_mm, crop).box_world()

    @classmethod
    def from_function(
        cls,
        fn: Callable[[np.ndarray], np.ndarray] | DistanceField,
        affine,
        shape,
        *,
        function_error_mm: float | None = None,
        chunk_points: int = SAMPLE_CHUNK_POINTS,
    ) -> VoxelSDF:
        """Sample a signed distance function at the voxel centres (in chunks).

        Parameters
        ----------
        fn : callable or DistanceField
            Maps world points ``(n, 3)`` (RAS, mm) to signed distances ``(n,)`` (mm).
        affine : array_like, shape (4, 4)
            Voxel->RAS affine (orthogonal axes), e.g. from :func:`grid_for_bounds`.
        shape : tuple of int
            Grid shape ``(i, j, k)``.
        function_error_mm : float, optional
            Largest error of ``fn`` against the true signed distance (default: the
            field's ``error_bound_mm``, or 0 for a plain function).
        chunk_points : int
            Points evaluated per call of ``fn``.

        Returns
        -------
        VoxelSDF
            Error bound ``function_error_mm +`` half voxel diagonal (+ rounding): the
            interpolation error of the 1-Lipschitz true distance (module notes); it does
            not depend on how smooth ``fn`` is.

        Examples
        --------
        >>> affine, shape = grid_for_bounds([[-5, -5, -5], [5, 5, 5]], 0.5, 2.0)
        >>> ball = VoxelSDF.from_function(lambda p: np.linalg.norm(p, axis=1) - 4.0, affine, shape)
        >>> ball.shape
        (29, 29, 29)
        """
        a, _, _ = _orthogonal_affine(affine, "affine")
        try:
            shp = tuple(int(v) for v in shape)
        except TypeError as exc:
            raise InvalidInputError("shape", f"expected 3 whole numbers, got {shape}") from exc
        if len(shp) != 3 or min(shp) < 2:
            raise InvalidInputError("shape", f"expected 3 whole numbers >= 2, got {shape}")
        if isinstance(fn, DistanceField):
            err = fn.error_bound_mm if function_error_mm is None else function_error_mm
            call = fn.signed_distance
        else:
            err = 0.0 if function_error_mm is None else function_error_mm
            call = fn
        err = as_scalar(err, "function_error_mm")
        chunk = max(int(chunk_points), 1)
        n = shp[0] * shp[1] * shp[2]
        values = np.empty(n, dtype=np.float32)
        for start in range(0, n, chunk):
            idx = np.stack(np.unravel_index(np.arange(start, min(start + chunk, n)), shp), axis=1)
            pts = idx @ a[:3, :3].T + a[:3, 3]
            d = np.asarray(call(pts), dtype=np.float64)
            if d.shape != (len(pts),):
                raise InvalidInputError(
                    "fn", f"expected {len(pts)} distances for {len(pts)} points, got {d.shape}"
                )
            values[start : start + len(pts)] = d
        return cls(values.reshape(shp), a, value_error_mm=err)

    # -- storing and restoring ------------------------------------------------------------

    def prepared_state(self) -> dict:
        """What, besides :attr:`values`, rebuilds this field exactly with
        :meth:`from_prepared_state`: plain floats and lists (JSON round-trips them exactly).

        Returns
        -------
        dict
            ``affine`` (4x4 list), ``value_error_mm``, ``error_bound_mm`` and ``box``
            (2x3 list, the :meth:`bounds` box; NaN when empty).
        """
        return {
            "affine": self.affine.tolist(),
            "value_error_mm": float(self.value_error_mm),
            "error_bound_mm": float(self.error_bound_mm),
            "box": self._box.tolist(),
        }

    @classmethod
    def from_prepared_state(cls, values, state: dict) -> VoxelSDF:
        """The field :meth:`prepared_state` described, around already-checked values.

        The whole-grid checks of the constructor (finite values, structure inside the grid)
        and the passes that compute the error bound and the structure's box are skipped:
        ``state`` carries their results. Use it only for values and state that a
        :class:`VoxelSDF` produced (e.g. read back from the prepared-anatomy cache, which
        checks every byte against its signed record); the values may be a read-only memory map.

        Parameters
        ----------
        values : ndarray of float32, shape (i, j, k)
            C-contiguous; kept as given (no copy).
        state : dict
            From :meth:`prepared_state`.

        Returns
        -------
        VoxelSDF
            Answers every query bit for bit as the field that gave ``state``.

        Raises
        ------
        InvalidInputError
            Values not a C-contiguous float32 3-D grid, or a bad affine.

        Examples
        --------
        >>> m = np.zeros((8, 8, 8), bool); m[3:5, 3:5, 3:5] = True
        >>> a = VoxelSDF.from_mask(m, np.eye(4))
        >>> b = VoxelSDF.from_prepared_state(a.values, a.prepared_state())
        >>> bool(b.signed_distance([1.0, 2.0, 3.0]) == a.signed_distance([1.0, 2.0, 3.0]))
        True
        """
        vals = np.asarray(values)
        if (
            vals.ndim != 3
            or min(vals.shape) < 2
            or vals.dtype != np.float32
            or not vals.flags.c_contiguous
        ):
            raise InvalidInputError(
                "values",
                f"expected a C-contiguous float32 3-D grid, got {vals.dtype} {vals.shape}",
            )
        a, spacing, _ = _orthogonal_affine(state["affine"], "affine")
        if vals.flags.writeable:
            vals = vals.view()
            vals.flags.writeable = False
        a.flags.writeable = False
        sdf = cls.__new__(cls)
        sdf.values = vals
        sdf.affine = a
        sdf.inv_affine = np.linalg.inv(a)
        sdf.spacing_mm = spacing
        sdf.shape = vals.shape
        sdf.interpolation_error_mm = 0.5 * float(np.linalg.norm(spacing))
        sdf.value_error_mm = float(state["value_error_mm"])
        sdf.error_bound_mm = float(state["error_bound_mm"])
        sdf._box = np.array(state["box"], dtype=np.float64).reshape(2, 3)
        return sdf

    # -- queries --------------------------------------------------------------------------

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        if points.shape[0] <= FEW_POINTS:
            return trilinear_few(self.values, self.inv_affine, points)
        out = np.empty(points.shape[0])
        kernel = _trilinear if points.shape[0] >= PARALLEL_MIN_POINTS else _trilinear_serial
        kernel(self.values, self.inv_affine, points, out)
        return out

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        if points.shape[0] <= FEW_POINTS:
            return trilinear_few(self.values, self.inv_affine, points, gradient=True)[1]
        out = np.empty(points.shape[0])
        grad = np.empty((points.shape[0], 3))
        big = points.shape[0] >= PARALLEL_MIN_POINTS
        kernel = _trilinear_gradient if big else _trilinear_gradient_serial
        kernel(self.values, self.inv_affine, points, out, grad)
        return grad

    @property
    def lipschitz_bound(self) -> float:
        """A Lipschitz constant of the interpolated field (computed once, slab by slab).

        Inside a cell each partial derivative of the trilinear interpolant is a weighted
        mean of the four differences of neighbouring values along that axis, over the
        spacing, so ``|grad I| <= sqrt(sum_i (max |diff_i| / h_i)^2)``. Beyond the grid the
        extrapolation ``sqrt(|x - p|^2 + max(I(p), 0)^2)`` changes at rate 1 across the
        box and as ``I`` along it, so the constant is also at least 1.

        Returns
        -------
        float
        """
        cached = getattr(self, "_lipschitz", None)
        if cached is None:
            v = self.values
            slab = max(1, (1 << 22) // max(1, v.shape[1] * v.shape[2]))
            most = np.zeros(3)
            for i0 in range(0, v.shape[0], slab):
                block = v[i0 : i0 + slab + 1]
                for axis in range(3):
                    if block.shape[axis] > 1:
                        d = float(np.max(np.abs(np.diff(block, axis=axis))))
                        most[axis] = max(most[axis], d)
            # float32 differences round by at most 2^-24 of the values
            per_axis = most * (1.0 + 1e-6) / self.spacing_mm
            cached = max(1.0, float(np.sqrt(np.sum(per_axis**2))))
            self._lipschitz = cached
        return cached

    def bounds(self) -> np.ndarray:
        """World box (RAS, mm) of the voxel boxes that can hold the structure.

        Returns
        -------
        ndarray, shape (2, 3)
            ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``; NaN if no voxel qualifies.
        """
        return self._box.copy()

    def grid_bounds(self) -> np.ndarray:
        """World box (RAS, mm) of the voxel centres, beyond which values are extrapolated.

        Returns
        -------
        ndarray, shape (2, 3)
        """
        n = np.array(self.shape) - 1
        corners = np.array([[x, y, z] for x in (0, n[0]) for y in (0, n[1]) for z in (0, n[2])])
        world = corners @ self.affine[:3, :3].T + self.affine[:3, 3]
        return np.stack([world.min(axis=0), world.max(axis=0)])

    def voxel_centres(self) -> np.ndarray:
        """World positions of all voxel centres, in C order.

        Returns
        -------
        ndarray, shape (i * j * k, 3)
            RAS (mm).
        """
        idx = np.indices(self.shape).reshape(3, -1).T
        return idx @ self.affine[:3, :3].T + self.affine[:3, 3]
