"""Tissue deformation models: analytic expectations of the needle-drag default (decay,
symmetry, drag along the insertion, radial push, superposition), the grid model against
fields trilinear interpolation reproduces exactly, file round trips, and bad input."""

from __future__ import annotations

import logging

import nibabel as nib
import numpy as np
import pytest

from needlekit.anatomy.needle_body import LIU_HEAD, NeedleBody
from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import so3_exp
from needlekit.planning.straight.deformation import (
    DEFAULT_DRAG_MM,
    DEFAULT_SUPPORT_RADIUS_MM,
    MAX_PLAUSIBLE_DISPLACEMENT_MM,
    CallableDeformation,
    DeformationModel,
    DisplacementGrid,
    GridDeformation,
    NeedleDragDeformation,
    NoDeformation,
    PlacedNeedle,
    deform_points,
)

TIP = np.array([10.0, -5.0, 20.0])
V = np.array([0.36, -0.48, -0.8])  # unit insertion direction (entry -> tip)
ENTRY = TIP - 90.0 * V
NEEDLE = PlacedNeedle(TIP, ENTRY, 0.5)


def _perp(v, angle):
    a = np.cross(v, [1.0, 0.0, 0.0])
    a /= np.linalg.norm(a)
    b = np.cross(v, a)
    return np.cos(angle) * a + np.sin(angle) * b


# ----------------------------------------------------------------------------------------
# placed needles, the interface, NoDeformation


def test_placed_needle_geometry_and_body():
    np.testing.assert_allclose(NEEDLE.direction, V, atol=1e-15)
    assert NEEDLE.length_mm == pytest.approx(90.0)
    assert not NEEDLE.tip_mm.flags.writeable
    body = NEEDLE.body()
    assert isinstance(body, NeedleBody) and body.head is LIU_HEAD
    np.testing.assert_allclose(body.axis_unit, -V, atol=1e-15)
    bare = NEEDLE.body(head=None, shaft_outside_mm=10.0)
    assert bare.head_field is None
    np.testing.assert_allclose(bare.head_start_mm, ENTRY - 10.0 * V)


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (([0, 0, 0], [0, 0, 0], 0.5), "entry_mm"),
        (([0, 0, np.nan], [0, 0, 9], 0.5), "tip_mm"),
        (([0, 0, 0], [[0, 0, 9]] * 2, 0.5), "entry_mm"),
        (([0, 0, 0], [0, 0, 9], -1.0), "radius_mm"),
    ],
)
def test_placed_needle_bad_input(args, field):
    with pytest.raises(InvalidInputError, match=f"^{field}: "):
        PlacedNeedle(*args)


def test_every_model_is_a_deformation_model_and_none_moves_nothing_without_needles():
    grid = DisplacementGrid(np.ones((2, 2, 2, 3)), np.diag([100.0, 100.0, 100.0, 1.0]))
    models = [
        NoDeformation(),
        NeedleDragDeformation(),
        GridDeformation(grid),
        CallableDeformation(lambda p, placed: np.full(p.shape, float(len(placed)))),
    ]
    pts = np.random.default_rng(0).uniform(1.0, 99.0, (20, 3))
    for m in models:
        assert isinstance(m, DeformationModel)
        np.testing.assert_array_equal(m.displacement(pts, []), 0.0)
        assert m.displacement(pts[0], []).shape == (3,)
    np.testing.assert_array_equal(NoDeformation().displacement(pts, [NEEDLE] * 3), 0.0)
    assert not isinstance(object(), DeformationModel)


class _Flat:
    """A user model that forgets a coordinate."""

    def displacement(self, points_mm, placed):
        return np.zeros((len(np.atleast_2d(points_mm)), 2))


def test_deform_points_adds_the_displacement():
    model = NeedleDragDeformation()
    p = TIP - 40.0 * V + 3.0 * _perp(V, 0.3)
    np.testing.assert_allclose(
        deform_points(model, p, [NEEDLE]), p + model.displacement(p, [NEEDLE])
    )
    with pytest.raises(InvalidInputError, match=r"^model: "):
        deform_points("drag", p, [NEEDLE])
    with pytest.raises(InvalidInputError, match=r"^model: "):
        deform_points(_Flat(), p, [NEEDLE])


class _Duck:
    """A needle record of another module: tip_mm, entry_mm, radius_mm only."""

    def __init__(self, tip, entry, r):
        self.tip_mm, self.entry_mm, self.radius_mm = tip, entry, r


