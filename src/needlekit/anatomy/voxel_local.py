"""A mask's signed distance near one point, from a small window of the mask.

Deciding which structure a start point lies on, or the normal of the surface it punctures,
needs the distance to a few structures at one point. Building each structure's whole field
for that (two Euclidean distance transforms over tens of millions of voxels each) is most
of the cost of a first plan on a CT. :func:`local_mask_sdf` transforms only a window of the
mask around the point instead.

Why the window is exact near the point: an EDT value at a voxel centre ``c`` is the distance
to the nearest voxel of the other kind (set voxels for ``c`` outside, unset ones inside).
Cutting the mask to a window and padding it with unset voxels removes set voxels beyond the
window and adds unset ones beyond it, so it changes the value at ``c`` only when the true
nearest voxel of the other kind lies farther from ``c`` than the window's boundary. The
window reaches ``radius + 5`` voxel diagonals ``h`` (and 2 voxels) from the point, so a
voxel centre within ``2h`` of the point keeps its value wherever ``|d| <= radius + 3h``.
A point ``q`` within ``h`` of ``point`` interpolates the 8 centres around it, all within
``2h`` of ``point``, whose values differ from its own by at most ``h`` (the stored values
are 1-Lipschitz between centres): where the full field has ``|d(q)| <= radius`` its trilinear
value and central-difference gradient are the full field's (the grids share voxel centres).
At ``point`` itself, where the full field has ``|d| > radius``, each of the 8 centres keeps
its sign and a magnitude above ``min(|d| - h, radius + 4h)`` (outside, fewer set voxels
only lengthen the distance; inside, the added unset voxels lie ``radius + 4h`` away), so
the local value keeps its sign and exceeds ``radius``: a "within ``radius``?" test gets the
full field's answer.
"""

from __future__ import annotations

import numpy as np

from needlekit._validation import as_points, as_scalar
from needlekit.anatomy.fields import GRADIENT_STEP_MM, DistanceField
from needlekit.anatomy.grids import (
    _bbox,
    _orthogonal_affine,
    downsample_mask,
    mask_edt,
    mask_surface_offset,
)
from needlekit.anatomy.voxel import VoxelSDF, _index_box_to_world, grid_error_bounds
from needlekit.errors import InvalidInputError

__all__ = [
    "LOCAL_REACH_DIAGONALS",
    "LocalMaskField",
    "local_mask_sdf",
    "preview_mask_sdf",
    "window_around",
]

#: How far from its point (voxel diagonals) a one-point local field answers. The window
#: reaches 5 diagonals beyond the point, so a point ``q`` up to 3 diagonals away still
#: interpolates centres whose values are the full field's where ``|d(q)| <= radius``: the
#: centres lie within ``|q - point| + h`` of the point, their window reaches
#: ``radius + 5h - |q - point| - h >= radius + h`` beyond them, and they need
#: ``|d| <= radius + h`` (module notes). Two diagonals keep a diagonal of that slack.
LOCAL_REACH_DIAGONALS: float = 2.0


