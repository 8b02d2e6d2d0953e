"""Voxel signed distance grids: kernels against references, error bounds against exact
distances to the voxel surface, the outside-grid rule, helpers and malformed input."""

import nibabel as nib
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.ndimage import distance_transform_edt, gaussian_filter, map_coordinates
from scipy.spatial.transform import Rotation

from needlekit.anatomy.grids import mask_edt
from needlekit.anatomy.voxel import (
    PARALLEL_MIN_POINTS,
    VoxelSDF,
    _trilinear,
    _trilinear_gradient,
    _trilinear_gradient_serial,
    _trilinear_serial,
    crop_mask,
    downsample_mask,
    grid_for_bounds,
    mask_surface_offset,
    trilinear_reference,
)
from needlekit.errors import InvalidInputError

# ----------------------------------------------------------------------------------------
# exact reference: signed distance to the boundary of the union of the set voxels' boxes


def _fronts(mask):
    """Set voxels with an unset face neighbour and unset voxels with a set one (indices),
    treating voxels beyond the array as unset."""
    padded = np.pad(mask, 1)
    nb_unset = np.zeros_like(padded)
    nb_set = np.zeros_like(padded)
    for axis in range(3):
        for shift in (1, -1):
            rolled = np.roll(padded, shift, axis)
            nb_unset |= ~rolled
            nb_set |= rolled
    return np.argwhere(padded & nb_unset) - 1, np.argwhere(~padded & nb_set) - 1


def voxel_surface_distance(mask, affine, points, chunk=256):
    """Exact signed distance (brute force) from world points to the mask's voxel surface."""
    inv = np.linalg.inv(affine)
    h = np.linalg.norm(affine[:3, :3], axis=0)
    u = points @ inv[:3, :3].T + inv[:3, 3]
    set_front, unset_front = _fronts(mask)
    idx = np.round(u).astype(np.int64)
    in_array = np.all((idx >= 0) & (idx < np.array(mask.shape)), axis=1)
    inside = np.zeros(len(points), bool)
    ii = idx[in_array]
    inside[in_array] = mask[ii[:, 0], ii[:, 1], ii[:, 2]]

    def box_distance(uu, centres):
        out = np.empty(len(uu))
        for s in range(0, len(uu), chunk):
            diff = np.maximum(np.abs(uu[s : s + chunk, None, :] - centres[None]) - 0.5, 0.0)
            out[s : s + chunk] = np.sqrt(((diff * h) ** 2).sum(-1).min(axis=1))
        return out

    d = np.empty(len(points))
    d[inside] = -box_distance(u[inside], unset_front)
    d[~inside] = box_distance(u[~inside], set_front)
    return d


def oblique_affine(spacing, seed, origin=(12.0, -40.0, 7.5)):
    """Rotated, axis-permuted and flipped voxel->RAS affine with the given spacings."""
    rot = Rotation.random(random_state=seed).as_matrix()
    perm = np.eye(3)[[2, 0, 1]] * np.array([1.0, -1.0, 1.0])[:, None]
    a = np.eye(4)
    a[:3, :3] = rot @ perm @ np.diag(spacing)
    a[:3, 3] = origin
    return a


def sphere_mask(shape, affine, centre, radius):
    idx = np.indices(shape).reshape(3, -1).T
    world = idx @ affine[:3, :3].T + affine[:3, 3]
    return (np.linalg.norm(world - centre, axis=1) <= radius).reshape(shape)


def points_in_box(rng, lo, hi, n):
    return rng.uniform(lo, hi, (n, 3))


def points_in_grid(rng, sdf, n):
    """Uniform points inside the box of voxel centres of an (oblique) grid."""
    u = rng.uniform(0.0, np.array(sdf.shape) - 1.0, (n, 3))
    return u @ sdf.affine[:3, :3].T + sdf.affine[:3, 3]


@pytest.fixture(scope="module")
def lung_like_sphere():
    """A voxelised sphere on an oblique grid with Med-RAD lung spacing."""
    spacing = (0.5508, 0.5508, 0.7)
    affine = oblique_affine(spacing, seed=3)
    shape = (28, 30, 24)
    centre = affine[:3, :3] @ (np.array(shape) / 2 - 0.3) + affine[:3, 3]
    mask = sphere_mask(shape, affine, centre, 5.2)
    return mask, affine, centre


# ----------------------------------------------------------------------------------------
# kernels


