"""Voxel grids and binary masks: orthogonal voxel->RAS affines, grids around a box,
cropping and downsampling masks, and the surface offset of a mask's signed distance.

The error analysis behind :func:`mask_surface_offset` is in :mod:`needlekit.anatomy.voxel`.
"""

from __future__ import annotations

import edt
import numpy as np

from needlekit._validation import as_positive, as_scalar
from needlekit.errors import InvalidInputError
from needlekit.memory import refuse_if_too_big

__all__ = [
    "AFFINE_ORTHOGONALITY_TOL",
    "DEFAULT_MASK_PADDING_MM",
    "MASK_OFFSET_MAX_FRACTION",
    "crop_mask",
    "downsample_mask",
    "grid_for_bounds",
    "mask_edt",
    "mask_surface_offset",
]

#: Largest |cos| of the angle between two affine columns still treated as orthogonal.
#: NIfTI stores the sform in float32 (relative rounding 6e-8), so real orthogonal affines
#: read back with defects ~1e-7; 1e-5 admits them while a defect that small moves a point
#: of a 500 mm grid by at most 0.005 mm (added to the error bound).
AFFINE_ORTHOGONALITY_TOL: float = 1e-5

#: Default margin (mm) kept around a mask's structure when cropping before the EDT. More
#: than a needle radius plus the safety margins planners use (<= 5 mm), so every distance a
#: planner compares with is interpolated from the grid, not extrapolated.
DEFAULT_MASK_PADDING_MM: float = 10.0

#: Cap on the surface offset ``a`` of a mask SDF as a fraction of the smallest spacing:
#: keeps every unset voxel centre at >= h_min / 4 outside (and set ones inside), so the
#: zero level set separates set from unset centres even for very anisotropic voxels.
MASK_OFFSET_MAX_FRACTION: float = 0.75


# ----------------------------------------------------------------------------------------
# affine checks


