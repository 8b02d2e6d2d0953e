"""Reachability and shortest arc-then-line length, against brute-force searches over arcs."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import propagate_arcs
from needlekit.geometry.se3 import se3_exp
from needlekit.needle.reachability import (
    arc_line_lengths_from,
    arc_line_lengths_from_unchecked,
    is_reachable,
    is_reachable_unchecked,
    lecture_reachability_condition,
    shortest_arc_line,
    single_arc_to,
    tip_coordinates,
)

R_MIN = 50.0


def _random_pose(rng):
    return se3_exp(np.concatenate([rng.normal(0, 80, 3), rng.normal(0, 1.5, 3)]))


def _to_world(g, local):
    return local @ g[:3, :3].T + g[:3, 3]


def _in_plane(rho, z):
    """Points in the tip frame's x-z half-plane (x = rho >= 0)."""
    return np.column_stack([rho, np.zeros_like(rho), z])


@pytest.fixture(scope="module")
def arc_end_cloud():
    """Brute force: end points of forward single arcs (radius >= R_MIN, turn <= pi) in the
    (rho, z) half-plane, densely sampled in curvature and arc length."""
    kappa = np.linspace(0.0, 1.0 / R_MIN, 1500)
    s = np.arange(0.0, 320.0, 0.2)
    kk, ss = np.meshgrid(kappa, s, indexing="ij")
    phi = kk * ss
    keep = phi <= np.pi
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.where(kk > 0, (1 - np.cos(phi)) / np.where(kk > 0, kk, 1), 0.0)
        z = np.where(kk > 0, np.sin(phi) / np.where(kk > 0, kk, 1), ss)
    return cKDTree(np.column_stack([rho[keep], z[keep]]))


def _distance_to_boundary(rho, z):
    """Distance of (rho, z) to the boundary of the forward single-arc reachable set."""
    d_circle = np.abs(np.hypot(rho - R_MIN, z) - R_MIN)
    d_floor = np.where(rho >= 2 * R_MIN, np.abs(z), np.hypot(rho - 2 * R_MIN, z))
    return np.minimum(d_circle, d_floor)


def test_lecture_condition_equals_frame_free_form():
    rng = np.random.default_rng(0)
    local = rng.uniform([-250, -250, -100], [250, 250, 250], (5000, 3))
    expected = lecture_reachability_condition(local, R_MIN)
    assert np.array_equal(is_reachable(np.eye(4), local, R_MIN), expected)
    for _ in range(5):
        g = _random_pose(rng)
        assert np.array_equal(is_reachable(g, _to_world(g, local), R_MIN), expected)
    assert expected.any() and not expected.all()


def test_reachability_matches_brute_force_over_arcs(arc_end_cloud):
    rng = np.random.default_rng(1)
    rho = rng.uniform(0, 220, 4000)
    z = rng.uniform(-60, 220, 4000)
    clear = _distance_to_boundary(rho, z) > 1.0  # verdicts not decided by grid resolution
    rho, z = rho[clear], z[clear]
    verdict = is_reachable(np.eye(4), _in_plane(rho, z), R_MIN)
    # the cloud holds arcs up to 320 mm long, sampled finely enough below 250 mm
    in_range = single_arc_to(np.eye(4), _in_plane(rho, z)).length_mm < 250
    dist, _ = arc_end_cloud.query(np.column_stack([rho, z]))
    assert np.all(dist[verdict & in_range] < 0.4)
    assert np.all(dist[~verdict] > 0.9)
    assert verdict.sum() > 500 and (~verdict).sum() > 500


def test_single_arc_geometry():
    arc = single_arc_to(np.eye(4), [[0.0, -50.0, 50.0], [0.0, 0.0, 30.0], [0.0, 0.0, -1.0]])
    assert arc.radius_mm[0] == pytest.approx(50.0) and arc.turn_rad[0] == pytest.approx(np.pi / 2)
    assert np.isinf(arc.radius_mm[1]) and arc.length_mm[1] == pytest.approx(30.0)
    assert np.isnan(arc.radius_mm[2]) and np.isinf(arc.length_mm[2])
    axial, radial = tip_coordinates(np.eye(4), [3.0, 4.0, -2.0])
    assert axial == pytest.approx(-2.0) and radial == pytest.approx(5.0)


def test_max_turn_limits_the_arc():
    p = [[0.0, -100.0, 0.0]]  # a half circle of radius 50
    assert is_reachable(np.eye(4), p, R_MIN)[0]
    assert not is_reachable(np.eye(4), p, R_MIN, max_turn_rad=np.pi / 2)[0]


def _brute_arc_line_length(rho, z):
    """Min over curvatures kappa in [0, 1/R_MIN] of the arc-then-tangent-line length to
    (rho, z), the arc length found by scanning for the tangent through the point."""
    best = np.inf
    s = np.linspace(0.0, 2 * np.pi * R_MIN * 1.2, 8001)
    for kappa in np.linspace(1e-9, 1.0 / R_MIN, 150):
        phi = kappa * s
        ex, ez = (1 - np.cos(phi)) / kappa, np.sin(phi) / kappa
        tx, tz = np.sin(phi), np.cos(phi)
        dx, dz = rho - ex, z - ez
        cross = tx * dz - tz * dx  # zero when the point lies on the tangent line
        along = tx * dx + tz * dz
        idx = np.flatnonzero(np.sign(cross[:-1]) != np.sign(cross[1:]))
        for i in idx:
            f = cross[i] / (cross[i] - cross[i + 1])
            a = along[i] + f * (along[i + 1] - along[i])
            if a >= 0:
                best = min(best, s[i] + f * (s[i + 1] - s[i]) + a)
    return best


