"""The adaptation law (Eq. 3): estimates converge to the measurements, the stability row
holds, and an infeasible QP leaves the estimate alone with a warning."""

import logging

import numpy as np
import pytest

from needlekit.control.adaptation import (
    AdaptationSettings,
    MeasurementHistory,
    adaptation_step,
    measurement_error,
)
from needlekit.control.controller import Step, StepVFI
from needlekit.control.panda import PandaModel
from needlekit.control.parameters import model_from_parameters, parameter_jacobians
from needlekit.control.qp import QPStatus
from needlekit.control.vfi import Zone
from needlekit.errors import InvalidInputError

NOMINAL = np.array([-650.0, 0.0, -450.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
SPREAD = np.array([200.0] * 3 + [np.radians(10)] * 3 + [10.0] * 3 + [np.radians(5)] * 3)
SETTINGS = AdaptationSettings(NOMINAL - SPREAD, NOMINAL + SPREAD)
Q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])


def _estimate_at(a, q):
    m = model_from_parameters(PandaModel(), a)
    s = m.state(q)
    return m, s, parameter_jacobians(m, s, a)


def test_estimate_converges_to_noise_free_measurements():
    rng = np.random.default_rng(0)
    true_a = NOMINAL + rng.uniform(-0.8, 0.8, 12) * SPREAD
    truth = model_from_parameters(PandaModel(), true_a)
    a = NOMINAL.copy()
    dt = 0.01  # a measurement every 10 ms
    # the arm still (the paper's step 0): the error decays at about eta_a = 2 /s
    errors = []
    for _ in range(500):
        m, _, pj = _estimate_at(a, Q0)
        out = adaptation_step(a, m.tip_pose(Q0), truth.tip_pose(Q0), pj, SETTINGS)
        assert out.status is QPStatus.OPTIMAL
        a = a + dt * out.a_dot
        errors.append(np.linalg.norm(out.error))
    assert errors[-1] < 1e-3 * errors[0]
    assert errors[100] < np.exp(-1.0) * errors[0]
    # the arm moving: the estimate keeps up, and stays inside the uncertainty box
    for i in range(1000):
        q = Q0 + 0.3 * np.sin(0.5 * i * dt + np.arange(7))
        m, _, pj = _estimate_at(a, q)
        out = adaptation_step(a, m.tip_pose(q), truth.tip_pose(q), pj, SETTINGS)
        a = a + dt * out.a_dot
        errors.append(np.linalg.norm(out.error))
    assert max(errors[-500:]) < 0.05 * errors[0]
    assert np.all(a >= SETTINGS.lower - 1e-9) and np.all(a <= SETTINGS.upper + 1e-9)


@pytest.mark.parametrize("step", [Step.ALIGN, Step.APPROACH, Step.PUNCTURE])
def test_the_stability_row_holds(step):
    from needlekit.control.controller import ControllerSettings, task_parameter_jacobian

    rng = np.random.default_rng(1)
    a = NOMINAL.copy()
    truth = model_from_parameters(PandaModel(), NOMINAL + rng.uniform(-0.5, 0.5, 12) * SPREAD)
    m, _, pj = _estimate_at(a, Q0)
    cfg = ControllerSettings()
    jx = task_parameter_jacobian(step, pj, cfg)
    direction = rng.normal(size=jx.shape[0])
    direction /= np.linalg.norm(direction)
    free = adaptation_step(a, m.tip_pose(Q0), truth.tip_pose(Q0), pj, SETTINGS)
    assert np.linalg.norm(free.a_dot) > 0
    for radius, size in [(0.0, 0.1), (0.0, 3.0), (1.5, 3.0), (1.5, 1.0), (1.5, 0.1)]:
        settings = AdaptationSettings(SETTINGS.lower, SETTINGS.upper, stability_radius_mm=radius)
        for sign in (1.0, -1.0):
            task_error = sign * size * direction
            out = adaptation_step(
                a, m.tip_pose(Q0), truth.tip_pose(Q0), pj, settings, step=step,
                task_error=task_error, controller=cfg,
            )  # fmt: skip
            assert out.status is QPStatus.OPTIMAL
            allowed = max(0.0, 0.5 * settings.eta * (radius**2 - size**2))  # 0: the paper's row
            growth = task_error @ jx @ out.a_dot
            assert growth <= allowed + 1e-9
            if task_error @ jx @ free.a_dot <= allowed:
                # the row binds only where it must
                np.testing.assert_allclose(out.a_dot, free.a_dot, atol=1e-9)


