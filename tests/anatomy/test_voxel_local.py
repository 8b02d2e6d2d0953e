"""A mask's field near one point from a window of the mask (anatomy.voxel_local): the
full field's values and gradients where the distance is within the radius, the full
field's answer to "within the radius?" everywhere, and the lazy fields that use it."""

import numpy as np
import pytest

from needlekit.anatomy.fields import DistanceField, LazyField
from needlekit.anatomy.scene import Role
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.anatomy.voxel_local import local_mask_sdf, window_around
from needlekit.constants import MIN_NORMAL_GRADIENT
from needlekit.errors import InvalidInputError


def _blobs(seed: int, shape=(60, 52, 40)) -> np.ndarray:
    """Random union of balls and slabs: concave, thin and touching parts."""
    rng = np.random.default_rng(seed)
    idx = np.indices(shape).reshape(3, -1).T.astype(float)
    m = np.zeros(len(idx), bool)
    for _ in range(7):
        c = rng.uniform(5, np.array(shape) - 5)
        r = rng.uniform(2, 9)
        m |= np.linalg.norm(idx - c, axis=1) <= r
    a = rng.integers(0, 3)
    lo = rng.integers(10, shape[a] - 12)
    slab = (idx[:, a] >= lo) & (idx[:, a] < lo + 2)
    m |= slab & (np.linalg.norm(idx - np.array(shape) / 2, axis=1) < 15)
    return m.reshape(shape)


AFFINE = np.array(
    [[0.0, -0.7, 0.0, 12.0], [0.8, 0.0, 0.0, -30.0], [0.0, 0.0, 1.25, 5.5], [0, 0, 0, 1]]
)  # permuted axes and a flip: the window must follow the affine
DIAG = float(np.linalg.norm([0.7, 0.8, 1.25]))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_local_equals_the_full_field_where_the_distance_is_within_the_radius(seed):
    mask = _blobs(seed)
    full = VoxelSDF.from_mask(mask, AFFINE)
    rng = np.random.default_rng(100 + seed)
    lo, hi = full.bounds()
    checked = beyond = 0
    for _ in range(160):  # far points mostly answer None now: enough are left beyond
        p = rng.uniform(lo, hi)
        radius = float(rng.choice([0.0, 1.0, 3.0, 6.0]))
        local = local_mask_sdf(mask, AFFINE, p, radius)
        d_full = float(full.signed_distance(p))
        if local is None:  # nothing set in the window: farther than the radius
            assert d_full > radius
            continue
        d_local = float(local.signed_distance(p))
        if abs(d_full) <= radius:
            # value and gradient at the point and at points a voxel diagonal around it
            qs = p + rng.normal(size=(8, 3)) * (0.5 * DIAG / np.sqrt(3))
            qs = np.vstack([p, qs[np.abs(full.signed_distance(qs)) <= radius]])
            np.testing.assert_allclose(local.signed_distance(qs), full.signed_distance(qs),
                                       rtol=0, atol=1e-6)  # fmt: skip
            np.testing.assert_allclose(
                DistanceField._gradient(local, qs), DistanceField._gradient(full, qs),
                rtol=0, atol=1e-2 * DistanceField._gradient(full, qs).std() + 1e-9,
            )  # fmt: skip
            checked += 1
        else:  # the answer to "within the radius?" is the full field's
            assert np.sign(d_local) == np.sign(d_full)
            assert abs(d_local) > radius
            beyond += 1
    assert checked >= 10 and beyond >= 10


def test_gradient_equals_the_full_fields_at_surface_points():
    mask = _blobs(4)
    full = VoxelSDF.from_mask(mask, AFFINE)
    rng = np.random.default_rng(7)
    lo, hi = full.bounds()
    pts = rng.uniform(lo, hi, size=(4000, 3))
    near = pts[np.abs(full.signed_distance(pts)) <= 2.0][:40]
    assert len(near) == 40
    for p in near:
        local = local_mask_sdf(mask, AFFINE, p, 3.0)
        g_local = DistanceField._gradient(local, p[None])[0]
        g_full = DistanceField._gradient(full, p[None])[0]
        np.testing.assert_allclose(g_local, g_full, rtol=0, atol=1e-9)


