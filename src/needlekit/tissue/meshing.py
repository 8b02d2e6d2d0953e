"""An organ's segmentation (boolean voxels and their affine, RAS mm) as a tetrahedral mesh.

**How** (:func:`mesh_mask`): the mask, cut to its set voxels, is coarsened to cells of
about ``cell_mm`` (whole blocks of voxels, as near a cube in millimetres as the voxel
spacing allows); a cell belongs to the organ when more than half its voxels are set. Cells
that touch by a face form components (6-connectivity); components smaller than
:data:`MIN_COMPONENT_FRACTION` of the largest are dropped (specks of segmentation that
would float free), or, given ``seed_mm``, only the component holding (or nearest) that
point is kept.
Every kept cell is cut into six tetrahedra around its main diagonal (Kuhn's subdivision):
neighbouring cells cut their shared face the same way, so the mesh is conforming, and
every tetrahedron of a cube has dihedral angles of 45, 60 and 90 degrees (on a box that
is not a cube they spread a little). Nodes are the cells' corners, placed through the
mask's affine, so the mesh lies in the same RAS millimetres as the anatomy.

**Why voxels** rather than a surface mesher (tetgen, fTetWild, gmsh on a marching-cubes
surface): measured on the five Med-RAD lungs and a liver (docs/tissue.md), the voxel
mesh was the only one of the four to mesh every case, in well under a second, with a
guaranteed element quality; its price is a staircase surface of about half a cell, which
for the loads of a needle deep in the organ and for the boundary conditions (held
surfaces) is within the segmentation's own uncertainty.

**Size.** Without ``cell_mm``, the cell size is chosen from the mask's volume so that the
mesh has about ``target_tets`` tetrahedra (default :data:`DEFAULT_TARGET_TETS`; a
Med-RAD lung then has at least 50,000); it is refined until at least ``target_tets`` are
reached (at most three times).

Bad masks (empty, too few voxels, too thin to hold :data:`MIN_CELLS` cells at the cell
size) raise :class:`~needlekit.errors.InvalidInputError` naming the field, before the
mesh is built.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = [
    "DEFAULT_TARGET_TETS",
    "MIN_CELLS",
    "MIN_COMPONENT_FRACTION",
    "TetMesh",
    "dihedral_angles_deg",
    "mesh_mask",
    "organ_body",
    "shape_quality",
    "tet_volumes",
]

#: Tetrahedra aimed at when no cell size is given: a Med-RAD lung (both lungs) gets
#: 50,000 to 70,000, a liver about as many.
DEFAULT_TARGET_TETS: int = 60_000
#: Fewest cells a mask must fill at the cell size (six tetrahedra each): fewer is not an
#: organ but a speck, and its stiffness would be mostly boundary.
MIN_CELLS: int = 64
#: Components (face-connected cells) smaller than this fraction of the largest are dropped.
MIN_COMPONENT_FRACTION: float = 0.01
_MAX_REFINE = 3

# the six tetrahedra of a unit cell around its diagonal (0,0,0)-(1,1,1), as corner offsets
_KUHN = np.array(
    [
        [(0, 0, 0), tuple(np.eye(3, dtype=int)[p[0]]),
         tuple(np.eye(3, dtype=int)[p[0]] + np.eye(3, dtype=int)[p[1]]), (1, 1, 1)]
        for p in itertools.permutations(range(3))
    ]
)  # fmt: skip


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A tetrahedral mesh in world millimetres.

    Attributes
    ----------
    nodes_mm : ndarray, shape (n, 3)
        Node positions (RAS mm).
    tets : ndarray of int64, shape (m, 4)
        Node indices of each tetrahedron, positively oriented (positive volume).
    cell_mm : ndarray, shape (3,)
        The coarse cell's edges (mm) along the mask's i, j, k axes (nan for a mesh not
        made from a grid).
    method : str
        How it was made (``"voxel"``, or what a caller built it with).
    """

    nodes_mm: np.ndarray
    tets: np.ndarray
    cell_mm: np.ndarray
    method: str = "voxel"

    @property
    def n_nodes(self) -> int:
        """Number of nodes."""
        return int(self.nodes_mm.shape[0])

    @property
    def n_tets(self) -> int:
        """Number of tetrahedra."""
        return int(self.tets.shape[0])

    def volumes_mm3(self) -> np.ndarray:
        """Signed volume of every tetrahedron (mm^3; all positive).

        Returns
        -------
        ndarray, shape (m,)
        """
        return tet_volumes(self.nodes_mm, self.tets)

    def boundary_faces(self) -> np.ndarray:
        """Faces of one tetrahedron only (the surface), oriented outward.

        Returns
        -------
        ndarray of int, shape (f, 3)
        """
        return _boundary_faces(self.tets)

    def boundary_nodes(self) -> np.ndarray:
        """Sorted indices of the nodes on the surface.

        Returns
        -------
        ndarray of int, shape (b,)
        """
        return np.unique(self.boundary_faces())

    def boundary_normals(self) -> np.ndarray:
        """Area-weighted outward normal at every node: unit length on the surface, zero
        inside.

        Returns
        -------
        ndarray, shape (n, 3)
        """
        faces = self.boundary_faces()
        p = self.nodes_mm[faces]
        area_n = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        out = np.zeros_like(self.nodes_mm)
        for c in range(3):
            np.add.at(out, faces[:, c], area_n)
        norm = np.linalg.norm(out, axis=1)
        on = norm > 0
        out[on] /= norm[on, None]
        return out