@pytest.mark.parametrize("seed", [0, 1])
def test_kernels_match_numpy_reference_and_scipy(seed):
    rng = np.random.default_rng(seed)
    vals = rng.normal(size=(7, 9, 11)).astype(np.float32)
    vals.flags.writeable = False  # as VoxelSDF holds its grid: the kernels' one signature
    affine = oblique_affine((0.7, 0.5, 1.2), seed)
    inv = np.linalg.inv(affine)
    u = rng.uniform(-2.0, np.array(vals.shape) + 1.0, (3000, 3))  # inside and outside
    pts = u @ affine[:3, :3].T + affine[:3, 3]
    fast = np.empty(len(pts))
    serial = np.empty(len(pts))
    val_g = np.empty(len(pts))
    grad = np.empty((len(pts), 3))
    _trilinear(vals, inv, pts, fast)
    _trilinear_serial(vals, inv, pts, serial)
    _trilinear_gradient(vals, inv, pts, val_g, grad)
    val_gs = np.empty(len(pts))
    grad_s = np.empty((len(pts), 3))
    _trilinear_gradient_serial(vals, inv, pts, val_gs, grad_s)
    assert np.array_equal(val_gs, val_g) and np.array_equal(grad_s, grad)
    ref, ref_grad = trilinear_reference(vals, inv, pts, gradient=True)
    assert np.abs(fast - ref).max() < 1e-12
    assert np.array_equal(fast, serial)
    assert np.array_equal(fast, val_g)
    assert np.abs(grad - ref_grad).max() < 1e-12
    inside = np.all((u >= 0) & (u <= np.array(vals.shape) - 1), axis=1)
    scipy_vals = map_coordinates(vals.astype(np.float64), u[inside].T, order=1)
    assert np.abs(fast[inside] - scipy_vals).max() < 1e-12


def test_gradient_matches_finite_differences_inside_and_outside_grid():
    rng = np.random.default_rng(5)
    vals = (rng.normal(size=(6, 7, 8)) + 3.0).astype(np.float32)  # > 0 on the boundary
    affine = oblique_affine((0.6, 0.9, 1.1), 5)
    inv = np.linalg.inv(affine)
    u = rng.uniform(-3.0, np.array(vals.shape) + 2.0, (2000, 3))
    pts = u @ affine[:3, :3].T + affine[:3, 3]
    _, grad = trilinear_reference(vals, inv, pts, gradient=True)
    step = 1e-6
    fd = np.stack(
        [
            (
                trilinear_reference(vals, inv, pts + step * e)
                - trilinear_reference(vals, inv, pts - step * e)
            )
            / (2 * step)
            for e in np.eye(3)
        ],
        axis=1,
    )
    # central differences straddle a cell face for a few points: compare the bulk
    err = np.abs(fd - grad).max(axis=1)
    assert np.median(err) < 1e-7
    assert np.mean(err < 1e-6) > 0.99


def test_field_uses_serial_and_parallel_kernels_consistently(lung_like_sphere):
    mask, affine, centre = lung_like_sphere
    sdf = VoxelSDF.from_mask(mask, affine)
    pts = centre + np.random.default_rng(1).normal(0, 6.0, (PARALLEL_MIN_POINTS + 10, 3))
    big = sdf.signed_distance(pts)
    small = np.array([float(sdf.signed_distance(p)) for p in pts[:50]])
    assert np.array_equal(big[:50], small)
    big_g = sdf.gradient(pts)
    assert np.array_equal(big_g[:50], np.array([sdf.gradient(p) for p in pts[:50]]))
    assert sdf.signed_distance(pts[0]).shape == ()
    assert sdf.gradient(pts[0]).shape == (3,)


# ----------------------------------------------------------------------------------------
# mask fields: error bound against the exact voxel surface


@pytest.mark.parametrize("seed", range(12))
def test_mask_edt_is_scipys_transform_and_edts_boolean_one(seed):
    """The shared EDT (the mask's bytes as uint8 labels) against SciPy's exact transform
    (unset voxels beyond the array, as ``black_border=False`` leaves them) and against
    the edt package given the boolean mask, on random anisotropic blobs and their
    complements."""
    import edt

    rng = np.random.default_rng(seed)
    shape = tuple(int(v) for v in rng.integers(2, 24, size=3))
    mask = gaussian_filter(rng.standard_normal(shape), 1.5) > rng.uniform(-0.2, 0.2)
    spacing = tuple(float(v) for v in rng.uniform(0.3, 2.0, size=3))
    for m in (mask, ~mask):
        got = mask_edt(m, spacing, threads=int(rng.integers(1, 3)))
        assert got.dtype == np.float32 and got.shape == m.shape
        boolean = edt.edt(m, anisotropy=spacing, black_border=False, parallel=1)
        assert np.array_equal(got, boolean)
        if m.all():  # no unset voxel at all: edt's convention, the array's border is not one
            continue
        exact = distance_transform_edt(m, sampling=spacing)
        np.testing.assert_allclose(got, exact, rtol=1e-6, atol=1e-6)


