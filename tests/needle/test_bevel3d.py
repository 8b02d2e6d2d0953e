"""3D bevel-tip model: exact propagation vs solve_ivp, and agreement with the planar model."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from needlekit.conventions import TIP_BEND_DIRECTION, TIP_INSERTION_AXIS
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import make_pose, se3_exp
from needlekit.geometry.so3 import rot_z
from needlekit.needle.bevel3d import body_twist, pose_rate, propagate_bevel, simulate_bevel
from needlekit.needle.planar import simulate_planar


def _integrate(g0, inputs, kappa):
    g = g0.copy()
    for u1, u2, dur in inputs:
        sol = solve_ivp(
            lambda t, y, u1=u1, u2=u2: pose_rate(y.reshape(4, 4), u1, u2, kappa).ravel(),
            (0.0, dur),
            g.ravel(),
            method="DOP853",
            rtol=1e-13,
            atol=1e-13,
        )
        g = sol.y[:, -1].reshape(4, 4)
    return g


def test_body_twist_is_mu1_u1_plus_mu2_u2():
    kappa = 0.02
    mu1 = np.array([0, 0, 1, kappa, 0, 0])
    mu2 = np.array([0, 0, 0, 0, 0, 1])
    assert np.allclose(body_twist(3.0, -0.7, kappa), 3.0 * mu1 - 0.7 * mu2)
    assert body_twist([1.0, 2.0], 0.0, kappa).shape == (2, 6)


@pytest.mark.parametrize("seed", range(5))
def test_exact_propagation_matches_numerical_integration(seed):
    rng = np.random.default_rng(seed)
    g0 = se3_exp(np.concatenate([rng.normal(0, 50, 3), rng.normal(0, 1, 3)]))
    inputs = np.column_stack([rng.uniform(0, 10, 4), rng.uniform(-2, 2, 4), rng.uniform(0.5, 4, 4)])
    inputs[1, 1] = 0.0  # a pure arc among helices
    kappa = rng.uniform(0.005, 0.04)
    exact = propagate_bevel(g0, inputs, kappa)[-1]
    numeric = _integrate(g0, inputs, kappa)
    assert np.abs(exact[:3, 3] - numeric[:3, 3]).max() < 1e-6  # mm
    assert np.abs(exact[:3, :3] - numeric[:3, :3]).max() < 1e-8


def test_simulation_samples_agree_with_segment_ends():
    inputs = [[5.0, 0.0, 2.0], [0.0, np.pi, 1.0], [5.0, 0.5, 3.0]]
    ends = propagate_bevel(np.eye(4), inputs, 0.02)
    traj = simulate_bevel(np.eye(4), inputs, 0.02, dt_s=0.1)
    for t_end, g in zip(np.cumsum([0, 2.0, 1.0, 3.0]), ends, strict=True):
        i = int(np.argmin(np.abs(traj.time_s - t_end)))
        assert traj.time_s[i] == pytest.approx(t_end)
        assert np.allclose(traj.world_T_tip[i], g, atol=1e-12)
    assert traj.points_mm.shape == (len(traj.time_s), 3)


def test_bending_side_is_tip_minus_y():
    g = propagate_bevel(np.eye(4), [[1.0, 0.0, 1.0]], 0.01)[-1]
    turn = g[:3, 2] - TIP_INSERTION_AXIS
    assert np.allclose(turn / np.linalg.norm(turn), TIP_BEND_DIRECTION, atol=1e-2)
    assert g[1, 3] < 0


def test_pure_spin_turns_in_place():
    g = propagate_bevel(np.eye(4), [[0.0, 0.8, 1.0]], 0.02)[-1]
    assert np.allclose(g[:3, 3], 0.0)
    assert np.allclose(g[:3, :3], rot_z(0.8))


@pytest.mark.parametrize(("spin", "bevel"), [(0.0, -1), (np.pi, 1)])
def test_matches_planar_model_in_the_tip_yz_plane(spin, bevel):
    """Planar state (z, y, theta) is the 3D tip in the world y-z plane: lambda = -1 is the
    unspun needle (bends toward -y), lambda = +1 the needle spun by pi."""
    kappa, v, dur = 1 / 60, 4.0, 10.0
    g0 = make_pose(rot_z(spin))
    g = propagate_bevel(g0, [[v, 0.0, dur]], kappa)[-1]
    planar = simulate_planar([[v, bevel, dur]], kappa, dt_s=dur).final_state
    assert np.allclose([g[2, 3], g[1, 3]], planar[:2], atol=1e-12)
    heading = np.arctan2(g[1, 2], g[2, 2])
    assert heading == pytest.approx(planar[2])


def test_bad_input():
    with pytest.raises(InvalidInputError, match="kappa_per_mm"):
        propagate_bevel(np.eye(4), [[1.0, 0.0, 1.0]], -0.1)
    with pytest.raises(InvalidInputError, match="duration_s"):
        propagate_bevel(np.eye(4), [[1.0, 0.0, -1.0]], 0.1)
    with pytest.raises(InvalidInputError, match="inputs"):
        propagate_bevel(np.eye(4), [[1.0, 0.0]], 0.1)
    with pytest.raises(InvalidInputError, match="world_T_tip"):
        propagate_bevel(np.eye(3), [[1.0, 0.0, 1.0]], 0.1)
    with pytest.raises(InvalidInputError, match="u1_mm_s"):
        body_twist(np.nan, 0.0, 0.1)
    with pytest.raises(InvalidInputError, match="dt_s"):
        simulate_bevel(np.eye(4), [[1.0, 0.0, 1.0]], 0.1, dt_s=np.nan)
