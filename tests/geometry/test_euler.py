"""Tests of needlekit.geometry.euler against independent oracles.

Oracles: scipy's ``Rotation`` (matrices and ``as_euler``), central finite differences of
rotation matrices (for T(phi)), the lecture's closed form for Euler XYZ, and finite
differences of a 7-joint serial chain (for the analytic Jacobian).
"""

from __future__ import annotations

from contextlib import nullcontext

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from needlekit.errors import InvalidInputError, SingularityError
from needlekit.geometry.euler import (
    CONVENTIONS,
    EULER_CONVENTIONS,
    FIXED_AXIS_CONVENTIONS,
    analytic_jacobian,
    angular_velocity_to_euler_rates,
    euler_rate_matrix,
    euler_rate_matrix_inv,
    euler_rates_to_angular_velocity,
    euler_to_matrix,
    matrix_to_euler,
)

FRAMES = ("world", "body")


def _is_proper(seq: str) -> bool:
    return seq[0].lower() == seq[2].lower()


def _random_angles(seq: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """Angles (n, 3) with the middle angle at least 0.25 rad from gimbal lock."""
    phi = rng.uniform(-np.pi, np.pi, size=(n, 3))
    if _is_proper(seq):
        phi[:, 1] = rng.uniform(0.25, np.pi - 0.25, size=n)
    else:
        phi[:, 1] = rng.uniform(-np.pi / 2 + 0.25, np.pi / 2 - 0.25, size=n)
    return phi


def _vee(m: np.ndarray) -> np.ndarray:
    """(…, 3, 3) skew part -> (…, 3) vector, averaging both triangles."""
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]],
        axis=-1,
    )


def _scipy_matrix(seq: str, phi: np.ndarray) -> np.ndarray:
    return Rotation.from_euler(seq, phi).as_matrix()


def _fd_omega(seq: str, phi: np.ndarray, phi_dot: np.ndarray, h: float = 1e-6):
    """World and body angular velocity of R(phi + t phi_dot) at t = 0, by central FD."""
    r = _scipy_matrix(seq, phi)
    r_dot = (_scipy_matrix(seq, phi + h * phi_dot) - _scipy_matrix(seq, phi - h * phi_dot)) / (
        2 * h
    )
    rt = np.swapaxes(r, -1, -2)
    return _vee(r_dot @ rt), _vee(rt @ r_dot)


# --------------------------------------------------------------------------- conventions


def test_convention_lists():
    assert len(EULER_CONVENTIONS) == len(FIXED_AXIS_CONVENTIONS) == 12
    assert CONVENTIONS == EULER_CONVENTIONS + FIXED_AXIS_CONVENTIONS
    assert len(set(CONVENTIONS)) == 24
    assert all(s.isupper() for s in EULER_CONVENTIONS)
    assert all(s.islower() for s in FIXED_AXIS_CONVENTIONS)
    assert sum(_is_proper(s) for s in CONVENTIONS) == 12
    for seq in CONVENTIONS:  # all valid sequences, no repeated neighbouring axes
        assert seq[0].lower() != seq[1].lower() != seq[2].lower()
        Rotation.from_euler(seq, [0.1, 0.2, 0.3])


# --------------------------------------------------------------------------- matrices


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_euler_to_matrix_matches_scipy(seq):
    rng = np.random.default_rng(1)
    phi = rng.uniform(-2 * np.pi, 2 * np.pi, size=(20, 3))
    expected = _scipy_matrix(seq, phi)
    np.testing.assert_allclose(euler_to_matrix(phi, seq), expected, atol=1e-14)
    single = euler_to_matrix(phi[3], seq)
    assert single.shape == (3, 3)
    np.testing.assert_allclose(single, expected[3], atol=1e-14)
    deg = euler_to_matrix(np.rad2deg(phi), seq, degrees=True)
    np.testing.assert_allclose(deg, expected, atol=1e-13)


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_matrix_to_euler_round_trip(seq):
    rng = np.random.default_rng(2)
    phi = _random_angles(seq, 10, rng)
    r = euler_to_matrix(phi, seq)
    back = matrix_to_euler(r, seq)
    assert back.shape == (10, 3)
    np.testing.assert_allclose(euler_to_matrix(back, seq), r, atol=1e-12)
    # unique representation inside scipy's ranges, so the angles come back too
    np.testing.assert_allclose(back, phi, atol=1e-10)
    np.testing.assert_allclose(matrix_to_euler(r[0], seq, degrees=True), np.rad2deg(phi[0]))