def test_mask_offset_and_bound_values():
    a, e = mask_surface_offset([1.0, 1.0, 1.0])
    assert a == pytest.approx((np.sqrt(3) / 2 + 0.5) / 2)
    assert e == pytest.approx((np.sqrt(3) - 1) / 4)
    # Med-RAD lungs: value error 0.124 mm, whole bound 0.648 mm
    a, e = mask_surface_offset([0.5508, 0.5508, 0.7])
    r = 0.5 * np.linalg.norm([0.5508, 0.5508, 0.7])
    assert e == pytest.approx(0.1241, abs=1e-4)
    assert e + r == pytest.approx(0.648, abs=1e-3)
    # very anisotropic (5 mm slices): the offset is capped to keep signs at centres
    a, e = mask_surface_offset([0.78, 0.78, 5.0])
    assert a == pytest.approx(0.75 * 0.78)
    assert e == pytest.approx(0.5 * np.linalg.norm([0.78, 0.78, 5.0]) - a)


def test_mask_sdf_values_at_centres_within_value_error(lung_like_sphere):
    mask, affine, _ = lung_like_sphere
    sdf = VoxelSDF.from_mask(mask, affine, padding_mm=2.0)
    centres = sdf.voxel_centres()
    exact = voxel_surface_distance(mask, affine, centres)
    err = np.abs(sdf.values.ravel() - exact)
    assert err.max() <= sdf.value_error_mm
    # signs at centres agree with the mask
    assert np.all((sdf.values.ravel() < 0) == (exact < 0))


def test_mask_sdf_within_bound_at_random_points(lung_like_sphere):
    mask, affine, centre = lung_like_sphere
    sdf = VoxelSDF.from_mask(mask, affine)
    rng = np.random.default_rng(7)
    dirs = rng.normal(size=(1500, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    near = centre + dirs * rng.uniform(3.0, 7.0, (1500, 1))  # around the surface
    far = points_in_grid(rng, sdf, 1500)  # anywhere in the grid
    pts = np.vstack([near, far])
    exact = voxel_surface_distance(mask, affine, pts)
    err = np.abs(sdf.signed_distance(pts) - exact)
    assert err.max() <= sdf.error_bound_mm
    assert sdf.error_bound_mm == pytest.approx(0.648, abs=2e-3)


def test_mask_sdf_within_bound_plus_discretisation_of_analytic_sphere(lung_like_sphere):
    # the voxel surface lies within r of the sphere (both centres of a face pair are)
    mask, affine, centre = lung_like_sphere
    sdf = VoxelSDF.from_mask(mask, affine)
    rng = np.random.default_rng(8)
    pts = centre + rng.uniform(-9, 9, (3000, 3))
    analytic = np.linalg.norm(pts - centre, axis=1) - 5.2
    err = np.abs(sdf.signed_distance(pts) - analytic)
    assert err.max() <= sdf.error_bound_mm + sdf.interpolation_error_mm


def test_value_error_is_attained_by_a_single_voxel():
    mask = np.zeros((9, 9, 9), bool)
    mask[4, 4, 4] = True
    sdf = VoxelSDF.from_mask(mask, np.eye(4))
    # exact depth of the centre of a unit voxel is -0.5
    assert float(sdf.signed_distance([4.0, 4.0, 4.0])) - (-0.5) == pytest.approx(
        sdf.value_error_mm, abs=1e-6
    )


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**31 - 1),
    spacing=st.tuples(*[st.floats(0.3, 1.5)] * 3),
    level=st.floats(-0.3, 0.3),
)
def test_mask_sdf_bound_holds_for_random_blobs(seed, spacing, level):
    rng = np.random.default_rng(seed)
    noise = gaussian_filter(rng.normal(size=(12, 11, 10)), 1.5)
    mask = noise > level * noise.std()
    if not mask.any():
        mask[5, 5, 5] = True
    affine = oblique_affine(spacing, seed % 1000)
    sdf = VoxelSDF.from_mask(mask, affine, padding_mm=1.0)
    pts = points_in_grid(rng, sdf, 400)
    exact = voxel_surface_distance(mask, affine, pts)
    assert np.abs(sdf.signed_distance(pts) - exact).max() <= sdf.error_bound_mm