def test_window_reaches_the_radius_and_five_voxel_diagonals():
    lo, hi = window_around(AFFINE, [12.0, -30.0, 5.5], 3.0)  # at index (0, 0, 0)
    spacing = np.array([0.8, 0.7, 1.25])  # of index axes i, j, k
    half = np.ceil((3.0 + 5 * DIAG) / spacing) + 2
    assert (hi == half).all() and (lo == -half).all()
    assert local_mask_sdf(_blobs(0), AFFINE, [500.0, 500.0, 500.0], 3.0) is None


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"point_mm": [np.nan, 0, 0]}, "point_mm"),
        ({"point_mm": [[0, 0, 0], [1, 1, 1]]}, "point_mm"),
        ({"radius_mm": -1.0}, "radius_mm"),
    ],
)
def test_bad_input_names_the_argument(kwargs, field):
    args = {"point_mm": [20.0, -10.0, 20.0], "radius_mm": 2.0, **kwargs}
    with pytest.raises(InvalidInputError, match=field):
        local_mask_sdf(_blobs(0), AFFINE, **args)


def test_lazy_field_answers_one_point_questions_without_building():
    mask = _blobs(5)
    builds = []

    def build():
        builds.append(1)
        return VoxelSDF.from_mask(mask, AFFINE)

    lazy = LazyField(build, "blobs", local=lambda p, r: local_mask_sdf(mask, AFFINE, p, r))
    full = VoxelSDF.from_mask(mask, AFFINE)
    lo, hi = full.bounds()
    p = 0.5 * (lo + hi)
    near = lazy.near(p, 2.0)
    assert not lazy.built and builds == []
    assert near is lazy.near(p, 2.0)  # kept for the next question at the same point
    if abs(float(full.signed_distance(p))) <= 2.0:
        assert float(near.signed_distance(p)) == pytest.approx(float(full.signed_distance(p)))
    lazy.get()
    assert lazy.near(p, 2.0) is lazy.get()  # once built, the field itself
    plain = LazyField(build, "blobs")  # no local function: built on the question
    assert plain.near(p, 2.0) is plain.get() and len(builds) == 2


# -- on Med-RAD lungs: the start's surface and normal as from the whole fields ------------


def _box_distance_oracle(mask, affine, p, half_mm=15.0):
    """Signed distance (brute force) from ``p`` to the union of the set voxels' boxes,
    from the voxels within ``half_mm`` of it (exact where ``|d| < half_mm``)."""
    inv = np.linalg.inv(affine)
    h = np.linalg.norm(affine[:3, :3], axis=0)
    u = inv[:3, :3] @ p + inv[:3, 3]
    lo = np.maximum(np.floor(u - half_mm / h).astype(int), 0)
    hi = np.minimum(np.ceil(u + half_mm / h).astype(int) + 1, np.array(mask.shape))
    sub = np.asarray(mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]], dtype=bool)
    idx = np.round(u).astype(int) - lo
    inside = bool(np.all((idx >= 0) & (idx < sub.shape)) and sub[tuple(idx)])
    centres = np.argwhere(~sub if inside else sub) + lo
    if len(centres) == 0:
        return -np.inf if inside else np.inf
    gap = np.maximum(np.abs(u - centres) - 0.5, 0.0) * h
    d = float(np.sqrt((gap**2).sum(axis=1)).min())
    return -d if inside else d