def window_around(affine, point_mm, radius_mm: float, half_size_mm=None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Index box (inclusive) reaching ``radius_mm + 5`` voxel diagonals and 2 voxels beyond
    a point, or beyond the world box ``point_mm +- half_size_mm``, in every direction.

    Parameters
    ----------
    affine : array_like, shape (4, 4)
        Voxel->RAS affine (orthogonal axes).
    point_mm : array_like, shape (3,)
    radius_mm : float
    half_size_mm : array_like, shape (3,), optional
        Half the sides of a world box centred on the point (default: the point alone).

    Returns
    -------
    lo, hi : ndarray of int, shape (3,)
    """
    a, spacing, _ = _orthogonal_affine(affine, "affine")
    p, single = as_points(point_mm, "point_mm")
    if not single:
        raise InvalidInputError("point_mm", f"expected one point (3,), got shape {p.shape}")
    r = as_scalar(radius_mm, "radius_mm")
    if not r >= 0:
        raise InvalidInputError("radius_mm", f"must be >= 0, got {r}")
    h = np.zeros(3) if half_size_mm is None else np.asarray(half_size_mm, dtype=float)
    if h.shape != (3,) or not np.all(np.isfinite(h) & (h >= 0)):
        raise InvalidInputError("half_size_mm", f"expected 3 finite numbers >= 0, got {h}")
    diag = float(np.linalg.norm(spacing))
    corners = p[0] + h * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    idx = np.linalg.solve(a[:3, :3], (corners - a[:3, 3]).T).T
    half = np.ceil((r + 5.0 * diag) / spacing).astype(np.int64) + 2
    lo = np.floor(idx.min(axis=0)).astype(np.int64) - half
    return lo, np.ceil(idx.max(axis=0)).astype(np.int64) + half


def local_mask_sdf(mask, affine, point_mm, radius_mm: float, half_size_mm=None) -> VoxelSDF | None:  # fmt: skip
    """Signed distance to a mask's surface that equals :meth:`VoxelSDF.from_mask`'s field
    near ``point_mm`` (or over the box ``point_mm +- half_size_mm``) wherever that field has
    ``|d| <= radius_mm``.

    Parameters
    ----------
    mask : array_like of bool, shape (i, j, k)
        The structure (a read-only memory map is fine: only the window is read).
    affine : array_like, shape (4, 4)
        Voxel->RAS affine of ``mask`` (orthogonal axes).
    point_mm : array_like, shape (3,)
    radius_mm : float
    half_size_mm : array_like, shape (3,), optional
        Half the sides of a world box around the point where the field is wanted (e.g. a
        figure's view); default the point alone.

    Returns
    -------
    LocalMaskField, VoxelSDF or None
        None when no voxel of the window is set, or, for a point, when its nearest set
        voxel lies farther than ``radius_mm`` + a voxel diagonal + the surface offset: the
        structure lies farther than ``radius_mm`` from the point (the box). For a point, a :class:`LocalMaskField`
        whose value and gradient at points within :data:`LOCAL_REACH_DIAGONALS` voxel
        diagonals of ``point_mm`` are the full field's where ``|d| <= radius_mm`` (it
        refuses farther points); for a box, a :class:`VoxelSDF` of the window, the same
        within one voxel diagonal of every point of the box (the window reaches as far
        beyond every point of the box as beyond a single point). Where the full field has
        ``|d| > radius_mm`` at the point, the local value there keeps its sign and exceeds
        ``radius_mm`` in magnitude (module notes).
    """
    m = np.asarray(mask)
    if m.ndim != 3:
        raise InvalidInputError("mask", f"expected a 3-D mask, got shape {m.shape}")
    lo, hi = window_around(affine, point_mm, radius_mm, half_size_mm)
    src_lo = np.maximum(lo, 0)
    src_hi = np.minimum(hi, np.array(m.shape) - 1)
    if np.any(src_hi < src_lo):
        return None
    src = m[tuple(slice(a, b + 1) for a, b in zip(src_lo, src_hi, strict=True))]
    if not np.any(src):
        return None
    # the whole window, beyond the array too (unset there, as the full field pads): the
    # point stays inside the grid, never in the field's extrapolated outside
    part = np.zeros(tuple(int(v) for v in hi - lo + 1), dtype=bool)
    dst_lo = src_lo - lo
    part[tuple(slice(a, a + n) for a, n in zip(dst_lo, src.shape, strict=True))] = src
    a = np.asarray(affine, dtype=np.float64).copy()
    a[:3, 3] = a[:3, :3] @ lo + a[:3, 3]
    if half_size_mm is not None:  # a box (a figure's view): the window's whole field
        return VoxelSDF.from_mask(part, a, crop=False, padding_mm=0.0, n_threads=1)
    point = np.asarray(point_mm, dtype=np.float64).reshape(3)
    if _set_voxels_beyond(part, a, point, float(radius_mm)):
        return None
    return _point_field(part, a, point)


def _set_voxels_beyond(part: np.ndarray, affine: np.ndarray, point: np.ndarray, radius: float) -> bool:  # fmt: skip
    """Whether every set centre of the window lies farther than ``radius`` + a voxel
    diagonal + the surface offset from the point: then the 8 centres the point
    interpolates (within a diagonal of it, unset) hold more than ``radius``, and so does
    the full field at the point (a set voxel beyond the window is farther still)."""
    a, spacing, _ = _orthogonal_affine(affine, "affine")
    offset, _ = mask_surface_offset(spacing)
    centres = np.argwhere(part) @ a[:3, :3].T + a[:3, 3]
    nearest = float(np.sqrt(np.min(np.sum((centres - point) ** 2, axis=1))))
    return nearest > radius + float(np.linalg.norm(spacing)) + offset


def _point_field(part: np.ndarray, affine: np.ndarray, point: np.ndarray) -> LocalMaskField:
    """The field of a window near its point: the window's distance transforms, as
    :meth:`VoxelSDF.from_mask` computes them, kept only at the centres that queries within
    :data:`LOCAL_REACH_DIAGONALS` voxel diagonals of the point interpolate.

    ``from_mask`` would pad the window with a few unset layers (its grid must hold the
    whole structure) and keep every value; one unset layer gives the same values (the
    nearest unset voxel beyond a box lies in its first outer layer, and the outer layers
    hold no set voxel), and the inner transform is skipped where the kept centres are all
    unset (their values come from the outer transform alone)."""
    a, spacing, defect = _orthogonal_affine(affine, "affine")
    diag = float(np.linalg.norm(spacing))
    reach = LOCAL_REACH_DIAGONALS * diag
    u = np.linalg.solve(a[:3, :3], point - a[:3, 3]) + 1.0  # index in the padded window
    half = np.ceil((reach + 2.0 * GRADIENT_STEP_MM) / spacing).astype(np.int64) + 1
    padded = np.pad(part, 1)
    b_lo = np.maximum(np.floor(u).astype(np.int64) - half, 0)
    b_hi = np.minimum(np.ceil(u).astype(np.int64) + half, np.array(padded.shape) - 1)
    block = tuple(slice(int(x), int(y) + 1) for x, y in zip(b_lo, b_hi, strict=True))
    offset, value_error = mask_surface_offset(spacing)
    values = mask_edt(~padded, spacing)[block]
    values -= np.float32(offset)
    inside_block = padded[block]
    if inside_block.any():
        inside = mask_edt(padded, spacing)[block]
        np.subtract(np.float32(offset), inside, out=values, where=inside_block)
    values = np.ascontiguousarray(values, dtype=np.float32)
    origin = a.copy()
    origin[:3, 3] = a[:3, :3] @ (b_lo - 1.0) + a[:3, 3]
    value_err, bound = grid_error_bounds(values, spacing, defect, value_error)
    box = _bbox(values <= 0.5 * diag + value_err)
    world_box = (
        np.full((2, 3), np.nan) if box is None
        else _index_box_to_world(origin, box[0] - 0.5, box[1] + 0.5)
    )  # fmt: skip
    state = {"affine": origin.tolist(), "value_error_mm": value_err,
             "error_bound_mm": bound, "box": world_box.tolist()}  # fmt: skip
    return LocalMaskField(VoxelSDF.from_prepared_state(values, state), point, reach)


class LocalMaskField(DistanceField):
    """A mask's signed distance near one point (:func:`local_mask_sdf`): the full field's
    value and gradient at points within ``reach_mm`` of the point wherever the full field
    has ``|d| <= radius``; farther points are refused.

    Parameters
    ----------
    grid : VoxelSDF
        The distances at the voxel centres those points interpolate (the full field's
        centres, the same values).
    point_mm : ndarray, shape (3,)
    reach_mm : float

    Raises
    ------
    InvalidInputError
        From the queries, for a point farther than ``reach_mm`` from ``point_mm``.
    """

    def __init__(self, grid: VoxelSDF, point_mm: np.ndarray, reach_mm: float) -> None:
        self.grid = grid
        self.point_mm = np.array(point_mm, dtype=np.float64).reshape(3)
        self.reach_mm = float(reach_mm)
        self.error_bound_mm = grid.error_bound_mm
        self.shape = grid.shape

    def _within_reach(self, points: np.ndarray) -> None:
        far = float(np.max(np.linalg.norm(points - self.point_mm, axis=1), initial=0.0))
        if far > self.reach_mm + 2.0 * GRADIENT_STEP_MM:
            raise InvalidInputError(
                "points",
                f"this local field answers within {self.reach_mm:.3g} mm of "
                f"{np.round(self.point_mm, 3).tolist()}, got a point {far:.3g} mm away; "
                "use the structure's whole field",
            )

    @property  # type: ignore[override]
    def lipschitz_bound(self) -> float:
        return self.grid.lipschitz_bound

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        self._within_reach(points)
        return self.grid._signed_distance(points)

    def _gradient(self, points: np.ndarray) -> np.ndarray:
        self._within_reach(points)
        return self.grid._gradient(points)

    def bounds(self) -> np.ndarray:
        """World box (RAS, mm) of the part of the structure near the point.

        Returns
        -------
        ndarray, shape (2, 3)
        """
        return self.grid.bounds()


def preview_mask_sdf(mask, affine, max_cells: int) -> VoxelSDF:
    """A coarse field of a mask to draw it whole: the mask cut to its set voxels, pooled
    (a coarse voxel is set when any of its fine voxels is) so that no axis has more than
    about ``max_cells`` voxels, and transformed.

    Parameters
    ----------
    mask : array_like of bool, shape (i, j, k)
    affine : array_like, shape (4, 4)
    max_cells : int

    Returns
    -------
    VoxelSDF
        Display only: thin structures stay visible (pooling keeps them), at most a coarse
        voxel thicker than they are; transforming the coarse grid takes a few hundredths of
        the whole mask's time.
    """
    m = np.asarray(mask)
    box = _bbox(m)
    if box is None:
        raise InvalidInputError("mask", "no voxel is set: the structure is empty")
    part = np.asarray(m[box[0][0] : box[1][0] + 1, box[0][1] : box[1][1] + 1,
                        box[0][2] : box[1][2] + 1], dtype=bool)  # fmt: skip
    a = np.asarray(affine, dtype=np.float64).copy()
    a[:3, 3] = a[:3, :3] @ box[0] + a[:3, 3]
    # the few unset layers from_mask adds must stay within max_cells too
    factor = max(1, int(np.ceil(max(part.shape) / max(int(max_cells) - 8, 2))))
    coarse, coarse_affine = downsample_mask(part, a, factor)
    return VoxelSDF.from_mask(coarse, coarse_affine, padding_mm=0.0, n_threads=1)
