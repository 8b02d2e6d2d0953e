"""Segment clearance bounds in closed form, convex obstacles, placed needles added to a map,
and the march to the entry surface (the straight planner's fast paths)."""

import numpy as np
import pytest

from needlekit.anatomy.needle_body import NeedleBody
from needlekit.anatomy.primitives import Capsule, Sphere, Superquadric
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.planning.straight.cfrw import (
    CONVEX_TOL_MM,
    Blocked,
    cfrw_map,
    convex_segment_bound,
    entry_points,
    obstacle_segment_bound,
    segment_clearance_bound,
)
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem

CAP = 12.5


def _segments(rng, n, centre, spread, max_len):
    o = rng.normal(size=(n, 3)) * spread + centre
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return o, u, rng.uniform(0.0, max_len, n)


SAMPLES = 6001


def _dense_min(field, o, u, L, samples=SAMPLES):
    """The oracle: the field's exact distance at dense samples of each segment, an upper
    bound of the true minimum and above it by at most half a sample step (1-Lipschitz):
    :func:`_slack`."""
    t = np.linspace(0.0, 1.0, samples)
    return np.array(
        [field.signed_distance(o[i] + (t * L[i])[:, None] * u[i]).min() for i in range(len(o))]
    )


def _slack(L):
    return L / (SAMPLES - 1) / 2 + 1e-9


def test_capsule_bound_is_the_exact_segment_distance():
    rng = np.random.default_rng(1)
    cap = Capsule([0.0, 0.0, 0.0], [0.0, 0.0, 40.0], 1.0)
    o, u, L = _segments(rng, 300, [0.0, 0.0, 20.0], 10.0, 50.0)
    got = obstacle_segment_bound(cap, o, u, L, cap_mm=CAP)
    want = np.minimum(_dense_min(cap, o, u, L), CAP)
    assert np.all(got <= want + 1e-9)  # a lower bound ...
    assert np.all(want - got <= _slack(L))  # ... equal to the oracle to its sampling


@pytest.mark.slow
def test_convex_bound_is_certified_and_within_tolerance_of_the_exact_minimum():
    rng = np.random.default_rng(2)
    head = NeedleBody([0.0, 0.0, 0.0], [0.0, 0.0, 30.0], radius_mm=1.0).head_field
    o, u, L = _segments(rng, 400, [0.0, 0.0, 25.0], 8.0, 60.0)
    got = convex_segment_bound(head, o, u, L, cap_mm=CAP)
    exact = _dense_min(head, o, u, L)
    want = np.minimum(exact, CAP)
    assert np.all(got <= want + 1e-9)
    outside = exact > 0.05
    assert np.all((want - got - _slack(L))[outside] <= CONVEX_TOL_MM)
    # segments through the head get the deepest any point can be: -min semi-axis
    through = exact < 0.0
    assert through.any()
    assert np.allclose(got[through], -np.min(head.semi_axes_mm) - head.error_bound_mm)
    # sphere tracing, the general path, is a lower bound too and looser (its half step)
    traced, _ = segment_clearance_bound(head, o, u, L, cap_mm=CAP)
    assert np.all(traced[outside] <= got[outside] + CONVEX_TOL_MM)


def test_convex_bound_of_monotone_and_flat_segments():
    ball = Superquadric([5.0, 5.0, 5.0], [2.0, 2.0, 2.0])  # a sphere of radius 5
    o = np.array([[20.0, 0.0, 0.0], [20.0, 0.0, 0.0], [-20.0, 8.0, 0.0]])
    u = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    L = np.array([10.0, 10.0, 40.0])
    got = convex_segment_bound(ball, o, u, L, cap_mm=50.0)
    # falling all the way (min at the far end), rising all the way (at the start), and
    # passing by at 8 mm from the centre (3 mm from the surface) in the middle
    assert got == pytest.approx([5.0, 15.0, 3.0], abs=CONVEX_TOL_MM + 1e-6)
    assert np.all(got <= [5.0, 15.0, 3.0])