def test_fixed_axis_is_reversed_euler():
    """Fixed-axis 'abc' at (p1, p2, p3) is Euler 'CBA' at (p3, p2, p1)."""
    phi = np.array([0.3, -0.7, 1.9])
    for seq in FIXED_AXIS_CONVENTIONS:
        rev = seq[::-1].upper()
        np.testing.assert_allclose(
            euler_to_matrix(phi, seq), euler_to_matrix(phi[::-1], rev), atol=1e-15
        )
        for frame in FRAMES:
            t = euler_rate_matrix(phi, seq, frame=frame)
            t_rev = euler_rate_matrix(phi[::-1], rev, frame=frame)
            np.testing.assert_allclose(t, t_rev[:, ::-1], atol=1e-15)


# --------------------------------------------------------------------------- T(phi)


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("seq", CONVENTIONS)
def test_rate_matrix_matches_finite_differences(seq, frame):
    rng = np.random.default_rng(3)
    phi = rng.uniform(-np.pi, np.pi, size=(8, 3))  # T is defined everywhere
    phi_dot = rng.normal(size=(8, 3))
    w_world, w_body = _fd_omega(seq, phi, phi_dot)
    expected = w_world if frame == "world" else w_body
    t = euler_rate_matrix(phi, seq, frame=frame)
    assert t.shape == (8, 3, 3)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", t, phi_dot), expected, atol=1e-7)
    omega = euler_rates_to_angular_velocity(phi, phi_dot, seq, frame=frame)
    np.testing.assert_allclose(omega, expected, atol=1e-7)
    single = euler_rates_to_angular_velocity(phi[0], phi_dot[0], seq, frame=frame)
    assert single.shape == (3,)
    np.testing.assert_allclose(single, expected[0], atol=1e-7)


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_world_and_body_rate_matrices_are_related_by_R(seq):
    phi = _random_angles(seq, 5, np.random.default_rng(4))
    r = _scipy_matrix(seq, phi)
    t_world = euler_rate_matrix(phi, seq, frame="world")
    t_body = euler_rate_matrix(phi, seq, frame="body")
    np.testing.assert_allclose(r @ t_body, t_world, atol=1e-14)


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("seq", CONVENTIONS)
def test_det_is_cos_or_sin_of_middle_angle(seq, frame):
    phi = np.random.default_rng(5).uniform(-np.pi, np.pi, size=(10, 3))
    det = np.linalg.det(euler_rate_matrix(phi, seq, frame=frame))
    expected = np.sin(phi[:, 1]) if _is_proper(seq) else np.cos(phi[:, 1])
    np.testing.assert_allclose(np.abs(det), np.abs(expected), atol=1e-14)


def test_lecture_xyz_closed_form():
    rng = np.random.default_rng(6)
    for a, b, g in rng.uniform(-np.pi, np.pi, size=(10, 3)):
        sa, ca, sb, cb = np.sin(a), np.cos(a), np.sin(b), np.cos(b)
        lecture = np.array([[1.0, 0.0, sb], [0.0, ca, -sa * cb], [0.0, sa, ca * cb]])
        np.testing.assert_allclose(euler_rate_matrix([a, b, g], "XYZ"), lecture, atol=1e-15)
        # independent of gamma, as the lecture's derivation shows
        np.testing.assert_allclose(euler_rate_matrix([a, b, 0.0], "XYZ"), lecture, atol=1e-15)


