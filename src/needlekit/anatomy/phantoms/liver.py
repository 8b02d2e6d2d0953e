"""Liver phantom for straight multi-needle ablation (Liu et al. 2016).

Straight needles go from the skin of the right upper abdomen, between or below the ribs,
to targets in a large liver tumour, avoiding the ribs and the portal and hepatic veins:

* ``skin`` (entry surface): the body as an elliptic cylinder 300-330 x 210-236 mm (LR x
  AP), with the parametric skin ``S(u, v)`` of Liu's Eq. (13)
  (:class:`~needlekit.anatomy.phantoms._shapes.EllipticCylinderSkin`; ``u`` the angle
  from the patient's right toward anterior, ``v`` the height);
* ``ribs`` (obstacle): six right lower ribs, 10-13 mm tubes 16-20 mm under the skin,
  running from the spine around the right side and descending anteriorly, the lower ones
  ending more laterally (costal margin); 15-25 mm intercostal gaps;
* ``liver`` (allowed region): the convex hull of a right (55-62 mm) and a left (20-25 mm)
  ball, cut by the sloping inferior (visceral) plane: about 150 x 120 x 100 mm;
* ``portal_vein`` and ``hepatic_vein`` (obstacles): space-filling trees grown together
  in the liver, from the porta hepatis (14 mm) and from the inferior vena cava (trunk
  15 mm), down to ~2 mm;
* ``vena_cava`` (obstacle): the inferior vena cava, a 22 mm tube in the liver's posterior
  groove;
* ``tumour`` (target): a lobulated ball 25-45 mm across in the right lobe, every vessel
  >= 3 mm from it and vessels over 6 mm in diameter >= 10 mm from it.

``targets_mm`` holds the tumour centre and two ablation targets on an axis through it
(Liu's three-needle plan), ``entry_points_mm`` up to three skin points from which a
straight path to the centre is at most 150 mm long and clears ribs and vessels by
2.5 mm (needle radius 1 mm + Liu's safety distance 1.5 mm), and ``start_poses`` the
needle poses there (z toward the centre).
"""

from __future__ import annotations

import functools
import time

import numpy as np

from needlekit.anatomy.fields import ComplementField, union
from needlekit.anatomy.phantoms._shapes import (
    AtomField,
    EllipticCylinderSkin,
    Phantom,
    assemble_scene,
    bake_structures,
    ball_union_diameter,
    check_seed,
    check_voxel_size,
    frozen,
    half_space,
    pose_from_z,
    region_extent,
    round_cone,
)
from needlekit.anatomy.phantoms._trees import (
    CollisionWorld,
    Tree,
    TreeSeed,
    TreeSpec,
    chain_atoms,
    grow_forest,
    sample_in_region,
)
from needlekit.anatomy.scene import Role
from needlekit.errors import NeedlekitError

__all__ = ["DEFAULT_VOXEL_SIZE_MM", "VOXEL_SIZE_RANGE_MM", "liver_phantom"]

#: Default voxel size (mm) of the baked vessels: the 2 mm vessels are resolved (bound:
#: half voxel diagonal 0.61 mm) with grids of ~12 M voxels.
DEFAULT_VOXEL_SIZE_MM: float = 0.7

#: Accepted voxel sizes (mm): grids stay below 10^8 voxels and 2 mm vessels resolved.
VOXEL_SIZE_RANGE_MM: tuple[float, float] = (0.4, 1.5)

#: Recommended straight needle: a microwave antenna of 200 mm, 150 mm of it insertable,
#: 2 mm in diameter; Liu's safety distance gamma = 1.5 mm; a 30 mm ablation zone.
NEEDLE = {
    "length_mm": 200.0,
    "max_insertion_mm": 150.0,
    "diameter_mm": 2.0,
    "safety_distance_mm": 1.5,
    "ablation_diameter_mm": 30.0,
}

_COLOURS = {
    "skin": "#e9c46a",
    "body": "#f4e3d7",
    "ribs": "#e9e4d4",
    "liver": "#c98474",
    "portal_vein": "#8e7dbe",
    "hepatic_vein": "#3d5a80",
    "vena_cava": "#1d3557",
    "tumour": "#2a9d8f",
}

