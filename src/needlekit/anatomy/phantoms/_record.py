"""The phantom record (:class:`Phantom`), argument checks and small geometric helpers
shared by the phantom builders."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from needlekit._validation import as_positive
from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.phantoms._atoms import (
    AtomField,
)
from needlekit.anatomy.scene import Scene, Structure
from needlekit.errors import InvalidInputError

# ----------------------------------------------------------------------------------------
# the phantom record and argument checks


@dataclass(frozen=True)
class Phantom:
    """A procedural phantom: a scene with its start poses, targets and settings.

    Attributes
    ----------
    name : str
        ``"lung"``, ``"liver"`` or ``"neck"``.
    scene : Scene
        Structures with roles. Unions of many atoms (trees, rings) are baked voxel grids
        (:class:`~needlekit.anatomy.voxel.VoxelSDF`); closed forms of a few atoms
        (pleura, liver, nodule, fissure, ribs, skin) stay exact (:class:`AtomField`,
        faster than a grid lookup or, for the ribs, spread over a large empty box). The
        scene's combined obstacle field is one baked grid (one lookup per query).
    start_poses : ndarray, shape (k, 4, 4)
        Needle start poses ``world_T_tip`` (RAS, mm), z the insertion direction.
    targets_mm : ndarray, shape (m, 3)
        Target points (RAS, mm); ``targets_mm[0]`` is the main target.
    entry_points_mm : ndarray, shape (j, 3)
        Skin entry points where the procedure has them (``j = 0`` otherwise).
    seed : int
        The seed it was built from.
    info : dict
        Sizes, counts, build times, error bounds and recommended needle settings.
    exact_fields : mapping of str to DistanceField
        The exact geometry of every structure (what was baked), for verification.

    Notes
    -----
    Phantoms are cached per (name, seed, voxel size); their arrays are read-only and the
    scene is shared between calls, so treat a phantom as immutable.
    """

    name: str
    scene: Scene
    start_poses: np.ndarray
    targets_mm: np.ndarray
    entry_points_mm: np.ndarray
    seed: int
    info: dict
    exact_fields: Mapping[str, DistanceField] = field(default_factory=dict, repr=False)

    def __repr__(self) -> str:
        return (
            f"Phantom({self.name!r}, seed={self.seed}, structures={self.scene.names}, "
            f"starts={len(self.start_poses)}, targets={len(self.targets_mm)})"
        )


def check_seed(seed) -> int:
    """The seed as a non-negative ``int``, or :class:`InvalidInputError` naming ``seed``.

    Parameters
    ----------
    seed : int
        Integers only (``numpy`` integers accepted; floats and booleans refused).

    Returns
    -------
    int
    """
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise InvalidInputError("seed", f"expected a whole number >= 0, got {seed!r}")
    if seed < 0:
        raise InvalidInputError("seed", f"expected a whole number >= 0, got {seed}")
    return int(seed)


def check_voxel_size(voxel_size_mm, lo: float, hi: float) -> float:
    """The voxel size as a float in ``[lo, hi]`` mm, or :class:`InvalidInputError`.

    Parameters
    ----------
    voxel_size_mm : float
    lo, hi : float
        Range (mm) in which the phantom's finest structures are resolved and memory stays
        modest.

    Returns
    -------
    float
    """
    v = as_positive(voxel_size_mm, "voxel_size_mm")
    if not lo <= v <= hi:
        raise InvalidInputError(
            "voxel_size_mm", f"must lie in [{lo:g}, {hi:g}] mm for this phantom, got {v:g}"
        )
    return v


def frozen(arr) -> np.ndarray:
    """A read-only float64 copy of ``arr`` (cached phantoms share their arrays).

    Parameters
    ----------
    arr : array_like, any shape

    Returns
    -------
    ndarray, shape of ``arr``, float64, not writeable
    """
    out = np.array(arr, dtype=np.float64)
    out.flags.writeable = False
    return out


def pose_from_z(origin, z, x_hint) -> np.ndarray:
    """A pose ``world_T_tip`` at ``origin`` whose z axis is ``z`` and x axis the part of
    ``x_hint`` perpendicular to it.

    Parameters
    ----------
    origin, z, x_hint : array_like, shape (3,)

    Returns
    -------
    ndarray, shape (4, 4)
    """
    zz = np.asarray(z, float) / np.linalg.norm(z)
    xh = np.asarray(x_hint, float)
    xx = xh - (xh @ zz) * zz
    if np.linalg.norm(xx) < 1e-6:
        xx = np.cross(zz, [1.0, 0.0, 0.0] if abs(zz[0]) < 0.9 else [0.0, 1.0, 0.0])
    xx = xx / np.linalg.norm(xx)
    g = np.eye(4)
    g[:3, 0], g[:3, 1], g[:3, 2], g[:3, 3] = xx, np.cross(zz, xx), zz, origin
    return g


def ball_union_diameter(field_: AtomField) -> float:
    """Largest distance (mm) between two points of a union of balls (a lobulated
    nodule): ``max |c_i - c_j| + r_i + r_j`` over pairs of balls.

    Parameters
    ----------
    field_ : AtomField
        A union whose atoms are balls.

    Returns
    -------
    float
    """
    q = field_.params
    c, r = q[:, 0:3], q[:, 6]
    d = np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2) + r[:, None] + r[None, :]
    return float(d.max())


def region_extent(region: DistanceField, step_mm: float = 1.0) -> np.ndarray:
    """Box of the points of ``region`` (negative values) on a grid of ``step_mm``.

    Parameters
    ----------
    region : DistanceField
        With a finite :meth:`~needlekit.anatomy.fields.DistanceField.bounds`.
    step_mm : float
        Grid spacing (mm): the box is exact to within it.

    Returns
    -------
    ndarray, shape (2, 3)
        ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm).
    """
    b = region.bounds()
    axes = [np.arange(b[0, i], b[1, i] + step_mm, step_mm) for i in range(3)]
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for x in axes[0][::8]:  # slabs keep the sampled points few at a time
        g = np.stack(
            np.meshgrid(x + np.arange(8) * step_mm, axes[1], axes[2], indexing="ij"), axis=-1
        ).reshape(-1, 3)
        inside = g[region.signed_distance(g) < 0.0]
        if len(inside):
            lo, hi = np.minimum(lo, inside.min(axis=0)), np.maximum(hi, inside.max(axis=0))
    return np.stack([lo, hi])


def assemble_scene(
    name: str, seed: int, roles: dict, layout, baked: dict, colours: dict, obstacle_field
) -> Scene:
    """The phantom's scene: each structure baked or exact, with its role, colour and the
    representation and error bound it carries.

    Parameters
    ----------
    name : str
        Phantom name (``"lung"``, ...).
    seed : int
    roles : dict of str to Role
        Structures in order.
    layout : mapping of str to DistanceField
        Exact geometry by name.
    baked : dict of str to VoxelSDF
        The structures baked into grids.
    colours : dict of str to str
    obstacle_field : DistanceField
        The combined obstacle field.

    Returns
    -------
    Scene
    """
    src = f"needlekit {name} phantom (seed {seed})"
    structures = []
    for key, role in roles.items():
        fld = baked.get(key, layout[key])
        meta = {
            "representation": "voxel" if key in baked else "exact",
            "error_bound_mm": float(fld.error_bound_mm),
        }
        structures.append(Structure(key, role, fld, colours[key], src, meta))
    return Scene(structures, name=f"{name} phantom {seed}", obstacle_field=obstacle_field)