#: Starts where the airway's distance gradient is too short to give a normal (on a voxel
#: edge or the medial axis), measured with the whole fields.
UNDEFINED_NORMALS = {1: 1, 2: 0, 3: 1, 4: 1, 5: 0}


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize("patient", [1, 2, 3, 4, 5])
def test_medrad_start_surfaces_and_normals_from_windows_equal_the_whole_fields(medrad_dir, patient):
    from needlekit.benchmarks.steerable import medrad_lung_problem
    from needlekit.io.medrad import load_medrad
    from needlekit.io.volumes import read_mask

    case = load_medrad("lung", patient, medrad_dir)
    obstacles = case.scene.by_role(Role.OBSTACLE)
    masks = {s.name: read_mask(s.source) for s in obstacles}
    # the entry surface's whole field, as the scene would build it (read separately, so
    # that the scene's own fields stay unbuilt)
    whole = VoxelSDF.from_mask(masks["bronchialTree"])
    undefined = 0
    for start in case.starts:
        problem = medrad_lung_problem(case, start.name, 50.0)
        p = start.world_T_tip[:3, 3]
        excl = problem.start_exclusion_mm
        # each obstacle's local answer against the brute-force distance to its voxels
        for s in obstacles:
            local = s.field.near(p, excl)
            truth = _box_distance_oracle(masks[s.name].data, masks[s.name].affine, p)
            if local is None:
                assert truth > excl
                continue
            got = float(local.signed_distance(p))
            bound = local.error_bound_mm
            if abs(truth) <= excl + bound:
                assert abs(got - truth) <= bound
            else:
                assert np.sign(got) == np.sign(truth) and abs(got) > excl
        assert problem.entry_surface == "bronchialTree"  # transbronchial starts
        g = DistanceField._gradient(whole, p[None])[0]
        if np.linalg.norm(g) < MIN_NORMAL_GRADIENT:  # undefined there, for both
            assert problem.puncture_normal is None
            undefined += 1
        else:
            np.testing.assert_allclose(problem.puncture_normal, g / np.linalg.norm(g), atol=1e-9)
    assert not any(s.field.built for s in obstacles)  # windows answered every question
    assert undefined == UNDEFINED_NORMALS[patient]


def test_a_box_window_equals_the_full_field_near_surfaces_inside_the_box():
    """near_box: what a figure of a region draws, without the whole field: the full
    field's values wherever |d| <= radius inside the box, the right side elsewhere."""
    mask = _blobs(6)
    full = VoxelSDF.from_mask(mask, AFFINE)
    lo, hi = full.bounds()
    centre = 0.5 * (lo + hi)
    half = 0.3 * (hi - lo)
    local = local_mask_sdf(mask, AFFINE, centre, 2.0, half)
    assert local is not None and np.prod(local.shape) < np.prod(full.shape)
    rng = np.random.default_rng(11)
    pts = rng.uniform(centre - half, centre + half, size=(20000, 3))
    d_full, d_local = full.signed_distance(pts), local.signed_distance(pts)
    near = np.abs(d_full) <= 2.0
    assert near.sum() > 500
    np.testing.assert_allclose(d_local[near], d_full[near], rtol=0, atol=1e-6)
    assert np.all(np.sign(d_local[~near]) == np.sign(d_full[~near]))
    lazy = LazyField(lambda: full, "blobs",
                     local=lambda p, r, h=None: local_mask_sdf(mask, AFFINE, p, r, h))  # fmt: skip
    box = np.stack([centre - half, centre + half])
    assert lazy.near_box(box, 2.0) is not None and not lazy.built
    far = box + 1000.0
    assert lazy.near_box(far, 2.0) is None