def _orthogonal_affine(affine, name: str) -> tuple[np.ndarray, np.ndarray, float]:
    """Validate a voxel->world affine with orthogonal columns.

    Returns the affine (4, 4), the spacings (3,) (column norms, mm) and the
    orthogonality defect (largest |cos| between columns).
    """
    a = np.asarray(affine, dtype=np.float64)
    if a.shape != (4, 4):
        raise InvalidInputError(name, f"expected a 4x4 voxel->RAS affine, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InvalidInputError(name, "must be finite, got NaN or infinity")
    if np.abs(a[3] - [0.0, 0.0, 0.0, 1.0]).max() > 1e-12:
        raise InvalidInputError(name, f"last row must be [0, 0, 0, 1], got {a[3]}")
    m = a[:3, :3]
    spacing = np.linalg.norm(m, axis=0)
    if np.any(spacing <= 0.0):
        raise InvalidInputError(name, f"degenerate: voxel spacings {spacing} (mm) must be > 0")
    unit = m / spacing
    cos = np.abs(unit.T @ unit - np.eye(3)).max()
    if cos > AFFINE_ORTHOGONALITY_TOL:
        raise InvalidInputError(
            name,
            f"axes are sheared (largest |cos| between voxel axes {cos:.2e} > "
            f"{AFFINE_ORTHOGONALITY_TOL:g}); resample the volume onto an orthogonal grid",
        )
    return a, spacing, float(cos)


def mask_surface_offset(spacing_mm) -> tuple[float, float]:
    """Offset subtracted from centre-to-centre EDT distances of a mask, and the resulting
    error at the voxel centres against the mask's surface (see the module notes).

    Parameters
    ----------
    spacing_mm : array_like, shape (3,)
        Voxel spacings (mm).

    Returns
    -------
    offset_mm : float
        ``a = min((r + h_min / 2) / 2, MASK_OFFSET_MAX_FRACTION * h_min)``.
    value_error_mm : float
        ``max(a - h_min / 2, r - a)``, the largest error of a stored value.

    Examples
    --------
    >>> a, e = mask_surface_offset([1.0, 1.0, 1.0])
    >>> round(a, 4), round(e, 4)
    (0.683, 0.183)
    """
    h = np.asarray(spacing_mm, dtype=np.float64)
    r = 0.5 * float(np.linalg.norm(h))
    half_min = 0.5 * float(h.min())
    a = min(0.5 * (r + half_min), MASK_OFFSET_MAX_FRACTION * 2.0 * half_min)
    return a, max(a - half_min, r - a)


def mask_edt(mask: np.ndarray, spacing_mm, threads: int = 1) -> np.ndarray:
    """Euclidean distance (mm, float32) from each set voxel centre of a boolean mask to
    the nearest unset one (0 at unset voxels); the grid's border is not a boundary.

    The ``edt`` package's transform, given the mask's bytes as ``uint8`` 0/1 labels: the
    same values as a boolean input (one label against the background; the tests compare
    both with SciPy's transform), and on this package's masks about twice as fast (edt
    3.1: a lung's free space 0.36 -> 0.19 s per transform on 2 cores, a start's 40 x 40 x
    34 window 4.1 -> 2.0 ms).

    Parameters
    ----------
    mask : ndarray of bool, shape (i, j, k)
    spacing_mm : sequence of 3 floats
        Voxel spacings along the array's axes.
    threads : int

    Returns
    -------
    ndarray of float32, shape (i, j, k)
    """
    m = np.ascontiguousarray(mask, dtype=bool)
    aniso = tuple(float(s) for s in spacing_mm)
    return edt.edt(m.view(np.uint8), anisotropy=aniso, black_border=False, parallel=int(threads))


def grid_for_bounds(bounds, voxel_size_mm: float, padding_mm: float):
    """An axis-aligned grid (RAS axes) covering a box plus padding.

    Parameters
    ----------
    bounds : array_like, shape (2, 3)
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm, RAS); must be finite.
    voxel_size_mm : float
        Isotropic spacing (mm), > 0.
    padding_mm : float
        Margin (mm) added on every side, >= 0.

    Returns
    -------
    affine : ndarray, shape (4, 4)
        Voxel->RAS affine (diagonal spacing, origin at voxel (0, 0, 0)).
    shape : tuple of int
        Grid shape ``(i, j, k)``, at least 2 along every axis.

    Raises
    ------
    InvalidInputError
        A grid whose voxels (a byte each, at least: any grid holds a mask) would need more
        memory than the machine has, named ``voxel_size_mm``
        (:func:`~needlekit.memory.refuse_if_too_big`).

    Examples
    --------
    >>> affine, shape = grid_for_bounds([[0, 0, 0], [10, 5, 1]], 1.0, 2.0)
    >>> shape, affine[:3, 3].tolist()
    ((15, 10, 6), [-2.0, -2.0, -2.0])
    """
    b = np.asarray(bounds, dtype=np.float64)
    if b.shape != (2, 3) or not np.all(np.isfinite(b)) or np.any(b[1] < b[0]):
        raise InvalidInputError("bounds", f"expected a finite (2, 3) box with min <= max, got {b}")
    h = as_positive(voxel_size_mm, "voxel_size_mm")
    pad = as_scalar(padding_mm, "padding_mm")
    if pad < 0:
        raise InvalidInputError("padding_mm", f"must be >= 0, got {pad}")
    lo = b[0] - pad
    n = np.maximum(np.ceil((b[1] + pad - lo) / h) + 1, 2)  # float: no overflow
    cells = float(np.prod(n))
    refuse_if_too_big(cells, "voxel_size_mm", f"a {h:g} mm grid ({cells:.3g} voxels)")
    affine = np.diag([h, h, h, 1.0])
    affine[:3, 3] = lo
    return affine, tuple(int(v) for v in n)


# ----------------------------------------------------------------------------------------
# mask helpers


def _as_mask(mask, name: str = "mask") -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim != 3:
        raise InvalidInputError(name, f"expected a 3-D array (i, j, k), got shape {m.shape}")
    if m.dtype != np.bool_:
        if not (np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)):
            raise InvalidInputError(name, f"expected booleans or 0/1 numbers, got {m.dtype}")
        if np.issubdtype(m.dtype, np.floating) and np.isnan(m).any():
            raise InvalidInputError(name, "contains NaN")
        bad = (m != 0) & (m != 1)
        if bad.any():
            vals = np.unique(m[bad])[:5]
            raise InvalidInputError(name, f"expected 0/1 values, found also {vals.tolist()}")
        m = m != 0
    if m.size == 0:
        raise InvalidInputError(name, f"is empty, shape {m.shape}")
    return m


def _mask_and_affine(mask, affine) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(mask, "data") and hasattr(mask, "affine"):
        if affine is not None and not np.allclose(affine, mask.affine):
            raise InvalidInputError("affine", "differs from the affine the mask carries")
        mask, affine = mask.data, mask.affine
    if affine is None:
        raise InvalidInputError("affine", "a plain array needs its voxel->RAS affine")
    return _as_mask(mask), np.asarray(affine, dtype=np.float64)


