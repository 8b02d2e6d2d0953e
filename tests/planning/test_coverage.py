"""Ablation coverage: analytic and brute-force oracles, bad input, Med-RAD liver nodules."""

import json
import math

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.planning.straight.coverage import (
    DEFAULT_MARGIN_MM,
    AblationZone,
    CoverageStatus,
    choose_targets,
    evaluate_coverage,
    target_region,
)


def _ball_volume_ml(r):
    return 4.0 / 3.0 * math.pi * r**3 / 1000.0


def _affine(spacing, origin=(0.0, 0.0, 0.0), flip=(1, 1, 1)):
    a = np.diag([s * f for s, f in zip(spacing, flip, strict=True)] + [1.0])
    a[:3, 3] = origin
    return a


def _grid_points(shape, affine):
    idx = np.indices(shape).reshape(3, -1).T
    return idx, idx @ affine[:3, :3].T + affine[:3, 3]


def _sphere_mask(shape, affine, centre, radius):
    _, pts = _grid_points(shape, affine)
    inside = np.linalg.norm(pts - centre, axis=1) <= radius
    return inside.reshape(shape)


def _half_diagonal(affine):
    return 0.5 * float(np.linalg.norm(np.linalg.norm(affine[:3, :3], axis=0)))


# -- the margin region ------------------------------------------------------------------


@pytest.mark.parametrize("spacing", [(1.0, 1.0, 1.0), (0.8, 0.7, 2.5)])
def test_region_matches_brute_force_distance(spacing):
    rng = np.random.default_rng(0)
    shape = (14, 15, 8)
    affine = _affine(spacing, origin=(-30.0, 12.0, 7.0), flip=(-1, -1, 1))
    tumour = np.zeros(shape, bool)
    tumour[4:9, 5:11, 2:5] = rng.random((5, 6, 3)) < 0.4
    tumour[0, 0, 0] = True  # at the grid's edge: the margin reaches past the grid
    r = target_region(tumour, affine, margin_mm=3.0)
    # brute force on the original lattice extended by 6 voxels each way
    pad = 6
    idx = np.indices(tuple(s + 2 * pad for s in shape)).reshape(3, -1).T - pad
    pts = idx @ affine[:3, :3].T + affine[:3, 3]
    tum_pts = np.argwhere(tumour) @ affine[:3, :3].T + affine[:3, 3]
    d = np.min(np.linalg.norm(pts[:, None] - tum_pts[None], axis=2), axis=1)
    want = {tuple(p) for p in np.round(pts[d <= 3.0 + 1e-9], 6)}
    got = {tuple(p) for p in np.round(r.points_mm, 6)}
    assert got == want
    assert r.tumour.sum() == tumour.sum()
    assert not (r.tumour & ~r.mask).any()
    # cropped with padding: no region voxel on the crop's faces
    m = r.mask
    assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())
    assert not (m[:, :, 0].any() or m[:, :, -1].any())
    assert r.margin_mm == 3.0


def test_region_default_margin_and_mask_object():
    class MaskLike:
        data = np.zeros((9, 9, 9), bool)
        affine = np.eye(4)

    MaskLike.data[4, 4, 4] = True
    r = target_region(MaskLike())
    assert r.margin_mm == DEFAULT_MARGIN_MM == 5.0
    # lattice points within 5 of the origin: count them
    g = np.arange(-5, 6)
    want = int((g[:, None, None] ** 2 + g[None, :, None] ** 2 + g[None, None] ** 2 <= 25).sum())
    assert int(r.mask.sum()) == want


# -- the zone ---------------------------------------------------------------------------


def test_ellipsoid_lies_along_the_needle():
    z = AblationZone.ellipsoid(30.0, 10.0)
    pts = np.array([[14.0, 0, 0], [0, 14.0, 0], [0, 0, 4.0]])
    assert z.contains(pts, [0, 0, 0], [1, 0, 0]).tolist() == [True, False, True]
    assert z.contains(pts, [0, 0, 0], [0, 2, 0]).tolist() == [False, True, True]
    both = z.contains(pts, [[0, 0, 0], [0, 0, 0]], [[1, 0, 0], [0, 1, 0]])
    assert both.shape == (2, 3)
    sd = z.signed_distance([[20.0, 0, 0], [0, 10.0, 0], [0, 0, 0]], [0, 0, 0], [1, 0, 0])
    np.testing.assert_allclose(sd, [5.0, 5.0, -5.0], atol=1e-9)
    # sign agrees with the inside test on random points
    rng = np.random.default_rng(1)
    p = rng.uniform(-20, 20, (500, 3))
    w = np.array([1.0, 2.0, -0.5])
    np.testing.assert_array_equal(
        z.signed_distance(p, [1, 2, 3], w) <= 0, z.contains(p, [1, 2, 3], w)
    )


