"""Q_dot = J^-1 mu1 u1 + J^-1 mu2 u2 in all 24 conventions, against the SE(3) model."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from needlekit.errors import SingularityError
from needlekit.geometry.euler import CONVENTIONS
from needlekit.needle.bevel3d import body_twist, propagate_bevel
from needlekit.needle.state_rates import (
    needle_jacobian,
    pose_from_state,
    state_from_pose,
    state_rates,
)

# Middle angles away from both kinds of gimbal lock (0, +-pi/2, pi) along the whole path.
Q0 = np.array([5.0, -3.0, 20.0, 0.4, 0.8, -0.6])


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_integrating_q_dot_reproduces_the_se3_model(seq):
    u1, u2, kappa, dur = 3.0, 0.05, 0.02, 4.0
    sol = solve_ivp(
        lambda t, q: state_rates(q, u1, u2, kappa, seq),
        (0.0, dur),
        Q0,
        method="DOP853",
        rtol=1e-12,
        atol=1e-12,
    )
    got = pose_from_state(sol.y[:, -1], seq)
    ref = propagate_bevel(pose_from_state(Q0, seq), [[u1, u2, dur]], kappa)[-1]
    assert np.abs(got[:3, 3] - ref[:3, 3]).max() < 1e-6
    assert np.abs(got[:3, :3] - ref[:3, :3]).max() < 1e-8


@pytest.mark.parametrize("seq", CONVENTIONS)
def test_jacobian_maps_rates_back_to_the_body_twist(seq):
    xi = body_twist(2.0, -0.4, 0.03)
    qdot = state_rates(Q0, 2.0, -0.4, 0.03, seq)
    assert np.allclose(needle_jacobian(Q0, seq) @ qdot, xi, atol=1e-12)


@pytest.mark.parametrize("seq", ["ZYZ", "xyz", "ZYX", "yxy"])
def test_state_pose_round_trip(seq):
    rng = np.random.default_rng(0)
    g = propagate_bevel(
        pose_from_state(Q0, seq),
        np.column_stack([rng.uniform(1, 5, 8), rng.uniform(-1, 1, 8), np.ones(8)]),
        0.02,
    )
    assert np.allclose(pose_from_state(state_from_pose(g, seq), seq), g, atol=1e-12)


def test_gimbal_lock_is_an_error():
    with pytest.raises(SingularityError, match="angles"):
        state_rates([0, 0, 0, 0.3, np.pi / 2, 0.1], 1.0, 0.0, 0.01, "XYZ")
    with pytest.raises(SingularityError, match="angles"):
        state_rates([0, 0, 0, 0.3, 0.0, 0.1], 1.0, 0.0, 0.01, "ZYZ")