def test_crop_does_not_change_values_inside_the_cropped_grid(lung_like_sphere):
    mask, affine, _ = lung_like_sphere
    big = np.zeros((60, 50, 40), bool)
    big[10:38, 5:35, 8:32] = mask
    cropped = VoxelSDF.from_mask(big, affine, padding_mm=2.0)
    full = VoxelSDF.from_mask(big, affine, crop=False)
    assert cropped.shape < full.shape
    pts = points_in_grid(np.random.default_rng(2), cropped, 2000)
    assert np.abs(cropped.signed_distance(pts) - full.signed_distance(pts)).max() < 1e-5
    assert np.allclose(cropped.bounds(), full.bounds())


def test_mask_touching_the_array_edge_is_closed_by_padding():
    mask = np.zeros((6, 6, 6), bool)
    mask[:3] = True  # touches the i = 0 face
    sdf = VoxelSDF.from_mask(mask, np.eye(4), crop=False)
    assert sdf.shape[0] > 6
    # the face beyond index 0 is surface: the point at index -0.5 is on it
    assert abs(float(sdf.signed_distance([-0.5, 2.5, 2.5]))) <= sdf.error_bound_mm
    assert float(sdf.signed_distance([-3.0, 2.5, 2.5])) > 2.5 - sdf.error_bound_mm


def test_bounds_are_the_box_of_the_set_voxels():
    mask = np.zeros((10, 10, 10), bool)
    mask[2:5, 3, 4:9] = True
    affine = np.diag([0.5, -1.0, 2.0, 1.0])
    sdf = VoxelSDF.from_mask(mask, affine)
    assert np.allclose(sdf.bounds(), [[0.75, -3.5, 7.0], [2.25, -2.5, 17.0]])


# ----------------------------------------------------------------------------------------
# outside the grid


def test_outside_grid_values_are_conservative(lung_like_sphere):
    mask, affine, _ = lung_like_sphere
    sdf = VoxelSDF.from_mask(mask, affine, padding_mm=1.5)
    rng = np.random.default_rng(11)
    lo, hi = sdf.grid_bounds()
    pts = points_in_box(rng, lo - 15, hi + 15, 4000)
    inv = sdf.inv_affine
    u = pts @ inv[:3, :3].T + inv[:3, 3]
    outside = np.any((u < 0) | (u > np.array(sdf.shape) - 1), axis=1)
    pts = pts[outside]
    got = sdf.signed_distance(pts)
    exact = voxel_surface_distance(mask, affine, pts)
    assert np.all(got > 0)
    assert np.all(got <= exact + sdf.error_bound_mm)
    assert np.all(got >= (exact - sdf.error_bound_mm) / np.sqrt(2))


def test_outside_grid_rule_is_continuous_at_the_grid_boundary():
    mask = np.zeros((12, 12, 12), bool)
    mask[4:8, 5:7, 3:9] = True
    sdf = VoxelSDF.from_mask(mask, np.diag([0.8, 0.6, 1.0, 1.0]), padding_mm=0.5)
    edge = sdf.grid_bounds()[1, 0]
    y, z = 3.3, 6.2
    inner = float(sdf.signed_distance([edge - 1e-9, y, z]))
    outer = float(sdf.signed_distance([edge + 1e-9, y, z]))
    assert outer == pytest.approx(inner, abs=1e-6)


# ----------------------------------------------------------------------------------------
# fields from functions


def test_from_function_sphere_within_bound():
    centre = np.array([3.0, -2.0, 10.0])
    affine, shape = grid_for_bounds([centre - 6, centre + 6], 0.7, 2.0)
    affine = affine @ np.diag([1.0, 1.0, 1.0, 1.0])
    sdf = VoxelSDF.from_function(
        lambda p: np.linalg.norm(p - centre, axis=1) - 6.0, affine, shape, chunk_points=5000
    )
    assert sdf.error_bound_mm == pytest.approx(0.5 * 0.7 * np.sqrt(3), abs=1e-5)
    pts = centre + np.random.default_rng(4).uniform(-7.9, 7.9, (3000, 3))
    exact = np.linalg.norm(pts - centre, axis=1) - 6.0
    assert np.abs(sdf.signed_distance(pts) - exact).max() <= sdf.error_bound_mm


