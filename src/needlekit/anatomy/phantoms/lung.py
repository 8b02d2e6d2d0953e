"""Lung phantom for transbronchial needle aspiration (TBNA; Feng et al. 2023).

A left lung (lateral is -x in RAS) whose needle starts on the wall of an airway and
curves through the parenchyma to a nodule, as in the Med-RAD lung environments:

* ``pleura`` (allowed region): the convex hull of an apical and a basal ball (a round
  cone, apex 22-28 mm and base 70-80 mm in radius, 95-115 mm apart), cut by the flat
  mediastinal plane and lifted by the diaphragm's dome (outside a 110-140 mm ball):
  about 110-125 x 140-160 x 170-190 mm (LR x AP x SI);
* ``airways`` (obstacle): trachea stub (18 mm), left main bronchus (14 mm) entering at
  the hilum, then a space-filling tree (:mod:`._trees`) down to ~2 mm, the two lobar
  subtrees split by the oblique fissure;
* ``vessels`` (obstacle): two pulmonary veins (superior, inferior; 12 mm at the hilum)
  whose trees fill the upper and lower lobe down to 1.5 mm, grown together with the
  bronchi, and pulmonary arteries running beside the bronchi wherever there is room
  (0.85 of their diameter, 11 mm at most; where one cannot follow its bronchus, the
  next starts afresh beside the following one);
* ``fissures`` (obstacle): the oblique fissure, a 1.5 mm sheet from posterior-superior to
  anterior-inferior, open near the hilum;
* ``ribs`` (obstacle, display): 9-12 mm tubes wrapped around the pleura, 2-4 mm outside;
* ``nodule`` (target): a lobulated ball 8-25 mm across, in the periphery, clear of
  vessels by >= 3 mm, at least 20 mm from every airway and 20-60 mm from a mid-sized one
  (3-8 mm).

Start poses: 3-5 points on the outer airway wall (0.1-0.5 mm outside) of the airways
nearest the nodule, z axis leaving the wall (at least 30 deg from tangent) and pointing
5-20 deg off the nodule centre, with the first 2-12 mm along z clear of everything; the
target is the nodule centre.
"""

from __future__ import annotations

import functools
import time

import numpy as np

from needlekit.anatomy.phantoms._shapes import (
    AtomField,
    Phantom,
    assemble_scene,
    bake_structures,
    ball_outside,
    ball_union_diameter,
    check_seed,
    check_voxel_size,
    frozen,
    half_space,
    plate,
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
    companion_tree,
    grow_forest,
    rotate,
    sample_in_region,
)
from needlekit.anatomy.phantoms._tubes import segment_ok
from needlekit.anatomy.scene import Role
from needlekit.errors import NeedlekitError

__all__ = ["DEFAULT_VOXEL_SIZE_MM", "NEEDLE", "VOXEL_SIZE_RANGE_MM", "lung_phantom"]

#: Default voxel size (mm): resolves the 2 mm airways (bound: half voxel diagonal 0.61 mm,
#: close to the 0.65 mm of Med-RAD's masks at 0.55 x 0.55 x 0.7 mm) with three grids of
#: ~17 M voxels (200 MB); 0.6 mm (bound 0.52 mm) costs ~1.6 x the time and memory.
DEFAULT_VOXEL_SIZE_MM: float = 0.7

#: Accepted voxel sizes (mm): below 0.4 the grids pass 10^8 voxels; above 1.5 the 2 mm
#: airways are no longer resolved.
VOXEL_SIZE_RANGE_MM: tuple[float, float] = (0.4, 1.5)

#: Recommended needle (Feng et al. 2023, Section 5): 2 mm diameter, 100 mm insertion,
#: 20 deg minimum puncture angle, 1 mm target tolerance; 50 mm minimum radius of
#: curvature (bevel-tip needles in lung tissue); obstacles within 3 mm of the start are
#: ignored, as the Med-RAD reference planner does.
NEEDLE = {
    "diameter_mm": 2.0,
    "r_min_mm": 50.0,
    "l_max_mm": 100.0,
    "alpha_deg": 20.0,
    "tau_mm": 1.0,
    "start_exclusion_mm": 3.0,
}

_COLOURS = {
    "pleura": "#9ecae1",
    "airways": "#f2c14e",
    "vessels": "#d1495b",
    "fissures": "#8d99ae",
    "ribs": "#e9e4d4",
    "nodule": "#2a9d8f",
}

