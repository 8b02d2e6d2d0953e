"""The collision-free reachable workspace of a straight needle (Liu et al. 2016)."""

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.cfrw import (
    Blocked,
    cfrw_map,
    entry_points,
    inside_polylines,
    segment_clearance_bound,
)
from needlekit.planning.straight.problem import (
    StraightNeedle,
    StraightProblem,
    angles_of,
    directions_of,
)

GAMMA = 1.5
SKIN_R = 120.0


def _scene():
    return Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], SKIN_R)),
            Structure("vessel", Role.OBSTACLE, Capsule([-60, 5, 40], [60, 5, 40], 4.0)),
            Structure("vessel2", Role.OBSTACLE, Capsule([20, -60, 70], [20, 60, 70], 3.0)),
        ]
    )


@pytest.fixture(scope="module")
def cfrw():
    pr = StraightProblem(_scene(), [0, 0, 0], "skin", StraightNeedle(1.0, 150.0), gamma_mm=GAMMA)
    return cfrw_map(pr, resolution_deg=2.0)


def _exact_clearance(problem, directions):
    """Dense exact clearance of the needle's surface along each direction (the oracle)."""
    f = problem.obstacle_field()
    t = np.linspace(0.0, SKIN_R, 24001)
    return np.array([f.signed_distance(t[:, None] * d).min() for d in directions]) - 1.0


def test_angles_round_trip_and_follow_eq1():
    pr = StraightProblem(_scene(), [0, 0, 0], "skin", up=[0.0, 1.0, 0.0])
    rng = np.random.default_rng(0)
    theta, phi = rng.uniform(0.01, 3.1, 50), rng.uniform(-3.1, 3.1, 50)
    u = directions_of(theta, phi, pr.world_T_sigma)
    t2, p2 = angles_of(u, pr.world_T_sigma)
    assert np.allclose(t2, theta) and np.allclose(p2, phi)
    # Eq. 1: the point at height h along the needle is h tan(theta) (cos phi, sin phi)
    local = u @ pr.world_T_sigma[:3, :3]
    ok = theta < 1.5
    h = 150.0
    xy = h / local[ok, 2:3] * local[ok, :2]
    assert np.allclose(xy, h * np.tan(theta[ok])[:, None] * np.c_[np.cos(phi[ok]), np.sin(phi[ok])])


def test_certified_clearance_is_a_lower_bound_within_half_a_step(cfrw):
    ok = np.isfinite(cfrw.clearance_mm) & (cfrw.clearance_mm < GAMMA + 9.0)
    dirs = cfrw.directions[ok][::13]
    exact = _exact_clearance(cfrw.problem, dirs)
    mapped = cfrw.clearance_mm[ok][::13]
    assert np.all(mapped <= exact + 1e-9)
    assert np.all(mapped >= exact - 0.25 - 1e-9)  # half the 0.5 mm step near obstacles


def test_segment_bound_certifies_the_cap_far_from_obstacles():
    f = Sphere([0.0, 50.0, 0.0], 5.0)
    b, at = segment_clearance_bound(
        f, np.zeros((2, 3)), np.array([[1.0, 0, 0], [0, 1.0, 0]]), np.array([100.0, 100.0]),
        cap_mm=10.0,
    )  # fmt: skip
    assert b[0] == pytest.approx(10.0)  # 45 mm away: capped
    assert b[1] == pytest.approx(-5.0, abs=1e-9) and at[1] == pytest.approx(50.0, abs=0.5)


def test_trajectories_on_the_boundary_clear_by_gamma(cfrw):
    polys = cfrw.layer(150.0)
    assert polys and all(np.allclose(p[0], p[-1]) for p in polys)
    pts = np.vstack(polys)
    theta = np.arctan2(np.hypot(pts[:, 0], pts[:, 1]), 150.0)
    phi = np.arctan2(pts[:, 1], pts[:, 0])
    clear_part = theta < np.radians(84.0)  # the rest is the plane's cut at 85 deg
    assert clear_part.sum() > 100
    exact = _exact_clearance(
        cfrw.problem, directions_of(theta, phi, cfrw.problem.world_T_sigma)[clear_part]
    )
    assert np.all(np.abs(exact - GAMMA) <= 0.05), (exact.min(), exact.max())