def test_tip_offset_puts_the_centre_behind_the_tip():
    z = AblationZone.ellipsoid(30.0, 20.0, tip_offset_mm=5.0)
    np.testing.assert_allclose(z.centre_of([0, 0, 50.0], [0, 0, 2.0]), [0, 0, 45.0])
    np.testing.assert_allclose(z.target_of([0, 0, 45.0], [0, 0, 1.0]), [0, 0, 50.0])
    # reaches 15 mm behind the centre (20 behind the tip) and 10 past the tip
    assert z.contains([[0, 0, 30.5], [0, 0, 29.0], [0, 0, 59.5], [0, 0, 61.0]], [0, 0, 50.0],
                      [0, 0, 1.0]).tolist() == [True, False, True, False]  # fmt: skip


def test_sphere_distance_and_volume():
    z = AblationZone.sphere(15.0)
    assert z.kind == "sphere" and z.radius_mm == 15.0 and not z.needs_direction
    assert z.volume_ml == pytest.approx(_ball_volume_ml(15.0))
    np.testing.assert_allclose(z.signed_distance([[0, 0, 20.0], [3, 4, 0]], [0, 0, 0]), [5, -10])


# -- choosing targets -------------------------------------------------------------------


def test_small_tumour_needs_one_needle():
    affine = _affine((1.0, 1.0, 1.0), origin=(-20.0, -20.0, -20.0))
    tumour = _sphere_mask((41, 41, 41), affine, np.zeros(3), 4.0)
    r = target_region(tumour, affine, margin_mm=2.0)
    plan = choose_targets(r, AblationZone.sphere(10.0))
    assert plan.needles == 1 and plan.status is CoverageStatus.COVERED
    assert plan.report.coverage == 1.0 and plan.report.tumour_coverage == 1.0
    json.dumps(plan.to_dict())


def test_tumour_plus_margin_is_covered_by_one_sphere_of_radius_r_plus_m():
    # every region voxel centre is within m of a tumour centre within R of c: within R + m
    affine = _affine((0.8, 0.9, 2.5), origin=(-25.0, -25.0, -25.0))
    c = np.array([0.3, -0.2, 1.1])
    tumour = _sphere_mask((64, 56, 21), affine, c, 8.0)
    r = target_region(tumour, affine, margin_mm=4.0)
    rep = evaluate_coverage(r, AblationZone.sphere(12.0), c)
    assert rep.coverage == 1.0 and rep.needles == 1
    assert evaluate_coverage(r, AblationZone.sphere(10.0), c).coverage < 1.0


def test_cylinder_needs_the_analytic_number_of_needles():
    # cylinder of radius 6, |x| <= 32, 1 mm voxels; balls of radius 10
    affine = _affine((1.0, 1.0, 1.0), origin=(-40.0, -10.0, -10.0))
    _, pts = _grid_points((81, 21, 21), affine)
    tumour = ((np.abs(pts[:, 0]) <= 32) & (np.hypot(pts[:, 1], pts[:, 2]) <= 6)).reshape(81, 21, 21)
    r = target_region(tumour, affine, margin_mm=0.0)
    zone = AblationZone.sphere(10.0)
    # lower bound: 65 axis voxel centres 1 mm apart, a ball of radius 10 holds at most 21
    lower = math.ceil(65 / 21)
    # a cover with 4: balls on the axis 16 mm apart cover |x - xc| <= 8 of the full disc
    four = [[-24.0, 0, 0], [-8.0, 0, 0], [8.0, 0, 0], [24.0, 0, 0]]
    assert lower == 4 and evaluate_coverage(r, zone, four).coverage == 1.0
    plan = choose_targets(r, zone)
    assert plan.status is CoverageStatus.COVERED and plan.report.coverage == 1.0
    assert plan.needles_lower_bound <= lower <= plan.needles <= 5
    assert plan.greedy_needles >= lower  # the plain greedy cover, before the local search