def tet_volumes(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Signed volumes of tetrahedra (positive when ``tets`` is positively oriented).

    Parameters
    ----------
    nodes : ndarray, shape (n, 3)
    tets : ndarray of int, shape (m, 4)

    Returns
    -------
    ndarray, shape (m,)

    Examples
    --------
    >>> tet_volumes(np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]), np.array([[0, 1, 2, 3]]))
    array([0.16666667])
    """
    p = nodes[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def dihedral_angles_deg(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """The six dihedral angles of every tetrahedron (degrees), shape (m, 6).

    Parameters
    ----------
    nodes : ndarray, shape (n, 3)
    tets : ndarray of int, shape (m, 4)

    Returns
    -------
    ndarray, shape (m, 6)
    """
    p = nodes[tets]
    normals = []
    for k in range(4):  # the face opposite vertex k, its normal pointing away from k
        a, b, c = (p[:, j] for j in range(4) if j != k)
        n = np.cross(b - a, c - a)
        n *= np.sign(np.einsum("ij,ij->i", n, a - p[:, k]))[:, None]
        normals.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    angles = [
        np.pi - np.arccos(np.clip(np.einsum("ij,ij->i", normals[a], normals[b]), -1.0, 1.0))
        for a, b in itertools.combinations(range(4), 2)
    ]
    return np.degrees(np.stack(angles, axis=1))


def shape_quality(nodes: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Volume-to-edge shape quality ``6 sqrt(2) V / l_rms^3``: 1 for the regular
    tetrahedron, 0 for a flat one, shape (m,).

    Parameters
    ----------
    nodes : ndarray, shape (n, 3)
    tets : ndarray of int, shape (m, 4)

    Returns
    -------
    ndarray, shape (m,)
    """
    p = nodes[tets]
    sq = sum(np.sum((p[:, a] - p[:, b]) ** 2, axis=1) for a, b in itertools.combinations(range(4), 2))
    l_rms = np.sqrt(sq / 6.0)
    return 6.0 * math.sqrt(2.0) * tet_volumes(nodes, tets) / l_rms**3


def _boundary_faces(tets: np.ndarray) -> np.ndarray:
    # faces opposite vertices 0..3, ordered so that the normal points away from the vertex
    # for a positively oriented tetrahedron
    order = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])
    faces = tets[:, order].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, first, counts = np.unique(key, axis=0, return_index=True, return_counts=True)
    return faces[first[counts == 1]]


def organ_body(mask, affine, inside=()) -> np.ndarray:
    """The organ's body on its own grid: the organ's mask with the structures lying in it
    (nodules, vessels, airways) set too, each given on its own grid (Med-RAD's liver masks
    leave the nodules and vessels out, on grids of other slices). Every set voxel of a
    structure sets the organ-grid voxel holding its centre.

    Parameters
    ----------
    mask : ndarray of bool, shape (i, j, k)
    affine : ndarray, shape (4, 4)
    inside : iterable of (ndarray of bool, ndarray (4, 4))
        The structures and their affines.

    Returns
    -------
    ndarray of bool, shape (i, j, k)
    """
    body, a = _check_mask(mask, affine, "mask")
    body = body.copy()
    to_index = np.linalg.inv(a)
    for k, (m, aff) in enumerate(inside):
        data, b = _check_mask(m, aff, f"inside[{k}]")
        vox = np.argwhere(data)
        if len(vox) == 0:
            continue
        idx = np.rint((vox @ b[:3, :3].T + b[:3, 3]) @ to_index[:3, :3].T + to_index[:3, 3]).astype(int)
        ok = np.all((idx >= 0) & (idx < np.array(body.shape)), axis=1)
        body[tuple(idx[ok].T)] = True
    return body


