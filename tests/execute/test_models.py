"""The second implementation of each plug point against what it must do: the unscented
estimator against the Kalman filter and the arc's second-order mean, the sliding-mode law
against Rucker et al.'s switching rule, the layered tissue against its layers' draws."""

from __future__ import annotations

import math

import numpy as np
import pytest

from needlekit.execute.estimator import TipEstimator
from needlekit.execute.needle_sim import ExecutionNoise
from needlekit.execute.sliding_mode import SlidingMode
from needlekit.execute.tissue_layers import LayeredNeedle
from needlekit.execute.unscented import UnscentedTipEstimator

ARGS = dict(start_sigma_mm=0.4, start_sigma_rad=0.0, r_min_mm=50.0, noise=ExecutionNoise(),
            position_sigma_mm=0.4, orientation_sigma_rad=0.01)  # fmt: skip


def test_without_orientation_uncertainty_the_unscented_prediction_is_the_kalman_one():
    """With no orientation error the step's map of the error is linear (a translation
    error stays what it is): the unscented covariance is the Kalman filter's exactly."""
    ekf, ukf = TipEstimator(np.eye(4), **ARGS), UnscentedTipEstimator(np.eye(4), **ARGS)
    command = (0.3, 0.02, 5.0, 2.5, None, 0.0)
    pe, Pe = ekf._propagate(ekf.pose, ekf.P, command)
    pu, Pu = ukf._propagate(ukf.pose, ukf.P, command)
    assert np.allclose(pu, pe, atol=1e-12) and np.allclose(Pu, Pe, atol=1e-12)


def test_the_unscented_mean_falls_short_by_sigma_squared_along_the_step():
    """An uncertain heading (SD s per axis) swings a straight step ``a`` on a sphere: the
    mean end lies ``E[(exp(phi^) - I) a] = -s^2 a`` (to leading order) from the nominal one;
    the sigma poses give ``-(1 - cos(sqrt(6) s)) / 3 a`` exactly, the Kalman filter none."""
    s = 0.05
    est = UnscentedTipEstimator(np.eye(4), **{**ARGS, "start_sigma_rad": s})
    pose, _ = est._propagate(est.pose, est.P, (0.0, 0.0, 20.0, 1.0, None, 0.0))
    expected = 20.0 - (1.0 - math.cos(math.sqrt(6.0) * s)) / 3.0 * 20.0
    assert pose[2, 3] == pytest.approx(expected, abs=1e-12)
    assert pose[2, 3] == pytest.approx(20.0 - s * s * 20.0, abs=2e-4)
    assert np.allclose(pose[:2, 3], 0.0, atol=1e-12)
    ekf = TipEstimator(np.eye(4), **{**ARGS, "start_sigma_rad": s})
    assert ekf._propagate(ekf.pose, ekf.P, (0.0, 0.0, 20.0, 1.0, None, 0.0))[0][2, 3] == 20.0


def test_a_late_sample_corrects_the_unscented_estimate_where_it_was_taken():
    est = UnscentedTipEstimator(np.eye(4), **ARGS)
    for _ in range(10):
        est.predict(0.0, 0.0, 0.1, 0.01)
    taken = np.eye(4)
    taken[:3, 3] = [0.3, 0.0, 0.5]  # at t = 0.05 s the tip was 0.3 mm off in x
    assert est.update(0.05, taken)
    # corrected there, then the five steps since replayed: the x offset carried forward
    assert 0.0 < est.pose[0, 3] < 0.3 and est.pose[2, 3] == pytest.approx(1.0, abs=0.01)


def test_the_sliding_mode_law_switches_on_the_bevel_angle():
    law = SlidingMode(10.0, 0.02, 0.005)
    step = law.max_spin_rad
    assert step == pytest.approx(2 * math.pi * 0.005)
    # the bevel bends toward -y: a target there is on the surface; +x and -x are either side
    assert law.command(np.eye(4), [0.0, -5.0, 10.0]) == (0.0, 0.02)
    assert law.command(np.eye(4), [5.0, 0.0, 10.0]) == (step, 0.02)
    assert law.command(np.eye(4), [-5.0, 0.0, 10.0]) == (-step, 0.02)
    # straight ahead (the arc through it needs under a tenth of the curvature): spin on
    assert law.command(np.eye(4), [0.0, 0.1, 50.0]) == (step, 0.02)


def test_the_bevel_reaches_the_surface_in_the_steps_the_rate_allows_then_chatters():
    """From a bevel half a turn away the error after ``k`` steps is ``pi - k omega dt``:
    within one step's spin of the surface after ``pi / (omega dt) - 1`` steps (99 at one
    turn a second and 5 ms), and within it from then on."""
    law = SlidingMode(10.0, 0.02, 0.005)
    pose, target = np.eye(4), np.array([0.0, 5.0, 10.0])  # behind the bevel: sigma = pi
    angles = []
    for _ in range(150):
        spin, _ = law.command(pose, target)
        c, s = math.cos(spin), math.sin(spin)
        pose = pose @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        q = pose[:3, :3].T @ target
        angles.append(abs(math.atan2(q[0], -q[1])))
    first = next(i for i, a in enumerate(angles) if a <= law.max_spin_rad)
    assert first + 1 == round(math.pi / law.max_spin_rad) - 1 == 99
    assert max(angles[first:]) <= law.max_spin_rad + 1e-12


def test_each_layer_pushes_the_tip_by_its_own_draw():
    """Straight in, no orientation noise: the tip ends at the start direction's length plus
    each layer's push times the length inserted in it (15 mm layers, 40 mm: 15, 15, 10)."""
    noise = ExecutionNoise(orientation_sigma_rad=0.0, radius_sigma_mm=3.0, deflection_sigma=0.02)
    needle = LayeredNeedle(np.eye(4), 50.0, noise, np.random.default_rng(3), layer_mm=15.0)
    for _ in range(320):  # 0.125 mm steps: the lengths add up exactly
        needle.step(0.0, 0.0, 0.125, 0.05)
    pushes = [needle.layer_draws(i)[1] for i in range(3)]
    want = np.array([0.0, 0.0, 40.0]) + 15 * pushes[0] + 15 * pushes[1] + 10 * pushes[2]
    assert np.allclose(needle.pose[:3, 3], want, atol=1e-9)
    assert needle.layer == 2 and not np.allclose(pushes[0], pushes[1])
    assert all(abs(p[2]) < 1e-15 for p in pushes)  # perpendicular to the start direction
    radii = {needle.layer_draws(i)[0] for i in range(3)}
    assert len(radii) == 3 and all(r >= 25.0 for r in radii)


def test_a_layer_is_the_same_whatever_came_before_it():
    noise = ExecutionNoise()
    a = LayeredNeedle(np.eye(4), 50.0, noise, np.random.default_rng(5))
    b = LayeredNeedle(np.eye(4), 50.0, noise, np.random.default_rng(5))
    a.step(0.4, 0.02, 20.0, 1.0)  # a goes in first; b asks for layer 4 before any other
    assert b.layer_draws(4)[0] == a.layer_draws(4)[0]
    assert np.array_equal(b.layer_draws(4)[1], a.layer_draws(4)[1])
