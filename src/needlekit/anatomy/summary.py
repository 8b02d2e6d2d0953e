"""Facts about a scene's structures: kind, extent, voxel size, volume; and surface meshes.

Used by ``needlekit scene info`` and the 3D views. Volumes of voxel grids count the voxels
inside (exact for the grid); other shapes are measured on a regular grid over their box.

Surface meshes are kept, a bounded number of bytes (:data:`MESH_CACHE_BYTES`, least
recently used first out), under a key of what they are computed from
(:func:`field_content_key`: a shape's type and parameters, a hash of a grid's values),
never of which object asked: the same scene loaded again, for another page of the same
process, is not meshed again, and a field changed in place gets a new key.
"""

from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from needlekit.anatomy.fields import (
    BoundedField,
    ComplementField,
    DistanceField,
    LazyField,
    OffsetField,
    TransformedField,
    UnionField,
)
from needlekit.anatomy.primitives import (
    Box,
    Capsule,
    Cylinder,
    Ellipsoid,
    HalfSpace,
    Sphere,
    Superquadric,
)
from needlekit.anatomy.scene import Scene, Structure
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.anatomy.voxel_local import LocalMaskField

__all__ = [
    "MESH_CACHE_BYTES",
    "StructureSummary",
    "field_content_key",
    "sample_grid",
    "summarize",
    "summarize_scene",
    "surface_mesh",
]

#: Cells per axis when a non-voxel field is sampled to measure its volume or draw it.
SAMPLE_CELLS_PER_AXIS: int = 72
#: Bytes of surface meshes kept for reuse by :func:`surface_mesh`, at most; 0 keeps none
#: (a toy scene's four surfaces at 160 cells take about 6 MB).
MESH_CACHE_BYTES: int = 64 * 2**20


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


#: The analytic shapes keyed by their attributes (parameters and pose).
_SHAPES = (Sphere, Capsule, Cylinder, Box, HalfSpace, Ellipsoid, Superquadric)
#: Grids larger than this (bytes) inside a sampled field are not hashed (it would take
#: longer than sampling them); the field is then meshed afresh each time.
_HASH_MAX_BYTES: int = 32 * 2**20


def _array_key(a: np.ndarray) -> tuple:
    """Dtype, shape and contents (the bytes when small, else their SHA-256)."""
    a = np.ascontiguousarray(a)
    flat = a.reshape(-1).view(np.uint8)
    data = flat.tobytes() if a.nbytes <= 256 else hashlib.sha256(flat).digest()
    return ("array", a.dtype.str, a.shape, data)


def _value_key(value):
    """A bit-exact, hashable form of a number, string or numeric array; None otherwise."""
    if isinstance(value, np.ndarray):
        return None if value.dtype.hasobject else _array_key(value)
    if isinstance(value, (bool, np.bool_)):
        return ("bool", bool(value))
    if isinstance(value, (int, np.integer)):
        return ("int", int(value))
    if isinstance(value, (float, np.floating)):
        return ("float", np.float64(value).tobytes())  # -0.0 apart from 0.0
    if isinstance(value, str):
        return ("str", value)
    return None


def _attributes_key(field: DistanceField) -> tuple | None:
    """An analytic shape's key: its type and every public attribute (None when one is not
    a number, string or array); private numeric state (quantities derived from them) goes
    in too, so that a shape changed in place never matches its old key."""
    items = []
    for name, value in sorted(vars(field).items()):
        key = _value_key(value)
        if key is None and not name.startswith("_"):
            return None
        if key is not None:
            items.append((name, key))
    return (type(field).__module__, type(field).__qualname__, tuple(items))


def _parts_key(kind: str, parts, *extra) -> tuple | None:
    keys = [field_content_key(p) for p in parts]
    if any(k is None for k in keys) or any(e is None for e in extra):
        return None
    return (kind, tuple(keys), *extra)


def field_content_key(field: DistanceField) -> tuple | None:
    """A key of what a field is, equal for two fields only when they give the same signed
    distances everywhere, bit for bit; computed from the field's contents each time it is
    asked for (never from the object's identity), so a field rebuilt elsewhere has the
    same key and a field changed in place a new one.

    Analytic shapes (:mod:`needlekit.anatomy.primitives`) are keyed by their type and
    attributes; voxel grids by a hash of their values and their affine (grids above
    32 MB have none: hashing them would cost more than sampling them); offsets, unions,
    complements, bounded and placed fields, and local windows of a grid, by the keys of
    their parts and their own numbers; a field of another type by its own
    ``content_key()`` method when its class defines one. Only these exact types: a
    subclass may answer differently, so it has no key unless it defines
    ``content_key()`` itself.

    Parameters
    ----------
    field : DistanceField

    Returns
    -------
    tuple or None
        Hashable; None when the field has no cheap key (a lazy field, which may answer
        from a window or the whole structure; a field type not listed).
    """
    kind = type(field)
    own = kind.__dict__.get("content_key")
    if own is not None:
        return own(field)
    if kind in _SHAPES:
        return _attributes_key(field)
    if kind is VoxelSDF:
        if field.values.nbytes > _HASH_MAX_BYTES:
            return None
        return ("VoxelSDF", _value_key(field.values), _value_key(field.inv_affine))
    if kind is LocalMaskField:
        return _parts_key("LocalMaskField", [field.grid], _value_key(field.point_mm),
                          _value_key(field.reach_mm))  # fmt: skip
    if kind is OffsetField:
        return _parts_key("OffsetField", [field.base], _value_key(field.margin_mm))
    if kind is ComplementField:
        return _parts_key("ComplementField", [field.base])
    if kind is UnionField:
        return _parts_key("UnionField", field.fields)
    if kind is BoundedField:
        return _parts_key("BoundedField", [field.field, field.bound])
    if kind is TransformedField:
        return _parts_key("TransformedField", [field.local], _value_key(field.world_T_local))
    return None


