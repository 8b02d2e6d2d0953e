"""Exact geometry of the procedural phantoms: atoms, their fields, baking, the skin.

Every phantom structure is described exactly as a union or an intersection of *atoms*,
rows of a parameter table read by numba kernels:

==============  ==========================================================  ==========
kind            solid                                                       distance
==============  ==========================================================  ==========
``ROUND_CONE``  convex hull of two balls ``(a, ra)``, ``(b, rb)``: a        exact
                tapered tube segment (a capsule when ``ra == rb``, a ball
                when one ball holds the other)
``HALF_SPACE``  ``(p - q) . n <= 0``                                         exact
``BALL_OUT``    ``|p - c| >= R``, the outside of a ball                      exact
``PLATE``       points within ``t`` of a planar rounded rectangle: a sheet   exact
==============  ==========================================================  ==========

:class:`AtomField` combines atoms by ``min`` (a union: trees, ribs, rings, lobulated
nodules) or ``max`` (an intersection: the lung and liver volumes). The ``min`` of exact
signed distances is the exact distance to the union *outside* it, and inside it the
depth of the deepest atom, never deeper than the truth; the ``max`` is exact *inside*
an intersection, and outside it a lower bound. So every field is exact on the side a
planner measures: outside obstacles and inside allowed regions.

Spatial acceleration (unions of many atoms): a hierarchy of cubic cells, each holding
the atoms that can be nearest to some point of the cell. With ``D(c)`` the union's
distance at a cell centre ``c`` and ``rho`` the cell's half diagonal, an atom ``s``
nearest to a point ``p`` of the cell has ``d_s(c) <= d_s(p) + rho = D(p) + rho <= D(c) +
2 rho`` (every ``d_s`` and ``D`` are 1-Lipschitz), so keeping the atoms with ``d_s(c) <=
D(c) + 2 rho`` loses none; a child cell filters its parent's list. Points outside the
cells are evaluated against all atoms. Answers are therefore exact, not approximate.

Baking (:meth:`AtomField.bake`) samples the exact field at the voxel centres of a grid
into a :class:`~needlekit.anatomy.voxel.VoxelSDF` (value error 0, float32 rounding
added). With stored values ``v_k`` that are exact on the measured side and lie between
the truth and 0 on the other, trilinear interpolation ``I`` keeps ``|I - D| <= r``
(``r`` the half voxel diagonal) on the measured side: e.g. outside a union, ``D(x) >=
0`` and ``D(c_k) <= v_k <= max(D(c_k), 0) <= D(x) + |c_k - x|``, whose weighted mean is
within ``r`` of ``D(x)``. On the other side only the sign (to within ``r``) is
guaranteed, as for :class:`~needlekit.anatomy.fields.UnionField`.
"""

from __future__ import annotations

from needlekit.anatomy.phantoms._atom_kernels import (  # noqa: F401
    _N_PARAMS,
    ATOM_ERROR_BOUND_MM,
    BAKE_PADDING_MM,
    BALL_OUT,
    CELL_PADDING_MM,
    CELL_SIZE_MM,
    DIRECT_MAX_ATOMS,
    HALF_SPACE,
    MAX_BAKED_VOXELS,
    PARALLEL_MIN_POINTS,
    PLATE,
    ROUND_CONE,
    _atom_bounds,
    _atom_sd,
    _build_cells,
    _cannot_beat,
    _combine_all,
    _eval_grid,
    _eval_grid_cells,
    _eval_one,
    _eval_points,
    _eval_points_serial,
    _first_voxel,
    _refine_count,
    _refine_fill,
    _row,
    _sign,
    _union_cells,
    ball_outside,
    half_space,
    plate,
    round_cone,
)
from needlekit.anatomy.phantoms._atoms import (  # noqa: F401
    AtomField,
    _union_box,
    atom_distance_reference,
    bake_structures,
    round_cone_distance_reference,
)
from needlekit.anatomy.phantoms._record import (  # noqa: F401
    Phantom,
    assemble_scene,
    ball_union_diameter,
    check_seed,
    check_voxel_size,
    frozen,
    pose_from_z,
    region_extent,
)
from needlekit.anatomy.phantoms._skin import (  # noqa: F401
    EllipticCylinderSkin,
    _ellipse_root,
    ellipse_signed_distance,
)

__all__ = [
    "ATOM_ERROR_BOUND_MM",
    "BALL_OUT",
    "HALF_SPACE",
    "PLATE",
    "ROUND_CONE",
    "AtomField",
    "EllipticCylinderSkin",
    "Phantom",
    "atom_distance_reference",
    "ball_outside",
    "check_seed",
    "check_voxel_size",
    "half_space",
    "plate",
    "round_cone",
    "round_cone_distance_reference",
]