def test_ellipsoid_direction_decides_the_needle_count():
    # a rod along z, 40 mm long: one 50 x 12 mm zone along z covers it, across it cannot
    affine = _affine((1.0, 1.0, 1.0), origin=(-25.0, -25.0, -25.0))
    _, pts = _grid_points((51, 51, 51), affine)
    rod = ((np.abs(pts[:, 2]) <= 20) & (np.hypot(pts[:, 0], pts[:, 1]) <= 3)).reshape(51, 51, 51)
    r = target_region(rod, affine, margin_mm=0.0)
    zone = AblationZone.ellipsoid(50.0, 12.0)
    along = choose_targets(r, zone, direction=[0, 0, 1])
    across = choose_targets(r, zone, direction=[1, 0, 0])
    assert along.needles == 1 and along.report.coverage == 1.0
    assert across.needles >= 4 and across.report.coverage == 1.0
    np.testing.assert_allclose(along.directions, [[0, 0, 1]])


def test_plan_is_reevaluated_the_same_and_honours_tip_offset_and_entry_point():
    affine = _affine((0.8, 0.8, 2.0), origin=(-30.0, -30.0, -30.0))
    tumour = _sphere_mask((76, 76, 31), affine, np.zeros(3), 9.0)
    r = target_region(tumour, affine, margin_mm=3.0)
    entry = np.array([0.0, -120.0, 10.0])
    zone = AblationZone.ellipsoid(30.0, 20.0, tip_offset_mm=4.0)
    plan = choose_targets(r, zone, direction=lambda c: c - entry)
    assert plan.status is CoverageStatus.COVERED
    want_w = plan.centres_mm - entry
    np.testing.assert_allclose(plan.directions, want_w / np.linalg.norm(want_w, axis=1)[:, None])
    np.testing.assert_allclose(plan.targets_mm, plan.centres_mm + 4.0 * plan.directions)
    again = evaluate_coverage(r, zone, plan.targets_mm, plan.directions)
    assert again.coverage == pytest.approx(plan.report.coverage, abs=1.0 / r.mask.sum())
    assert plan.needles_lower_bound <= plan.needles


def test_partial_when_needles_run_out():
    affine = _affine((1.0, 1.0, 1.0), origin=(-30.0, -30.0, -30.0))
    tumour = _sphere_mask((61, 61, 61), affine, np.zeros(3), 15.0)
    r = target_region(tumour, affine, margin_mm=5.0)
    plan = choose_targets(r, AblationZone.sphere(8.0), max_needles=2)
    assert plan.status is CoverageStatus.PARTIAL and plan.needles == 2
    assert 0.0 < plan.report.coverage < 1.0


# -- the report against brute force ------------------------------------------------------


def test_report_matches_brute_force_counts():
    rng = np.random.default_rng(7)
    affine = _affine((0.9, 0.8, 2.5), origin=(10.0, -5.0, 40.0), flip=(-1, 1, 1))
    shape = (40, 44, 14)
    _, pts = _grid_points(shape, affine)
    c1 = affine[:3, :3] @ [20, 22, 7] + affine[:3, 3]
    tumour = ((np.linalg.norm(pts - c1, axis=1) <= 7) | (np.linalg.norm(pts - c1 - [6, 5, 4], axis=1) <= 6)).reshape(shape)  # fmt: skip
    r = target_region(tumour, affine, margin_mm=4.0)
    zone = AblationZone.ellipsoid(26.0, 14.0, tip_offset_mm=3.0)
    targets = r.points_mm[rng.choice(len(r.points_mm), 3, replace=False)]
    dirs = rng.normal(size=(3, 3))
    rep = evaluate_coverage(r, zone, targets, dirs)
    # brute force: every voxel of the region's lattice in a box far larger than the zones
    pad = 25
    idx = np.indices(tuple(s + 2 * pad for s in r.mask.shape)).reshape(3, -1).T - pad
    world = idx @ r.affine[:3, :3].T + r.affine[:3, 3]
    ablated = zone.contains(world, targets, dirs).any(axis=0)
    in_grid = np.all((idx >= 0) & (idx < r.mask.shape), axis=1)
    reg = np.zeros(len(idx), bool)
    tum = np.zeros(len(idx), bool)
    reg[in_grid] = r.mask[tuple(idx[in_grid].T)]
    tum[in_grid] = r.tumour[tuple(idx[in_grid].T)]
    unit = r.voxel_volume_mm3 / 1000.0
    assert rep.needles == 3
    assert rep.coverage == (ablated & reg).sum() / reg.sum()
    assert rep.tumour_coverage == (ablated & tum).sum() / tum.sum()
    assert rep.ablated_ml == pytest.approx(ablated.sum() * unit)
    assert rep.healthy_ablated_ml == pytest.approx((ablated & ~tum).sum() * unit)
    assert rep.ablated_outside_region_ml == pytest.approx((ablated & ~reg).sum() * unit)
    assert rep.uncovered_ml == pytest.approx((reg & ~ablated).sum() * unit)
    assert rep.region_volume_ml == pytest.approx(reg.sum() * unit)
    assert rep.tumour_volume_ml == pytest.approx(tum.sum() * unit)
    assert 0.0 < rep.coverage < 1.0


