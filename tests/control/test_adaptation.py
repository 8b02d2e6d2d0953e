"""The adaptation law (Eq. 3): estimates converge to the measurements, the stability row
holds, and an infeasible QP leaves the estimate alone with a warning."""

import logging

import numpy as np
import pytest

from needlekit.control.adaptation import AdaptationSettings, adaptation_step
from needlekit.control.controller import Step, StepVFI
from needlekit.control.panda import PandaModel
from needlekit.control.parameters import model_from_parameters, parameter_jacobians
from needlekit.control.qp import QPStatus
from needlekit.control.vfi import Zone

pytest.importorskip("daqp", reason="daqp solves the adaptation QP")

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
    task_error = rng.normal(size=jx.shape[0])
    out = adaptation_step(
        a, m.tip_pose(Q0), truth.tip_pose(Q0), pj, SETTINGS, step=step, task_error=task_error,
        controller=cfg,
    )  # fmt: skip
    assert out.status is QPStatus.OPTIMAL
    assert task_error @ jx @ out.a_dot <= 1e-9
    free = adaptation_step(a, m.tip_pose(Q0), truth.tip_pose(Q0), pj, SETTINGS)
    assert np.linalg.norm(free.a_dot) > 0  # the row binds only where it must


def test_an_infeasible_qp_keeps_the_estimate_and_warns(caplog):
    a = NOMINAL.copy()
    m, _, pj = _estimate_at(a, Q0)
    # a VFI the estimate already violates, which no parameter rate can fix
    stuck = StepVFI("guide", 10.0, 1.0, Zone.INSIDE, 1.0, np.zeros(7), np.zeros(12))
    with caplog.at_level(logging.WARNING, logger="needlekit.control.adaptation"):
        out = adaptation_step(a, m.tip_pose(Q0), m.tip_pose(Q0), pj, SETTINGS, vfis=[stuck])
    assert out.status is QPStatus.INFEASIBLE and np.all(out.a_dot == 0)
    assert "a_dot = 0" in caplog.text
