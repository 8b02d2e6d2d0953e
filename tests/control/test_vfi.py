"""VFI distances and Jacobians: finite differences on the Panda and dqrobotics as oracle."""

import numpy as np
import pytest

from needlekit.control.panda import PandaModel
from needlekit.control.vfi import (
    Line,
    Plane,
    Zone,
    joint_limit_bounds,
    line_angle_distance,
    point_line_sq_distance,
    point_plane_distance,
    vfi_row,
)
from needlekit.errors import InvalidInputError

LINE = Line([400.0, 50.0, 300.0], [0.3, -0.2, 0.9])
PLANE = Plane([420.0, 0.0, 250.0], [0.1, 0.2, 1.0])
U = np.array([0.2, 0.1, -1.0]) / np.linalg.norm([0.2, 0.1, -1.0])


def _distances(state, k):
    """Every VFI distance of the state: point k to the line, needle angle, tip to plane."""
    return (
        point_line_sq_distance(state.origins[k], state.point_jacobian(k), LINE),
        point_line_sq_distance(state.tip_mm, state.tip_jacobian, LINE),
        line_angle_distance(state.needle_axis, state.axis_jacobian, U),
        point_plane_distance(state.tip_mm, state.tip_jacobian, PLANE),
    )


@pytest.mark.parametrize("seed", range(5))
def test_every_vfi_jacobian_matches_finite_differences(seed):
    rng = np.random.default_rng(seed)
    m = PandaModel()
    q = rng.uniform(m.q_min, m.q_max)
    k = int(rng.integers(2, 8))
    s = m.state(q)
    h = 1e-6
    for i in range(7):
        e = np.zeros(7)
        e[i] = h
        plus, minus = _distances(m.state(q + e), k), _distances(m.state(q - e), k)
        for (d, jac), (dp, _), (dm, _) in zip(_distances(s, k), plus, minus, strict=True):
            rounding = 1e-9 * max(1.0, abs(d)) / h  # float error of the difference quotient
            assert (dp - dm) / (2 * h) == pytest.approx(jac[i], rel=1e-5, abs=rounding)


def test_distances_and_jacobians_match_dqrobotics():
    from dqrobotics import DQ, E_, cross, vec4
    from dqrobotics.robot_modeling import DQ_Kinematics
    from dqrobotics.utils import DQ_Geometry

    rng = np.random.default_rng(7)
    m = PandaModel()
    robot = m.reference_robot()
    line_dq = DQ(np.r_[0.0, LINE.direction]) + E_ * cross(
        DQ(np.r_[0.0, LINE.point_mm]), DQ(np.r_[0.0, LINE.direction])
    )
    plane_dq = DQ(np.r_[0.0, PLANE.normal]) + E_ * float(PLANE.point_mm @ PLANE.normal)
    for _ in range(5):
        q = rng.uniform(m.q_min, m.q_max)
        s = m.state(q)
        x = robot.fkm(q)
        jac = robot.pose_jacobian(q)
        jt = DQ_Kinematics.translation_jacobian(jac, x)
        t = DQ(np.r_[0.0, s.tip_mm])
        d, row = point_line_sq_distance(s.tip_mm, s.tip_jacobian, LINE)
        assert d == pytest.approx(DQ_Geometry.point_to_line_squared_distance(t, line_dq))
        np.testing.assert_allclose(
            row, DQ_Kinematics.point_to_line_distance_jacobian(jt, t, line_dq).ravel(), atol=1e-7
        )
        d, row = point_plane_distance(s.tip_mm, s.tip_jacobian, PLANE)
        assert d == pytest.approx(DQ_Geometry.point_to_plane_distance(t, plane_dq))
        np.testing.assert_allclose(
            row, DQ_Kinematics.point_to_plane_distance_jacobian(jt, t, plane_dq).ravel(), atol=1e-9
        )
        # the needle axis as a line through the tip, against the fixed direction U
        jl = DQ_Kinematics.line_jacobian(jac, x, DQ([0.0, 0.0, 0.0, 1.0]))
        needle = DQ(np.r_[0.0, s.needle_axis]) + E_ * cross(t, DQ(np.r_[0.0, s.needle_axis]))
        target = DQ(np.r_[0.0, U])
        f, row = line_angle_distance(s.needle_axis, s.axis_jacobian, U)
        assert f == pytest.approx(2 - 2 * float(vec4(needle)[1:] @ U))
        np.testing.assert_allclose(
            row, DQ_Kinematics.line_to_line_angle_jacobian(jl, needle, target).ravel(), atol=1e-9
        )


def test_vfi_rows_keep_the_distance_on_its_side():
    # d_dot = jac . u; every u the row allows keeps d - d_s decaying at most at rate eta
    rng = np.random.default_rng(0)
    for zone in Zone:
        for _ in range(50):
            jac, u = rng.normal(size=3), rng.normal(size=3)
            d, safe, eta = rng.uniform(0, 10), rng.uniform(0, 10), 0.7
            row, rhs = vfi_row(d, jac, safe, zone, eta)
            if row @ u <= rhs:
                rate = jac @ u
                if zone is Zone.OUTSIDE:
                    assert rate >= -eta * (d - safe) - 1e-12
                else:
                    assert rate <= eta * (safe - d) + 1e-12


def test_joint_limit_bounds():
    q = np.array([0.0, 1.7, -1.7])
    lo, hi = joint_limit_bounds(q, np.full(3, -1.8), np.full(3, 1.8), np.full(3, 2.0), gain=1.0)
    np.testing.assert_allclose(lo, [-1.8, -2.0, -0.1])
    np.testing.assert_allclose(hi, [1.8, 0.1, 2.0])


def test_primitives_validate_their_fields():
    with pytest.raises(InvalidInputError, match="direction"):
        Line([0, 0, 0], [0, 0, 0])
    with pytest.raises(InvalidInputError, match="point_mm"):
        Plane([0, np.nan, 0], [0, 0, 1])


def test_batched_robot_point_distances_match_one_at_a_time():
    rng = np.random.default_rng(5)
    m = PandaModel()
    line = Line(rng.normal(0, 100, 3), rng.normal(size=3))
    for _ in range(5):
        s = m.state(rng.uniform(m.q_min, m.q_max))
        ks = np.arange(8)
        d, jac = s.points_line_sq_distances(ks, line.point_mm, line.direction)
        for r, k in enumerate(ks):
            d1, j1 = point_line_sq_distance(s.origins[k], s.point_jacobian(k), line)
            assert d[r] == pytest.approx(d1, rel=1e-12)
            np.testing.assert_allclose(jac[r], j1, atol=1e-9 * max(1.0, np.abs(j1).max()))