def test_a_violated_vfi_never_pulls_the_estimate_in():
    a = NOMINAL.copy()
    m, _, pj = _estimate_at(a, Q0)
    # the estimate outside a VFI's safe set while it agrees with the measurement: the
    # adaptation leaves it where it is (the joints must move the arm in)
    violated = StepVFI("guide", 10.0, 1.0, Zone.INSIDE, 5.0, np.ones(7), np.ones(12))
    out = adaptation_step(a, m.tip_pose(Q0), m.tip_pose(Q0), pj, SETTINGS, vfis=[violated])
    assert out.status is QPStatus.OPTIMAL
    np.testing.assert_allclose(out.a_dot, 0.0, atol=1e-12)
    # and it never pushes it further out
    truth = model_from_parameters(PandaModel(), NOMINAL + 0.3 * SPREAD)
    out = adaptation_step(a, m.tip_pose(Q0), truth.tip_pose(Q0), pj, SETTINGS, vfis=[violated])
    assert np.ones(12) @ out.a_dot <= 1e-9


def test_an_infeasible_qp_keeps_the_estimate_and_warns(caplog):
    # an estimate below its lower bound on t_b,x must move up; a VFI the estimate violates
    # forbids exactly that: no parameter rate satisfies both
    a = NOMINAL.copy()
    a[0] = SETTINGS.lower[0] - 1.0
    m, _, pj = _estimate_at(a, Q0)
    stuck = StepVFI("guide", 10.0, 1.0, Zone.INSIDE, 1.0, np.zeros(7), np.eye(12)[0])
    with caplog.at_level(logging.WARNING, logger="needlekit.control.adaptation"):
        out = adaptation_step(a, m.tip_pose(Q0), m.tip_pose(Q0), pj, SETTINGS, vfis=[stuck])
    assert out.status is QPStatus.INFEASIBLE and np.all(out.a_dot == 0)
    assert "a_dot = 0" in caplog.text


def _flange_in_base(model, q):
    return np.linalg.inv(model.world_T_base) @ model.tip_pose(q) @ np.linalg.inv(model.flange_T_tip)


def test_history_errors_and_jacobian_match_single_measurements_and_finite_differences():
    rng = np.random.default_rng(3)
    truth = model_from_parameters(PandaModel(), NOMINAL + rng.uniform(-0.7, 0.7, 12) * SPREAD)
    a = NOMINAL + rng.uniform(-0.7, 0.7, 12) * SPREAD
    m = model_from_parameters(PandaModel(), a)
    hist = MeasurementHistory(capacity=3)
    ramp = np.arange(1, 8) / 7
    # the third keyframe lies near the first: when a fourth arrives, the older of that
    # closest pair goes, and the distinct configurations stay
    qs = [Q0, Q0 + 0.4 * ramp, Q0 + 0.06 * ramp, Q0 - 0.4 * ramp]
    for q in qs:
        hist.add(_flange_in_base(m, q), truth.tip_pose(q))
    assert len(hist) == 3 and hist.counts.tolist() == [1, 1, 1]
    err, jac = hist.stacked(a, SETTINGS.orientation_scale_mm)
    for k, q in enumerate(qs[1:]):
        s = m.state(q)
        pj = parameter_jacobians(m, s, a)
        expected = measurement_error(m.tip_pose(q), truth.tip_pose(q), 100.0)
        np.testing.assert_allclose(err[6 * k : 6 * k + 6], expected, atol=1e-9)
        np.testing.assert_allclose(jac[6 * k : 6 * k + 3], pj.tip, atol=1e-9)
        np.testing.assert_allclose(jac[6 * k + 3 : 6 * k + 6], 100.0 * pj.angular, atol=1e-9)
    # the position rows against finite differences of the stacked error itself
    h = 1e-6
    for i in range(12):
        d = np.zeros(12)
        d[i] = h
        fd = (hist.stacked(a + d, 100.0)[0] - hist.stacked(a - d, 100.0)[0]) / (2 * h)
        np.testing.assert_allclose(fd.reshape(-1, 6)[:, :3], jac[:, i].reshape(-1, 6)[:, :3],
                                   atol=1e-5)  # fmt: skip