def test_healthy_volume_of_one_sphere_away_from_and_around_the_tumour():
    # Voxels counted by their centres: their boxes hold the ball of radius R - h and lie in
    # the ball of radius R + h (h = half voxel diagonal), so a count is within
    # V(R + h) - V(R) of the true volume.
    affine = _affine((0.7, 0.8, 1.5), origin=(-40.0, -40.0, -40.0))
    h = _half_diagonal(affine)
    rho, R = 6.0, 12.0
    tumour = _sphere_mask((115, 100, 54), affine, np.zeros(3), rho)
    r = target_region(tumour, affine, margin_mm=2.0)
    zone = AblationZone.sphere(R)

    def tol(radius):
        return _ball_volume_ml(radius + h) - _ball_volume_ml(radius)

    away = evaluate_coverage(r, zone, [60.0, 0.0, 0.0])
    assert away.coverage == 0.0 and away.tumour_coverage == 0.0
    assert away.healthy_ablated_ml == away.ablated_ml == away.ablated_outside_region_ml
    assert abs(away.ablated_ml - _ball_volume_ml(R)) <= tol(R)
    assert abs(r.tumour_volume_ml - _ball_volume_ml(rho)) <= tol(rho)

    around = evaluate_coverage(r, zone, [0.0, 0.0, 0.0])
    assert around.coverage == 1.0
    want = _ball_volume_ml(R) - _ball_volume_ml(rho)
    assert abs(around.healthy_ablated_ml - want) <= tol(R) + tol(rho)
    assert around.healthy_ablated_ml == pytest.approx(around.ablated_ml - r.tumour_volume_ml)
    assert around.ablated_outside_region_ml == pytest.approx(around.ablated_ml - r.volume_ml)


# -- bad input --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"kind": "cube"}, "kind"),
        ({"length_mm": 0.0}, "length_mm"),
        ({"diameter_mm": -1.0}, "diameter_mm"),
        ({"diameter_mm": float("nan")}, "diameter_mm"),
        ({"tip_offset_mm": -2.0}, "tip_offset_mm"),
        ({"kind": "sphere", "length_mm": 30.0, "diameter_mm": 20.0}, "length_mm"),
    ],
)
def test_bad_zone(kwargs, field):
    with pytest.raises(InvalidInputError, match=f"^{field}:"):
        AblationZone(**kwargs)


def test_bad_sphere_radius():
    with pytest.raises(InvalidInputError, match=r"^radius_mm:"):
        AblationZone.sphere(0.0)


def test_bad_region_input():
    good = np.zeros((5, 5, 5), bool)
    good[2, 2, 2] = True
    with pytest.raises(InvalidInputError, match=r"^tumour_mask: is empty"):
        target_region(np.zeros((5, 5, 5), bool), np.eye(4))
    nan = good.astype(float)
    nan[0, 0, 0] = np.nan
    with pytest.raises(InvalidInputError, match=r"^tumour_mask: contains NaN"):
        target_region(nan, np.eye(4))
    with pytest.raises(InvalidInputError, match=r"^tumour_mask:"):
        target_region(good.astype(float) * 3, np.eye(4))
    with pytest.raises(InvalidInputError, match=r"^tumour_mask:"):
        target_region(good[0], np.eye(4))
    with pytest.raises(InvalidInputError, match=r"^affine:"):
        target_region(good)
    sheared = np.eye(4)
    sheared[0, 1] = 0.5
    with pytest.raises(InvalidInputError, match=r"^affine:"):
        target_region(good, sheared)
    with pytest.raises(InvalidInputError, match=r"^margin_mm:"):
        target_region(good, np.eye(4), margin_mm=-1.0)
    with pytest.raises(InvalidInputError, match=r"^margin_mm:"):
        target_region(good, np.eye(4), margin_mm=float("nan"))


