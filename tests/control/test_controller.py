"""The constrained controller (Eq. 1): one step obeys every row; the closed loop punctures
along the guide line with a perfect model without leaving the guide cylinder or the cone."""

import numpy as np
import pytest

from needlekit.control.controller import ControllerSettings, GuideLine, Step, control_step
from needlekit.control.panda import PandaModel
from needlekit.control.qp import QPStatus
from needlekit.errors import InvalidInputError

Q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])


def _guide(model):
    tip = model.state(Q0).tip_mm
    return GuideLine(tip + np.array([60.0, 30.0, -320.0]), [0.2, -0.1, 1.0])


@pytest.mark.parametrize("step", list(Step))
def test_one_step_reduces_the_task_error_within_the_joint_limits(step):
    m = PandaModel()
    g = _guide(m)
    desired = g.start_point(300.0) if step is Step.APPROACH else m.state(Q0).tip_mm + [0, 0, -5.0]
    out = control_step(m, Q0, step, g, desired_mm=desired)
    assert out.status is QPStatus.OPTIMAL
    assert np.all(np.abs(out.q_dot) <= m.q_dot_max + 1e-9)
    dt = 1e-4
    after = control_step(m, Q0 + dt * out.q_dot, step, g, desired_mm=desired)
    assert np.linalg.norm(after.task_error) < np.linalg.norm(out.task_error)


def test_a_step_without_its_desired_position_is_refused():
    m = PandaModel()
    with pytest.raises(InvalidInputError, match="desired_mm"):
        control_step(m, Q0, Step.PUNCTURE, _guide(m))


@pytest.mark.slow
def test_closed_loop_puncture_with_a_perfect_model_keeps_every_constraint():
    m = PandaModel()
    g = _guide(m)
    cfg = ControllerSettings()
    q, dt = Q0.copy(), 1e-3
    start = g.start_point(300.0)
    for step, n in ((Step.ALIGN, 4000), (Step.APPROACH, 9000)):
        for _ in range(n):
            q = q + dt * control_step(m, q, step, g, cfg, desired_mm=start).q_dot
    s = m.state(q)
    assert np.linalg.norm(s.tip_mm - start) < 3.0  # the paper's step-2 accuracy
    T = 10.0
    guide_sq, cone, plane = [], [], []
    for i in range(int(T / dt) + 5000):  # and 5 s to settle (task gain 0.5 /s)
        tau = min(i * dt / T, 1.0)
        p_d = start + (g.target_mm - start) * (10 * tau**3 - 15 * tau**4 + 6 * tau**5)
        v_d = (g.target_mm - start) * (30 * tau**2 - 60 * tau**3 + 30 * tau**4) / T
        out = control_step(m, q, Step.PUNCTURE, g, cfg, desired_mm=p_d, desired_velocity_mm_s=v_d)
        assert out.status is QPStatus.OPTIMAL
        if i > 2000:  # once pulled inside the cylinder and the cone
            guide_sq.append(out.distances["guide_sq_mm2"])
            cone.append(out.distances["cone_f"])
        plane.append(out.distances["plane_mm"])
        q = q + dt * out.q_dot
    s = m.state(q)
    assert np.linalg.norm(s.tip_mm - g.target_mm) < 0.5
    assert np.sqrt(max(guide_sq)) <= cfg.guide_radius_mm + 1e-3
    angle = np.degrees(np.arccos(1 - max(cone) / 2))
    assert angle <= np.degrees(cfg.cone_angle_rad) + 1e-3
    assert min(plane) >= -1e-6  # never past the target's plane
