"""The compiled model rebuild, parameter Jacobians and arm state against the numpy code they
replaced (kept here as the oracle).

The model's transforms and dual quaternions are the same operations in the same order:
equal bit for bit. The parameter Jacobians sum their 3-term products in a fixed order where
numpy's matrix product may use BLAS: 1e-12 relative to the largest entry.
"""

import numpy as np
import pytest

from needlekit.control.dq import dq_to_matrix
from needlekit.control.panda import PandaModel
from needlekit.control.parameters import (
    N_PARAMETERS,
    model_from_parameters,
    parameter_jacobians,
    pose_from_parameters,
    xyz_euler_rate_matrix,
)
from needlekit.errors import InvalidInputError

NOMINAL = np.array([-650.0, 0.0, -450.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
SPREAD = np.array([200.0] * 3 + [np.radians(20)] * 3 + [10.0] * 3 + [np.radians(10)] * 3)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _ref_parameter_jacobians(model, state, a):
    wb = xyz_euler_rate_matrix(a[3:6])
    r_tip = dq_to_matrix(state.tip_dq)[:3, :3]
    r_flange = r_tip @ model.flange_T_tip[:3, :3].T
    tip = np.zeros((3, N_PARAMETERS))
    ang = np.zeros((3, N_PARAMETERS))
    tip[:, :3] = np.eye(3)
    tip[:, 3:6] = -_skew(state.tip_mm - a[:3]) @ wb
    ang[:, 3:6] = wb
    tip[:, 6:9] = r_flange
    ang[:, 9:12] = r_flange @ xyz_euler_rate_matrix(a[9:12])
    axis = -_skew(state.needle_axis) @ ang
    return tip, ang, axis, wb


def _close(got, want):
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * max(1.0, np.abs(want).max()))


def test_the_rebuilt_model_is_the_validated_one_bit_for_bit():
    rng = np.random.default_rng(0)
    arm = PandaModel()
    for _ in range(50):
        a = NOMINAL + rng.uniform(-1, 1, 12) * SPREAD
        got = model_from_parameters(arm, a)
        want = arm.with_parameters(pose_from_parameters(a[:6]), pose_from_parameters(a[6:]))
        for name in ("world_T_base", "flange_T_tip", "_base_dq", "_tool_dq", "q_min", "q_max"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
        q = rng.uniform(arm.q_min, arm.q_max)
        np.testing.assert_array_equal(got.tip_pose(q), want.tip_pose(q))


def test_parameter_jacobians_equal_the_numpy_ones():
    rng = np.random.default_rng(1)
    for _ in range(50):
        a = NOMINAL + rng.uniform(-1, 1, 12) * SPREAD
        model = model_from_parameters(PandaModel(), a)
        state = model.state(rng.uniform(model.q_min, model.q_max))
        got = parameter_jacobians(model, state, a)
        want = _ref_parameter_jacobians(model, state, a)
        for g, w in zip((got.tip, got.angular, got.axis, got.base_rate), want, strict=True):
            _close(g, w)


def test_the_state_checks_its_input_as_before():
    m = PandaModel()
    for bad in ([0.0] * 6, [np.nan] + [0.0] * 6, [0.0] * 6 + [np.inf], np.zeros((7, 1, 2))):
        with pytest.raises(InvalidInputError, match="q"):
            m.state(bad)
    s = m.state([0, 0, 0, -1, 0, 1, 0])  # ints and lists as before
    assert s.q.dtype == float and s.tip_mm.shape == (3,) and s.origins.shape == (8, 3)
    with pytest.raises(AttributeError):  # still frozen
        s.q = np.zeros(7)