def test_degrees_apply_to_angles_only():
    phi = np.array([10.0, 20.0, 30.0])
    rates = np.array([0.1, -0.2, 0.3])  # rad/s in both calls
    for frame in FRAMES:
        w_deg = euler_rates_to_angular_velocity(phi, rates, "ZYX", frame=frame, degrees=True)
        w_rad = euler_rates_to_angular_velocity(np.deg2rad(phi), rates, "ZYX", frame=frame)
        np.testing.assert_allclose(w_deg, w_rad, atol=1e-15)
        back = angular_velocity_to_euler_rates(phi, w_deg, "ZYX", frame=frame, degrees=True)
        np.testing.assert_allclose(back, rates, atol=1e-14)


# --------------------------------------------------------------------------- inverse


@pytest.mark.parametrize("frame", FRAMES)
@pytest.mark.parametrize("seq", CONVENTIONS)
def test_inverse_and_round_trip(seq, frame):
    rng = np.random.default_rng(7)
    phi = _random_angles(seq, 10, rng)
    t = euler_rate_matrix(phi, seq, frame=frame)
    t_inv = euler_rate_matrix_inv(phi, seq, frame=frame)
    np.testing.assert_allclose(t_inv @ t, np.broadcast_to(np.eye(3), t.shape), atol=1e-12)
    np.testing.assert_allclose(t_inv, np.linalg.inv(t), atol=1e-12)
    rates = rng.normal(size=(10, 3))
    omega = euler_rates_to_angular_velocity(phi, rates, seq, frame=frame)
    back = angular_velocity_to_euler_rates(phi, omega, seq, frame=frame)
    np.testing.assert_allclose(back, rates, atol=1e-12)
    one = angular_velocity_to_euler_rates(phi[0], omega[0], seq, frame=frame)
    assert one.shape == (3,)
    np.testing.assert_allclose(one, rates[0], atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(
    seq=st.sampled_from(CONVENTIONS),
    frame=st.sampled_from(FRAMES),
    phi=st.lists(st.floats(-10.0, 10.0), min_size=3, max_size=3),
)
def test_inverse_property(seq, frame, phi):
    mid = np.sin(phi[1]) if _is_proper(seq) else np.cos(phi[1])
    if abs(mid) < 1e-3:
        with pytest.raises(SingularityError) if abs(mid) < 1e-9 else nullcontext():
            euler_rate_matrix_inv(phi, seq, frame=frame)
        return
    t = euler_rate_matrix(phi, seq, frame=frame)
    t_inv = euler_rate_matrix_inv(phi, seq, frame=frame)
    np.testing.assert_allclose(t_inv @ t, np.eye(3), atol=1e-9 / abs(mid))


def test_broadcast_single_angles_against_batch_of_rates():
    phi = np.array([0.2, 0.3, 0.4])
    rates = np.random.default_rng(8).normal(size=(4, 3))
    w = euler_rates_to_angular_velocity(phi, rates, "ZYZ")
    assert w.shape == (4, 3)
    np.testing.assert_allclose(w, rates @ euler_rate_matrix(phi, "ZYZ").T, atol=1e-15)
    back = angular_velocity_to_euler_rates(phi, w, "ZYZ")
    np.testing.assert_allclose(back, rates, atol=1e-13)


# --------------------------------------------------------------------------- gimbal lock


def _locked_middle_angles(seq: str) -> list[float]:
    return [0.0, np.pi] if _is_proper(seq) else [np.pi / 2, -np.pi / 2]


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_gimbal_lock_raises(seq):
    jac = np.vstack([np.eye(3, 7), np.eye(3, 7, 2)])
    for mid in _locked_middle_angles(seq):
        phi = np.array([0.3, mid, -0.8])
        t = euler_rate_matrix(phi, seq)  # T itself exists, only singular
        assert abs(np.linalg.det(t)) < 1e-12
        for frame in FRAMES:
            with pytest.raises(SingularityError, match="angles") as info:
                euler_rate_matrix_inv(phi, seq, frame=frame)
            assert info.value.field == "angles"
            assert "gimbal lock" in str(info.value)
            assert "middle angle angles[1]" in str(info.value)
            with pytest.raises(SingularityError, match="angles"):
                angular_velocity_to_euler_rates(phi, [0.1, 0.2, 0.3], seq, frame=frame)
        with pytest.raises(SingularityError, match="gimbal lock"):
            analytic_jacobian(jac, phi, seq)
        with pytest.raises(SingularityError, match="gimbal lock"):
            euler_rate_matrix_inv(np.rad2deg(phi), seq, degrees=True)
    # just outside the tolerance the inverse exists
    near = np.array([0.3, _locked_middle_angles(seq)[0] + 1e-6, -0.8])
    t_inv = euler_rate_matrix_inv(near, seq)
    np.testing.assert_allclose(t_inv @ euler_rate_matrix(near, seq), np.eye(3), atol=1e-8)


def test_gimbal_lock_message_names_item_and_angle():
    phi = np.array([[0.1, 0.2, 0.3], [0.1, 0.2, 0.3], [0.5, np.pi / 2, 0.1]])
    with pytest.raises(SingularityError, match=r"angles\[2, 1\].*\+-pi/2.*Tait-Bryan"):
        euler_rate_matrix_inv(phi, "XYZ")
    with pytest.raises(SingularityError, match=r"= 180 deg is at 0 or pi.*proper Euler"):
        euler_rate_matrix_inv([10.0, 180.0, 20.0], "zyz", degrees=True)


# --------------------------------------------------------------------------- analytic Jacobian


def _rodrigues(w: np.ndarray, theta: float) -> np.ndarray:
    k = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    return np.eye(3) + np.sin(theta) * k + (1.0 - np.cos(theta)) * (k @ k)


class _Chain:
    """A 7-joint revolute chain as a product of exponentials (independent of needlekit)."""

    def __init__(self, rng: np.random.Generator) -> None:
        w = rng.normal(size=(7, 3))
        self.axes = w / np.linalg.norm(w, axis=1, keepdims=True)
        steps = rng.uniform(-0.3, 0.3, size=(7, 3)) + np.array([0.0, 0.0, 0.3])
        self.points = np.cumsum(steps, axis=0)
        self.home_r = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        self.home_p = self.points[-1] + [0.1, 0.05, 0.2]

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r_acc, p_acc = np.eye(3), np.zeros(3)
        for w, pt, qi in zip(self.axes, self.points, q, strict=True):
            r = _rodrigues(w, qi)
            p_acc = p_acc + r_acc @ ((np.eye(3) - r) @ pt)
            r_acc = r_acc @ r
        return r_acc @ self.home_r, r_acc @ self.home_p + p_acc

    def geometric_jacobian(self, q: np.ndarray) -> np.ndarray:
        """Rows (v of the end-effector point; world omega), analytic."""
        _, p_ee = self.fk(q)
        r_acc, p_acc = np.eye(3), np.zeros(3)
        jac = np.zeros((6, 7))
        for i, (w, pt, qi) in enumerate(zip(self.axes, self.points, q, strict=True)):
            w_now, pt_now = r_acc @ w, r_acc @ pt + p_acc
            jac[:3, i] = np.cross(w_now, p_ee - pt_now)
            jac[3:, i] = w_now
            r = _rodrigues(w, qi)
            p_acc = p_acc + r_acc @ ((np.eye(3) - r) @ pt)
            r_acc = r_acc @ r
        return jac


def _pose_angles(chain: _Chain, q: np.ndarray, seq: str) -> tuple[np.ndarray, np.ndarray]:
    r, p = chain.fk(q)
    return p, Rotation.from_matrix(r).as_euler(seq)  # scipy is the oracle here


def _well_conditioned_q(chain: _Chain, seq: str, rng: np.random.Generator) -> np.ndarray:
    """A configuration whose angles are away from gimbal lock and from the +-pi wrap."""
    for _ in range(1000):
        q = rng.uniform(-np.pi, np.pi, size=7)
        _, phi = _pose_angles(chain, q, seq)
        mid = abs(np.sin(phi[1])) if _is_proper(seq) else abs(np.cos(phi[1]))
        if mid > 0.3 and np.all(np.pi - np.abs(phi[[0, 2]]) > 0.2):
            return q
    raise AssertionError("no well-conditioned configuration found")


def test_chain_geometric_jacobian_matches_finite_differences():
    rng = np.random.default_rng(9)
    chain = _Chain(rng)
    q, q_dot, h = rng.uniform(-np.pi, np.pi, size=7), rng.normal(size=7), 1e-6
    (r_p, p_p), (r_m, p_m) = chain.fk(q + h * q_dot), chain.fk(q - h * q_dot)
    r, _ = chain.fk(q)
    fd = np.concatenate([(p_p - p_m) / (2 * h), _vee((r_p - r_m) / (2 * h) @ r.T)])
    np.testing.assert_allclose(chain.geometric_jacobian(q) @ q_dot, fd, atol=1e-8)


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_analytic_jacobian_matches_finite_differences(seq):
    rng = np.random.default_rng(10)
    chain = _Chain(rng)
    qs = np.array([_well_conditioned_q(chain, seq, rng) for _ in range(3)])
    jac_g = np.array([chain.geometric_jacobian(q) for q in qs])
    phi = np.array([_pose_angles(chain, q, seq)[1] for q in qs])
    np.testing.assert_allclose(phi, [matrix_to_euler(chain.fk(q)[0], seq) for q in qs])

    jac_a = analytic_jacobian(jac_g, phi, seq)
    assert jac_a.shape == (3, 6, 7)
    np.testing.assert_array_equal(jac_a[:, :3], jac_g[:, :3])
    h = 1e-5
    for k, q in enumerate(qs):
        q_dot = rng.normal(size=7)
        p_p, phi_p = _pose_angles(chain, q + h * q_dot, seq)
        p_m, phi_m = _pose_angles(chain, q - h * q_dot, seq)
        fd = np.concatenate([p_p - p_m, phi_p - phi_m]) / (2 * h)
        np.testing.assert_allclose(jac_a[k] @ q_dot, fd, atol=1e-7)
        one = analytic_jacobian(jac_g[k], np.rad2deg(phi[k]), seq, degrees=True)
        assert one.shape == (6, 7)
        np.testing.assert_allclose(one, jac_a[k], atol=1e-12)


def test_analytic_jacobian_broadcasts_single_angles():
    jac = np.random.default_rng(11).normal(size=(4, 6, 5))
    phi = np.array([0.1, 0.2, 0.3])
    out = analytic_jacobian(jac, phi, "zyx")
    t_inv = euler_rate_matrix_inv(phi, "zyx")
    np.testing.assert_allclose(out[:, 3:], t_inv @ jac[:, 3:], atol=1e-15)


# --------------------------------------------------------------------------- bad input


def _angle_calls(phi):
    jac = np.zeros((6, 7))
    return [
        lambda: euler_to_matrix(phi, "XYZ"),
        lambda: euler_rate_matrix(phi, "XYZ"),
        lambda: euler_rate_matrix_inv(phi, "XYZ"),
        lambda: euler_rates_to_angular_velocity(phi, [0.0, 0.0, 0.0], "XYZ"),
        lambda: angular_velocity_to_euler_rates(phi, [0.0, 0.0, 0.0], "XYZ"),
        lambda: analytic_jacobian(jac, phi, "XYZ"),
    ]


@pytest.mark.parametrize(
    "phi",
    [
        [0.1, np.nan, 0.2],
        [[0.1, 0.2, 0.3], [np.inf, 0.0, 0.0]],
        [0.1, 0.2],
        [0.1, 0.2, 0.3, 0.4],
        np.zeros((2, 3, 3)),
        "abc",
    ],
    ids=["nan", "inf", "short", "long", "3d", "text"],
)
def test_bad_angles(phi):
    for call in _angle_calls(phi):
        with pytest.raises(InvalidInputError, match="angles") as info:
            call()
        assert info.value.field == "angles"


@pytest.mark.parametrize("seq", ["abc", "XYz", "xxy", "XY", "XYZX", "", 123, None])
def test_unknown_seq(seq):
    calls = [
        lambda: euler_to_matrix([0.1, 0.2, 0.3], seq),
        lambda: matrix_to_euler(np.eye(3), seq),
        lambda: euler_rate_matrix([0.1, 0.2, 0.3], seq),
        lambda: euler_rate_matrix_inv([0.1, 0.2, 0.3], seq),
        lambda: euler_rates_to_angular_velocity([0.1, 0.2, 0.3], [0, 0, 0], seq),
        lambda: angular_velocity_to_euler_rates([0.1, 0.2, 0.3], [0, 0, 0], seq),
        lambda: analytic_jacobian(np.zeros((6, 2)), [0.1, 0.2, 0.3], seq),
    ]
    for call in calls:
        with pytest.raises(InvalidInputError, match="expected one of the 24 conventions") as info:
            call()
        assert info.value.field == "seq"
        assert repr(seq) in str(info.value)


@pytest.mark.parametrize("frame", ["spatial", "World", "", None])
def test_bad_frame(frame):
    for call in [
        lambda: euler_rate_matrix([0.1, 0.2, 0.3], "XYZ", frame=frame),
        lambda: euler_rate_matrix_inv([0.1, 0.2, 0.3], "XYZ", frame=frame),
        lambda: euler_rates_to_angular_velocity([0.1, 0.2, 0.3], [0, 0, 0], "XYZ", frame=frame),
        lambda: angular_velocity_to_euler_rates([0.1, 0.2, 0.3], [0, 0, 0], "XYZ", frame=frame),
    ]:
        with pytest.raises(InvalidInputError, match="frame: expected 'world' or 'body'"):
            call()


def test_bad_rates_omega_and_jacobian():
    phi = np.zeros((2, 3)) + 0.1
    with pytest.raises(InvalidInputError, match="angle_rates"):
        euler_rates_to_angular_velocity(phi, np.zeros((3, 3)), "XYZ")  # 2 vs 3 items
    with pytest.raises(InvalidInputError, match="angle_rates"):
        euler_rates_to_angular_velocity(phi, [0.0, np.nan, 0.0], "XYZ")
    with pytest.raises(InvalidInputError, match="omega"):
        angular_velocity_to_euler_rates(phi, np.zeros(4), "XYZ")
    with pytest.raises(InvalidInputError, match="geometric_jacobian"):
        analytic_jacobian(np.zeros((5, 7)), phi[0], "XYZ")
    with pytest.raises(InvalidInputError, match="geometric_jacobian"):
        analytic_jacobian(np.zeros(6), phi[0], "XYZ")
    with pytest.raises(InvalidInputError, match="geometric_jacobian"):
        analytic_jacobian(np.full((6, 7), np.nan), phi[0], "XYZ")
    with pytest.raises(InvalidInputError, match="geometric_jacobian"):
        analytic_jacobian(np.zeros((3, 6, 7)), phi, "XYZ")  # 3 vs 2 items
    with pytest.raises(InvalidInputError, match="geometric_jacobian"):
        analytic_jacobian([[0.0] * 7] * 5 + [[0.0] * 6], phi[0], "XYZ")  # ragged
    with pytest.raises(InvalidInputError, match="R: rotation part"):
        matrix_to_euler(2.0 * np.eye(3), "XYZ")