def test_objects_with_the_three_fields_count_as_placed_needles():
    m = NeedleDragDeformation()
    pts = np.random.default_rng(8).uniform(-30.0, 60.0, (50, 3))
    duck = _Duck(TIP, ENTRY, 0.5)
    np.testing.assert_array_equal(m.displacement(pts, [duck]), m.displacement(pts, [NEEDLE]))
    seen = {}

    def record(points, placed):
        seen["n"] = placed
        return np.zeros(points.shape)

    CallableDeformation(record).displacement(pts, [duck])
    assert isinstance(seen["n"][0], PlacedNeedle)
    with pytest.raises(InvalidInputError, match=r"^placed\[0\]\.radius_mm: "):
        m.displacement(pts, [_Duck(TIP, ENTRY, -1.0)])
    with pytest.raises(InvalidInputError, match=r"^placed\[0\]\.entry_mm: "):
        m.displacement(pts, [_Duck(TIP, TIP, 0.5)])


@pytest.mark.parametrize("model", [NoDeformation(), NeedleDragDeformation()])
def test_placed_must_be_a_sequence_of_needles(model):
    with pytest.raises(InvalidInputError, match=r"^placed: "):
        model.displacement([0.0, 0.0, 0.0], NEEDLE)
    with pytest.raises(InvalidInputError, match=r"^placed\[1\]: "):
        model.displacement([0.0, 0.0, 0.0], [NEEDLE, (TIP, ENTRY, 0.5)])
    with pytest.raises(InvalidInputError, match=r"^points_mm: "):
        model.displacement([[0.0, 0.0]], [NEEDLE])


# ----------------------------------------------------------------------------------------
# the needle-drag default


def test_defaults_and_window():
    m = NeedleDragDeformation()
    assert (m.drag_mm, m.support_radius_mm, m.radial_push) == (2.0, 30.0, True)
    assert (DEFAULT_DRAG_MM, DEFAULT_SUPPORT_RADIUS_MM) == (2.0, 30.0)
    np.testing.assert_allclose(
        m.window([0.0, 15.0, 29.999, 30.0, 45.0]), [1, 0.421875, 0, 0, 0], atol=1e-12
    )
    r = np.linspace(0.0, 30.0, 301)
    assert np.all(np.diff(m.window(r)) <= 0.0)  # decays monotonically


def test_on_the_shaft_drag_equals_the_insertion_direction():
    m = NeedleDragDeformation()
    for s in (0.0, 10.0, 45.0, 90.0):  # entry to tip, on the axis
        u = m.displacement(ENTRY + s * V, [NEEDLE])
        np.testing.assert_allclose(u, DEFAULT_DRAG_MM * V, atol=1e-12)


def test_drag_alone_is_along_the_insertion_and_decays_with_the_distance():
    m = NeedleDragDeformation(radial_push=False)
    rng = np.random.default_rng(1)
    pts = TIP - rng.uniform(-20.0, 110.0, (500, 1)) * V + rng.normal(size=(500, 3)) * 12.0
    u = m.displacement(pts, [NEEDLE])
    along = u @ V
    np.testing.assert_allclose(u, along[:, None] * V, atol=1e-12)  # parallel to V
    assert np.all(along >= 0.0) and np.all(along <= DEFAULT_DRAG_MM)
    # beside the middle of the shaft: exactly D g(r)
    mid = ENTRY + 45.0 * V
    for r in (0.0, 1.0, 5.0, 10.0, 15.0, 29.0):
        d = m.displacement(mid + r * _perp(V, 1.1), [NEEDLE])
        assert d @ V == pytest.approx(2.0 * (1.0 - (r / 30.0) ** 2) ** 3, abs=1e-12)
    assert m.displacement(mid + 10.0 * _perp(V, 0.0), [NEEDLE]) @ V == pytest.approx(
        2.0 * (8.0 / 9.0) ** 3
    )