_VESSEL_SPEC = TreeSpec(d_min_mm=2.0, region_margin_mm=1.0, gap_mm=1.0)
_N_SEEDS = 350  # per tree: 14 mm * (2 / 350)^(1/3) = 2.5 mm, 15 mm * (1 / 350)^(1/3) = 2.1 mm
_PATH_CLEARANCE_MM = 2.5  # needle radius 1 mm + safety distance 1.5 mm
_MAX_LAYOUTS = 8


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def _ribs(rng, a: float, b: float):
    """Six right lower ribs as capsule chains; returns the field, radii and gaps."""
    depth = rng.uniform(16.0, 20.0)
    slope = rng.uniform(16.0, 22.0)  # mm of descent per radian toward anterior
    phi0 = np.radians(-80.0)
    ends = np.radians([80.0, 70.0, 58.0, 42.0, 18.0, -15.0]) + np.radians(rng.uniform(-5, 5, 6))
    radii = rng.uniform(5.0, 6.5, size=6)
    gaps = rng.uniform(15.0, 25.0, size=5)

    def centreline(z0, end):
        phi = np.linspace(phi0, end, max(6, int(np.degrees(end - phi0) / 8.0)))
        return np.stack(
            [(a - depth) * np.cos(phi), (b - depth) * np.sin(phi), z0 - slope * (phi - phi0)],
            axis=1,
        )

    def gap_between(c1, c2, r1, r2):
        d = np.linalg.norm(c1[:, None, :] - c2[None, :, :], axis=2)
        return float(d.min()) - r1 - r2

    z0 = [rng.uniform(105.0, 115.0)]
    lines = [centreline(z0[0], ends[0])]
    for j in range(5):  # place rib j+1 below rib j so that their gap is gaps[j]
        step = gaps[j] + radii[j] + radii[j + 1]
        for _ in range(4):
            cand = centreline(z0[j] - step, ends[j + 1])
            dense_j = centreline(z0[j], ends[j])
            got = gap_between(_densify(dense_j), _densify(cand), radii[j], radii[j + 1])
            step *= (gaps[j] + radii[j] + radii[j + 1]) / (got + radii[j] + radii[j + 1])
        z0.append(z0[j] - step)
        lines.append(centreline(z0[-1], ends[j + 1]))
    measured = [
        gap_between(_densify(lines[j]), _densify(lines[j + 1]), radii[j], radii[j + 1])
        for j in range(5)
    ]
    atoms = [atom for line, r in zip(lines, radii, strict=True) for atom in chain_atoms(line, r)]
    return AtomField(atoms), radii, measured, lines


def _densify(line: np.ndarray, step: float = 1.0) -> np.ndarray:
    seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
    out = [line[0]]
    for p, q, s in zip(line[:-1], line[1:], seg, strict=True):
        k = max(1, int(np.ceil(s / step)))
        out.extend(p + (q - p) * (np.arange(1, k + 1) / k)[:, None])
    return np.array(out)


def _liver(rng, a: float, rib_lines, rib_radii):
    """The liver, shrunk (right lobe radius, 2 mm at a time) until it keeps 3 mm from
    every rib."""
    r_right = rng.uniform(55.0, 62.0)
    r_left = rng.uniform(20.0, 25.0)
    width = rng.uniform(145.0, 158.0)
    y_r = rng.uniform(-10.0, 5.0)
    dy_l, dz_l = rng.uniform(18.0, 28.0), rng.uniform(8.0, 18.0)
    gap = rng.uniform(10.0, 14.0)
    below = rng.uniform(38.0, 45.0)
    depth = a - max(float(np.max(line[:, 0])) for line in rib_lines)  # rib centre depth
    dense = [(_densify(line), r) for line, r in zip(rib_lines, rib_radii, strict=True)]
    while True:
        x_r = a - depth - float(np.max(rib_radii)) - gap - r_right
        c_r = np.array([x_r, y_r, 10.0])
        c_l = np.array([x_r + r_right + r_left - width, y_r + dy_l, 10.0 + dz_l])
        n_inf = _unit([-0.15, -0.25, -1.0])
        liver = AtomField(
            [round_cone(c_l, c_r, r_left, r_right), half_space(c_r + [0.0, 0.0, -below], n_inf)],
            op="intersection",
        )
        if all(float(liver.signed_distance(p).min()) >= r + 3.0 for p, r in dense):
            return liver, c_r, c_l, r_right
        r_right -= 2.0  # pragma: no cover - depends on the seed


