"""Transformation-matrix method: the lecture's matrices, inverse/forward round trips."""

import numpy as np
import pytest

from needlekit.errors import InvalidInputError, UnreachableTargetError
from needlekit.geometry.arcs import arc_transform
from needlekit.geometry.se3 import make_pose, se3_exp
from needlekit.geometry.so3 import rot_y, rot_z
from needlekit.needle.transform_method import tm_inverse, tm_pose, tm_transform, tm_waypoints


def _trans(x=0.0, z=0.0):
    return make_pose(translation=[x, 0.0, z])


def test_product_of_elementary_transforms_and_lecture_matrix():
    rng = np.random.default_rng(0)
    for alpha, phi, r in rng.uniform([-np.pi, 0.01, 5], [np.pi, 2 * np.pi, 500], (200, 3)):
        oa, ab = r * (1 - np.cos(phi)), r * np.sin(phi)
        product = make_pose(rot_z(alpha)) @ _trans(x=oa) @ _trans(z=ab) @ make_pose(rot_y(phi))
        ca, sa, cp, sp = np.cos(alpha), np.sin(alpha), np.cos(phi), np.sin(phi)
        lecture = np.array(
            [
                [ca * cp, -sa, ca * sp, r * ca * (1 - cp)],
                [sa * cp, ca, sa * sp, r * sa * (1 - cp)],
                [-sp, 0, cp, r * sp],
                [0, 0, 0, 1],
            ]
        )
        g = tm_transform(alpha, phi, r)
        assert np.allclose(g, product, atol=1e-10)
        assert np.allclose(g, lecture, atol=1e-10)


def test_frame_relation_to_the_twist_model():
    rng = np.random.default_rng(1)
    for alpha, phi, r in rng.uniform([-np.pi, 0.0, 5], [np.pi, 2 * np.pi, 500], (100, 3)):
        twist = arc_transform(alpha + np.pi / 2, 1 / r, r * phi)
        assert np.allclose(
            tm_transform(alpha, phi, r), twist @ make_pose(rot_z(-np.pi / 2)), atol=1e-10
        )


def _random_pose(rng):
    return se3_exp(np.concatenate([rng.normal(0, 100, 3), rng.normal(0, 2, 3)]))


def test_forward_of_inverse_returns_target_to_1e9_mm():
    rng = np.random.default_rng(2)
    worst = 0.0
    for _ in range(20):
        g = _random_pose(rng)
        local = rng.uniform(-200, 200, (500, 3))
        local[:25, :2] *= 1e-6  # nearly on the axis, ahead of the tip
        local[:25, 2] = np.abs(local[:25, 2])
        local[25:50, :2] = 0.0  # on the axis, ahead
        local[25:50, 2] = np.abs(local[25:50, 2])
        targets = local @ g[:3, :3].T + g[:3, 3]
        sol = tm_inverse(targets, g)
        worst = max(worst, np.abs(sol.end_poses()[:, :3, 3] - targets).max())
    assert worst < 1e-9


def test_targets_just_behind_the_tip_are_exact_to_machine_precision_of_the_arc():
    """A point 1e-4 mm off the axis behind the tip needs a near-full circle of radius
    ~1e8 mm: (alpha, r, phi, l) is ill-conditioned there, and the round trip is exact up to
    rounding relative to the arc length."""
    rng = np.random.default_rng(5)
    g = _random_pose(rng)
    local = np.column_stack([rng.uniform(-1e-4, 1e-4, (200, 2)), rng.uniform(-200, -1, 200)])
    targets = local @ g[:3, :3].T + g[:3, 3]
    sol = tm_inverse(targets, g)
    err = np.linalg.norm(sol.end_poses()[:, :3, 3] - targets, axis=1)
    assert np.all(sol.phi_rad > 2 * np.pi - 1e-3)
    assert np.all(err <= 1e-15 * sol.length_mm + 1e-9)


def test_lecture_inverse_formulas():
    rng = np.random.default_rng(3)
    p = rng.uniform([-100, -100, 1], [100, 100, 150], (1000, 3))  # z > 0 for the atan form
    sol = tm_inverse(p)
    k = np.hypot(p[:, 0], p[:, 1])
    assert np.allclose(sol.radius_mm, k / 2 + p[:, 2] ** 2 / (2 * k))
    assert np.allclose(sol.phi_rad, np.pi - 2 * np.arctan(p[:, 2] / k))
    assert np.allclose(sol.length_mm, sol.radius_mm * sol.phi_rad)
    assert np.allclose(sol.alpha_rad, np.arctan2(p[:, 1], p[:, 0]))


def test_straight_and_behind():
    sol = tm_inverse([[0.0, 0.0, 40.0], [0.0, 0.0, 0.0]])
    assert np.all(np.isinf(sol.radius_mm)) and np.allclose(sol.length_mm, [40.0, 0.0])
    assert np.allclose(sol.kappa_per_mm, 0.0)
    with pytest.raises(UnreachableTargetError, match="behind"):
        tm_inverse([0.0, 0.0, -1.0])
    with pytest.raises(UnreachableTargetError, match="r_min_mm = 100"):
        tm_inverse([50.0, 0.0, 50.0], r_min_mm=100.0)


def test_waypoints_split_phi_evenly():
    sol = tm_inverse([[30.0, 20.0, 60.0], [0.0, -10.0, 90.0]])
    wp = tm_waypoints(sol, 45)
    assert wp.shape == (2, 46, 4, 4)
    # the method's frame starts turned by alpha about z (see module docstring)
    assert np.allclose(wp[:, 0, :3, 3], 0.0)
    assert np.allclose(wp[:, 0, :3, 2], [0.0, 0.0, 1.0])
    assert np.allclose(wp[:, -1], sol.end_poses())
    cos_step = np.einsum("nki,nki->nk", wp[:, 1:, :3, 2], wp[:, :-1, :3, 2])
    assert np.allclose(np.arccos(np.clip(cos_step, -1, 1)), (sol.phi_rad / 45)[:, None], atol=1e-7)


def test_tm_pose_straight_and_bad_input():
    assert np.allclose(tm_pose(0.3, 0.0, 25.0)[:3, 3], [0, 0, 25.0])
    with pytest.raises(InvalidInputError, match="radius_mm"):
        tm_transform(0.0, 1.0, 0.0)
    with pytest.raises(InvalidInputError, match="targets"):
        tm_inverse([np.nan, 0.0, 1.0])
    with pytest.raises(InvalidInputError, match="length_mm"):
        tm_pose(0.0, 0.01, -1.0)
    with pytest.raises(InvalidInputError, match="n_steps"):
        tm_waypoints(tm_inverse([1.0, 0.0, 1.0]), 0)
    with pytest.raises(InvalidInputError, match="world_T_tip"):
        tm_inverse([1.0, 0.0, 1.0], np.stack([np.eye(4)] * 2))