def test_radial_push_points_away_from_the_axis_with_the_stated_size():
    m = NeedleDragDeformation()
    drag_only = NeedleDragDeformation(radial_push=False)
    mid = ENTRY + 30.0 * V
    R = NEEDLE.radius_mm
    for r in (0.1, 0.5, 1.0, 3.0, 10.0, 25.0):
        n = _perp(V, 2.0)
        p = mid + r * n
        radial = m.displacement(p, [NEEDLE]) - drag_only.displacement(p, [NEEDLE])
        g = (1.0 - (r / 30.0) ** 2) ** 3
        np.testing.assert_allclose(radial, R**2 * r / (2.0 * (r**2 + R**2)) * g * n, atol=1e-13)
        assert radial @ n > 0.0
    # far from the shaft it is the area balance R^2 / (2 r) of an incompressible medium
    wide = NeedleDragDeformation(drag_mm=0.0, support_radius_mm=1e9)
    for r in (5.0, 20.0, 80.0):
        u = wide.displacement(mid + r * _perp(V, 0.4), [NEEDLE])
        assert np.linalg.norm(u) == pytest.approx(R**2 / (2.0 * r), rel=2 * R**2 / r**2)
    # largest at the shaft wall: R / 4 there
    rs = np.linspace(0.0, 3.0, 3001)
    sizes = np.linalg.norm(wide.displacement(mid + rs[:, None] * _perp(V, 0.0), [NEEDLE]), axis=1)
    assert rs[np.argmax(sizes)] == pytest.approx(R, abs=1e-3)
    assert sizes.max() == pytest.approx(R / 4.0, rel=1e-6)


def test_axisymmetry_and_tissue_ahead_of_the_tip_is_pushed_forward():
    m = NeedleDragDeformation()
    base = ENTRY + 50.0 * V + 7.0 * _perp(V, 0.0)
    u0 = m.displacement(base, [NEEDLE])
    for angle in (0.7, 2.0, 4.4):
        rot = so3_exp(angle * V)
        p = ENTRY + rot @ (base - ENTRY)
        np.testing.assert_allclose(m.displacement(p, [NEEDLE]), rot @ u0, atol=1e-12)
    ahead = m.displacement(TIP + 2.0 * V, [NEEDLE])
    np.testing.assert_allclose(ahead / np.linalg.norm(ahead), V, atol=1e-12)
    # behind the needle, past the support: nothing moves
    np.testing.assert_array_equal(m.displacement(TIP + 30.0 * V, [NEEDLE]), 0.0)
    np.testing.assert_array_equal(
        m.displacement(ENTRY + 50.0 * V + 30.0 * _perp(V, 1.0), [NEEDLE]), 0.0
    )


def test_continuous_finite_and_zero_far_away():
    m = NeedleDragDeformation()
    # lines through the shaft, past the tip and across the support boundary
    t = np.linspace(-40.0, 40.0, 80001)[:, None]
    lines = [
        ENTRY + 45.0 * V + t * _perp(V, 0.2),
        TIP + t * _perp(V, 1.3),
        TIP + t * V,
        TIP + t * (V + _perp(V, 0.5)) / np.sqrt(2.0),
    ]
    bound = DEFAULT_DRAG_MM + NEEDLE.radius_mm / 4.0
    for pts in lines:
        u = m.displacement(pts, [NEEDLE])
        assert np.all(np.isfinite(u))
        assert np.linalg.norm(u, axis=1).max() <= bound + 1e-12
        jumps = np.linalg.norm(np.diff(u, axis=0), axis=1)
        assert jumps.max() < 1e-3  # steps of 1e-3 mm: Lipschitz, no jump
    far = np.random.default_rng(2).normal(size=(100, 3))
    far = TIP + 200.0 * far / np.linalg.norm(far, axis=1, keepdims=True)
    np.testing.assert_array_equal(m.displacement(far, [NEEDLE]), 0.0)


def test_several_needles_add_up():
    m = NeedleDragDeformation()
    second = PlacedNeedle([25.0, 0.0, 15.0], [40.0, 30.0, 90.0], 0.8)
    pts = np.random.default_rng(3).uniform(-30.0, 60.0, (400, 3))
    both = m.displacement(pts, [NEEDLE, second])
    np.testing.assert_allclose(
        both, m.displacement(pts, [NEEDLE]) + m.displacement(pts, [second]), atol=1e-14
    )
    np.testing.assert_allclose(both, m.displacement(pts, [second, NEEDLE]), atol=1e-14)
    # the same needle twice drags twice as far
    np.testing.assert_allclose(
        m.displacement(pts, [NEEDLE, NEEDLE]), 2.0 * m.displacement(pts, [NEEDLE]), atol=1e-14
    )


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"drag_mm": -1.0}, "drag_mm"),
        ({"drag_mm": np.nan}, "drag_mm"),
        ({"support_radius_mm": 0.0}, "support_radius_mm"),
        ({"radial_push": "yes"}, "radial_push"),
    ],
)
def test_drag_bad_parameters(kwargs, field):
    with pytest.raises(InvalidInputError, match=f"^{field}: "):
        NeedleDragDeformation(**kwargs)


