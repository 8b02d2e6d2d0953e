"""Facts about a scene's structures: kind, extent, voxel size, volume; and surface meshes.

Used by ``needlekit scene info`` and the 3D views. Volumes of voxel grids count the voxels
inside (exact for the grid); other shapes are measured on a regular grid over their box.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.anatomy.fields import (
    ComplementField,
    DistanceField,
    LazyField,
    OffsetField,
    TransformedField,
    UnionField,
)
from needlekit.anatomy.scene import Scene, Structure
from needlekit.anatomy.voxel import VoxelSDF

__all__ = ["StructureSummary", "summarize", "summarize_scene", "surface_mesh", "sample_grid"]

#: Cells per axis when a non-voxel field is sampled to measure its volume or draw it.
SAMPLE_CELLS_PER_AXIS: int = 72


@dataclass(frozen=True)
class StructureSummary:
    """What ``needlekit scene info`` prints for one structure.

    Attributes
    ----------
    name, role, kind : str
        ``kind`` is the field's type (``VoxelSDF``, ``Sphere``, ...).
    extent_mm : ndarray, shape (2, 3)
        Bounding box (RAS mm); infinite for unbounded shapes.
    voxel_size_mm : ndarray, shape (3,) or None
        Grid spacing of voxel fields.
    grid_shape : tuple of int or None
    volume_ml : float
        Volume inside the surface (1 ml = 1000 mm^3); ``inf`` for unbounded shapes.
    error_bound_mm : float
    source : str
    """

    name: str
    role: str
    kind: str
    extent_mm: np.ndarray
    voxel_size_mm: np.ndarray | None
    grid_shape: tuple[int, int, int] | None
    volume_ml: float
    error_bound_mm: float
    source: str

    def to_dict(self) -> dict:
        """JSON-ready form of the summary.

        Returns
        -------
        dict
            Plain numbers and lists; missing or infinite values become ``None``.
        """

        def clean(a):
            return (
                None
                if a is None
                else [
                    [None if not np.isfinite(v) else float(v) for v in r] for r in np.atleast_2d(a)
                ]
            )

        return {
            "name": self.name,
            "role": self.role,
            "kind": self.kind,
            "extent_mm": clean(self.extent_mm),
            "voxel_size_mm": None
            if self.voxel_size_mm is None
            else [float(v) for v in self.voxel_size_mm],
            "grid_shape": None if self.grid_shape is None else list(self.grid_shape),
            "volume_ml": None if not np.isfinite(self.volume_ml) else float(self.volume_ml),
            "error_bound_mm": float(self.error_bound_mm),
            "source": self.source,
        }


def _unwrap(field: DistanceField) -> DistanceField:
    return field.get() if isinstance(field, LazyField) else field


def _voxel_of(field: DistanceField) -> VoxelSDF | None:
    f = _unwrap(field)
    return f if isinstance(f, VoxelSDF) else None


def sample_grid(field: DistanceField, bounds: np.ndarray, cells: int = SAMPLE_CELLS_PER_AXIS):
    """Sample a field on a regular grid over a box (one cell of margin).

    Parameters
    ----------
    field : DistanceField
    bounds : array_like, shape (2, 3)
        Finite box (mm).
    cells : int
        Samples along the longest axis.

    Returns
    -------
    values : ndarray, shape (i, j, k)
    origin : ndarray, shape (3,)
        World position of sample (0, 0, 0).
    spacing : float
        Sample spacing (mm), the same along every axis.
    """
    b = np.asarray(bounds, dtype=float)
    size = b[1] - b[0]
    spacing = float(max(size.max(), 1e-6)) / cells
    lo = b[0] - spacing
    shape = np.ceil((size + 2 * spacing) / spacing).astype(int) + 1
    axes = [lo[i] + spacing * np.arange(shape[i]) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    values = field.signed_distance(pts).reshape(tuple(shape))
    return values, lo, spacing


def summarize(structure: Structure) -> StructureSummary:
    """Summary of one structure (builds lazy fields).

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    StructureSummary
    """
    field = _unwrap(structure.field)
    extent = field.bounds()
    vox = _voxel_of(field)
    if vox is not None:
        inside = int(np.count_nonzero(vox.values < 0.0))
        volume_mm3 = inside * float(np.prod(vox.spacing_mm))
        voxel_size, shape = (
            np.asarray(vox.spacing_mm, dtype=float),
            tuple(int(s) for s in vox.shape),
        )
    elif np.all(np.isfinite(extent)):
        values, _, h = sample_grid(field, extent)
        volume_mm3 = float(np.count_nonzero(values < 0.0)) * h**3
        voxel_size, shape = None, None
    else:
        volume_mm3, voxel_size, shape = float("inf"), None, None
    kind = type(field).__name__
    if isinstance(field, (OffsetField, UnionField, TransformedField, ComplementField)):
        kind = f"{kind} (composite)"
    return StructureSummary(
        structure.name,
        structure.role.value,
        kind,
        extent,
        voxel_size,
        shape,
        volume_mm3 / 1000.0,
        float(field.error_bound_mm),
        structure.source,
    )


def summarize_scene(scene: Scene) -> list[StructureSummary]:
    """Summaries of every structure of a scene, in order.

    Parameters
    ----------
    scene : Scene

    Returns
    -------
    list of StructureSummary
    """
    return [summarize(s) for s in scene.structures]


def surface_mesh(field: DistanceField, *, max_cells: int = 160, bounds=None, crop=None):
    """Triangle mesh of a field's zero level set by marching cubes (for display).

    Voxel fields are meshed on their own grid, subsampled so that no axis has more than
    ``max_cells`` samples; other fields are sampled over their box (or ``bounds``). With
    ``crop``, only the part of the surface inside that box is meshed, at the resolution
    ``max_cells`` gives over the box (a view zoomed onto a path gets its detail, not the
    whole organ's).

    Parameters
    ----------
    field : DistanceField
    max_cells : int
        Largest number of samples along an axis.
    bounds : array_like, shape (2, 3), optional
        Box to mesh for unbounded fields (e.g. half-spaces).
    crop : array_like, shape (2, 3), optional
        Mesh only inside this box (world mm, lower and upper corners).

    Returns
    -------
    vertices : ndarray, shape (v, 3)
        World coordinates (mm).
    faces : ndarray of int, shape (f, 3)
        Empty arrays when the surface does not cross the sampled box.
    """
    from skimage.measure import marching_cubes

    # a CT structure not built whole is drawn from its coarse preview (fields.LazyField)
    if isinstance(field, LazyField) and crop is not None:
        # the window around the box at full resolution (the field itself once built)
        field = field.near_box(np.asarray(crop, dtype=float).reshape(2, 3), 1.0)
        if field is None:  # nothing of the structure near the box
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    field = field.preview(max_cells) if isinstance(field, LazyField) else field
    vox = _voxel_of(field)
    crop = None if crop is None else np.asarray(crop, dtype=float).reshape(2, 3)
    if vox is not None:
        lo, hi = np.zeros(3, dtype=int), np.asarray(vox.shape, dtype=int)
        if crop is not None:  # the index box holding the crop's 8 corners (any affine)
            corners = np.array([[crop[i, 0], crop[j, 1], crop[k, 2]]
                                for i in (0, 1) for j in (0, 1) for k in (0, 1)])  # fmt: skip
            ijk = corners @ vox.inv_affine[:3, :3].T + vox.inv_affine[:3, 3]
            lo = np.clip(np.floor(ijk.min(axis=0)).astype(int) - 1, 0, hi)
            hi = np.clip(np.ceil(ijk.max(axis=0)).astype(int) + 2, 0, hi)
        step = max(1, int(np.ceil(max(hi - lo) / max_cells)))
        window = vox.values[lo[0] : hi[0] : step, lo[1] : hi[1] : step, lo[2] : hi[2] : step]
        values = np.array(window, dtype=np.float32)  # writable copy
        affine = vox.affine.copy()
        affine[:3, 3] = affine[:3, :3] @ lo + affine[:3, 3]
        affine[:3, :3] *= step
    else:
        box = field.bounds() if bounds is None else np.asarray(bounds, dtype=float)
        if crop is not None:
            box = np.array([np.maximum(box[0], crop[0]), np.minimum(box[1], crop[1])])
            if np.any(box[1] <= box[0]):
                return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        if not np.all(np.isfinite(box)):
            return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
        values, origin, h = sample_grid(field, box, cells=max_cells)
        affine = np.diag([h, h, h, 1.0])
        affine[:3, 3] = origin
    if values.min() >= 0.0 or values.max() <= 0.0 or min(values.shape) < 2:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    verts, faces, _, _ = marching_cubes(values, level=0.0)
    world = verts @ affine[:3, :3].T + affine[:3, 3]
    return world, faces.astype(np.int64)
