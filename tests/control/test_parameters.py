"""The 12 uncertain parameters (base and needle poses): round trips and Jacobians."""

import numpy as np
import pytest

from needlekit.control.panda import PandaModel
from needlekit.control.parameters import (
    model_from_parameters,
    parameter_jacobians,
    parameters_from_model,
    pose_from_parameters,
    xyz_euler_rate_matrix,
)
from needlekit.errors import InvalidInputError
from needlekit.geometry.euler import euler_rate_matrix, euler_to_matrix

NOMINAL = np.array([-650.0, 0.0, -450.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])


def _random_parameters(rng):
    a = NOMINAL.copy()
    a[:3] += rng.uniform(-200, 200, 3)
    a[3:6] += np.radians(rng.uniform(-10, 10, 3))
    a[6:9] += rng.uniform(-10, 10, 3)
    a[9:12] += np.radians(rng.uniform(-5, 5, 3))
    return a


def test_euler_convention_matches_the_geometry_module():
    rng = np.random.default_rng(0)
    for _ in range(10):
        ang = rng.uniform(-1, 1, 3)
        np.testing.assert_allclose(
            pose_from_parameters([0, 0, 0, *ang])[:3, :3], euler_to_matrix(ang, "XYZ"), atol=1e-12
        )
        np.testing.assert_allclose(
            xyz_euler_rate_matrix(ang), euler_rate_matrix(ang, "XYZ"), atol=1e-12
        )


def test_parameters_round_trip_through_the_model():
    rng = np.random.default_rng(1)
    a = _random_parameters(rng)
    m = model_from_parameters(PandaModel(), a)
    np.testing.assert_allclose(parameters_from_model(m), a, atol=1e-10)
    with pytest.raises(InvalidInputError, match="parameters"):
        model_from_parameters(PandaModel(), a[:11])


@pytest.mark.parametrize("seed", range(4))
def test_parameter_jacobians_match_finite_differences(seed):
    rng = np.random.default_rng(seed)
    a = _random_parameters(rng)
    base = PandaModel()
    q = rng.uniform(base.q_min, base.q_max)
    m = model_from_parameters(base, a)
    s = m.state(q)
    jac = parameter_jacobians(m, s, a)
    h = 1e-6
    for i in range(12):
        e = np.zeros(12)
        e[i] = h
        sp = model_from_parameters(base, a + e).state(q)
        sm = model_from_parameters(base, a - e).state(q)
        np.testing.assert_allclose((sp.tip_mm - sm.tip_mm) / (2 * h), jac.tip[:, i], atol=2e-5)
        np.testing.assert_allclose(
            (sp.needle_axis - sm.needle_axis) / (2 * h), jac.axis[:, i], atol=1e-7
        )
        rp = model_from_parameters(base, a + e).tip_pose(q)[:3, :3]
        rm = model_from_parameters(base, a - e).tip_pose(q)[:3, :3]
        w = (rp - rm) / (2 * h) @ s_rot(m, q).T  # hat(omega) = R_dot R^T
        np.testing.assert_allclose([w[2, 1], w[0, 2], w[1, 0]], jac.angular[:, i], atol=1e-7)
        for k in (2, 5, 7):
            np.testing.assert_allclose(
                (sp.origins[k] - sm.origins[k]) / (2 * h), jac.point(s, a, k)[:, i], atol=2e-5
            )


def s_rot(model, q):
    return model.tip_pose(q)[:3, :3]


def test_closed_form_xyz_euler_maps_match_the_general_ones():
    rng = np.random.default_rng(11)
    for angles in rng.uniform(-1.5, 1.5, (20, 3)):
        g = pose_from_parameters(np.concatenate([[1.0, 2.0, 3.0], angles]))
        np.testing.assert_allclose(g[:3, :3], euler_to_matrix(angles, "XYZ"), atol=1e-14)
        np.testing.assert_allclose(
            xyz_euler_rate_matrix(angles), euler_rate_matrix(angles, "XYZ"), atol=1e-14
        )


@pytest.mark.parametrize("step", ["approach", "puncture"])
def test_vfi_parameter_rows_match_finite_differences(step):
    from needlekit.control.controller import ControllerSettings, GuideLine, Step, step_vfis

    rng = np.random.default_rng(12)
    a = np.array([-650.0, 0.0, -450.0, 0.1, -0.05, 0.2, 1.0, -2.0, 100.0, 0.03, 0.02, -0.04])
    q = np.array([0.1, -0.5, 0.2, -2.2, 0.1, 1.9, 0.6])
    guide = GuideLine(np.array([-150.0, 0.0, -250.0]), rng.normal(size=3) + [0, 0, 3])
    cfg, st = ControllerSettings(), Step(step)

    def vfis(params):
        m = model_from_parameters(PandaModel(), params)
        s = m.state(q)
        return step_vfis(s, st, guide, cfg, parameter_jacobians(m, s, params), params)

    base = vfis(a)
    h = 1e-6
    for i in range(12):
        d = np.zeros(12)
        d[i] = h
        plus, minus = vfis(a + d), vfis(a - d)
        for v, vp, vm in zip(base, plus, minus, strict=True):
            fd = (vp.distance - vm.distance) / (2 * h)
            assert v.jac_a[i] == pytest.approx(
                fd, rel=1e-5, abs=1e-4 * max(1.0, abs(v.distance)) ** 0.5
            )