def test_history_averages_at_rest_and_keeps_the_current_sample_in_motion():
    m = PandaModel()
    hist = MeasurementHistory(capacity=5, spacing_mm=10.0, merge_mm=0.5)
    rng = np.random.default_rng(0)
    pose = m.tip_pose(Q0)
    noisy = []
    for _ in range(400):  # the arm still: one keyframe, the noise averaged
        y = pose.copy()
        y[:3, 3] += rng.normal(0.0, 1.0, 3)
        noisy.append(y[:3, 3])
        hist.add(_flange_in_base(m, Q0), y)
    assert hist.counts.tolist() == [400]
    err, _ = hist.stacked(np.concatenate([np.zeros(6), [0, 0, 0, 0, 0, 0]]), 100.0)
    np.testing.assert_allclose(err[:3], pose[:3, 3] - np.mean(noisy, axis=0), atol=1e-9)
    assert np.linalg.norm(err[:3]) < 0.2  # 1 mm noise over 400 samples
    # a few mm away: not a keyframe, but the newest sample is in the objective
    q = Q0.copy()
    q[0] += 0.005
    hist.add(_flange_in_base(m, q), m.tip_pose(q))
    assert len(hist) == 1 and len(hist.stacked(np.zeros(12), 100.0)[0]) == 12
    q[0] += 0.1  # far enough for a keyframe
    hist.add(_flange_in_base(m, q), m.tip_pose(q))
    assert len(hist) == 2 and len(hist.stacked(np.zeros(12), 100.0)[0]) == 12
    with pytest.raises(InvalidInputError, match="history"):
        MeasurementHistory(spacing_mm=1.0, merge_mm=2.0)


def test_history_identifies_what_one_measurement_cannot():
    """Measurements at a few configurations pin down all 12 parameters: the estimate then
    predicts the tip at a configuration it never saw, which the single-measurement law does
    not."""
    rng = np.random.default_rng(4)
    true_a = NOMINAL + rng.uniform(-0.8, 0.8, 12) * SPREAD
    truth = model_from_parameters(PandaModel(), true_a)
    qs = [Q0 + 0.25 * rng.uniform(-1, 1, 7) for _ in range(6)]
    unseen = Q0 + 0.25 * rng.uniform(-1, 1, 7)

    def run(history):
        a = NOMINAL.copy()
        for q in qs:  # 3 s at each configuration, a measurement every 10 ms
            for _ in range(300):
                m, _, pj = _estimate_at(a, q)
                if history is not None:
                    history.add(_flange_in_base(m, q), truth.tip_pose(q))
                out = adaptation_step(a, m.tip_pose(q), truth.tip_pose(q), pj, SETTINGS,
                                      history=history)  # fmt: skip
                a = a + 0.01 * out.a_dot
        m = model_from_parameters(PandaModel(), a)
        return np.linalg.norm(m.tip_pose(unseen)[:3, 3] - truth.tip_pose(unseen)[:3, 3])

    with_history = run(MeasurementHistory())
    alone = run(None)
    assert with_history < 0.05 and alone > 1.0


def test_rotation_log_kernel_matches_so3_log_near_zero_and_pi():
    from needlekit.control.adaptation import _rotation_log
    from needlekit.geometry.so3 import so3_exp, so3_log

    rng = np.random.default_rng(8)
    for scale in (1e-10, 1e-4, 0.5, 2.0, np.pi - 1e-3, np.pi - 1e-7, np.pi):
        for _ in range(10):
            axis = rng.normal(size=3)
            w = scale * axis / np.linalg.norm(axis)
            r = so3_exp(w)
            np.testing.assert_allclose(_rotation_log(r), so3_log(r), atol=1e-7)


def test_unclamped_vfi_rows_pull_the_estimate_in_at_the_vfi_rate():
    from dataclasses import replace

    a = NOMINAL.copy()
    m, _, pj = _estimate_at(a, Q0)
    violated = StepVFI("guide", 10.0, 1.0, Zone.INSIDE, 5.0, np.ones(7), np.ones(12))
    raw = replace(SETTINGS, clamp_vfi_rows=False)
    out = adaptation_step(
        a, m.tip_pose(Q0), m.tip_pose(Q0), pj, raw, vfis=[violated], vfi_share=0.5
    )
    assert out.status is QPStatus.OPTIMAL
    # the VFI law as written: d_dot <= -(1 - share) gain (d - safe) = -0.5 * 5 * 9
    assert np.ones(12) @ out.a_dot == pytest.approx(-22.5, abs=1e-6)
