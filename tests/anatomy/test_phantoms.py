"""Procedural phantoms: exact kernels against references, determinism, realistic sizes,
baked grids within their bounds, and what each procedure needs (starts on the airway
wall, a clear straight path to the tumour, a guide line between two rings)."""

import itertools
import math

import numpy as np
import pytest

from needlekit.anatomy.clearance import segment_clearance
from needlekit.anatomy.fields import union
from needlekit.anatomy.phantoms import (
    PHANTOMS,
    liver_phantom,
    lung_phantom,
    make_phantom,
    neck_phantom,
)
from needlekit.anatomy.phantoms import _shapes as S
from needlekit.anatomy.phantoms import _trees as T
from needlekit.anatomy.phantoms import liver as liver_mod
from needlekit.anatomy.phantoms import lung as lung_mod
from needlekit.anatomy.phantoms import neck as neck_mod
from needlekit.anatomy.scene import Role
from needlekit.anatomy.voxel import VoxelSDF, grid_for_bounds
from needlekit.errors import InvalidInputError

#: Coarse voxel sizes for the second seed and the determinism rebuilds: the geometry
#: does not depend on the voxel size, and coarse grids bake in a fraction of the time.
COARSE = {"lung": 1.2, "liver": 1.2, "neck": 1.0}
BUILDERS = {"lung": lung_mod._build, "liver": liver_mod._build, "neck": neck_mod._build}


# ----------------------------------------------------------------------------------------
# fixtures: each phantom once per session (the builds are cached in the process)


@pytest.fixture(scope="module")
def lung0():
    return lung_phantom(0)


@pytest.fixture(scope="module")
def liver0():
    return liver_phantom(0)


@pytest.fixture(scope="module")
def neck0():
    return neck_phantom(0)


def coarse(name, seed):
    return PHANTOMS[name](seed, voxel_size_mm=COARSE[name])


@pytest.fixture(scope="module", params=[0, 1], ids=["seed0", "seed1"])
def lung_any(request, lung0):
    return lung0 if request.param == 0 else coarse("lung", 1)


@pytest.fixture(scope="module", params=[0, 1], ids=["seed0", "seed1"])
def liver_any(request, liver0):
    return liver0 if request.param == 0 else coarse("liver", 1)


@pytest.fixture(scope="module", params=[0, 1], ids=["seed0", "seed1"])
def neck_any(request, neck0):
    return neck0 if request.param == 0 else coarse("neck", 1)


# ----------------------------------------------------------------------------------------
# helpers measuring the geometry description


def balls(field):
    """Centres (k, 3) and radii (k,) of an AtomField made of balls."""
    q = field.params
    assert np.all(q[:, 12] == 1.0)
    return q[:, 0:3], q[:, 6]


def chains(field):
    """Split the round cones of a field into chains (end of one = start of the next)."""
    q = field.params
    out, cur = [], [0]
    for i in range(1, len(q)):
        if np.array_equal(q[i, 0:3], q[i - 1, 3:6]):
            cur.append(i)
        else:
            out.append(cur)
            cur = [i]
    out.append(cur)
    return [q[c] for c in out]


def branch_angles_and_ratios(field, skip_parents_of=()):
    """Angle (deg) to the parent (the segment ending where it starts) and length /
    diameter of every segment of a tree field."""
    q = field.params
    ends = {tuple(q[j, 3:6]): j for j in range(len(q))}
    d = q[:, 3:6] - q[:, 0:3]
    length = np.linalg.norm(d, axis=1)
    u = d / length[:, None]
    angles = []
    for i in range(len(q)):
        j = ends.get(tuple(q[i, 0:3]))
        if j is None or j in skip_parents_of:
            continue
        angles.append(math.degrees(math.acos(np.clip(u[i] @ u[j], -1.0, 1.0))))
    return np.array(angles), length / (2.0 * np.maximum(q[:, 6], q[:, 7]))