def test_interpolation_bound_is_attained_at_a_cell_centre():
    # a structure of (almost) zero size at a cell centre: all 8 corners read r
    affine = oblique_affine((0.5, 0.8, 1.1), 9)
    shape = (8, 8, 8)
    x0 = affine[:3, :3] @ np.array([3.5, 3.5, 3.5]) + affine[:3, 3]
    eps = 1e-3
    sdf = VoxelSDF.from_function(lambda p: np.linalg.norm(p - x0, axis=1) - eps, affine, shape)
    err = float(sdf.signed_distance(x0)) - (-eps)
    assert 0.999 * sdf.interpolation_error_mm <= err <= sdf.error_bound_mm


def test_from_function_accepts_a_field_and_adds_its_error():
    inner = VoxelSDF.from_function(
        lambda p: np.linalg.norm(p, axis=1) - 3.0, *grid_for_bounds([[-3] * 3, [3] * 3], 1.0, 3.0)
    )
    affine, shape = grid_for_bounds(inner.bounds(), 0.5, 2.0)
    baked = VoxelSDF.from_function(inner, affine, shape)
    assert baked.value_error_mm >= inner.error_bound_mm
    assert baked.error_bound_mm == pytest.approx(inner.error_bound_mm + 0.25 * np.sqrt(3), abs=1e-4)


def test_structure_reaching_the_grid_boundary_is_refused():
    affine, shape = grid_for_bounds([[-3] * 3, [3] * 3], 1.0, 0.0)
    with pytest.raises(InvalidInputError, match="reaches the grid boundary"):
        VoxelSDF.from_function(lambda p: np.linalg.norm(p, axis=1) - 3.0, affine, shape)


# ----------------------------------------------------------------------------------------
# helpers


def test_crop_mask_keeps_world_positions():
    mask = np.zeros((30, 20, 25), bool)
    mask[12:15, 3:9, 20:24] = True
    affine = oblique_affine((0.5, 0.7, 0.9), 1)
    cropped, caff = crop_mask(mask, affine, padding_mm=2.0)
    assert cropped.sum() == mask.sum()

    def world(m, a):
        return np.sort((np.argwhere(m) @ a[:3, :3].T + a[:3, 3]).round(9), axis=0)

    assert np.allclose(world(mask, affine), world(cropped, caff))
    # margin of ceil(2 / h) voxels, zero-padded beyond the array (k: 24 + 3 > 25)
    assert cropped.shape == (3 + 2 * 4, 6 + 2 * 3, 4 + 2 * 3)


def test_downsample_contains_the_fine_structure():
    rng = np.random.default_rng(1)
    fine = gaussian_filter(rng.normal(size=(20, 18, 16)), 1.0) > 0.1
    affine = oblique_affine((0.5, 0.6, 0.7), 2)
    coarse, caff = downsample_mask(fine, affine, 3)
    assert coarse.shape == (7, 6, 6)
    assert np.allclose(np.linalg.norm(caff[:3, :3], axis=0), [1.5, 1.8, 2.1])
    # every fine set voxel centre lies in the box of a set coarse voxel
    fine_world = np.argwhere(fine) @ affine[:3, :3].T + affine[:3, 3]
    u = fine_world @ np.linalg.inv(caff)[:3, :3].T + np.linalg.inv(caff)[:3, 3]
    idx = np.round(u).astype(int)
    assert np.all(coarse[idx[:, 0], idx[:, 1], idx[:, 2]])


def test_grid_for_bounds_covers_the_box():
    affine, shape = grid_for_bounds([[0.0, -1.0, 2.0], [3.3, 1.0, 2.0]], 0.5, 1.0)
    last = affine[:3, :3] @ (np.array(shape) - 1) + affine[:3, 3]
    assert np.all(affine[:3, 3] <= [-1.0, -2.0, 1.0])
    assert np.all(last >= [4.3, 2.0, 3.0])


# ----------------------------------------------------------------------------------------
# malformed input


def _blob():
    m = np.zeros((5, 5, 5), bool)
    m[2, 2, 2] = True
    return m