# ----------------------------------------------------------------------------------------
# grids


AFFINE = np.eye(4)
AFFINE[:3, :3] = so3_exp([0.2, -0.4, 0.3]) @ np.diag([1.5, 2.0, 2.5])
AFFINE[:3, 3] = [-20.0, 5.0, 12.0]
B = np.array([[0.01, -0.02, 0.03], [0.0, 0.015, -0.01], [0.02, 0.01, 0.005]])
C = np.array([0.3, -0.2, 1.1])


def _linear_grid(shape=(6, 5, 7)):
    """A field linear in the world, u(x) = B x + C, sampled at the voxel centres."""
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in shape], indexing="ij"), axis=-1)
    world = ijk @ AFFINE[:3, :3].T + AFFINE[:3, 3]
    return world @ B.T + C


def _inside_points(n, shape, rng):
    ijk = rng.uniform(0.0, 1.0, (n, 3)) * (np.array(shape) - 1)
    return ijk @ AFFINE[:3, :3].T + AFFINE[:3, 3]


def test_trilinear_reproduces_a_linear_field_exactly():
    grid = DisplacementGrid(_linear_grid(), AFFINE)
    rng = np.random.default_rng(4)
    pts = _inside_points(2000, grid.shape, rng)
    np.testing.assert_allclose(grid.sample(pts), pts @ B.T + C, atol=1e-12)
    # at the voxel centres, the stored values; on the far corner, still inside
    corner = AFFINE[:3, :3] @ (np.array(grid.shape) - 1) + AFFINE[:3, 3]
    np.testing.assert_allclose(grid.sample(corner), corner @ B.T + C, atol=1e-12)
    assert grid.contains(corner)
    lo, hi = grid.bounds()
    assert np.all(pts >= lo) and np.all(pts <= hi)


def test_outside_the_grid_is_an_error_or_zero():
    grid = DisplacementGrid(_linear_grid(), AFFINE)
    inside = _inside_points(3, grid.shape, np.random.default_rng(5))
    beyond = AFFINE[:3, :3] @ np.array([-0.01, 2.0, 2.0]) + AFFINE[:3, 3]
    pts = np.vstack([inside, beyond])
    with pytest.raises(InvalidInputError, match=r"^points_mm: 1 of 4 points lie outside"):
        grid.sample(pts)
    u = grid.sample(pts, outside="zero")
    np.testing.assert_array_equal(u[3], 0.0)
    np.testing.assert_allclose(u[:3], inside @ B.T + C, atol=1e-12)
    np.testing.assert_array_equal(grid.contains(pts), [True, True, True, False])
    with pytest.raises(InvalidInputError, match=r"^outside: "):
        grid.sample(pts, outside="clamp")
    model = GridDeformation(grid, outside="zero")
    np.testing.assert_array_equal(model.displacement(beyond, [NEEDLE]), 0.0)
    with pytest.raises(InvalidInputError, match=r"^points_mm: "):
        GridDeformation(grid).displacement(beyond, [NEEDLE])


def test_one_grid_once_or_per_needle_and_one_grid_per_insertion():
    rng = np.random.default_rng(6)
    g1 = DisplacementGrid(_linear_grid(), AFFINE)
    g2 = DisplacementGrid(2.0 * _linear_grid() - 1.0, AFFINE)
    pts = _inside_points(50, g1.shape, rng)
    once = GridDeformation(g1)
    np.testing.assert_allclose(once.displacement(pts, [NEEDLE] * 3), g1.sample(pts))
    per = GridDeformation(g1, per_needle=True)
    np.testing.assert_allclose(per.displacement(pts, [NEEDLE] * 3), 3.0 * g1.sample(pts))
    seq = GridDeformation([g1, g2])
    np.testing.assert_allclose(seq.displacement(pts, [NEEDLE]), g1.sample(pts))
    np.testing.assert_allclose(
        seq.displacement(pts, [NEEDLE] * 2), g1.sample(pts) + g2.sample(pts), atol=1e-13
    )
    with pytest.raises(InvalidInputError, match=r"^placed: 3 needles placed but 2"):
        seq.displacement(pts, [NEEDLE] * 3)
    with pytest.raises(InvalidInputError, match=r"^per_needle: "):
        GridDeformation([g1, g2], per_needle=True)
    with pytest.raises(InvalidInputError, match=r"^grids: "):
        GridDeformation([])
    with pytest.raises(InvalidInputError, match=r"^grids\[1\]: "):
        GridDeformation([g1, np.zeros((2, 2, 2, 3))])
    with pytest.raises(InvalidInputError, match=r"^grids: "):
        GridDeformation(42)