class _MeshCache:
    """Meshes by key, at most :data:`MESH_CACHE_BYTES` of them (read at each use; 0 turns
    the cache off), the least recently used dropped first; each caller gets its own copy."""

    def __init__(self) -> None:
        self._items: OrderedDict[tuple, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()
        self.hits = 0
        self.misses = 0

    def get(self, key: tuple) -> tuple[np.ndarray, np.ndarray] | None:
        if MESH_CACHE_BYTES <= 0:  # turned off
            return None
        with self._lock:
            item = self._items.get(key)
            if item is None:
                self.misses += 1
                return None
            self._items.move_to_end(key)
            self.hits += 1
        return item[0].copy(), item[1].copy()

    def put(self, key: tuple, verts: np.ndarray, faces: np.ndarray) -> None:
        limit = MESH_CACHE_BYTES
        size = verts.nbytes + faces.nbytes
        if size > limit:
            return
        item = (verts.copy(), faces.copy())
        for a in item:
            a.flags.writeable = False
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old[0].nbytes + old[1].nbytes
            self._items[key] = item
            self._bytes += size
            while self._bytes > limit:
                _, (v, f) = self._items.popitem(last=False)
                self._bytes -= v.nbytes + f.nbytes

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0
            self.hits = self.misses = 0


_MESHES = _MeshCache()


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

    Meshes are kept under a key of what they are computed from (the grid window meshed,
    or :func:`field_content_key` with the box and ``max_cells``), up to
    :data:`MESH_CACHE_BYTES`: the same surface asked for again is a copy of the first.

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
    # a CT structure not built whole is drawn from its coarse preview (fields.LazyField)
    if isinstance(field, LazyField) and crop is not None:
        # the window around the box at full resolution (the field itself once built)
        field = field.near_box(np.asarray(crop, dtype=float).reshape(2, 3), 1.0)
        if field is None:  # nothing of the structure near the box
            return _no_mesh()
    field = field.preview(max_cells) if isinstance(field, LazyField) else field
    vox = _voxel_of(field)
    crop = None if crop is None else np.asarray(crop, dtype=float).reshape(2, 3)
    if vox is not None:
        values, affine = _voxel_window(vox, max_cells, crop)
        key = ("voxel", _array_key(values), _array_key(affine))
        mesh = _MESHES.get(key)
        if mesh is None:
            mesh = _march(values, affine)
            _MESHES.put(key, *mesh)
        return mesh
    box = field.bounds() if bounds is None else np.asarray(bounds, dtype=float)
    if crop is not None:
        box = np.array([np.maximum(box[0], crop[0]), np.minimum(box[1], crop[1])])
        if np.any(box[1] <= box[0]):
            return _no_mesh()
    if not np.all(np.isfinite(box)):
        return _no_mesh()
    content = field_content_key(field)
    key = None if content is None else ("sampled", content, _array_key(box), float(max_cells))
    mesh = None if key is None else _MESHES.get(key)
    if mesh is None:
        values, origin, h = sample_grid(field, box, cells=max_cells)
        affine = np.diag([h, h, h, 1.0])
        affine[:3, 3] = origin
        mesh = _march(values, affine)
        if key is not None:
            _MESHES.put(key, *mesh)
    return mesh


def _no_mesh() -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)


def _voxel_window(vox: VoxelSDF, max_cells: int, crop) -> tuple[np.ndarray, np.ndarray]:
    """The grid values to mesh (a writable float32 copy: the part holding ``crop``, every
    ``step``-th sample) and their index -> world affine."""
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
    return values, affine


def _march(values: np.ndarray, affine: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Marching cubes of sampled values at level 0, in world coordinates."""
    from skimage.measure import marching_cubes

    if values.min() >= 0.0 or values.max() <= 0.0 or min(values.shape) < 2:
        return _no_mesh()
    verts, faces, _, _ = marching_cubes(values, level=0.0)
    world = verts @ affine[:3, :3].T + affine[:3, 3]
    return world, faces.astype(np.int64)