def test_ray_casting_agrees_with_the_clearance(cfrw):
    polys = cfrw.layer(150.0)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-300.0, 300.0, (600, 2))
    theta = np.arctan2(np.hypot(xy[:, 0], xy[:, 1]), 150.0)
    phi = np.arctan2(xy[:, 1], xy[:, 0])
    ok = theta < np.radians(84.0)
    clear = cfrw.clearance_of(theta[ok], phi[ok]) >= GAMMA
    assert np.array_equal(inside_polylines(xy[ok], polys), clear)


def test_layers_scale_with_height(cfrw):
    # the same directions meet higher planes proportionally farther out (Fig. 11 b)
    a, b = cfrw.layer(150.0, refine=False), cfrw.layer(170.0, refine=False)
    ra = max(np.hypot(*p.T).max() for p in a)
    rb = max(np.hypot(*p.T).max() for p in b)
    assert rb / ra == pytest.approx(170.0 / 150.0, rel=0.02)


def test_each_limit_blocks_and_says_so():
    scene = _scene()
    short = StraightProblem(scene, [0, 0, 0], "skin", StraightNeedle(1.0, 100.0))
    m = cfrw_map(short, resolution_deg=5.0)
    assert m.counts()["too_long"] == m.blocked.size - m.counts()["angle_limit"]  # skin 120 mm away
    box = StraightProblem(scene, [0, 0, 0], "skin", theta_range_deg=(10, 30), phi_range_deg=(0, 90))
    m = cfrw_map(box, resolution_deg=5.0)
    assert np.allclose(np.degrees(m.theta_rad), [10, 15, 20, 25, 30])
    assert np.allclose(np.degrees(m.phi_rad), np.arange(0, 91, 5))
    cone = StraightProblem(
        scene, [0, 0, 0], "skin", approach_direction=[0, 0, 1], approach_cone_deg=20
    )
    m = cfrw_map(cone, resolution_deg=5.0)
    assert set(np.unique(m.blocked[np.degrees(m.theta_rad) > 20.0 + 1e-9])) == {Blocked.ANGLE_LIMIT}
    # off-centre target: rays meet the skin obliquely
    oblique = StraightProblem(scene, [0, 0, 100.0], "skin", max_normal_angle_deg=30.0)
    m = cfrw_map(oblique, resolution_deg=5.0)
    assert m.counts()["normal_angle"] > 0
    assert np.all(m.normal_angle_deg[m.feasible] <= 30.0 + 1e-9)


def test_entry_points_lie_on_the_surface():
    u = directions_of(np.radians([0, 30, 60, 90]), np.radians([0, 45, 90, 180]), np.eye(4))
    length, entry = entry_points(Sphere([0, 0, 0], SKIN_R), np.array([0, 0, 10.0]), u, 150.0)
    assert np.allclose(np.linalg.norm(entry, axis=1), SKIN_R, atol=1e-3)
    assert length[0] == pytest.approx(110.0, abs=1e-3)


def test_bad_problems_are_refused():
    scene = _scene()
    with pytest.raises(InvalidInputError, match=r"target_mm: .* outside the skin surface"):
        cfrw_map(StraightProblem(scene, [0, 0, 130.0], "skin"))
    with pytest.raises(InvalidInputError, match="entry_surface"):
        StraightProblem(scene, [0, 0, 0], "nope")
    with pytest.raises(InvalidInputError, match="theta_range_deg"):
        StraightProblem(scene, [0, 0, 0], "skin", theta_range_deg=(30, 10))
    with pytest.raises(InvalidInputError, match="gamma_mm"):
        StraightProblem(scene, [0, 0, 0], "skin", gamma_mm=-1)
    with pytest.raises(InvalidInputError, match="resolution_deg"):
        cfrw_map(StraightProblem(scene, [0, 0, 0], "skin"), resolution_deg=0)
