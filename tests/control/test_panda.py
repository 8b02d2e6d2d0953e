"""Panda kinematics: the numba dual-quaternion chain against dqrobotics and finite differences."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from needlekit.control.dq import dq_conj, dq_from_matrix, dq_mul, dq_to_matrix, dq_translation
from needlekit.control.panda import Q_DOT_MAX, Q_MAX, Q_MIN, PandaModel
from needlekit.errors import InvalidInputError


def _random_pose(rng, scale_mm):
    g = np.eye(4)
    g[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
    g[:3, 3] = rng.uniform(-scale_mm, scale_mm, 3)
    return g


@pytest.fixture(scope="module")
def models():
    rng = np.random.default_rng(1)
    out = [PandaModel()]
    out += [PandaModel(_random_pose(rng, 500.0), _random_pose(rng, 100.0)) for _ in range(3)]
    return out


def test_dual_quaternion_algebra_matches_matrices():
    rng = np.random.default_rng(0)
    for _ in range(20):
        a, b = _random_pose(rng, 100.0), _random_pose(rng, 100.0)
        xa, xb = dq_from_matrix(a), dq_from_matrix(b)
        np.testing.assert_allclose(dq_to_matrix(dq_mul(xa, xb)), a @ b, atol=1e-10)
        np.testing.assert_allclose(dq_to_matrix(dq_conj(xa)), np.linalg.inv(a), atol=1e-10)
        np.testing.assert_allclose(dq_translation(xa), a[:3, 3], atol=1e-12)


def test_limits_are_the_pandas_own_not_the_librarys():
    from dqrobotics.robots import FrankaEmikaPandaRobot

    shipped = FrankaEmikaPandaRobot.kinematics()
    assert not np.allclose(shipped.get_upper_q_limit(), Q_MAX)  # why we set them ourselves
    np.testing.assert_allclose(Q_MIN[[0, 3, 5]], [-2.8973, -3.0718, -0.0175])
    np.testing.assert_allclose(Q_MAX[[3, 5]], [-0.0698, 3.7525])
    np.testing.assert_allclose(Q_DOT_MAX, [2.175] * 4 + [2.61] * 3)
    np.testing.assert_allclose(
        np.vstack([shipped.get_thetas(), shipped.get_ds(), shipped.get_as(), shipped.get_alphas()])
        * np.array([[1], [1000], [1000], [1]]),
        __import__("needlekit.control.panda", fromlist=["PANDA_MDH_MM"]).PANDA_MDH_MM,
    )


def test_tip_pose_and_pose_jacobian_match_dqrobotics(models):
    from dqrobotics import vec8

    rng = np.random.default_rng(2)
    for m in models:
        robot = m.reference_robot()
        for _ in range(10):
            q = rng.uniform(m.q_min, m.q_max)
            s = m.state(q)
            np.testing.assert_allclose(s.tip_dq, vec8(robot.fkm(q)), atol=1e-10)
            np.testing.assert_allclose(s.pose_jacobian, robot.pose_jacobian(q), atol=1e-9)


def test_translation_axis_and_link_jacobians_match_finite_differences(models):
    rng = np.random.default_rng(3)
    h = 1e-6
    for m in models:
        q = rng.uniform(m.q_min, m.q_max)
        s = m.state(q)
        for i in range(7):
            e = np.zeros(7)
            e[i] = h
            sp, sm = m.state(q + e), m.state(q - e)
            np.testing.assert_allclose(
                (sp.tip_mm - sm.tip_mm) / (2 * h), s.tip_jacobian[:, i], atol=1e-5
            )
            np.testing.assert_allclose(
                (sp.needle_axis - sm.needle_axis) / (2 * h), s.axis_jacobian[:, i], atol=1e-8
            )
            np.testing.assert_allclose(
                (sp.tip_dq - sm.tip_dq) / (2 * h), s.pose_jacobian[:, i], atol=1e-5
            )
            for k in range(8):
                np.testing.assert_allclose(
                    (sp.origins[k] - sm.origins[k]) / (2 * h),
                    s.point_jacobian(k)[:, i],
                    atol=1e-5,
                )


def test_needle_tip_pose_composes_base_chain_flange_and_needle(models):
    m = models[1]
    q = np.array([0.3, -0.2, 0.1, -1.8, 0.2, 1.6, -0.4])
    bare = PandaModel()
    flange = np.eye(4)
    flange[2, 3] = 107.0
    chain = bare.tip_pose(q) @ np.linalg.inv(flange)
    np.testing.assert_allclose(
        m.tip_pose(q), m.world_T_base @ chain @ flange @ m.flange_T_tip, atol=1e-9
    )


def test_bad_input_names_the_field():
    with pytest.raises(InvalidInputError, match="q"):
        PandaModel().state(np.zeros(6))
    with pytest.raises(InvalidInputError, match="q"):
        PandaModel().state([np.nan] * 7)
    with pytest.raises(InvalidInputError, match="world_T_base"):
        PandaModel(world_T_base=np.diag([1.0, 1.0, -1.0, 1.0]))
    with pytest.raises(InvalidInputError, match="q_min"):
        PandaModel(q_min=Q_MAX)


def test_dq_from_matrix_round_trips_every_branch():
    from needlekit.geometry.so3 import so3_exp

    rng = np.random.default_rng(9)
    # generic rotations, and half-turns about each axis (each branch of the conversion)
    omegas = [rng.normal(size=3) for _ in range(20)]
    omegas += [np.pi * e for e in np.eye(3)] + [0.999 * np.pi * np.array([1.0, 1.0, 0.0]) / 2**0.5]
    for w in omegas:
        g = np.eye(4)
        g[:3, :3] = so3_exp(w)
        g[:3, 3] = rng.normal(0, 100, 3)
        x = dq_from_matrix(g)
        assert x[0] >= 0 and abs(np.linalg.norm(x[:4]) - 1) < 1e-12
        np.testing.assert_allclose(dq_to_matrix(x), g, atol=1e-9)
