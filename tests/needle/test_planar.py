"""Planar unicycle model: closed form vs numerical integration, inverse steering round trips."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from needlekit.errors import InvalidInputError, UnreachableTargetError
from needlekit.needle.planar import (
    planar_inverse,
    planar_rates,
    planar_steer_waypoints,
    simulate_planar,
)


def test_rates_are_the_lecture_matrix_form():
    rng = np.random.default_rng(0)
    x = rng.uniform(-3, 3, (20, 3))
    v, kappa = 4.0, 0.02
    for lam in (1, -1):
        m = np.array(
            [[[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, lam]] for t in x[:, 2]]
        )
        expected = m @ np.array([v, 0.0, kappa * v])
        assert np.allclose(planar_rates(x, v, kappa, lam), expected)


def test_closed_form_matches_numerical_integration():
    inputs = [[5.0, 1, 3.0], [2.0, -1, 4.0], [7.0, 1, 1.5], [0.0, -1, 1.0]]
    kappa = 1 / 40
    traj = simulate_planar(inputs, kappa, state0=(1.0, -2.0, 0.3), dt_s=0.25)
    state, t0 = np.array([1.0, -2.0, 0.3]), 0.0
    for v, lam, dur in inputs:
        sol = solve_ivp(
            lambda t, x, v=v, lam=lam: planar_rates(x, v, kappa, lam),
            (0, dur),
            state,
            rtol=1e-12,
            atol=1e-12,
            method="DOP853",
            dense_output=True,
        )
        mask = (traj.time_s >= t0 - 1e-12) & (traj.time_s <= t0 + dur + 1e-12)
        ref = sol.sol(traj.time_s[mask] - t0).T
        assert np.allclose(traj.states[mask], ref, atol=1e-7)
        state, t0 = sol.y[:, -1], t0 + dur


def test_bevel_plus_one_bends_toward_plus_y():
    up = simulate_planar([[1.0, 1, 10.0]], 0.01).final_state
    down = simulate_planar([[1.0, -1, 10.0]], 0.01).final_state
    assert up[1] > 0 > down[1]
    assert up[2] == pytest.approx(0.1) and down[2] == pytest.approx(-0.1)


def test_inverse_steering_analytic_case():
    s = planar_inverse([50.0, 50.0], sampling_time_s=2.0)
    assert s.radius_mm == pytest.approx(50.0)
    assert s.length_mm == pytest.approx(25 * np.pi)
    assert s.angle_rad == pytest.approx(np.pi / 2)
    assert s.speed_mm_s == pytest.approx(25 * np.pi / 2)
    assert s.bevel == 1
    assert planar_inverse([50.0, -50.0]).bevel == -1


def test_inverse_then_forward_returns_the_target():
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(3000):
        state = rng.uniform([-50, -50, -np.pi], [50, 50, np.pi])
        target = rng.uniform(-150, 150, 2)
        s = planar_inverse(target, state=state, sampling_time_s=0.5)
        end = simulate_planar(s.inputs(0.5), s.kappa_per_mm, state0=state, dt_s=0.5).final_state
        worst = max(worst, np.abs(end[:2] - target).max())
    assert worst < 1e-9


def test_lecture_radius_without_factor_two_misses_the_target():
    """The lecture slide's r = (y^2 + z^2)/|y| is the diameter: its arc misses (50, 50)."""
    z, y = 50.0, 50.0
    r_slide = (y**2 + z**2) / abs(y)
    length = r_slide * np.arctan2(z, r_slide - abs(y))
    end = simulate_planar([[length, 1, 1.0]], 1 / r_slide, dt_s=1.0).final_state
    assert np.hypot(end[0] - z, end[1] - y) > 10.0
    ours = planar_inverse([z, y])
    end = simulate_planar(ours.inputs(1.0), ours.kappa_per_mm, dt_s=1.0).final_state
    assert np.allclose(end[:2], [z, y], atol=1e-12)


def test_straight_ahead_and_behind():
    s = planar_inverse([30.0, 0.0])
    assert np.isinf(s.radius_mm) and s.length_mm == pytest.approx(30.0) and s.kappa_per_mm == 0.0
    with pytest.raises(UnreachableTargetError, match="target_zy"):
        planar_inverse([-30.0, 0.0])


def test_r_min_makes_tight_targets_unreachable():
    with pytest.raises(UnreachableTargetError, match=r"r_min_mm = 100"):
        planar_inverse([50.0, 50.0], r_min_mm=100.0)
    assert planar_inverse([50.0, 50.0], r_min_mm=50.0).radius_mm == pytest.approx(50.0)


def test_waypoints_are_visited_in_turn():
    wps = np.array([[40.0, 5.0], [80.0, -5.0], [120.0, 10.0], [160.0, 0.0]])
    steps, states = planar_steer_waypoints(wps, sampling_time_s=0.1)
    assert len(steps) == 4 and states.shape == (5, 3)
    assert np.allclose(states[1:, :2], wps, atol=1e-9)
    # replaying each arc (its own curvature) with the forward model visits the way-points
    state = np.zeros(3)
    for s, wp in zip(steps, wps, strict=True):
        state = simulate_planar(
            [[s.length_mm, s.bevel, 1.0]], s.kappa_per_mm, state0=state, dt_s=1.0
        ).final_state
        assert np.allclose(state[:2], wp, atol=1e-9)


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda: planar_rates([0, 0, 0], 1.0, 0.01, 0), "bevel"),
        (lambda: planar_rates([0, 0], 1.0, 0.01, 1), "state"),
        (lambda: planar_rates([0, 0, 0], 1.0, -0.01, 1), "kappa_per_mm"),
        (lambda: simulate_planar([[1.0, 1, -1.0]], 0.01), "duration_s"),
        (lambda: simulate_planar([[1.0, 1, 1.0]], 0.01, dt_s=0.0), "dt_s"),
        (lambda: simulate_planar([[np.nan, 1, 1.0]], 0.01), "inputs"),
        (lambda: planar_inverse([np.nan, 1.0]), "target_zy"),
        (lambda: planar_inverse([1.0, 1.0], sampling_time_s=-1.0), "sampling_time_s"),
        (lambda: planar_inverse([1.0, 1.0], r_min_mm=0.0), "r_min_mm"),
    ],
)
def test_bad_input_names_the_field(call, field):
    with pytest.raises(InvalidInputError, match=field):
        call()