def _write_nifti(path, data, affine, units="mm"):
    img = nib.Nifti1Image(data.astype(np.float32), affine)
    img.header.set_xyzt_units(xyz=units)
    img.header.set_intent("vector")
    nib.save(img, str(path))


def test_nifti_round_trip_5d_and_4d(tmp_path):
    u = _linear_grid()
    _write_nifti(tmp_path / "d.nii.gz", u[:, :, :, None, :], AFFINE)
    grid = DisplacementGrid.load(tmp_path / "d.nii.gz")
    np.testing.assert_allclose(grid.displacement_mm, u, atol=1e-5)  # stored as float32
    np.testing.assert_allclose(grid.affine, AFFINE, atol=1e-6)
    pts = _inside_points(100, grid.shape, np.random.default_rng(7))
    np.testing.assert_allclose(grid.sample(pts), pts @ B.T + C, atol=1e-4)
    _write_nifti(tmp_path / "d4.nii", u, AFFINE)
    np.testing.assert_allclose(
        DisplacementGrid.from_nifti(tmp_path / "d4.nii").displacement_mm, u, atol=1e-5
    )
    # the model reads files too
    model = GridDeformation(str(tmp_path / "d.nii.gz"))
    np.testing.assert_allclose(model.displacement(pts, [NEEDLE]), grid.sample(pts))
    assert "d.nii.gz" in repr(model)


def test_nifti_units_and_lps_vectors(tmp_path):
    u = _linear_grid()
    metres = AFFINE.copy()
    metres[:3] /= 1000.0
    _write_nifti(tmp_path / "m.nii", u[:, :, :, None, :] / 1000.0, metres, units="meter")
    grid = DisplacementGrid.from_nifti(tmp_path / "m.nii")
    np.testing.assert_allclose(grid.affine, AFFINE, atol=1e-6)
    np.testing.assert_allclose(grid.displacement_mm, u, atol=1e-4)
    _write_nifti(tmp_path / "lps.nii", u[:, :, :, None, :], AFFINE)
    lps = DisplacementGrid.from_nifti(tmp_path / "lps.nii", vector_frame="LPS")
    np.testing.assert_allclose(lps.displacement_mm, u * [-1.0, -1.0, 1.0], atol=1e-5)
    with pytest.raises(InvalidInputError, match=r"^vector_frame: "):
        DisplacementGrid.from_nifti(tmp_path / "lps.nii", vector_frame="ras")


def test_nifti_bad_files(tmp_path):
    _write_nifti(tmp_path / "scalar.nii", np.zeros((4, 4, 4)), AFFINE)
    with pytest.raises(InvalidInputError, match=r"scalar\.nii: expected a vector image"):
        DisplacementGrid.from_nifti(tmp_path / "scalar.nii")
    _write_nifti(tmp_path / "two.nii", np.zeros((4, 4, 4, 1, 2)), AFFINE)
    with pytest.raises(InvalidInputError, match=r"two\.nii: expected a vector image"):
        DisplacementGrid.from_nifti(tmp_path / "two.nii")
    (tmp_path / "junk.nii").write_bytes(b"not a nifti file at all")
    with pytest.raises(InvalidInputError, match=r"junk\.nii: not a readable NIfTI"):
        DisplacementGrid.from_nifti(tmp_path / "junk.nii")
    with pytest.raises(InvalidInputError, match=r"missing\.nii: no such file"):
        DisplacementGrid.load(tmp_path / "missing.nii")
    nan = np.zeros((3, 3, 3, 1, 3))
    nan[1, 2, 0, 0, 1] = np.nan
    _write_nifti(tmp_path / "nan.nii", nan, AFFINE)
    with pytest.raises(InvalidInputError, match=r"nan\.nii: displacement_mm: 1 voxels hold NaN"):
        DisplacementGrid.from_nifti(tmp_path / "nan.nii")
    with pytest.raises(InvalidInputError, match=r"\.vtk: expected a \.nii"):
        DisplacementGrid.load(tmp_path / "field.vtk")