def _tumour(rng, liver, c_r, r_right, keep_away):
    """A lobulated tumour in the right lobe, ``1.12 radius + 30`` mm from each point of
    ``keep_away`` (where the main vessels enter)."""
    for _ in range(4000):
        diameter = rng.uniform(25.0, 45.0)
        radius = diameter / 2.0 / 1.12
        c = c_r + rng.uniform(-0.6, 0.6, 3) * r_right
        if liver.signed_distance(c) > -(1.12 * radius + 10.0):
            continue
        if min(np.linalg.norm(c - k) for k in keep_away) < 1.12 * radius + 30.0:
            continue
        axis = _unit(rng.normal(size=3))
        atoms = [round_cone(c, c, radius, radius)]
        for sgn in (1.0, -1.0):  # lobulated along an axis, bumps protrude 0.12 radius
            q = c + sgn * 0.52 * radius * axis
            atoms.append(round_cone(q, q, 0.6 * radius, 0.6 * radius))
        extra = _unit(np.cross(axis, rng.normal(size=3)))
        q = c + 0.5 * radius * extra
        atoms.append(round_cone(q, q, 0.62 * radius, 0.62 * radius))
        return AtomField(atoms), c, radius, axis
    raise NeedlekitError("could not place a tumour")  # pragma: no cover


def _path_clear(points_a, target, fields, clearance: float, spacing: float = 1.0):
    """Which straight paths ``points_a[i] -> target`` keep ``clearance`` from every
    field (sampled every ``spacing`` mm; the fields are 1-Lipschitz, so half the
    spacing is added)."""
    lengths = np.linalg.norm(target - points_a, axis=1)
    m = int(np.ceil(lengths.max() / spacing)) + 1
    t = np.linspace(0.0, 1.0, m)
    pts = points_a[:, None, :] + t[None, :, None] * (target - points_a)[:, None, :]
    ok = np.ones(len(points_a), dtype=bool)
    gap = lengths / (m - 1)
    flat = pts.reshape(-1, 3)
    for f in fields:
        # samples farther than the clearance (+ half a gap) from the field's box cannot
        # fail: the box holds the solid
        box = f.bounds()
        margin = clearance + 0.5 * float(gap.max()) + 1.0
        near = np.all((flat >= box[0] - margin) & (flat <= box[1] + margin), axis=1)
        d = np.full(len(flat), np.inf)
        d[near] = f.signed_distance(flat[near])
        ok &= d.reshape(len(points_a), m).min(axis=1) - 0.5 * gap >= clearance
    return ok


def _entries(skin: EllipticCylinderSkin, target, fields, *, max_len: float, count: int):
    """Up to ``count`` skin points with clear straight paths to ``target``: the shortest,
    at least 15 mm apart, entering within 60 deg of the inward normal."""
    u = np.radians(np.arange(-45.0, 112.0, 2.5))
    v = np.arange(skin.v_range_mm[0], skin.v_range_mm[1] + 1e-9, 2.5)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    pts = skin.skin_point(uu.ravel(), vv.ravel())
    normal = skin.skin_normal(uu.ravel(), vv.ravel())
    d = target - pts
    length = np.linalg.norm(d, axis=1)
    cos_in = -np.einsum("ij,ij->i", d, normal) / length
    cand = np.flatnonzero((length <= max_len) & (cos_in >= np.cos(np.radians(60.0))))
    if len(cand) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    clear = cand[_path_clear(pts[cand], target, fields, _PATH_CLEARANCE_MM)]
    chosen: list[int] = []
    for i in clear[np.argsort(length[clear], kind="stable")]:
        if all(np.linalg.norm(pts[i] - pts[j]) >= 15.0 for j in chosen):
            chosen.append(int(i))
        if len(chosen) == count:
            break
    return pts[chosen], normal[chosen]