_AIRWAY_SPEC = TreeSpec(d_min_mm=2.0, region_margin_mm=1.5, gap_mm=1.0)
_VEIN_SPEC = TreeSpec(d_min_mm=1.5, region_margin_mm=1.0, gap_mm=0.8)
_N_AIRWAY_SEEDS = 600  # 14 mm * (2 / 600)^(1/3) = 2.1 mm: terminal airways ~2 mm
_N_VEIN_SEEDS = 500  # per lobe 250: 11 mm * (1 / 250)^(1/3) = 1.75 mm
_AIRWAY_CLEAR_OF_NODULE_MM = 20.0  # from the nodule centre
_VESSEL_CLEAR_OF_NODULE_MM = 3.0  # from the nodule surface
_MAX_LAYOUTS = 6


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


# ----------------------------------------------------------------------------------------
# the layout


def _pleura(rng):
    x_med = -25.0
    r_base = rng.uniform(70.0, 80.0)
    r_apex = rng.uniform(22.0, 28.0)
    height = rng.uniform(95.0, 115.0)
    w_med = rng.uniform(38.0, 46.0)
    base = np.array([x_med - w_med, 0.0, 0.0])
    apex = base + [rng.uniform(4.0, 10.0), rng.uniform(-14.0, -4.0), height]
    r_dome = rng.uniform(110.0, 140.0)
    dome_top = base[2] - rng.uniform(28.0, 40.0)
    dome = np.array([base[0] + 8.0, base[1], dome_top - r_dome])
    field = AtomField(
        [
            round_cone(base, apex, r_base, r_apex),
            half_space([x_med, 0, 0], [1, 0, 0]),
            ball_outside(dome, r_dome),
        ],
        op="intersection",
    )
    return field, {"x_med": x_med, "base": base, "apex": apex, "r_base": r_base, "r_apex": r_apex}


def _fissure(rng, pleura, hilum, gap_mm: float = 20.0):
    gamma = np.radians(rng.uniform(35.0, 50.0))
    n = np.array([0.0, np.sin(gamma), np.cos(gamma)])  # toward the upper lobe
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(n, e1)  # anterior-inferior, in the plane
    s, t = np.meshgrid(np.arange(-200.0, 200.0, 4.0), np.arange(-200.0, 200.0, 4.0))
    pts = hilum + s.reshape(-1, 1) * e1 + t.reshape(-1, 1) * e2
    inside = pleura.signed_distance(pts) < 0.0
    s_in, t_in = s.reshape(-1)[inside], t.reshape(-1)[inside]
    s_lo, s_hi = s_in.min() - 4.0, -gap_mm  # stop short of the hilum (medial, +x)
    t_lo, t_hi = t_in.min() - 4.0, t_in.max() + 4.0
    centre = hilum + 0.5 * (s_lo + s_hi) * e1 + 0.5 * (t_lo + t_hi) * e2
    half = (0.5 * (s_hi - s_lo), 0.5 * (t_hi - t_lo))
    sheet = AtomField([plate(centre, e1, e2, half, 0.75, corner_mm=0.4 * min(half))])
    return sheet, n, e2


def _place_nodule(rng, pleura, fissure, hilum):
    for _ in range(2000):
        radius = 0.5 * rng.uniform(8.0, 20.0)
        c = rng.uniform(pleura.bounds()[0], pleura.bounds()[1])
        if (
            pleura.signed_distance(c) > -(1.15 * radius + 10.0)
            or abs(fissure.signed_distance(c)) < 1.15 * radius + 8.0
            or np.linalg.norm(c - hilum) < 55.0
        ):
            continue
        atoms = [round_cone(c, c, radius, radius)]
        for _k in range(2):  # lobulation: two bumps protruding 0.2 radius
            d = _unit(rng.normal(size=3))
            atoms.append(
                round_cone(c + 0.6 * radius * d, c + 0.6 * radius * d, 0.6 * radius, 0.6 * radius)
            )
        return AtomField(atoms), c, radius
    raise NeedlekitError("could not place a nodule")  # pragma: no cover