@pytest.mark.slow
def test_needle_body_bound_is_the_lower_of_tube_and_head():
    rng = np.random.default_rng(3)
    body = NeedleBody([0.0, 0.0, 0.0], [0.0, 0.0, 30.0], radius_mm=1.0)
    o, u, L = _segments(rng, 300, [0.0, 0.0, 28.0], 8.0, 40.0)
    got = obstacle_segment_bound(body, o, u, L, cap_mm=CAP)
    exact = _dense_min(body, o, u, L)
    want = np.minimum(exact, CAP)
    assert np.all(got <= want + 1e-9)
    clear = exact > 0.05
    assert np.all((want - got - _slack(L))[clear] <= CONVEX_TOL_MM)


def _problem(extra=()):
    scene = Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 80.0)),
            Structure("vessel", Role.OBSTACLE, Capsule([-50, 6, 30], [50, 6, 30], 3.0)),
        ]
    )
    pr = StraightProblem(scene, [0, 0, 0], "skin", StraightNeedle(1.0, 120.0), gamma_mm=1.5)
    return pr.with_obstacles(*extra)


def test_map_with_placed_needles_is_the_map_of_the_problem_with_them():
    bodies = (
        NeedleBody([4.0, 0.0, 0.0], [4.0, 20.0, 77.0], radius_mm=1.0),
        NeedleBody([-3.0, 2.0, 0.0], [-30.0, -10.0, 73.0], radius_mm=1.0),
    )
    base = cfrw_map(_problem(), resolution_deg=3.0)
    added = base.with_obstacles(*bodies)
    direct = cfrw_map(_problem(bodies), resolution_deg=3.0)
    for name in ("clearance_mm", "length_mm", "normal_angle_deg", "entry_mm"):
        assert np.array_equal(getattr(added, name), getattr(direct, name), equal_nan=True), name
    assert np.array_equal(added.blocked, direct.blocked)
    assert added.problem.extra_obstacles == bodies
    # the placed needles only take directions away, and those are told apart
    assert np.all(added.feasible <= base.feasible)
    taken = base.feasible & ~added.feasible
    assert taken.any()
    assert np.all(added.blocked[taken] == Blocked.PLACED_NEEDLE)
    assert np.array_equal(added.blocked[~taken], base.blocked[~taken])
    c = added.counts()
    assert c["placed_needle"] == int(taken.sum())
    words = added.blocking_summary()
    within = added.blocked.size - c["angle_limit"]
    assert words.startswith(f"of {within} directions within the angle limits")
    assert f"{c['placed_needle']} closer than gamma to a needle placed before" in words
    assert f"{c['clearance']} closer than gamma to the anatomy" in words


def _slab_mask(gap_voxels):
    """A 1 mm grid holding a block with a slot `gap_voxels` wide cut across x = 10."""
    mask = np.zeros((40, 12, 12), dtype=bool)
    mask[2:38, 2:10, 2:10] = True
    mask[10 : 10 + gap_voxels, :, :] = False
    return mask


def test_voxel_lipschitz_bound_holds_and_is_at_least_one():
    sdf = VoxelSDF.from_mask(_slab_mask(2), np.eye(4), crop=False)
    lip = sdf.lipschitz_bound
    assert 1.0 <= lip <= np.sqrt(3.0) * 1.5
    rng = np.random.default_rng(4)
    lo, hi = sdf.grid_bounds()
    a = rng.uniform(lo, hi, size=(4000, 3))
    b = a + rng.normal(scale=0.3, size=a.shape)
    ratio = np.abs(sdf.signed_distance(a) - sdf.signed_distance(b)) / np.linalg.norm(a - b, axis=1)
    assert ratio.max() <= lip


def test_entry_march_stops_at_the_first_crossing_of_a_voxel_surface():
    # the ray from inside the block along +x meets a one-voxel slot (x in [9.5, 10.5])
    # first, then the block again: steps of |d| / L never pass a sign change of the field,
    # so the entry is the slot's near face, where the field is 0
    sdf = VoxelSDF.from_mask(_slab_mask(1), np.eye(4), crop=False)
    for start in (3.0, 5.0, 8.0, 9.0):
        length, entry = entry_points(
            sdf, np.array([start, 5.5, 5.5]), np.array([[1.0, 0.0, 0.0]]), 50.0
        )
        assert float(sdf.signed_distance(entry[0])) == pytest.approx(0.0, abs=1e-3)
        assert entry[0, 0] == pytest.approx(9.5, abs=0.1)  # not the far end at x = 37.5
        assert length[0] == pytest.approx(entry[0, 0] - start)