def uniform_in(box, n, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(box[0], box[1], size=(n, 3))


# ----------------------------------------------------------------------------------------
# exact atoms: kernels against independent references


def test_round_cone_kernel_matches_support_function_reference():
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(60):
        a, b = rng.uniform(-10, 10, 3), rng.uniform(-10, 10, 3)
        ra, rb = rng.uniform(0.3, 6.0, 2)
        field = S.AtomField([S.round_cone(a, b, ra, rb)])
        c = 0.5 * (a + b)
        p = np.concatenate([rng.uniform(-20, 20, (100, 3)), c + rng.normal(size=(100, 3))])
        ref = S.round_cone_distance_reference(p, a, b, ra, rb)
        assert np.any(ref < 0) and np.any(ref > 0)
        worst = max(worst, float(np.abs(field.signed_distance(p) - ref).max()))
    assert worst < 1e-7


@pytest.mark.parametrize(
    ("a", "b", "ra", "rb"),
    [
        ([0, 0, 0], [0, 0, 0], 2.0, 2.0),
        ([0, 0, 0], [0, 0, 1], 5.0, 1.0),
        ([0, 0, 0], [0, 0, 10], 2.0, 2.0),
        ([1, 2, 3], [1, 2, 3.5], 1.0, 3.0),
    ],
    ids=["ball", "ball-holds-ball", "capsule", "small-inside-large"],
)
def test_degenerate_round_cones(a, b, ra, rb):
    field = S.AtomField([S.round_cone(a, b, ra, rb)])
    p = uniform_in([[-12, -12, -12], [12, 12, 16]], 400, seed=1)
    ref = S.round_cone_distance_reference(p, a, b, ra, rb, n_angles=20001)
    assert np.abs(field.signed_distance(p) - ref).max() < 1e-6


def test_plate_half_space_and_ball_outside_match_references():
    rng = np.random.default_rng(4)
    atoms = [
        S.plate([1, 2, 3], [1, 1, 0], [0, 1, 1], (20.0, 8.0), 0.75, corner_mm=5.0),
        S.plate([0, 0, 0], [1, 0, 0], [0, 1, 0], (3.0, 3.0), 0.5),
        S.half_space([1, 1, 1], [0.3, -1, 0.2]),
        S.ball_outside([0, 0, -50], 40.0),
    ]
    p = rng.uniform(-30, 30, (3000, 3))
    for kind, q in atoms:
        got = S.AtomField([(kind, q)]).signed_distance(p)
        assert np.abs(got - S.atom_distance_reference(kind, q, p)).max() < 1e-9


def test_plate_reference_against_dense_sampling():
    kind, q = S.plate([0, 0, 0], [1, 0, 0], [0, 1, 0], (10.0, 6.0), 0.5, corner_mm=4.0)
    s, t = np.meshgrid(np.linspace(-10, 10, 201), np.linspace(-6, 6, 121))
    pts = np.stack([s.ravel(), t.ravel(), 0 * s.ravel()], axis=1)
    inner = np.clip(np.abs(pts[:, :2]) - [6.0, 2.0], 0, None)
    pts = pts[np.linalg.norm(inner, axis=1) <= 4.0]  # the rounded rectangle
    p = np.random.default_rng(5).uniform(-16, 16, (200, 3))
    brute = np.linalg.norm(p[:, None, :] - pts[None], axis=2).min(axis=1) - 0.5
    assert np.abs(S.atom_distance_reference(kind, q, p) - brute).max() < 0.08  # grid step


def test_union_with_cells_is_the_exact_minimum_everywhere():
    rng = np.random.default_rng(6)
    atoms = []
    for _ in range(300):
        a = rng.uniform(-40, 40, 3)
        atoms.append(
            S.round_cone(a, a + rng.normal(size=3) * 6, rng.uniform(0.5, 3), rng.uniform(0.5, 3))
        )
    field = S.AtomField(atoms)
    assert len(field) > S.DIRECT_MAX_ATOMS
    p = rng.uniform(-80, 80, (5000, 3))  # inside and beyond the cells
    # the minimum over the atoms one by one (each checked against its reference above)
    ref = np.min([S.AtomField([atom]).signed_distance(p) for atom in atoms], axis=0)
    np.testing.assert_array_equal(field.signed_distance(p), ref)
    np.testing.assert_array_equal(field.signed_distance(p[:10]), ref[:10])  # serial kernel


def test_grid_sampling_equals_point_queries_at_voxel_centres():
    rng = np.random.default_rng(7)
    atoms = [
        S.round_cone(a, a + rng.normal(size=3) * 5, 1.0, 2.0) for a in rng.uniform(-20, 20, (60, 3))
    ]
    cut = S.AtomField(
        [S.round_cone([0, 0, 0], [10, 0, 0], 12.0, 6.0), S.half_space([3, 0, 0], [0.6, 0.8, 0.0])],
        op="intersection",
    )
    for field in (S.AtomField(atoms), cut):
        for h in (0.5, 0.7, 1.3):
            affine, shape = grid_for_bounds(field.bounds(), h, 3.0)
            grid = field.sample_grid(affine, shape)
            centres = np.indices(shape).reshape(3, -1).T * h + affine[:3, 3]
            np.testing.assert_array_equal(
                grid.ravel(), field.signed_distance(centres).astype(np.float32)
            )


def test_intersection_is_exact_inside_and_a_lower_bound_outside():
    from scipy.spatial import cKDTree

    # a ball cut by a plane: its boundary is a spherical cap and a disc, sampled densely
    c, r, q, n = (
        np.array([1.0, 2.0, 3.0]),
        20.0,
        np.array([1.0, 2.0, 10.0]),
        np.array([0, 0.6, 0.8]),
    )
    field = S.AtomField([S.round_cone(c, c, r, r), S.half_space(q, n)], op="intersection")
    k = np.arange(200000) + 0.5  # Fibonacci sphere: ~0.16 mm apart
    phi, cos_t = np.pi * (1 + 5**0.5) * k, 1 - 2 * k / 200000
    sphere = c + r * np.stack(
        [np.cos(phi) * np.sqrt(1 - cos_t**2), np.sin(phi) * np.sqrt(1 - cos_t**2), cos_t], axis=1
    )
    cap = sphere[(sphere - q) @ n <= 0]
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(n, e1)
    g = np.arange(-r, r, 0.08)
    s_, t_ = np.meshgrid(g, g)
    centre = c + ((q - c) @ n) * n
    disc = centre + s_.reshape(-1, 1) * e1 + t_.reshape(-1, 1) * e2
    disc = disc[np.linalg.norm(disc - c, axis=1) <= r]
    tree = cKDTree(np.concatenate([cap, disc]))
    p = uniform_in([[-25, -25, -25], [25, 25, 25]], 3000, seed=8) + c
    d = field.signed_distance(p)
    near, _ = tree.query(p)
    inside = d < 0
    assert inside.sum() > 300 and (~inside).sum() > 300
    assert np.abs(-d[inside] - near[inside]).max() < 0.12  # sample spacing
    assert np.all(d[~inside] <= near[~inside] + 1e-9)


def test_ellipse_distance_matches_dense_sampling():
    rng = np.random.default_rng(10)
    for a, b in ((150.0, 110.0), (40.0, 60.0), (30.0, 30.0)):
        t = np.linspace(0, 2 * np.pi, 60001)  # <= 0.016 mm apart
        curve = np.stack([a * np.cos(t), b * np.sin(t)], axis=1)
        p = rng.uniform(-1.5 * max(a, b), 1.5 * max(a, b), (120, 2))
        p = np.concatenate([p, [[0, 0], [a / 3, 0], [0, b / 3], [2 * a, 0], [0, -2 * b]]])
        brute = np.sqrt(((p[:, None, :] - curve[None]) ** 2).sum(axis=2)).min(axis=1)
        inside = (p[:, 0] / a) ** 2 + (p[:, 1] / b) ** 2 < 1
        got = S.ellipse_signed_distance(p[:, 0], p[:, 1], a, b)
        assert np.abs(got - np.where(inside, -brute, brute)).max() < 0.01  # sample spacing


def test_skin_points_lie_on_the_skin_with_outward_normals(liver0, neck0):
    for ph in (liver0, neck0):
        skin = ph.scene["skin"].field
        u = np.linspace(*skin.u_range_rad, 7)
        v = np.linspace(*skin.v_range_mm, 7)
        uu, vv = np.meshgrid(u, v)
        pts = skin.skin_point(uu.ravel(), vv.ravel())
        assert np.abs(skin.signed_distance(pts)).max() < 1e-9
        n = skin.skin_normal(uu.ravel(), vv.ravel())
        np.testing.assert_allclose(n, skin.normal(pts), atol=1e-5)


def test_segment_distances_and_clearance_kernel_match_brute_force():
    rng = np.random.default_rng(11)
    q0, q1 = rng.uniform(-10, 10, (60, 3)), rng.uniform(-10, 10, (60, 3))
    q1[:5] = q0[:5]  # point segments
    t = np.linspace(0, 1, 401)  # <= 0.09 mm apart on these segments
    world = T.CollisionWorld(capacity=8)
    radii = rng.uniform(0.5, 2, 60)
    for a, b, r in zip(q0, q1, radii, strict=True):
        world.add(a, b, r)
    for _ in range(8):
        p0, p1 = rng.uniform(-10, 10, 3), rng.uniform(-10, 10, 3)
        got = T.segment_distances(p0, p1, q0, q1)
        sp = p0 + t[:, None] * (p1 - p0)
        sq = q0[:, None, :] + t[None, :, None] * (q1 - q0)[:, None, :]
        brute = np.array([np.linalg.norm(sp[:, None] - s[None], axis=2).min() for s in sq])
        assert np.all(got <= brute + 1e-9) and np.all(brute - got < 0.06)
        ex = list(rng.choice(60, 5, replace=False))
        assert world.clearance(p0, p1, 0.7, ex) == pytest.approx(
            world.clearance_reference(p0, p1, 0.7, ex), abs=1e-9
        )


# ----------------------------------------------------------------------------------------
# input checks


@pytest.mark.parametrize("name", ["kidney", "", None, "Lung"])
def test_unknown_phantom_name_lists_the_valid_ones(name):
    with pytest.raises(InvalidInputError, match=r"name: .*lung, liver, neck"):
        make_phantom(name)


@pytest.mark.parametrize("seed", [1.5, -1, "3", True, None, np.float64(2.0)])
@pytest.mark.parametrize("fn", [lung_phantom, liver_phantom, neck_phantom])
def test_bad_seed_is_refused(fn, seed):
    with pytest.raises(InvalidInputError, match=r"^seed: "):
        fn(seed)


@pytest.mark.parametrize("voxel", [-0.5, 0.0, float("nan"), float("inf"), 50.0, "a", [0.5]])
def test_bad_voxel_size_is_refused(voxel):
    for name in PHANTOMS:
        with pytest.raises(InvalidInputError, match=r"^voxel_size_mm: "):
            make_phantom(name, 0, voxel_size_mm=voxel)


def test_unknown_option_is_refused():
    with pytest.raises(InvalidInputError, match=r"^resolution: .*voxel_size_mm"):
        make_phantom("neck", 0, resolution=1.0)


def test_numpy_integer_seed_is_accepted():
    assert S.check_seed(np.int64(4)) == 4


# ----------------------------------------------------------------------------------------
# determinism


def _grid_of(field):
    """The voxel grid inside a combined obstacle field (complement of a free-space grid, or
    a union whose first part is the obstacles' grid)."""
    while not isinstance(field, VoxelSDF):
        field = field.base if hasattr(field, "base") else field.fields[0]
    return field


def assert_identical(p, q):
    assert p.name == q.name and p.seed == q.seed
    for attr in ("start_poses", "targets_mm", "entry_points_mm"):
        np.testing.assert_array_equal(getattr(p, attr), getattr(q, attr))
    drop = {"build_s"}
    assert {k: v for k, v in p.info.items() if k not in drop} == {
        k: v for k, v in q.info.items() if k not in drop
    }
    assert p.scene.names == q.scene.names
    for name in p.scene.names:
        fp, fq = p.scene[name].field, q.scene[name].field
        assert type(fp) is type(fq)
        if isinstance(fp, VoxelSDF):
            np.testing.assert_array_equal(fp.values, fq.values)
            np.testing.assert_array_equal(fp.affine, fq.affine)
        ep, eq = p.exact_fields[name], q.exact_fields[name]
        if isinstance(ep, S.AtomField):
            np.testing.assert_array_equal(ep.params, eq.params)
    op, oq = p.scene.obstacle_field(), q.scene.obstacle_field()
    np.testing.assert_array_equal(_grid_of(op).values, _grid_of(oq).values)


@pytest.mark.parametrize("name", ["lung", "liver", "neck"])
def test_same_seed_gives_the_same_phantom_bit_for_bit(name):
    cached = coarse(name, 1)
    rebuilt = BUILDERS[name].__wrapped__(1, COARSE[name])  # bypasses the cache
    assert rebuilt is not cached
    assert_identical(cached, rebuilt)
    assert make_phantom(name, 1, voxel_size_mm=COARSE[name]) is cached


@pytest.mark.parametrize("name", ["lung", "liver", "neck"])
def test_different_seeds_give_different_phantoms(name, lung0, liver0, neck0):
    p0 = {"lung": lung0, "liver": liver0, "neck": neck0}[name]
    p1 = coarse(name, 1)
    assert not np.allclose(p0.targets_mm, p1.targets_mm)
    assert not np.allclose(p0.start_poses[0], p1.start_poses[0])


def test_phantom_arrays_are_read_only(lung0):
    for arr in (lung0.start_poses, lung0.targets_mm, lung0.entry_points_mm):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 0.0


# ----------------------------------------------------------------------------------------
# baked grids against the exact geometry


@pytest.mark.parametrize("which", ["lung0", "liver0", "neck0"])
def test_baked_fields_agree_with_the_exact_geometry_within_their_bound(which, request):
    ph = request.getfixturevalue(which)
    for s in ph.scene.structures:
        if not isinstance(s.field, VoxelSDF):
            continue
        baked, exact = s.field, ph.exact_fields[s.name]
        box = baked.grid_bounds()
        p = uniform_in(box, 20000, seed=12)
        b, e = baked.signed_distance(p), exact.signed_distance(p)
        eb = baked.error_bound_mm
        assert eb == pytest.approx(0.5 * math.sqrt(3) * ph.info["voxel_size_mm"], rel=1e-4)
        measured = e >= 0 if exact.op == "union" else e <= 0
        assert np.all(np.abs(b - e)[measured] <= eb), s.name
        # the other side: the sign holds to within the bound
        assert np.all(np.sign(e[~measured]) * b[~measured] >= -eb), s.name


@pytest.mark.parametrize("which", ["lung0", "liver0", "neck0"])
def test_combined_obstacle_field_matches_the_exact_union_in_free_space(which, request):
    ph = request.getfixturevalue(which)
    scene = ph.scene
    parts = [ph.exact_fields[s.name] for s in scene.by_role(Role.OBSTACLE)]
    regions = [ph.exact_fields[s.name] for s in scene.by_role(Role.ALLOWED_REGION)]
    combined = scene.obstacle_field()
    box = _grid_of(combined).grid_bounds()
    p = uniform_in(box, 20000, seed=13)
    exact = np.min(
        [f.signed_distance(p) for f in parts] + [-f.signed_distance(p) for f in regions], axis=0
    )
    got = combined.signed_distance(p)
    free = exact >= 0
    assert free.mean() > 0.1
    assert np.all(np.abs(got - exact)[free] <= combined.error_bound_mm)
    assert np.all(got[~free] <= combined.error_bound_mm)


# ----------------------------------------------------------------------------------------
# lung


def test_lung_sizes_are_realistic(lung_any):
    ph = lung_any
    ext = S.region_extent(ph.exact_fields["pleura"], 2.0)
    size = ext[1] - ext[0]
    assert np.all(size >= 100.0) and np.all(size <= 200.0)
    assert 110.0 <= size[0] <= 140.0 and 130.0 <= size[1] <= 180.0
    airways = ph.exact_fields["airways"]
    d = 2.0 * np.maximum(airways.params[:, 6], airways.params[:, 7])
    assert d.min() <= 2.5 and d.min() >= 2.0 and d.max() == pytest.approx(18.0)
    angles, ratio = branch_angles_and_ratios(airways, skip_parents_of={0})
    assert len(angles) > 200
    assert angles.min() >= 30.0 - 1e-6 and angles.max() <= 70.0 + 1e-6
    assert 2.0 <= np.median(ratio[3:]) <= 3.5
    vessels = ph.exact_fields["vessels"]
    vd = 2.0 * np.maximum(vessels.params[:, 6], vessels.params[:, 7])
    assert vd.min() >= 1.0 and vd.max() <= 12.0 + 1e-9 and len(vd) > 300
    across = S.region_extent(ph.exact_fields["nodule"], 0.25)
    assert 8.0 <= (across[1] - across[0]).max()
    assert S.ball_union_diameter(ph.exact_fields["nodule"]) <= 25.0
    assert ph.info["nodule_diameter_mm"] == S.ball_union_diameter(ph.exact_fields["nodule"])
    assert ph.info["rib_count"] >= 4


@pytest.mark.slow
def test_lung_nodule_is_inside_the_pleura_clear_of_vessels_and_far_from_airways(lung_any):
    ph = lung_any
    c, r = balls(ph.exact_fields["nodule"])
    assert np.all(ph.exact_fields["pleura"].signed_distance(c) <= -(r + 5.0))
    assert np.all(ph.exact_fields["vessels"].signed_distance(c) >= r + 3.0 - 1e-6)
    assert np.all(ph.exact_fields["fissures"].signed_distance(c) >= r)
    centre = ph.targets_mm[0]
    airways = ph.exact_fields["airways"]
    assert airways.signed_distance(centre) >= 20.0 - 1e-6
    # a mid-sized airway (3-8 mm) within 20-60 mm of the nodule centre
    q = airways.params
    d = 2.0 * np.maximum(q[:, 6], q[:, 7])
    mid = [
        S.AtomField([(int(k), p)])
        for k, p, dd in zip(airways.kinds, q, d, strict=True)
        if 3.0 <= dd <= 8.0
    ]
    dist = np.array([float(f.signed_distance(centre)) for f in mid])
    assert np.any((dist >= 20.0) & (dist <= 60.0))


def test_lung_start_poses_are_on_the_airway_wall_pointing_into_the_tissue(lung_any):
    ph = lung_any
    g = ph.start_poses
    assert 3 <= len(g) <= 5
    np.testing.assert_allclose(
        np.einsum("nij,nik->njk", g[:, :3, :3], g[:, :3, :3]),
        np.broadcast_to(np.eye(3), (len(g), 3, 3)),
        atol=1e-12,
    )
    p, z = g[:, :3, 3], g[:, :3, 2]
    airway = ph.scene["airways"].field
    assert np.all(np.abs(airway.signed_distance(p)) <= 1.0)
    assert np.all(np.abs(ph.exact_fields["airways"].signed_distance(p)) <= 0.6)
    normal = ph.exact_fields["airways"].normal(p)
    assert np.all(np.einsum("ij,ij->i", z, normal) >= math.sin(math.radians(30.0)) - 1e-9)
    assert np.all(np.einsum("ij,ij->i", z, airway.gradient(p)) > 0.0)
    assert np.all(ph.scene["pleura"].field.signed_distance(p) < 0.0)
    target = ph.targets_mm[0]
    assert ph.scene["nodule"].field.signed_distance(target) < 0.0
    to_target = (target - p) / np.linalg.norm(target - p, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", z, to_target) >= math.cos(math.radians(20.0)) - 1e-9)
    assert np.all(np.einsum("ij,ij->i", z, to_target) <= math.cos(math.radians(5.0)) + 1e-9)


def test_lung_starts_leave_room_for_the_needle(lung0):
    g = lung0.start_poses
    p, z = g[:, :3, 3], g[:, :3, 2]
    c = lung0.scene.segment_clearance(p + 3.0 * z, p + 12.0 * z, spacing_mm=0.25)
    assert np.all(c.clearance_mm > 0.5)
    assert np.all(c.certified_mm > 0.0)
    # the first 3 mm leave the airway: clear of everything but it
    near = union(lung0.scene["vessels"].field, lung0.scene["fissures"].field)
    assert np.all(segment_clearance(near, p, p + 3.0 * z, spacing_mm=0.25).certified_mm > 0.0)


def test_lung_info_has_the_recommended_needle(lung0):
    needle = lung0.info["needle"]
    assert needle["r_min_mm"] > 0 and needle["diameter_mm"] == 2.0 and needle["l_max_mm"] == 100
    assert lung0.info["build_s"]["total"] > 0
    assert lung0.scene["pleura"].role is Role.ALLOWED_REGION
    assert lung0.scene["nodule"].role is Role.TARGET


# ----------------------------------------------------------------------------------------
# liver


def test_liver_sizes_are_realistic(liver_any):
    ph = liver_any
    ext = S.region_extent(ph.exact_fields["liver"], 2.0)
    size = ext[1] - ext[0]
    assert 130 <= size[0] <= 175 and 95 <= size[1] <= 135 and 85 <= size[2] <= 125
    across = S.region_extent(ph.exact_fields["tumour"], 0.5)
    assert 20.0 <= (across[1] - across[0]).max()
    assert S.ball_union_diameter(ph.exact_fields["tumour"]) <= 50.0
    for name in ("portal_vein", "hepatic_vein"):
        q = ph.exact_fields[name].params
        d = 2.0 * np.maximum(q[:, 6], q[:, 7])
        assert d.min() >= 2.0 - 1e-9 and d.max() <= 15.0 + 1e-9 and len(d) > 50
    ribs = chains(ph.exact_fields["ribs"])
    assert len(ribs) == 6
    for rib in ribs:
        assert 10.0 <= 2 * rib[0, 6] <= 15.0
    for r1, r2 in itertools.pairwise(ribs):
        gap = (
            min(
                T.segment_distances(a, b, r2[:, 0:3], r2[:, 3:6]).min()
                for a, b in zip(r1[:, 0:3], r1[:, 3:6], strict=True)
            )
            - r1[0, 6]
            - r2[0, 6]
        )
        assert 15.0 - 0.2 <= gap <= 25.0 + 0.2
    a, b = ph.scene["skin"].field.semi_axes_mm
    assert 290 <= 2 * a <= 340 and 200 <= 2 * b <= 250


def test_liver_tumour_is_inside_the_liver_and_clear_of_main_vessels(liver_any):
    ph = liver_any
    c, r = balls(ph.exact_fields["tumour"])
    assert np.all(ph.exact_fields["liver"].signed_distance(c) <= -(r + 5.0))
    for name in ("portal_vein", "hepatic_vein"):
        vessels = ph.exact_fields[name]
        assert np.all(vessels.signed_distance(c) >= r + 3.0 - 1e-6)
        q = vessels.params
        main = S.AtomField([(0, p) for p in q if max(p[6], p[7]) >= 3.0])
        assert np.all(main.signed_distance(c) >= r + 10.0 - 1e-6)
    for t in ph.targets_mm:
        assert ph.exact_fields["tumour"].signed_distance(t) < 0.0
    ribs = ph.exact_fields["ribs"]
    rib_c = np.concatenate([ribs.params[:, 0:3], ribs.params[:, 3:6]])
    assert np.all(ph.exact_fields["liver"].signed_distance(rib_c) >= ribs.params[0, 6])


def test_liver_brute_force_finds_a_straight_path_between_the_ribs(liver0):
    skin = liver0.scene["skin"].field
    u = np.radians(np.arange(-40.0, 105.0, 5.0))
    v = np.arange(-60.0, 100.0, 5.0)
    uu, vv = np.meshgrid(u, v)
    entries = skin.skin_point(uu.ravel(), vv.ravel())
    target = liver0.targets_mm[0]
    entries = entries[np.linalg.norm(entries - target, axis=1) <= 150.0]
    obstacles = union(*[liver0.scene[n].field for n in liver0.info["straight_path_obstacles"]])
    c = segment_clearance(obstacles, entries, target, spacing_mm=1.0)
    assert np.sum(c.certified_mm > 1.0) >= 1
    # the entries the phantom offers are such paths
    e = liver0.entry_points_mm
    assert 1 <= len(e) <= 3
    assert np.abs(skin.signed_distance(e)).max() < 1e-9
    assert np.all(segment_clearance(obstacles, e, target, spacing_mm=0.5).certified_mm > 1.0)
    z = liver0.start_poses[:, :3, 2]
    np.testing.assert_allclose(z, (target - e) / np.linalg.norm(target - e, axis=1)[:, None])


# ----------------------------------------------------------------------------------------
# neck


def test_neck_sizes_are_realistic(neck_any):
    ph = neck_any
    a, b = ph.scene["skin"].field.semi_axes_mm
    assert 110 <= 2 * a <= 130 and 100 <= 2 * b <= 125
    info = ph.info
    assert 18.0 <= info["trachea_outer_diameter_mm"] <= 22.0
    assert 4.0 <= info["ring_pitch_mm"] <= 5.5
    # the rings (measured from their atoms) fit the stated trachea
    o = np.array(info["trachea_axis_point_mm"])
    t = np.array(info["trachea_axis_direction"])
    q = ph.exact_fields["tracheal_rings"].params
    rel = q[:, 0:3] - o
    radial = np.linalg.norm(rel - np.outer(rel @ t, t), axis=1) + q[:, 6]
    rings = q[:, 6] < 1.0  # the cricoid is thicker
    assert radial[rings].max() == pytest.approx(0.5 * info["trachea_outer_diameter_mm"])
    thyroid = S.region_extent(ph.exact_fields["thyroid"], 1.0)
    size = thyroid[1] - thyroid[0]
    assert 45 <= size[0] <= 75 and 40 <= size[2] <= 65  # butterfly width, lobe height


def test_neck_guide_line_enters_between_two_rings_and_reaches_the_lumen(neck_any):
    ph = neck_any
    gl = ph.info["guide_line"]
    entry, target = ph.entry_points_mm[0], ph.targets_mm[0]
    np.testing.assert_allclose(gl["entry_mm"], entry)
    assert abs(float(ph.scene["skin"].field.signed_distance(entry))) < 1e-6
    assert ph.exact_fields["trachea_lumen"].signed_distance(target) < -5.0
    # between two rings: the wall point lies between two consecutive ring planes
    o = np.array(ph.info["trachea_axis_point_mm"])
    t = np.array(ph.info["trachea_axis_direction"])
    s_wall = (np.array(gl["wall_point_mm"]) - o) @ t
    rings = ph.info["ring_positions_mm"]
    k1, k2 = gl["interspace"]
    assert rings[k1 - 1] > s_wall > rings[k2 - 1]
    rings_c = segment_clearance(ph.exact_fields["tracheal_rings"], entry, target, spacing_mm=0.1)
    assert rings_c.certified_mm[0] > 0.8
    thyroid = segment_clearance(ph.exact_fields["thyroid"], entry, target, spacing_mm=0.2)
    assert thyroid.certified_mm[0] > 2.5
    for name in ("vessels", "oesophagus", "spine"):
        c = segment_clearance(ph.exact_fields[name], entry, target, spacing_mm=0.5)
        assert c.certified_mm[0] > 2.0, name
    # the line is below the isthmus, near the midline, and nearly perpendicular
    d = np.array(gl["direction"])
    assert d @ np.array([0.0, -1.0, 0.0]) > math.cos(math.radians(15.0))
    assert abs(d @ t) < math.sin(math.radians(10.0))
    np.testing.assert_allclose(ph.start_poses[0, :3, 2], d, atol=1e-12)
    # with the baked grids, the line is clear too
    c = ph.scene.segment_clearance(entry, target, spacing_mm=0.1)
    assert c.certified_mm[0] > 0.0


def test_neck_roles(neck0):
    roles = {s.name: s.role for s in neck0.scene.structures}
    assert roles["skin"] is Role.ENTRY_SURFACE
    assert roles["trachea_lumen"] is Role.TARGET
    assert roles["tracheal_rings"] is Role.OBSTACLE and roles["thyroid"] is Role.OBSTACLE