def _check_mask(mask, affine, field: str) -> tuple[np.ndarray, np.ndarray]:
    data = np.asarray(mask)
    if data.ndim != 3:
        raise InvalidInputError(field, f"expected a 3-D boolean mask, got shape {data.shape}")
    if data.dtype != bool:
        raise InvalidInputError(field, f"expected a boolean mask, got dtype {data.dtype}")
    a = np.asarray(affine, dtype=float)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)) or abs(np.linalg.det(a[:3, :3])) < 1e-12:
        raise InvalidInputError(
            f"{field} affine", "expected a finite invertible 4x4 voxel-to-RAS affine"
        )
    return data, a


def _block_counts(data: np.ndarray, block: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Set voxels per block of the mask cut to its set box; and the box's low corner."""
    lo, hi = [], []
    for ax in range(3):
        other = tuple(a for a in range(3) if a != ax)
        idx = np.flatnonzero(data.any(axis=other))
        lo.append(int(idx[0]))
        hi.append(int(idx[-1]) + 1)
    box = data[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    pad = [(0, (-s) % b) for s, b in zip(box.shape, block, strict=True)]
    box = np.pad(box, pad)
    n = [s // b for s, b in zip(box.shape, block, strict=True)]
    counts = box.reshape(n[0], block[0], n[1], block[1], n[2], block[2]).sum(
        axis=(1, 3, 5), dtype=np.int32
    )
    return counts, np.array(lo)


def _blocks_for(cell_mm: float, spacing: np.ndarray) -> tuple[int, int, int]:
    return tuple(max(1, round(cell_mm / s)) for s in spacing)


def _cells(data: np.ndarray, block, seed_index, spacing_of_block=1.0) -> tuple[np.ndarray, np.ndarray]:
    from scipy import ndimage

    counts, lo = _block_counts(data, block)
    cells = counts * 2 > int(np.prod(block))
    labels, n = ndimage.label(cells)  # 6-connectivity: cells sharing a face
    if n == 0:
        return cells, lo
    if seed_index is not None:
        # the component of the cell nearest the seed (the seed's own when it is in one)
        c = (np.asarray(seed_index) - lo + 0.5) / np.asarray(block) - 0.5
        occupied = np.argwhere(labels > 0)
        near = occupied[np.argmin(np.sum(((occupied - c) * spacing_of_block) ** 2, axis=1))]
        return labels == labels[tuple(near)], lo
    sizes = np.bincount(labels.ravel())[1:]
    keep = np.flatnonzero(sizes >= MIN_COMPONENT_FRACTION * sizes.max()) + 1
    return np.isin(labels, keep), lo


def _kuhn_mesh(cells: np.ndarray, lo: np.ndarray, block, affine: np.ndarray):
    ci = np.argwhere(cells)  # (c, 3) cell indices
    shape = np.array(cells.shape) + 1
    corners = ci[:, None, None, :] + _KUHN[None, :, :, :]  # (c, 6, 4, 3)
    flat = np.ravel_multi_index(corners.reshape(-1, 3).T, shape).reshape(-1, 4)
    used, tets = np.unique(flat, return_inverse=True)
    tets = tets.reshape(-1, 4).astype(np.int64)
    grid = np.stack(np.unravel_index(used, shape), axis=1).astype(float)
    # a cell corner in voxel indices: voxel centres are whole numbers, voxels span +-0.5
    vox = lo + grid * np.asarray(block, dtype=float) - 0.5
    nodes = vox @ affine[:3, :3].T + affine[:3, 3]
    vol = tet_volumes(nodes, tets)
    flip = vol < 0  # a left-handed affine (LPS masks) mirrors every tetrahedron
    tets[flip] = tets[flip][:, [0, 2, 1, 3]]
    return nodes, tets


def mesh_mask(
    mask,
    affine,
    *,
    target_tets: int = DEFAULT_TARGET_TETS,
    cell_mm: float | None = None,
    seed_mm=None,
    field: str = "mask",
) -> TetMesh:
    """A conforming tetrahedral mesh of a mask (see the module notes).

    Parameters
    ----------
    mask : ndarray of bool, shape (i, j, k)
        The organ (e.g. the lung inside the pleural boundary, or the liver).
    affine : ndarray, shape (4, 4)
        Voxel index -> RAS mm.
    target_tets : int
        Tetrahedra aimed at when ``cell_mm`` is not given (at least this many, unless the
        cells reach the voxels).
    cell_mm : float, optional
        Cell edge (mm); overrides ``target_tets``.
    seed_mm : array-like, shape (3,), optional
        Keep only the face-connected component holding this point (RAS mm), or nearest
        to it (e.g. the lung of the target: the two lungs lie in separate pleural
        cavities and do not load each other).
    field : str
        What errors name.

    Returns
    -------
    TetMesh

    Raises
    ------
    InvalidInputError
        Not a 3-D boolean mask with an invertible affine; empty; too few voxels or too
        thin to fill :data:`MIN_CELLS` cells; a bad ``cell_mm``/``target_tets``; a seed
        outside the mask's cells.
    """
    data, a = _check_mask(mask, affine, field)
    n_set = int(np.count_nonzero(data))
    if n_set == 0:
        raise InvalidInputError(field, "expected a mask with set voxels, got an empty one")
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    volume = n_set * float(np.prod(spacing))
    if cell_mm is not None:
        if not (isinstance(cell_mm, (int, float)) and math.isfinite(cell_mm) and cell_mm > 0):
            raise InvalidInputError("cell_mm", f"expected a finite size > 0 mm, got {cell_mm!r}")
        h = float(cell_mm)
    else:
        if not (isinstance(target_tets, (int, np.integer)) and 6 * MIN_CELLS <= target_tets <= 10**7):
            raise InvalidInputError(
                "target_tets", f"expected a whole number {6 * MIN_CELLS} to 10^7, got {target_tets!r}"
            )
        h = (6.0 * volume / target_tets) ** (1.0 / 3.0)
    if volume < MIN_CELLS * max(h, float(spacing.max())) ** 3 / 8.0:
        raise InvalidInputError(
            field,
            f"expected an organ of at least {MIN_CELLS} cells of {h:.3g} mm, got {n_set} "
            f"voxels ({volume:.4g} mm^3)",
        )
    seed_index = None
    if seed_mm is not None:
        s = np.asarray(seed_mm, dtype=float)
        if s.shape != (3,) or not np.all(np.isfinite(s)):
            raise InvalidInputError("seed_mm", f"expected a finite 3-vector, got {seed_mm!r}")
        seed_index = np.linalg.solve(a[:3, :3], s - a[:3, 3])
    block = _blocks_for(h, spacing)
    for _ in range(_MAX_REFINE + 1):
        cells, lo = _cells(data, block, seed_index, np.asarray(block) * spacing)
        n_cells = int(np.count_nonzero(cells))
        if cell_mm is not None or 6 * n_cells >= target_tets or block == (1, 1, 1):
            break
        h *= (6.0 * n_cells / target_tets) ** (1.0 / 3.0) * 0.97
        finer = _blocks_for(h, spacing)
        if finer == block:  # whole voxels: the next block size down along the longest edge
            top = max(b * s for b, s in zip(block, spacing, strict=True))
            finer = tuple(max(1, b - 1) if b * s >= top - 1e-9 else b
                          for b, s in zip(block, spacing, strict=True))  # fmt: skip
        block = finer
    if n_cells < MIN_CELLS:
        what = "the seed's component" if seed_index is not None else "the mask"
        raise InvalidInputError(
            field if seed_index is None else "seed_mm",
            f"expected {what} to fill at least {MIN_CELLS} cells of "
            f"{float(np.max(np.asarray(block) * spacing)):.3g} mm (too thin or "
            f"too few voxels), got {n_cells}",
        )
    nodes, tets = _kuhn_mesh(cells, lo, block, a)
    return TetMesh(nodes, tets, np.asarray(block, dtype=float) * spacing, "voxel")