def _layout(rng):
    a = rng.uniform(150.0, 165.0)
    b = rng.uniform(105.0, 118.0)
    ribs, rib_radii, rib_gaps, rib_lines = _ribs(rng, a, b)
    liver, c_r, c_l, r_right = _liver(rng, a, rib_lines, rib_radii)
    z_lo, z_hi = liver.bounds()[:, 2] if np.all(np.isfinite(liver.bounds())) else (-60, 80)
    skin = EllipticCylinderSkin(
        [0.0, 0.0], [a, b], np.radians([-45.0, 110.0]), [float(z_lo) - 40.0, float(z_hi) + 20.0]
    )
    ivc_x = c_l[0] + 0.55 * (c_r[0] - c_l[0])
    ivc_y = c_r[1] - 0.72 * r_right
    ivc = (np.array([ivc_x, ivc_y, c_r[2] - 75.0]), np.array([ivc_x, ivc_y, c_r[2] + 80.0]))
    h_start = np.array([ivc_x, ivc_y, c_r[2] + 42.0])
    h_node = _inside(liver, h_start, _unit([0.5, 0.7, -0.35]), 26.0, 10.0)
    p_start = np.array([ivc_x + 24.0, ivc_y + 30.0, c_r[2] - 62.0])
    p_node = _inside(liver, p_start, _unit([0.35, 0.25, 1.0]), 24.0, 12.0)
    cava = AtomField([round_cone(*ivc, 11.0, 11.0)])
    for _attempt in range(_MAX_LAYOUTS):
        tumour, centre, radius, axis = _tumour(rng, liver, c_r, r_right, [h_start, h_node, p_node])
        world = CollisionWorld()
        world.add(*ivc, 11.0)
        zones = ((tumour, 3.0), (tumour, 10.0, 3.0))

        def exclude(p, c=centre, r=radius):
            return np.linalg.norm(p - c, axis=1) < 1.25 * r + 4.0

        seeds = []
        for start, node, d0 in ((p_start, p_node, 14.0), (h_start, h_node, 15.0)):
            territory = sample_in_region(rng, liver, _N_SEEDS, depth_mm=4.0, exclude=exclude)
            wid = world.add(start, node, 0.5 * d0)
            seeds.append(
                TreeSeed(
                    node, node - start, d0, territory, _VESSEL_SPEC, zones=zones, root_world_id=wid
                )
            )
        portal, hepatic = grow_forest(rng, seeds, region=liver, world=world)
        portal = _with_root(portal, p_start, p_node, 7.0)
        hepatic = _with_root(hepatic, h_start, h_node, 7.5)
        portal_field = AtomField(portal.atoms())
        hepatic_field = AtomField(hepatic.atoms())
        entries, _normals = _entries(
            skin,
            centre,
            [ribs, portal_field, hepatic_field, cava],
            max_len=NEEDLE["max_insertion_mm"],
            count=3,
        )
        if len(entries):
            break
    else:  # pragma: no cover - every seed tried so far finds a layout at once
        raise NeedlekitError("liver phantom: no tumour placement with a clear straight path")
    targets = np.stack(
        [centre, centre + 0.35 * 2.24 * radius * axis, centre - 0.35 * 2.24 * radius * axis]
    )
    poses = [pose_from_z(p, centre - p, [0.0, 0.0, 1.0]) for p in entries]
    return {
        "skin": skin,
        "ribs": ribs,
        "liver": liver,
        "portal_vein": portal_field,
        "hepatic_vein": hepatic_field,
        "vena_cava": cava,
        "tumour": tumour,
        "centre": centre,
        "radius": radius,
        "targets": targets,
        "entries": entries,
        "poses": poses,
        "portal": portal,
        "hepatic": hepatic,
        "rib_radii": rib_radii,
        "rib_gaps": rib_gaps,
        "rib_lines": rib_lines,
        "ivc": ivc,
    }


def _inside(region, start, direction, least: float, depth: float) -> np.ndarray:
    """The first point ``start + s direction`` (``s >= least``, 1 mm steps) at least
    ``depth`` mm inside ``region``: where a vessel trunk entering the organ branches."""
    for s in np.arange(least, least + 120.0, 1.0):
        p = start + s * direction
        if region.signed_distance(p) <= -depth:
            return p
    raise NeedlekitError(
        "liver phantom: a vessel trunk does not enter the liver"
    )  # pragma: no cover


def _with_root(tree: Tree, start, node, r: float) -> Tree:
    rows = [(start, node, r, r, -1, 0)]
    rows += [
        (a, b, r0, r1, p + 1 if p >= 0 else 0, g)
        for a, b, r0, r1, p, g in zip(
            tree.start,
            tree.end,
            tree.r_start,
            tree.r_end,
            tree.parent,
            tree.generation,
            strict=True,
        )
    ]
    return Tree.from_rows(rows)