def _bbox(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Index bounding box (inclusive) of the set voxels, or None if there are none."""
    lo, hi = [], []
    for axis in range(3):
        other = tuple(a for a in range(3) if a != axis)
        idx = np.flatnonzero(mask.any(axis=other))
        if idx.size == 0:
            return None
        lo.append(idx[0])
        hi.append(idx[-1])
    return np.array(lo), np.array(hi)


def _window(mask: np.ndarray, affine: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Sub-array ``lo..hi`` (inclusive, may reach beyond the array: filled with False)."""
    shape = np.array(mask.shape)
    out = np.zeros(tuple(int(v) for v in hi - lo + 1), dtype=bool)
    src_lo = np.maximum(lo, 0)
    src_hi = np.minimum(hi, shape - 1)
    dst_lo = src_lo - lo
    dst_hi = dst_lo + (src_hi - src_lo)
    out[tuple(slice(a, b + 1) for a, b in zip(dst_lo, dst_hi, strict=True))] = mask[
        tuple(slice(a, b + 1) for a, b in zip(src_lo, src_hi, strict=True))
    ]
    shifted = affine.copy()
    shifted[:3, 3] = affine[:3, :3] @ lo + affine[:3, 3]
    return out, shifted


def crop_mask(mask, affine, padding_mm: float = DEFAULT_MASK_PADDING_MM):
    """Crop a mask to its set voxels plus a margin (zero-padding where the margin passes
    the array's edge), with the affine of the cropped grid.

    Parameters
    ----------
    mask : array_like of bool, shape (i, j, k)
        Set voxels mark the structure.
    affine : array_like, shape (4, 4)
        Voxel->RAS affine (mm) of ``mask``.
    padding_mm : float
        Margin (mm) kept on every side: ``ceil(padding_mm / h)`` voxels along an axis of
        spacing ``h``.

    Returns
    -------
    cropped : ndarray of bool, shape (i', j', k')
    cropped_affine : ndarray, shape (4, 4)
        Voxel->RAS affine of ``cropped``; world positions of voxels are unchanged.

    Examples
    --------
    >>> m = np.zeros((50, 50, 50), bool); m[20:23, 30, 10] = True
    >>> c, a = crop_mask(m, np.eye(4), padding_mm=2.0)
    >>> c.shape, a[:3, 3].tolist(), int(c.sum())
    ((7, 5, 5), [18.0, 28.0, 8.0], 3)
    """
    m = _as_mask(mask)
    a, spacing, _ = _orthogonal_affine(affine, "affine")
    pad = as_scalar(padding_mm, "padding_mm")
    if pad < 0:
        raise InvalidInputError("padding_mm", f"must be >= 0, got {pad}")
    box = _bbox(m)
    if box is None:
        raise InvalidInputError("mask", "no voxel is set: nothing to crop to")
    pad_vox = np.ceil(pad / spacing - 1e-9).astype(np.int64)
    return _window(m, a, box[0] - pad_vox, box[1] + pad_vox)


def downsample_mask(mask, affine, factor: int):
    """Coarser mask: a coarse voxel is set when any of its ``factor**3`` fine voxels is.

    The coarse structure contains the fine one (conservative for obstacles), and every
    point of its surface lies within one coarse voxel diagonal of the fine structure.

    Parameters
    ----------
    mask : array_like of bool, shape (i, j, k)
    affine : array_like, shape (4, 4)
        Voxel->RAS affine of ``mask``.
    factor : int
        Fine voxels per coarse voxel along each axis, >= 1.

    Returns
    -------
    coarse : ndarray of bool, shape (ceil(i / factor), ceil(j / factor), ceil(k / factor))
    coarse_affine : ndarray, shape (4, 4)
        Voxel->RAS affine of ``coarse``: spacing ``factor`` times larger, coarse centres at
        the centres of their fine blocks.

    Examples
    --------
    >>> m = np.zeros((4, 4, 4), bool); m[1, 2, 3] = True
    >>> c, a = downsample_mask(m, np.eye(4), 2)
    >>> c.shape, np.argwhere(c).tolist(), a[0].tolist()
    ((2, 2, 2), [[0, 1, 1]], [2.0, 0.0, 0.0, 0.5])
    """
    m = _as_mask(mask)
    a, _, _ = _orthogonal_affine(affine, "affine")
    f = int(factor)
    if f != factor or f < 1:
        raise InvalidInputError("factor", f"expected a whole number >= 1, got {factor}")
    n = -(-np.array(m.shape) // f)
    padded = np.zeros(tuple(n * f), dtype=bool)
    padded[: m.shape[0], : m.shape[1], : m.shape[2]] = m
    coarse = padded.reshape(n[0], f, n[1], f, n[2], f).any(axis=(1, 3, 5))
    scale = np.diag([f, f, f, 1.0])
    scale[:3, 3] = (f - 1) / 2.0
    return coarse, a @ scale
