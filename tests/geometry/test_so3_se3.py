"""SO(3)/SE(3): closed forms against scipy's expm and Rotation, round trips, edge cases."""

import numpy as np
import pytest
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import (
    adjoint,
    hat6,
    make_pose,
    pose_inverse,
    se3_exp,
    se3_log,
    transform_points,
    vee6,
)
from needlekit.geometry.so3 import (
    hat,
    hat_unchecked,
    rot_x,
    rot_y,
    rot_z,
    so3_exp,
    so3_exp_unchecked,
    so3_log,
    so3_log_unchecked,
    vee,
)


def _rotvecs(rng, n, max_angle=np.pi):
    w = rng.normal(size=(n, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    return w * rng.uniform(0, max_angle, (n, 1))


def test_hat_is_cross_product_and_vee_inverts_it():
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=(2, 50, 3))
    assert np.allclose(np.einsum("nij,nj->ni", hat(a), b), np.cross(a, b))
    assert np.allclose(vee(hat(a)), a)
    assert hat([1.0, 2.0, 3.0]).shape == (3, 3)


def test_so3_exp_matches_scipy_and_log_inverts():
    rng = np.random.default_rng(1)
    w = _rotvecs(rng, 2000, np.pi - 1e-9)
    assert np.allclose(so3_exp(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    assert np.allclose(so3_log(so3_exp(w)), w, atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 1e-5, 0.5, np.pi - 1e-4, np.pi - 1e-9, np.pi])
def test_so3_log_near_zero_and_pi(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    r = Rotation.from_rotvec(axis * angle).as_matrix()
    w = so3_log(r)
    assert np.allclose(so3_exp(w), r, atol=1e-12)
    assert np.linalg.norm(w) == pytest.approx(angle, abs=1e-9)


@pytest.mark.parametrize("w", [[0.0, 0.0, 0.0], [1e-9, 0.0, 0.0], [1e-3, 2e-3, -1e-3],
                               [0.3, -1.2, 2.0], [0.0, 0.0, np.pi]])  # fmt: skip
def test_the_unchecked_twins_match_scipy_for_one_vector(w):
    w = np.asarray(w, dtype=float)
    assert np.allclose(so3_exp_unchecked(w), Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    assert np.allclose(so3_exp_unchecked(w), so3_exp(w), atol=1e-15)
    assert np.array_equal(hat_unchecked(w), hat(w))


def test_elementary_rotations_match_scipy():
    for fn, ax in ((rot_x, "x"), (rot_y, "y"), (rot_z, "z")):
        t = np.array([-2.0, 0.0, 0.4, 3.0])
        assert np.allclose(fn(t), Rotation.from_euler(ax, t[:, None]).as_matrix())
        assert fn(0.4).shape == (3, 3)


def test_se3_exp_matches_matrix_exponential():
    rng = np.random.default_rng(2)
    xi = np.concatenate([rng.normal(0, 50, (300, 3)), _rotvecs(rng, 300, 3.0)], axis=1)
    xi[:20, 3:] *= 1e-9  # near-pure translations exercise the series branch
    ref = np.array([expm(h) for h in hat6(xi)])
    assert np.allclose(se3_exp(xi), ref, atol=1e-11)


def test_se3_log_round_trip():
    rng = np.random.default_rng(3)
    xi = np.concatenate([rng.normal(0, 50, (1000, 3)), _rotvecs(rng, 1000, np.pi - 1e-6)], axis=1)
    assert np.allclose(se3_log(se3_exp(xi)), xi, atol=1e-9)
    assert np.allclose(vee6(hat6(xi)), xi)


def test_pose_inverse_and_adjoint():
    rng = np.random.default_rng(4)
    g = se3_exp(np.concatenate([rng.normal(0, 20, (10, 3)), _rotvecs(rng, 10)], axis=1))
    assert np.allclose(pose_inverse(g) @ g, np.eye(4), atol=1e-12)
    xi = rng.normal(size=6)
    for gi in g:
        lhs = hat6(adjoint(gi) @ xi)
        assert np.allclose(lhs, gi @ hat6(xi) @ np.linalg.inv(gi), atol=1e-10)


def test_make_pose_and_transform_points():
    r = rot_z(np.pi / 2)
    g = make_pose(r, [1.0, 2.0, 3.0])
    assert np.allclose(transform_points(g, [1.0, 0.0, 0.0]), [1.0, 3.0, 3.0])
    assert transform_points(g, np.zeros((5, 3))).shape == (5, 3)
    with pytest.raises(InvalidInputError, match="pose"):
        transform_points(np.stack([g, g]), [0.0, 0.0, 0.0])


def test_bad_input_names_the_argument():
    with pytest.raises(InvalidInputError, match="omega"):
        so3_exp([np.nan, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="twist"):
        se3_exp(np.zeros(5))
    with pytest.raises(InvalidInputError, match="rotation"):
        so3_log(np.diag([1.0, 1.0, -1.0]))
    bad = np.eye(4)
    bad[3, 0] = 1.0
    with pytest.raises(InvalidInputError, match="last row"):
        se3_log(bad)
    with pytest.raises(InvalidInputError, match="omega"):
        hat("abc")


def test_angle_between_one_pair_gives_the_batch_bits():
    """One pair of 3-vectors takes a scalar path (a control tick's angle): the same bits
    as the batch formula, for lengths from 1e-8 to 1e3, near 0 and near pi."""
    from needlekit.geometry.so3 import angle_between

    rng = np.random.default_rng(7)
    u = rng.normal(size=(3000, 3)) * 10.0 ** rng.uniform(-8, 3, (3000, 1))
    v = rng.normal(size=(3000, 3)) * 10.0 ** rng.uniform(-8, 3, (3000, 1))
    v[:500] = u[:500] * (1.0 + 1e-13)  # parallel
    v[500:800] = -u[500:800]  # opposite
    batch = angle_between(u, v)  # the (n, 3) path
    for i in range(len(u)):
        one = angle_between(u[i], v[i])
        assert type(one) is np.float64 and one == batch[i], i
    w = np.array([1.0, 2.0, 3.0])
    assert angle_between(w, 2.0 * w) == 0.0 and angle_between(w, -w) == np.pi


def test_one_matrix_log_has_the_batch_logs_bits():
    # random rotations, small angles (the series), angles near pi (the symmetric part's
    # branch), and products of two rotations (a filter's innovation: rotations to
    # rounding, not exactly)
    rng = np.random.default_rng(7)
    axes = rng.normal(size=(3000, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([
        rng.uniform(0.0, np.pi, 1000), 10.0 ** rng.uniform(-12, -3, 1000),
        np.pi - 10.0 ** rng.uniform(-12, -0.5, 1000),
    ])  # fmt: skip
    rs = [so3_exp(a * w) for a, w in zip(angles, axes, strict=True)]
    rs += [rs[i] @ rs[i + 1].T for i in range(0, 600, 2)] + [np.eye(3)]
    batch = so3_log(np.stack(rs))
    one = np.stack([so3_log_unchecked(r) for r in rs])
    assert np.array_equal(one, batch)
    assert np.array_equal(so3_log_unchecked(np.eye(3)), np.zeros(3))