def _ribs(rng, pleura, info):
    base, apex = info["base"], info["apex"]
    z_top = apex[2] + 0.6 * info["r_apex"]
    pitch = rng.uniform(24.0, 30.0)
    drop = rng.uniform(25.0, 40.0)
    psi = np.radians(np.linspace(-105.0, 100.0, 18))
    atoms, radii = [], []
    z_post = z_top
    while z_post > base[2] - info["r_base"]:
        r_rib = rng.uniform(4.5, 6.0)
        gap = rng.uniform(2.0, 4.0)
        pts = []
        for ps in psi:
            z = z_post - drop * (ps - psi[0]) / (psi[-1] - psi[0])
            f = np.clip((z - base[2]) / (apex[2] - base[2]), 0.0, 1.0)
            axis = base + f * (apex - base)
            axis[2] = z
            d = np.array([-np.cos(ps), np.sin(ps), 0.0])
            if pleura.signed_distance(axis) >= 0.0:
                pts.append(None)
                continue
            lo, hi = 0.0, 200.0
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if pleura.signed_distance(axis + mid * d) < 0 else (lo, mid)
            pts.append(axis + (hi + gap + r_rib) * d)
        run: list = []
        for p in [*pts, None]:
            if p is not None:
                run.append(p)
                continue
            if len(run) >= 4:
                atoms += chain_atoms(np.array(run), r_rib)
                radii.append(r_rib)
            run = []
        z_post -= pitch
    return AtomField(atoms), radii


def _airway_roots(rng, hilum, n_fis, e2):
    delta = np.radians(rng.uniform(10.0, 25.0))
    u = _unit(-np.array([1.0, 0.0, 0.0]) * np.cos(delta) + e2 * np.sin(delta))
    carina = hilum - rng.uniform(34.0, 40.0) * u
    trachea_top = carina + [0.0, 0.0, rng.uniform(25.0, 35.0)]
    stub = carina + 15.0 * _unit([0.5, 0.0, -0.87])
    rows = [
        (trachea_top, carina, 9.0, 9.0, -1, 0),
        (carina, hilum, 7.0, 6.6, 0, 1),
        (carina, stub, 6.5, 6.2, 0, 1),
    ]
    return rows, u