@functools.lru_cache(maxsize=2)
def _build(seed: int, voxel_size_mm: float) -> Phantom:
    t_start = time.perf_counter()
    layout = _layout(np.random.default_rng(seed))
    t_layout = time.perf_counter() - t_start
    # A percutaneous needle crosses the body wall: the body (inside the skin) is where it
    # may go, the liver is context. One grid holds the union of the obstacles; the body's
    # outside joins it exactly.
    baked, obstacles, timings = bake_structures(
        layout,
        bake=("portal_vein", "hepatic_vein"),
        voxel_size_mm=voxel_size_mm,
        obstacles=("ribs", "portal_vein", "hepatic_vein", "vena_cava"),
    )
    layout = {**layout, "body": layout["skin"]}
    combined = union(obstacles, ComplementField(layout["body"]))
    roles = {
        "skin": Role.ENTRY_SURFACE,
        "body": Role.ALLOWED_REGION,
        "ribs": Role.OBSTACLE,
        "liver": Role.CONTEXT,
        "portal_vein": Role.OBSTACLE,
        "hepatic_vein": Role.OBSTACLE,
        "vena_cava": Role.OBSTACLE,
        "tumour": Role.TARGET,
    }
    scene = assemble_scene("liver", seed, roles, layout, baked, _COLOURS, combined)
    skin = layout["skin"]
    portal, hepatic = layout["portal"], layout["hepatic"]
    ext = region_extent(layout["liver"])
    info = {
        "voxel_size_mm": voxel_size_mm,
        "error_bound_mm": float(combined.error_bound_mm),
        "body_semi_axes_mm": skin.semi_axes_mm.tolist(),
        "skin_u_range_rad": skin.u_range_rad.tolist(),
        "skin_v_range_mm": skin.v_range_mm.tolist(),
        "liver_size_mm": (ext[1] - ext[0]).round(1).tolist(),
        "rib_count": len(layout["rib_radii"]),
        "rib_diameter_mm": (2.0 * layout["rib_radii"]).round(2).tolist(),
        "rib_gap_mm": np.round(layout["rib_gaps"], 2).tolist(),
        "portal_count": len(portal),
        "portal_diameter_mm": [
            float(portal.diameters_mm().min()),
            float(portal.diameters_mm().max()),
        ],
        "hepatic_count": len(hepatic),
        "hepatic_diameter_mm": [
            float(hepatic.diameters_mm().min()),
            float(hepatic.diameters_mm().max()),
        ],
        "ivc_diameter_mm": 22.0,
        "tumour_center_mm": layout["centre"].tolist(),
        "tumour_diameter_mm": ball_union_diameter(layout["tumour"]),
        "path_clearance_mm": _PATH_CLEARANCE_MM,
        "straight_path_obstacles": ["ribs", "portal_vein", "hepatic_vein", "vena_cava"],
        "needle": dict(NEEDLE),
        "build_s": {"layout": t_layout, **timings, "total": time.perf_counter() - t_start},
    }
    return Phantom(
        name="liver",
        scene=scene,
        start_poses=frozen(np.stack(layout["poses"])),
        targets_mm=frozen(layout["targets"]),
        entry_points_mm=frozen(layout["entries"]),
        seed=seed,
        info=info,
        exact_fields={n: layout[n] for n in roles},
    )


def liver_phantom(seed: int = 0, *, voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> Phantom:
    """A procedural right upper abdomen for straight multi-needle ablation (module notes).

    Parameters
    ----------
    seed : int
        Seed of every random choice (>= 0); the same seed gives the same phantom.
    voxel_size_mm : float
        Voxel size (mm) of the baked vessels and free space, in
        :data:`VOXEL_SIZE_RANGE_MM`.

    Returns
    -------
    Phantom
        Structures ``skin`` (entry surface, exact: ``skin_point(u, v)``,
        ``skin_normal(u, v)``), ``ribs``, ``portal_vein``, ``hepatic_vein``,
        ``vena_cava`` (obstacles), ``body`` (allowed region: inside the skin),
        ``liver`` (context) and ``tumour`` (target); ``targets_mm`` (3, 3);
        ``entry_points_mm`` and ``start_poses`` of clear straight paths to the centre;
        ``info`` with sizes, rib gaps and the recommended needle.

    Raises
    ------
    InvalidInputError
        ``seed`` not a whole number >= 0, or ``voxel_size_mm`` out of range.

    Notes
    -----
    A percutaneous needle crosses the body wall, so the body (inside the skin) is the
    allowed region and the liver is context:
    :meth:`~needlekit.anatomy.scene.Scene.obstacle_field` is the union of ribs, vessels
    and the outside of the body, and straight paths from the skin are checked against it.
    """
    s = check_seed(seed)
    v = check_voxel_size(voxel_size_mm, *VOXEL_SIZE_RANGE_MM)
    return _build(s, v)
