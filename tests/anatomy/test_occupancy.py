"""Exact voxel-centre collision tests against a KD-tree over all obstacle centres."""

import numpy as np
import pytest

from needlekit.anatomy.occupancy import VoxelObstacles, nearest_obstacle_distance_reference
from needlekit.errors import InvalidInputError


def _random_case(seed, affine):
    rng = np.random.default_rng(seed)
    occ = rng.random((30, 24, 18)) < 0.02
    obs = VoxelObstacles(occ, affine, needle_diameter_mm=1.0)
    lo = affine[:3, 3] - 3.0
    hi = affine[:3, :3] @ np.array(occ.shape) + affine[:3, 3] + 3.0
    pts = rng.uniform(np.minimum(lo, hi), np.maximum(lo, hi), (20000, 3))
    return obs, pts, rng


def _inside_image(obs, pts):
    ijk = (pts - obs.affine[:3, 3]) @ obs.inv_affine[:3, :3].T
    return np.all(ijk >= 0, axis=1) & np.all(np.round(ijk) < np.array(obs.occupancy.shape), axis=1)


@pytest.mark.parametrize(
    "affine",
    [
        np.diag([0.55, 0.55, 0.7, 1.0]),
        np.array([[0.5, 0, 0, -10.0], [0, -0.6, 0, 20.0], [0, 0, 0.8, 5.0], [0, 0, 0, 1]]),
        np.array([[0, 0.5, 0, 3.0], [0.7, 0, 0, -2.0], [0, 0, 0.6, 1.0], [0, 0, 0, 1]]),
    ],
    ids=["medrad", "flipped", "permuted"],
)
def test_collisions_match_the_kdtree_oracle(affine):
    obs, pts, _ = _random_case(0, affine)
    got = obs.collides(pts)
    d = nearest_obstacle_distance_reference(obs, pts)
    want = ~_inside_image(obs, pts) | (d < obs.min_distance_mm)
    assert np.array_equal(got, want)
    assert got.any() and not got.all()


def test_exclusion_around_the_start():
    obs, pts, _ = _random_case(1, np.diag([0.55, 0.55, 0.7, 1.0]))
    start = np.array([8.0, 6.0, 6.0])
    got = obs.collides(pts, exclude_near=start, exclusion_mm=3.0)
    d = nearest_obstacle_distance_reference(obs, pts, exclude_near=start, exclusion_mm=3.0)
    want = ~_inside_image(obs, pts) | (d < obs.min_distance_mm)
    assert np.array_equal(got, want)
    # the exclusion only ever removes collisions
    assert np.all(obs.collides(pts)[got])


def test_threshold_is_radius_plus_half_voxel_diagonal():
    affine = np.diag([0.55078125, 0.55078125, 0.70001960, 1.0])
    obs = VoxelObstacles(np.zeros((5, 5, 5), bool), affine, needle_diameter_mm=1.0)
    assert obs.min_distance_mm == pytest.approx(
        0.5 + 0.5 * np.linalg.norm([0.55078125, 0.55078125, 0.7000196])
    )
    assert obs.min_distance_mm == pytest.approx(1.0236, abs=1e-4)  # Med-RAD lung 1
    with pytest.raises(InvalidInputError, match="needle_diameter_mm"):
        VoxelObstacles(np.zeros((5, 5, 5), bool), affine, needle_diameter_mm=0.0)
    with pytest.raises(InvalidInputError, match="occupancy"):
        VoxelObstacles(np.zeros((5, 5)), affine, needle_diameter_mm=1.0)


def test_the_smallest_distance_over_points_is_the_per_point_minimum():
    # the plan check's one-number kernel (a shrinking search box) against the per-point
    # kernel and the KD-tree oracle, exclusion and cap included
    from needlekit.anatomy.occupancy import nearest_obstacle_distance_reference
    from needlekit.anatomy.voxel_clearance import (
        nearest_obstacle_distance,
        smallest_obstacle_distance,
    )

    rng = np.random.default_rng(4)
    occ = rng.random((30, 30, 30)) < 0.01
    obs = VoxelObstacles(occ, np.diag([0.6, 0.6, 0.8, 1.0]), needle_diameter_mm=1.0)
    for t in range(60):
        pts = rng.uniform(1.0, 16.0, size=(int(rng.integers(1, 80)), 3))
        excl = pts[0] if t % 2 else None
        kw = {"exclude_near": excl, "exclusion_mm": 2.0 if t % 2 else 0.0}
        cap = float(rng.uniform(0.5, 6.0))
        each = nearest_obstacle_distance(obs, pts, cap_mm=cap, **kw)
        oracle = np.minimum(nearest_obstacle_distance_reference(obs, pts, **kw), cap)
        got = smallest_obstacle_distance(obs, pts, cap_mm=cap, near_mm=1.0, **kw)
        assert got == each.min()
        assert got == pytest.approx(oracle.min(), abs=1e-12)
    outside = np.array([[5.0, 5.0, 5.0], [-3.0, 5.0, 5.0]])
    assert smallest_obstacle_distance(obs, outside, cap_mm=3.0) == -np.inf


def test_occupied_blocks_and_the_block_skip_agree_with_the_oracles():
    from needlekit.anatomy.occupancy import BLOCK_VOXELS, occupied_blocks

    rng = np.random.default_rng(3)
    occ = rng.random((23, 18, 30)) < 0.002  # sparse: most blocks empty, shape not a multiple
    b = BLOCK_VOXELS
    padded = np.pad(occ, [(0, -n % b) for n in occ.shape])
    ni, nj, nk = (n // b for n in padded.shape)
    expected = padded.reshape(ni, b, nj, b, nk, b).any(axis=(1, 3, 5))
    np.testing.assert_array_equal(occupied_blocks(occ), expected)
    affine = np.diag([0.55, 0.55, 0.7, 1.0])
    obs = VoxelObstacles(occ, affine, needle_diameter_mm=1.0, safety_margin_mm=0.3)
    pts = rng.uniform([0, 0, 0], [12.0, 9.5, 20.5], size=(4000, 3))
    d = nearest_obstacle_distance_reference(obs, pts)
    np.testing.assert_array_equal(obs.collides(pts), d < obs.min_distance_mm)