def test_npz_round_trip_and_keys(tmp_path):
    grid = DisplacementGrid(_linear_grid(), AFFINE)
    path = grid.to_npz(tmp_path / "field.npz")
    back = DisplacementGrid.load(path)
    np.testing.assert_array_equal(back.displacement_mm, grid.displacement_mm)
    np.testing.assert_array_equal(back.affine, grid.affine)
    assert grid.to_npz(tmp_path / "noext") == tmp_path / "noext.npz"
    np.savez(tmp_path / "metres.npz", displacement_m=np.zeros((2, 2, 2, 3)), affine=AFFINE)
    with pytest.raises(InvalidInputError, match=r"metres\.npz: missing \['displacement_mm'\]"):
        DisplacementGrid.from_npz(tmp_path / "metres.npz")
    np.savez(tmp_path / "bad.npz", displacement_mm=np.zeros((2, 2, 3)), affine=AFFINE)
    with pytest.raises(InvalidInputError, match=r"bad\.npz: displacement_mm: expected shape"):
        DisplacementGrid.from_npz(tmp_path / "bad.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(InvalidInputError, match=r"junk\.npz: not a readable"):
        DisplacementGrid.from_npz(tmp_path / "junk.npz")
    with pytest.raises(InvalidInputError, match=r"^vector_frame: applies to NIfTI"):
        DisplacementGrid.load(path, vector_frame="LPS")


@pytest.mark.parametrize(
    ("field", "affine", "match"),
    [
        (np.zeros((4, 4, 4)), AFFINE, r"^displacement_mm: expected shape \(i, j, k, 3\)"),
        (np.zeros((4, 4, 4, 2)), AFFINE, r"^displacement_mm: expected shape"),
        (np.zeros((4, 1, 4, 3)), AFFINE, r"^displacement_mm: needs at least 2 voxels"),
        (np.full((2, 2, 2, 3), np.inf), AFFINE, r"^displacement_mm: 8 voxels hold infinite"),
        (np.full((2, 2, 2, 3), 500.0), AFFINE, r"^displacement_mm: .* \(not micrometres"),
        ("abc", AFFINE, r"^displacement_mm: expected numbers"),
        (np.zeros((2, 2, 2, 3)), np.eye(3), r"^affine: expected shape \(4, 4\)"),
        (np.zeros((2, 2, 2, 3)), np.diag([1.0, 0.0, 1.0, 1.0]), r"^affine: .* singular"),
        (np.zeros((2, 2, 2, 3)), np.full((4, 4), np.nan), r"^affine: must be finite"),
        (np.zeros((2, 2, 2, 3)), np.ones((4, 4)), r"^affine: last row"),
    ],
)
def test_malformed_grids(field, affine, match):
    with pytest.raises(InvalidInputError, match=match):
        DisplacementGrid(field, affine)


def test_largest_plausible_displacement_is_accepted_and_tiny_grid_warns(caplog):
    u = np.zeros((2, 2, 2, 3))
    u[0, 0, 0] = [MAX_PLAUSIBLE_DISPLACEMENT_MM, 0.0, 0.0]
    DisplacementGrid(u, np.diag([10.0, 10.0, 10.0, 1.0]))
    with caplog.at_level(logging.WARNING):
        DisplacementGrid(np.zeros((3, 3, 3, 3)), np.diag([0.001, 0.001, 0.001, 1.0]))
    assert "millimetres" in caplog.text


# ----------------------------------------------------------------------------------------
# callables


def test_callable_receives_points_and_needles_and_is_checked():
    seen = {}

    def fn(points, placed):
        seen["placed"] = placed
        points[:] = 0.0  # a copy: the caller's points are untouched
        return np.tile([0.0, 0.0, -1.0], (len(points), 1)) * len(placed)

    model = CallableDeformation(fn)
    pts = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    np.testing.assert_array_equal(model.displacement(pts, [NEEDLE, NEEDLE]), [[0, 0, -2]] * 2)
    assert seen["placed"] == (NEEDLE, NEEDLE)
    np.testing.assert_array_equal(pts, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    with pytest.raises(InvalidInputError, match=r"^fn: returned shape \(3,\) for 2 points"):
        CallableDeformation(lambda p, n: np.zeros(3)).displacement(pts, [])
    with pytest.raises(InvalidInputError, match=r"^fn: returned NaN"):
        CallableDeformation(lambda p, n: np.full(p.shape, np.nan)).displacement(pts, [])
    with pytest.raises(InvalidInputError, match=r"^fn: did not return numbers"):
        CallableDeformation(lambda p, n: "x").displacement(pts, [])
    with pytest.raises(InvalidInputError, match=r"^fn: expected a callable"):
        CallableDeformation(3.0)