@pytest.mark.parametrize(
    ("mask", "affine", "match"),
    [
        (np.zeros((5, 5), bool), np.eye(4), "3-D"),
        (np.zeros((5, 5, 5), bool), np.eye(4), "no voxel is set"),
        (_blob() * 2, np.eye(4), r"0/1 values, found also \[2\]"),
        (np.where(_blob(), np.nan, 0.0), np.eye(4), "NaN"),
        (_blob().astype(complex), np.eye(4), "booleans"),
        (_blob(), np.eye(3), "4x4"),
        (_blob(), np.diag([1.0, 0.0, 1.0, 1.0]), "degenerate"),
        (_blob(), np.array([[1, 0.2, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]), "shear"),
        (_blob(), np.diag([1.0, 1.0, np.nan, 1.0]), "finite"),
        (_blob(), np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1, 1.0]]), "last row"),
        (_blob(), None, "needs its voxel->RAS affine"),
    ],
)
def test_from_mask_rejects_bad_input(mask, affine, match):
    with pytest.raises(InvalidInputError, match=match):
        VoxelSDF.from_mask(mask, affine)


def test_from_mask_accepts_mask_objects_and_checks_their_affine():
    class M:
        data = _blob()
        affine = np.diag([0.5, 0.5, 0.5, 1.0])

    sdf = VoxelSDF.from_mask(M())
    assert sdf.spacing_mm.tolist() == [0.5, 0.5, 0.5]
    with pytest.raises(InvalidInputError, match="differs"):
        VoxelSDF.from_mask(M(), np.eye(4))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"values": np.ones((1, 4, 4))}, ">= 2 voxels"),
        ({"values": np.full((4, 4, 4), np.nan)}, "finite"),
        ({"values": np.ones((4, 4, 4)) * 5, "value_error_mm": -1.0}, "value_error_mm"),
    ],
)
def test_constructor_rejects_bad_input(kwargs, match):
    kwargs = {"affine": np.eye(4), **kwargs}
    with pytest.raises(InvalidInputError, match=match):
        VoxelSDF(**kwargs)


def test_from_function_rejects_bad_output_and_shape():
    affine = np.eye(4)
    with pytest.raises(InvalidInputError, match="fn: expected 64 distances"):
        VoxelSDF.from_function(lambda p: np.ones(3), affine, (4, 4, 4))
    with pytest.raises(InvalidInputError, match="shape"):
        VoxelSDF.from_function(lambda p: np.ones(len(p)), affine, (4, 4))


# ----------------------------------------------------------------------------------------
# real anatomy


def _medrad_case(root, name):
    img = nib.load(root / "Lungs" / "TumorTargetEnvironments" / "Patient1" / f"{name}.nii.gz")
    return np.asanyarray(img.dataobj) != 0, img.affine


@pytest.mark.realdata
def test_medrad_nodule_sdf_within_bound_of_its_voxel_surface(medrad_dir):
    mask, affine = _medrad_case(medrad_dir, "nodule")
    sdf = VoxelSDF.from_mask(mask, affine, padding_mm=3.0)
    assert sdf.error_bound_mm == pytest.approx(0.648, abs=2e-3)
    cropped, caff = crop_mask(mask, affine, padding_mm=3.0)
    rng = np.random.default_rng(0)
    lo, hi = sdf.bounds()
    pts = points_in_box(rng, lo - 2, hi + 2, 600)
    exact = voxel_surface_distance(cropped, caff, pts)
    assert np.abs(sdf.signed_distance(pts) - exact).max() <= sdf.error_bound_mm


def test_wrappers_ask_for_the_grids_lipschitz_bound_only_when_needed(lung_like_sphere):
    """The bound takes a pass over every value of the grid (a 352 MB pass on a Med-RAD
    lung, on every load): wrapping a grid must not compute it, asking must give the grid's."""
    from needlekit.anatomy.fields import (
        BoundedField,
        ComplementField,
        OffsetField,
        TransformedField,
    )

    mask, affine, _ = lung_like_sphere
    sdf = VoxelSDF.from_mask(mask, affine)
    wrapped = [
        ComplementField(sdf),
        OffsetField(sdf, 1.0),
        TransformedField(sdf, np.eye(4)),
        BoundedField(sdf, sdf),
        ComplementField(OffsetField(TransformedField(sdf, np.eye(4)), 0.5)),
    ]
    assert getattr(sdf, "_lipschitz", None) is None
    bound = wrapped[-1].lipschitz_bound
    assert bound is not None and bound >= 1.0 and sdf._lipschitz == bound
    assert all(w.lipschitz_bound == bound for w in wrapped)