def _join(rows: list[tuple], tree: Tree, attach: int, root_parents=None) -> Tree:
    """``rows`` followed by ``tree``, whose roots become children of ``rows[attach]``
    (or, in order, of ``rows[root_parents[i]]``)."""
    k = len(rows)
    it = iter(root_parents or ())
    grown = [
        (a, b, r0, r1, p + k if p >= 0 else (next(it) if root_parents else attach), g)
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
    return Tree.from_rows(list(rows) + grown)


def _layout(rng):
    pleura, pinfo = _pleura(rng)
    base, apex = pinfo["base"], pinfo["apex"]
    hilum = np.array([pinfo["x_med"] - 10.0, base[1] - 5.0, base[2] + 0.45 * (apex[2] - base[2])])
    fissure, n_fis, e2 = _fissure(rng, pleura, hilum)
    ribs, rib_radii = _ribs(rng, pleura, pinfo)
    for _attempt in range(_MAX_LAYOUTS):
        nodule, centre, radius = _place_nodule(rng, pleura, fissure, hilum)
        world = CollisionWorld()
        root_rows, u = _airway_roots(rng, hilum, n_fis, e2)
        root_ids = [world.add(a, b, max(r0, r1)) for a, b, r0, r1, _, _ in root_rows]
        seeds = sample_in_region(
            rng,
            pleura,
            _N_AIRWAY_SEEDS,
            depth_mm=3.0,
            exclude=lambda p, c=centre: np.linalg.norm(p - c, axis=1) < 25.0,
        )
        core = AtomField([round_cone(centre, centre, radius, radius)])
        zones_v = ((fissure, 0.5), (nodule, _VESSEL_CLEAR_OF_NODULE_MM))
        tree_seeds = [
            TreeSeed(
                hilum,
                u,
                14.0,
                seeds,
                _AIRWAY_SPEC,
                zones=((fissure, 1.0), (core, _AIRWAY_CLEAR_OF_NODULE_MM - radius)),
                first_split=(hilum, n_fis),
                root_world_id=root_ids[1],
                first_generation=2,
            )
        ]
        vein_roots = []
        # superior vein: the upper lobe (+n side of the fissure); inferior: the lower one
        for node, lobe in ((hilum + [-4.0, 22.0, 12.0], 1.0), (hilum + [-4.0, -6.0, -28.0], -1.0)):
            v_seeds = sample_in_region(
                rng,
                pleura,
                _N_VEIN_SEEDS // 2,
                depth_mm=2.0,
                exclude=lambda p, c=centre, r=radius, lobe=lobe: (
                    (np.linalg.norm(p - c, axis=1) < r + 6.0)
                    | (lobe * ((p - hilum) @ n_fis) <= 0.0)
                ),
            )
            start = node + [22.0, 0.0, 0.0]
            vein_roots.append((start, node, 6.0, 5.5, -1, 0))
            tree_seeds.append(
                TreeSeed(
                    node,
                    node - start,
                    11.0,
                    v_seeds,
                    _VEIN_SPEC,
                    zones=zones_v,
                    root_world_id=world.add(start, node, 6.0),
                )
            )
        tree, *grown_veins = grow_forest(rng, tree_seeds, region=pleura, world=world)
        veins = [_join([r], g, attach=0) for r, g in zip(vein_roots, grown_veins, strict=True)]
        arteries, _ = companion_tree(
            tree,
            scale=0.85,
            d_max_mm=11.0,
            gap_mm=1.0,
            region=pleura,
            world=world,
            zones=zones_v,
            root_node_radius_mm=7.0,
            root_side=[0.0, 0.0, 1.0],
        )
        airways = _join(root_rows, tree, attach=1)
        vessel_atoms = arteries.atoms() + veins[0].atoms() + veins[1].atoms()
        airway_field = AtomField(airways.atoms())
        vessel_field = AtomField(vessel_atoms)
        starts = _start_poses(rng, airways, airway_field, vessel_field, fissure, pleura, centre)
        if len(starts) >= 3:
            break
    else:  # pragma: no cover - every seed tried so far finds a layout at once
        raise NeedlekitError("lung phantom: no nodule layout with 3 valid start poses")
    return {
        "pleura": pleura,
        "airways": airway_field,
        "vessels": vessel_field,
        "fissures": fissure,
        "ribs": ribs,
        "nodule": nodule,
        "centre": centre,
        "radius": radius,
        "airway_tree": airways,
        "arteries": arteries,
        "veins": veins[0].concat(veins[1]),
        "starts": starts,
        "rib_radii": rib_radii,
        "pinfo": pinfo,
        "hilum": hilum,
    }


def _start_poses(rng, airways: Tree, airway_field, vessel_field, fissure, pleura, target):
    """3-5 transbronchial start poses on the walls of the airways nearest the nodule."""
    want = int(rng.integers(3, 6))
    d = airways.diameters_mm()
    a, b = airways.start, airways.end
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", target - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.2, 0.8)
    foot = a + t[:, None] * ab
    r_at = airways.r_start + t * (airways.r_end - airways.r_start)
    wall_dist = np.linalg.norm(target - foot, axis=1) - r_at
    ok = (d >= 2.5) & (d <= 8.0) & (wall_dist >= 15.0) & (wall_dist <= 70.0)
    order = [int(i) for i in np.argsort(wall_dist) if ok[i]]
    obstacles = [airway_field, vessel_field, fissure]
    poses: list[np.ndarray] = []
    used: dict[int, int] = {}
    for s in order:
        axis = _unit(ab[s])
        for _try in range(12):
            if used.get(s, 0) >= 2 or len(poses) >= want:
                break
            ts = np.clip(t[s] + rng.uniform(-0.15, 0.15), 0.15, 0.85)
            centre = a[s] + ts * ab[s]
            r = airways.r_start[s] + ts * (airways.r_end[s] - airways.r_start[s])
            n = target - centre
            n = _unit(n - (n @ axis) * axis)
            n = rotate(n, axis, np.radians(rng.uniform(-30.0, 30.0)))
            p = centre + n * (r + rng.uniform(0.1, 0.5))
            g = _unit(target - p)
            perp = rng.normal(size=3)
            perp = _unit(perp - (perp @ g) * g)
            z = rotate(g, perp, np.radians(rng.uniform(5.0, 20.0)))
            normal = airway_field.normal(p)
            if z @ normal < np.sin(np.radians(30.0)) or pleura.signed_distance(p) > -3.0:
                continue
            if abs(airway_field.signed_distance(p)) > 0.6:
                continue  # another airway's wall is nearer: not on this wall cleanly
            if vessel_field.signed_distance(p) < 0.3 or fissure.signed_distance(p) < 1.0:
                continue
            near = [(vessel_field, 0.5), (fissure, 0.5)]
            far = [(f, 1.5) for f in obstacles]
            if not segment_ok(
                p,
                p + 2.0 * z,
                0.0,
                0.0,
                region=pleura,
                region_margin=1.0,
                zones=near,
                world=CollisionWorld(),
                gap=0.0,
            ):
                continue
            if not segment_ok(
                p + 2.0 * z,
                p + 12.0 * z,
                0.0,
                0.0,
                region=pleura,
                region_margin=1.5,
                zones=far,
                world=CollisionWorld(),
                gap=0.0,
            ):
                continue
            poses.append(pose_from_z(p, z, axis))
            used[s] = used.get(s, 0) + 1
    return poses


# ----------------------------------------------------------------------------------------
# baking and assembly


@functools.lru_cache(maxsize=2)
def _build(seed: int, voxel_size_mm: float) -> Phantom:
    t_start = time.perf_counter()
    rng = np.random.default_rng(seed)
    layout = _layout(rng)
    t_layout = time.perf_counter() - t_start
    baked, combined, timings = bake_structures(
        layout,
        bake=("airways", "vessels"),
        voxel_size_mm=voxel_size_mm,
        region="pleura",
        obstacles=("airways", "vessels", "fissures"),
    )
    roles = {
        "pleura": Role.ALLOWED_REGION,
        "airways": Role.OBSTACLE,
        "vessels": Role.OBSTACLE,
        "fissures": Role.OBSTACLE,
        "ribs": Role.OBSTACLE,
        "nodule": Role.TARGET,
    }
    scene = assemble_scene("lung", seed, roles, layout, baked, _COLOURS, combined)
    airways, arteries, veins = layout["airway_tree"], layout["arteries"], layout["veins"]
    bounds = region_extent(layout["pleura"])
    ad = airways.diameters_mm()
    vd = np.concatenate([arteries.diameters_mm(), veins.diameters_mm()])
    info = {
        "voxel_size_mm": voxel_size_mm,
        "grid_shape": tuple(int(v) for v in baked["airways"].shape),
        "error_bound_mm": float(combined.error_bound_mm),
        "lung_size_mm": (bounds[1] - bounds[0]).round(1).tolist(),
        "airway_count": len(airways),
        "airway_diameter_mm": [float(ad.min()), float(ad.max())],
        "airway_generations": int(airways.generation.max()),
        "airway_length_to_diameter_median": float(np.median(airways.lengths_mm()[3:] / ad[3:])),
        "vessel_count": len(arteries) + len(veins),
        "vessel_diameter_mm": [float(vd.min()), float(vd.max())],
        "rib_count": len(layout["rib_radii"]),
        "nodule_center_mm": layout["centre"].tolist(),
        "nodule_diameter_mm": ball_union_diameter(layout["nodule"]),
        "hilum_mm": layout["hilum"].tolist(),
        "needle": dict(NEEDLE),
        "build_s": {"layout": t_layout, **timings, "total": time.perf_counter() - t_start},
    }
    return Phantom(
        name="lung",
        scene=scene,
        start_poses=frozen(np.stack(layout["starts"])),
        targets_mm=frozen(layout["centre"][None]),
        entry_points_mm=frozen(np.zeros((0, 3))),
        seed=seed,
        info=info,
        exact_fields={n: layout[n] for n in roles},
    )


def lung_phantom(seed: int = 0, *, voxel_size_mm: float = DEFAULT_VOXEL_SIZE_MM) -> Phantom:
    """A procedural left lung for transbronchial needle planning (module notes).

    Parameters
    ----------
    seed : int
        Seed of every random choice (>= 0): the same seed gives the same phantom, bit
        for bit; other seeds give different, equally valid ones.
    voxel_size_mm : float
        Voxel size (mm) of the baked airways, vessels and free space, in
        :data:`VOXEL_SIZE_RANGE_MM`.

    Returns
    -------
    Phantom
        Structures ``pleura`` (allowed region), ``airways``, ``vessels``, ``fissures``,
        ``ribs`` (obstacles) and ``nodule`` (target); 3-5 ``start_poses`` on the airway
        wall; ``targets_mm`` the nodule centre; ``info`` with sizes, counts, build times
        and the recommended needle (``info["needle"]``).

    Raises
    ------
    InvalidInputError
        ``seed`` not a whole number >= 0, or ``voxel_size_mm`` out of range.

    Examples
    --------
    >>> ph = lung_phantom(0)  # doctest: +SKIP
    >>> ph.scene.names  # doctest: +SKIP
    ['pleura', 'airways', 'vessels', 'fissures', 'ribs', 'nodule']
    """
    s = check_seed(seed)
    v = check_voxel_size(voxel_size_mm, *VOXEL_SIZE_RANGE_MM)
    return _build(s, v)