def test_shortest_arc_line_matches_brute_force():
    rng = np.random.default_rng(2)
    rho = np.concatenate([rng.uniform(0, 200, 12), [0.0, 150.0, 30.0]])
    z = np.concatenate([rng.uniform(-100, 200, 12), [120.0, -80.0, 5.0]])
    path = shortest_arc_line(np.eye(4), _in_plane(rho, z), R_MIN)
    for i in range(rho.size):
        brute = _brute_arc_line_length(rho[i], z[i])
        if path.reachable[i]:
            assert path.length_mm[i] == pytest.approx(brute, rel=2e-3, abs=0.05)
        else:
            assert np.isinf(brute) and np.isinf(path.length_mm[i])
    assert path.reachable.sum() >= 8


def test_shortest_arc_line_path_reaches_the_point_from_any_pose():
    rng = np.random.default_rng(3)
    for _ in range(5):
        g = _random_pose(rng)
        pts = _to_world(g, rng.uniform(-200, 200, (2000, 3)))
        p = shortest_arc_line(g, pts, R_MIN)
        ok = p.reachable
        ends = propagate_arcs(g, p.spin_rad[ok], 1 / R_MIN, p.arc_length_mm[ok])
        reached = ends[:, :3, 3] + ends[:, :3, 2] * p.line_length_mm[ok, None]
        assert np.abs(reached - pts[ok]).max() < 1e-9
        # never shorter than the straight-line distance, and a single forward arc is no shorter
        assert np.all(p.length_mm[ok] >= np.linalg.norm(pts[ok] - g[:3, 3], axis=1) - 1e-9)
        single = single_arc_to(g, pts[ok])
        forward = is_reachable(g, pts[ok], R_MIN)
        assert np.all(p.length_mm[ok][forward] <= single.length_mm[forward] + 1e-9)
        # points inside the torus are exactly the unreachable ones
        axial, radial = tip_coordinates(g, pts)
        inside = axial**2 + radial**2 < 2 * R_MIN * radial
        assert np.array_equal(~ok, inside)


def test_unchecked_reachability_answers_as_the_checked_one():
    """RRT's sampler calls the unchecked test: the same verdict as :func:`is_reachable` on
    random points around random poses, on the boundary's exact cases (the normal plane, the
    axis ahead and behind, the r_min circle) and on the lecture's example."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        g = _random_pose(rng)
        pts = g[:3, 3] + rng.normal(0, 60, (50, 3))
        want = is_reachable(g, pts, R_MIN)
        got = [is_reachable_unchecked(g[:3, 3], g[:3, 2], p, R_MIN) for p in pts]
        assert list(want) == got
    eye = np.eye(4)
    cases = {
        (0.0, 0.0, 5.0): True,  # straight ahead
        (0.0, 0.0, -5.0): False,  # straight behind
        (0.0, 0.0, 0.0): True,  # the tip itself (zero-length arc)
        (100.0, 0.0, 0.0): True,  # in the normal plane, at the half turn of r = 50
        (99.0, 0.0, 0.0): False,  # ... and inside the circle
        (10.0, 0.0, 30.0): True,  # on the r_min circle: radius exactly 50
        (30.0, 0.0, 40.0): False,  # inside it (radius 41.7)
        (0.0, 10.0, -1e-9): False,  # a hair behind the normal plane
    }
    for p, want in cases.items():
        assert bool(is_reachable(eye, p, R_MIN)) is want, p
        assert is_reachable_unchecked((0, 0, 0), (0, 0, 1), p, R_MIN) is want, p


def test_unchecked_arc_line_lengths_equal_the_checked_ones_to_the_bit():
    rng = np.random.default_rng(8)
    poses = np.array([_random_pose(rng) for _ in range(40)])
    for _ in range(20):
        q = rng.normal(0, 80, 3)
        want = arc_line_lengths_from(poses, q, R_MIN)
        assert np.array_equal(arc_line_lengths_from_unchecked(poses, q, R_MIN), want)


def test_bad_input():
    with pytest.raises(InvalidInputError, match="r_min_mm"):
        is_reachable(np.eye(4), [0, 0, 1.0], 0.0)
    with pytest.raises(InvalidInputError, match="r_min_mm"):
        shortest_arc_line(np.eye(4), [0, 0, 1.0], -5.0)
    with pytest.raises(InvalidInputError, match="points"):
        shortest_arc_line(np.eye(4), [0, np.nan, 1.0], 5.0)
    with pytest.raises(InvalidInputError, match="max_turn_rad"):
        is_reachable(np.eye(4), [0, 0, 1.0], 5.0, max_turn_rad=7.0)