def test_padding_changes_no_value_on_the_smaller_grid():
    """The free space's field keeps no margin (io.medrad_prepare.FREE_SPACE_PADDING_MM): its values
    are the padded field's, voxel for voxel, and points beyond its grid stay outside."""
    rng = np.random.default_rng(3)
    mask = np.zeros((40, 36, 30), bool)
    idx = np.indices(mask.shape).reshape(3, -1).T
    for _ in range(5):
        c, r = rng.uniform(8, 24, 3), rng.uniform(3, 7)
        mask.reshape(-1)[np.linalg.norm(idx - c, axis=1) <= r] = True
    affine = np.diag([0.7, 0.8, 1.25, 1.0])
    tight = VoxelSDF.from_mask(mask, affine, padding_mm=0.0)
    wide = VoxelSDF.from_mask(mask, affine, padding_mm=10.0)
    # the tight grid sits inside the wide one at a whole-voxel offset
    off = np.round(np.linalg.solve(wide.affine[:3, :3], tight.affine[:3, 3] - wide.affine[:3, 3]))
    o = off.astype(int)
    assert (o > 0).all()
    s = tight.values.shape
    np.testing.assert_array_equal(tight.values, wide.values[o[0] : o[0] + s[0],
                                  o[1] : o[1] + s[1], o[2] : o[2] + s[2]])  # fmt: skip
    assert tight.error_bound_mm <= wide.error_bound_mm
    lo, hi = wide.bounds()
    pts = rng.uniform(lo - 12.0, hi + 12.0, size=(3000, 3))
    d_tight, d_wide = tight.signed_distance(pts), wide.signed_distance(pts)
    assert np.all(np.sign(d_tight) == np.sign(d_wide))
    assert np.all(d_tight[d_wide > 0] <= d_wide[d_wide > 0] + wide.error_bound_mm)


def test_few_point_lookups_run_the_kernels_source_bit_for_bit():
    # a problem's one-point questions go through the kernels' Python source (no numba
    # load): it must give exactly what the kernels give, inside and outside the grid
    from needlekit.anatomy._trilinear import (
        _trilinear_gradient_serial,
        _trilinear_serial,
        trilinear_few,
    )

    rng = np.random.default_rng(1)
    for t in range(200):
        shape = tuple(int(v) for v in rng.integers(2, 9, size=3))
        vals = rng.normal(size=shape).astype(np.float32 if t % 2 else np.float64)
        vals.flags.writeable = not t % 2  # float32 read-only, as VoxelSDF holds its grid
        a = np.diag(np.r_[rng.uniform(0.3, 2, 3), 1.0])
        a[:3, 3] = rng.normal(size=3)
        rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        a[:3, :3] = rot @ a[:3, :3]
        inv = np.linalg.inv(a)
        ijk = rng.uniform(-2, np.array(shape) + 1, size=(8, 3))
        pts = ijk @ a[:3, :3].T + a[:3, 3]
        out, grad, out2 = np.empty(8), np.empty((8, 3)), np.empty(8)
        _trilinear_gradient_serial(vals, inv, pts, out, grad)
        _trilinear_serial(vals, inv, pts, out2)
        few_grad = trilinear_few(vals, inv, pts, gradient=True)
        assert np.array_equal(trilinear_few(vals, inv, pts), out2)
        assert np.array_equal(few_grad[0], out) and np.array_equal(few_grad[1], grad)


def test_mask_bounding_box_matches_brute_force_tight_crops_included():
    """``_bbox`` against the brute-force box of the set voxels, masks already cut to their
    set voxels (as a prepared patient's are stored) among them."""
    from needlekit.anatomy.grids import _bbox

    rng = np.random.default_rng(7)
    tight = 0
    for _ in range(2000):
        shape = tuple(int(v) for v in rng.integers(1, 7, 3))
        m = rng.random(shape) < rng.choice([0.0, 0.05, 0.3, 0.9])
        got, idx = _bbox(m), np.argwhere(m)
        if len(idx) == 0:
            assert got is None
            continue
        assert np.array_equal(got[0], idx.min(0)) and np.array_equal(got[1], idx.max(0))
        tight += bool(np.all(idx.min(0) == 0) and np.all(idx.max(0) == np.array(shape) - 1))
    assert tight > 300  # masks that are their own box, many times