def test_a_preview_draws_the_whole_structure_without_building_it():
    from needlekit.anatomy.summary import surface_mesh
    from needlekit.anatomy.voxel_local import preview_mask_sdf

    mask = np.zeros((120, 100, 90), bool)
    mask[20:100, 30:70, 10:80] = True  # a box with a thin plate
    mask[60, 5:95, 5:85] = True
    full = VoxelSDF.from_mask(mask, AFFINE)
    lazy = LazyField(lambda: full, "box",
                     preview=lambda cells: preview_mask_sdf(mask, AFFINE, cells))  # fmt: skip
    verts, faces = surface_mesh(lazy, max_cells=40)
    assert not lazy.built and len(faces) > 0
    assert max(lazy.preview(40).shape) <= 40
    # every drawn vertex lies within a coarse voxel diagonal of the structure's surface
    coarse_diag = float(np.linalg.norm(np.linalg.norm(lazy.preview(40).affine[:3, :3], axis=0)))
    assert np.abs(full.signed_distance(verts)).max() <= coarse_diag + full.error_bound_mm
    assert lazy.preview(40) is lazy.preview(40)  # kept


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mask_bounds_are_the_built_fields_bounds_bit_for_bit(seed):
    """VoxelSDF.mask_bounds, from the mask or from a crop of it placed in the whole grid,
    against the bounds of the field from_mask builds (crop on and off, other paddings),
    and a lazy field that boxes the structure without building it."""
    mask = _blobs(seed)
    rng = np.random.default_rng(seed)
    for crop, pad in ((True, 5.0), (True, 0.0), (False, 5.0), (True, 17.3)):
        built = VoxelSDF.from_mask(mask, AFFINE, crop=crop, padding_mm=pad).bounds()
        got = VoxelSDF.mask_bounds(mask, AFFINE, crop=crop, padding_mm=pad)
        assert np.array_equal(got, built), (crop, pad)
        idx = np.argwhere(mask)
        lo = idx.min(axis=0) - rng.integers(0, 3, 3)
        lo = np.maximum(lo, 0)
        hi = idx.max(axis=0) + 1
        part = mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
        cropped = VoxelSDF.mask_bounds(
            part, AFFINE, offset=lo, shape=mask.shape, crop=crop, padding_mm=pad
        )
        assert np.array_equal(cropped, built), (crop, pad)
        # the crop a prepared patient stores (cut to its set voxels): read off its shape
        from needlekit.io.medrad_cache import _cropped
        from needlekit.io.volumes import Mask

        stored, meta = _cropped(Mask(mask, AFFINE, None))
        tight = VoxelSDF.mask_bounds(stored, AFFINE, offset=meta["offset"], shape=meta["shape"],
                                     crop=crop, padding_mm=pad, tight=True)  # fmt: skip
        assert np.array_equal(tight, built), (crop, pad)
    lazy = LazyField(lambda: VoxelSDF.from_mask(mask, AFFINE), "blobs",
                     bounds=lambda: VoxelSDF.mask_bounds(mask, AFFINE))  # fmt: skip
    assert np.array_equal(lazy.bounds(), VoxelSDF.from_mask(mask, AFFINE).bounds())
    assert not lazy.built
    lazy.get()
    assert np.array_equal(lazy.bounds(), VoxelSDF.from_mask(mask, AFFINE).bounds())
    with pytest.raises(InvalidInputError, match="mask"):
        VoxelSDF.mask_bounds(np.zeros((4, 4, 4), bool), AFFINE)


def test_a_point_field_refuses_points_beyond_its_reach():
    """A one-point field keeps only the centres near its point: a farther query is an
    error naming the argument, never a value from centres it does not hold."""
    from needlekit.anatomy.voxel_local import LOCAL_REACH_DIAGONALS, LocalMaskField

    mask = _blobs(3)
    full = VoxelSDF.from_mask(mask, AFFINE)
    rng = np.random.default_rng(5)
    lo, hi = full.bounds()
    pts = rng.uniform(lo, hi, size=(4000, 3))
    p = pts[np.abs(full.signed_distance(pts)) <= 1.0][0]
    local = local_mask_sdf(mask, AFFINE, p, 6.0)  # |d| <= 1 + reach < 6 wherever it answers
    assert isinstance(local, LocalMaskField)
    assert local.reach_mm == pytest.approx(LOCAL_REACH_DIAGONALS * DIAG)
    assert max(local.shape) < min(full.shape)  # the centres near the point, not the window
    direction = np.array([0.6, -0.48, 0.64])
    inside = p + 0.99 * local.reach_mm * direction
    assert float(local.signed_distance(inside)) == pytest.approx(
        float(full.signed_distance(inside)), abs=1e-6
    )
    with pytest.raises(InvalidInputError, match="points"):
        local.signed_distance(p + 1.01 * local.reach_mm * direction)
    with pytest.raises(InvalidInputError, match="points"):
        local.gradient(p + 1.5 * local.reach_mm * direction)