def test_bad_choose_and_evaluate_input():
    m = np.zeros((9, 9, 9), bool)
    m[4, 4, 4] = True
    r = target_region(m, np.eye(4), margin_mm=1.0)
    ell = AblationZone.ellipsoid(10.0, 6.0)
    with pytest.raises(InvalidInputError, match=r"^direction:"):
        choose_targets(r, ell)
    with pytest.raises(InvalidInputError, match=r"^direction:"):
        choose_targets(r, ell, direction=[0, 0, 0])
    with pytest.raises(InvalidInputError, match=r"^direction:"):
        choose_targets(r, ell, direction=[0, np.nan, 1])
    with pytest.raises(InvalidInputError, match=r"^coverage_goal:"):
        choose_targets(r, ell, direction=[0, 0, 1], coverage_goal=1.5)
    with pytest.raises(InvalidInputError, match=r"^coverage_goal:"):
        choose_targets(r, ell, direction=[0, 0, 1], coverage_goal=0.0)
    with pytest.raises(InvalidInputError, match=r"^max_needles:"):
        choose_targets(r, ell, direction=[0, 0, 1], max_needles=0)
    with pytest.raises(InvalidInputError, match=r"^candidate_spacing_mm:"):
        choose_targets(r, ell, direction=[0, 0, 1], candidate_spacing_mm=-1.0)
    with pytest.raises(InvalidInputError, match=r"^region:"):
        choose_targets(m, ell, direction=[0, 0, 1])
    with pytest.raises(InvalidInputError, match=r"^directions:"):
        evaluate_coverage(r, ell, [0, 0, 0])
    with pytest.raises(InvalidInputError, match=r"^targets_mm:"):
        evaluate_coverage(r, ell, [0, np.nan, 0], [0, 0, 1])
    with pytest.raises(InvalidInputError, match=r"^directions:"):
        evaluate_coverage(r, ell, [[0, 0, 0], [1, 1, 1]], [[0, 0, 1]] * 3)
    none = evaluate_coverage(r, ell, np.zeros((0, 3)))
    assert none.needles == 0 and none.coverage == 0.0 and none.ablated_ml == 0.0


# -- Med-RAD liver nodules ----------------------------------------------------------------


@pytest.mark.realdata
@pytest.mark.slow
def test_medrad_liver_nodules(medrad_dir):
    from needlekit.io.medrad import load_medrad
    from needlekit.io.volumes import read_mask

    rows = []
    for k in range(1, 6):
        case = load_medrad("liver", k, medrad_dir, use_cache=False)
        for s in case.scene.by_role("target"):
            start = next(p for p in case.starts if p.target == s.metadata["target"])
            direction = start.world_T_tip[:3, 2]  # the start pose's insertion direction
            region = target_region(read_mask(s.source))
            plan = choose_targets(region, AblationZone(), direction=direction)
            big = choose_targets(region, AblationZone.ellipsoid(50.0, 40.0), direction=direction)
            rows.append((region.tumour_diameter_mm, plan, big))
    assert len(rows) == 8
    diameters = sorted(d for d, _, _ in rows)
    assert 16.5 <= diameters[0] and diameters[-1] <= 46.5  # the 17-46 mm
    for _, plan, big in rows:
        assert plan.status is CoverageStatus.COVERED and plan.report.coverage == 1.0
        assert big.status is CoverageStatus.COVERED and big.report.coverage == 1.0
        assert plan.needles_lower_bound <= plan.needles and big.needles <= plan.needles
    _, largest, largest_big = max(rows, key=lambda row: row[0])
    assert largest.needles >= 2 and largest_big.needles >= 2
    assert largest.needles == max(p.needles for _, p, _ in rows)


def test_the_cover_keeps_each_candidates_gain_as_the_whole_product_gives_it():
    """The gains kept up to date as zones are added and removed equal the sparse product
    A @ (voxels uncovered), after every step of a random sequence (brute force)."""
    from scipy import sparse

    from needlekit.planning.straight.coverage.choose import _Cover

    rng = np.random.default_rng(7)
    A = sparse.random(60, 400, density=0.05, random_state=3, format="csr", dtype=np.float32)
    A.data[:] = 1.0
    cov = _Cover(A)
    assert np.array_equal(cov.gains(), A @ np.ones(400, np.float32))
    for step in range(300):
        if cov.chosen and (rng.random() < 0.4 or len(cov.chosen) > 25):
            cov.remove(cov.chosen[rng.integers(len(cov.chosen))])
        else:
            cov.add(int(rng.integers(60)))  # a candidate may be chosen twice
        if step % 3 == 0 or step > 280:
            expected = A @ (cov.count == 0).astype(np.float32)
            assert np.array_equal(cov.gains(), expected), step
