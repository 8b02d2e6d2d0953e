"""The fused control step (one numba kernel and one DAQP call on reused buffers) against the
numpy implementation it replaced, kept here as the oracle, on seeded random states with
active VFIs and joint limits.

Tolerances: the kernel does the oracle's arithmetic in the same order except the sums of
the small products (J'J, J' e, the 3-vector dot products), which BLAS may add in another
order or with fused multiply-adds: a few ulps of each entry's largest term. 1e-12 relative
to the largest entry of each quantity (for ``f``, whose terms cancel, to the largest sum of
absolute terms) leaves room for that and nothing else.

The QP's solution cannot be held to 1e-12: the Hessian ``2 (J'J + lambda^2 I)`` has a
condition number of 1e10-1e14 (lambda = 1e-3 against the 100-mm-weighted axis rows), and
the numpy step itself moves by up to 4e-6 when one ulp of its own ``H`` changes (measured
on these states). The solution is compared at ``10 eps cond(H)`` relative to its largest
entry (the first-order bound for a perturbation of a few ulps), never looser than the
oracle's own sensitivity demands.
"""

import numpy as np
import pytest

from needlekit.control import _tick
from needlekit.control.controller import (
    ControllerSettings,
    GuideLine,
    Step,
    StepVFI,
    _buffers,
    control_step,
    step_vfis,
)
from needlekit.control.panda import PandaModel
from needlekit.control.parameters import model_from_parameters, parameter_jacobians
from needlekit.control.qp import DEFAULT_SOLVER, QPStatus, solve_qp
from needlekit.control.vfi import (
    Zone,
    joint_limit_bounds,
    line_angle_distance,
    point_line_sq_distance,
    point_plane_distance,
    vfi_row,
)

NOMINAL = np.array([-650.0, 0.0, -450.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
SPREAD = np.array([50.0] * 3 + [np.radians(10)] * 3 + [10.0] * 3 + [np.radians(5)] * 3)
REL = 1e-12


# ---- the oracle: the numpy control step as it was before the kernel ----------------------


def _ref_task(state, step, guide, settings, p_d, v_d):
    u = guide.insertion_direction
    if step is Step.ALIGN:
        return state.axis_jacobian, state.needle_axis - u, np.zeros(3)
    if step is Step.APPROACH or settings.puncture_keeps_axis:
        w = settings.axis_scale_mm
        jac = np.vstack([state.tip_jacobian, w * state.axis_jacobian])
        err = np.concatenate([state.tip_mm - p_d, w * (state.needle_axis - u)])
        return jac, err, np.concatenate([v_d, np.zeros(3)])
    return state.tip_jacobian, state.tip_mm - p_d, v_d


def _ref_points_parameter_rows(points, line, pj, a):
    v = points - line.point_mm
    perp = v - np.outer(v @ line.direction, line.direction)
    rows = np.zeros((len(points), 12))
    rows[:, :3] = 2.0 * perp
    r = points - np.asarray(a)[:3]
    r_x_perp = np.column_stack(
        [
            r[:, 1] * perp[:, 2] - r[:, 2] * perp[:, 1],
            r[:, 2] * perp[:, 0] - r[:, 0] * perp[:, 2],
            r[:, 0] * perp[:, 1] - r[:, 1] * perp[:, 0],
        ]
    )
    rows[:, 3:6] = 2.0 * r_x_perp @ pj.base_rate
    return rows


def _ref_step_vfis(state, step, guide, cfg, pj=None, a=None):
    out = []
    if step is Step.PUNCTURE:
        d, j = point_line_sq_distance(state.tip_mm, state.tip_jacobian, guide.line)
        ja = None if pj is None else point_line_sq_distance(state.tip_mm, pj.tip, guide.line)[1]
        out.append(StepVFI("guide", d, cfg.guide_radius_mm**2, Zone.INSIDE, cfg.eta_guide, j, ja))
        u = guide.insertion_direction
        f, j = line_angle_distance(state.needle_axis, state.axis_jacobian, u)
        ja = None if pj is None else line_angle_distance(state.needle_axis, pj.axis, u)[1]
        safe = 2.0 - 2.0 * np.cos(cfg.cone_angle_rad)
        out.append(StepVFI("cone", f, safe, Zone.INSIDE, cfg.eta_cone, j, ja))
        d, j = point_plane_distance(state.tip_mm, state.tip_jacobian, guide.plane)
        ja = None if pj is None else point_plane_distance(state.tip_mm, pj.tip, guide.plane)[1]
        out.append(StepVFI("plane", d, 0.0, Zone.OUTSIDE, cfg.eta_plane, j, ja))
        return out
    cyl = guide.patient_line(cfg.patient_axis)
    ks = np.asarray(cfg.robot_points, dtype=np.int64)
    ds, js = state.points_line_sq_distances(ks, cyl.point_mm, cyl.direction)
    safe = cfg.patient_radius_mm**2
    jas = None if pj is None else _ref_points_parameter_rows(state.origins[ks], cyl, pj, a)
    for r in range(len(ks)):
        ja = None if jas is None else jas[r]
        out.append(StepVFI("patient", float(ds[r]), safe, Zone.OUTSIDE, cfg.eta_patient, js[r], ja))
    return out


_KEYS = {
    "patient": "patient_sq_mm2",
    "guide": "guide_sq_mm2",
    "cone": "cone_f",
    "plane": "plane_mm",
}


def _ref_qp(model, s, step, guide, cfg, p_d, v_d, vfis, vfi_share):
    jac, err, ff = _ref_task(s, step, guide, cfg, p_d, v_d)
    n = len(s.q)
    H = 2.0 * (jac.T @ jac + cfg.damping**2 * np.eye(n))
    f = 2.0 * jac.T @ (cfg.eta * err - ff)
    rows, rhs = np.empty((len(vfis), n)), np.empty(len(vfis))
    dist: dict = {}
    for i, v in enumerate(vfis):
        rows[i], rhs[i] = vfi_row(v.distance, v.jac_q, v.safe, v.zone, vfi_share * v.gain)
        dist[_KEYS[v.name]] = min(dist.get(_KEYS[v.name], np.inf), v.distance)
    lower, upper = joint_limit_bounds(
        s.q, model.q_min, model.q_max, model.q_dot_max, cfg.eta_joints
    )
    return H, f, rows, rhs, lower, upper, err, dist


def _ref_control_step(model, q, step, guide, cfg, desired_mm, desired_velocity_mm_s, vfi_share):
    s = model.state(q)
    p_d = np.asarray(desired_mm, dtype=float)
    v_d = np.asarray(desired_velocity_mm_s, dtype=float)
    vfis = _ref_step_vfis(s, step, guide, cfg)
    H, f, rows, rhs, lower, upper, err, dist = _ref_qp(model, s, step, guide, cfg, p_d, v_d,
                                                       vfis, vfi_share)  # fmt: skip
    sol = solve_qp(H, f, rows, rhs, lower, upper, check=False)
    q_dot = sol.x if sol.status is QPStatus.OPTIMAL else np.zeros(len(s.q))
    return q_dot, sol.status, err, dist


# ---- seeded random states ------------------------------------------------------------------


def _case(seed):
    """A model with a perturbed base and needle, a configuration (near a joint limit in one
    case in three), a guide line near the tip and settings whose VFIs bind."""
    rng = np.random.default_rng(seed)
    model = model_from_parameters(PandaModel(), NOMINAL + rng.uniform(-1, 1, 12) * SPREAD)
    q = rng.uniform(model.q_min + 0.3, model.q_max - 0.3)
    if seed % 3 == 0:  # at, or just past, a joint limit: the position VFI bounds bind
        j = rng.integers(7)
        q[j] = (model.q_max if rng.random() < 0.5 else model.q_min)[j] + rng.normal(0, 0.02)
    s = model.state(q)
    direction = -s.needle_axis + rng.normal(0, 0.05, 3)  # l_g points out of the patient
    direction /= np.linalg.norm(direction)
    target = s.tip_mm - rng.uniform(2.0, 80.0) * direction + rng.normal(0, 1.0, 3)
    guide = GuideLine(target, direction)
    d_patient = np.sqrt(
        s.points_line_sq_distances(np.arange(3, 8), target, np.array([0.0, 1.0, 0.0]))[0]
    )
    cfg = ControllerSettings(
        eta=rng.uniform(0.2, 1.0),
        damping=10 ** rng.uniform(-4, -2),
        patient_axis=np.array([0.0, 1.0, 0.0]),
        patient_radius_mm=float(rng.uniform(0.8, 1.05) * d_patient.min()),  # some rows bind
        guide_radius_mm=rng.uniform(0.5, 3.0),
        cone_angle_rad=np.radians(rng.uniform(0.2, 2.0)),
        puncture_keeps_axis=bool(seed % 4),
    )
    desired = s.tip_mm + rng.normal(0, 20.0, 3)
    velocity = rng.normal(0, 5.0, 3)
    return model, q, guide, cfg, desired, velocity, float(rng.uniform(0.3, 1.0))


def _qp_rel(model, q, step, guide, cfg, p_d, v_d, share):
    """``10 eps cond(H)``: how far a few ulps in the QP's data may move its solution."""
    s = model.state(q)
    H = _ref_qp(model, s, step, guide, cfg, p_d, v_d, [], share)[0]
    return max(REL, 10 * np.finfo(float).eps * np.linalg.cond(H))


def _close(got, want, rel=REL, terms=None):
    """``got == want`` to ``rel`` of the largest entry, or of the largest sum of absolute
    terms ``terms`` when ``want`` is a sum that cancels."""
    want = np.asarray(want, dtype=float)
    scale = float(np.max(np.abs(want if terms is None else terms))) if want.size else 1.0
    scale = max(1.0, scale)
    np.testing.assert_allclose(got, want, rtol=0, atol=rel * scale)


@pytest.mark.parametrize("step", list(Step))
def test_the_kernels_qp_is_the_numpy_qp(step):
    for seed in range(60):
        model, q, guide, cfg, p_d, v_d, share = _case(seed)
        s = model.state(q)
        want = _ref_qp(model, s, step, guide, cfg, p_d, v_d, _ref_step_vfis(s, step, guide, cfg),
                       share)  # fmt: skip
        H, f, rows, rhs, lower, upper, err, dist = want
        m = len(rhs)
        gH, gf, gA, gbu, gbl, gdist = _buffers(7, m)
        sense = DEFAULT_SOLVER._sense_of(7 + m)  # DAQP's: every bound an inequality
        task = {Step.ALIGN: 0, Step.APPROACH: 1}.get(step, 1 if cfg.puncture_keeps_axis else 2)
        kind = _tick.VFI_PUNCTURE if step is Step.PUNCTURE else _tick.VFI_PATIENT
        geo, par, ks = guide._kernel_data(cfg)
        gerr, infeasible = _tick.control_qp(
            task, kind, s.q, s.tip_mm, s.needle_axis, s.tip_jacobian, s.axis_jacobian, s.axes,
            s.origins, ks, geo, par, p_d, v_d, model.q_min, model.q_max, model.q_dot_max, share,
            gH, gf, gA, gbu, gbl, gdist,
        )  # fmt: skip
        _close(gH, H)
        jac, e, ff = _ref_task(s, step, guide, cfg, p_d, v_d)
        _close(gf, f, terms=2.0 * np.abs(jac.T) @ (cfg.eta * np.abs(e) + np.abs(ff)))
        _close(gA, rows)
        _close(gbu[7:], rhs)
        np.testing.assert_array_equal(gbu[:7], upper)  # elementwise: exactly numpy's
        np.testing.assert_array_equal(gbl[:7], lower)
        assert np.all(gbl[7:] == -1e30) and not sense.any()
        assert infeasible == bool((lower > upper).any())
        np.testing.assert_array_equal(gerr, err)
        _close(gdist[: len(dist)], list(dist.values()))
        # DAQP on the kernel's buffers solves what solve_qp solves from the same data
        if not infeasible:
            sol = solve_qp(gH, gf, gA, gbu[7:], gbl[:7], gbu[:7], check=False)
            got = control_step(model, q, step, guide, cfg, desired_mm=p_d,
                               desired_velocity_mm_s=v_d, state=s, vfi_share=share)  # fmt: skip
            assert got.status is sol.status
            if sol.status is QPStatus.OPTIMAL:
                np.testing.assert_array_equal(got.q_dot, sol.x)


@pytest.mark.parametrize("step", list(Step))
def test_control_step_equals_the_numpy_control_step(step):
    active_rows = active_bounds = 0
    for seed in range(60):
        model, q, guide, cfg, p_d, v_d, share = _case(seed)
        want = _ref_control_step(model, q, step, guide, cfg, p_d, v_d, share)
        got = control_step(model, q, step, guide, cfg, desired_mm=p_d,
                           desired_velocity_mm_s=v_d, vfi_share=share)  # fmt: skip
        assert got.status is want[1]
        _close(got.q_dot, want[0], _qp_rel(model, q, step, guide, cfg, p_d, v_d, share))
        np.testing.assert_array_equal(got.task_error, want[2])
        assert list(got.distances) == list(want[3])
        _close(list(got.distances.values()), list(want[3].values()))
        assert all(type(v) is float for v in got.distances.values())
        # the cases exercise the VFI rows and the joint-limit bounds where they bind
        s = model.state(q)
        vfis = _ref_step_vfis(s, step, guide, cfg)
        _, _, rows, rhs, lower, upper, _, _ = _ref_qp(model, s, step, guide, cfg, p_d, v_d,
                                                      vfis, share)  # fmt: skip
        if got.status is QPStatus.OPTIMAL:
            active_rows += bool(np.any(np.abs(rows @ got.q_dot - rhs) < 1e-9))
            active_bounds += bool(np.any(np.minimum(got.q_dot - lower, upper - got.q_dot) < 1e-9))
    assert active_rows >= 5 and active_bounds >= 5


def test_given_vfis_give_the_same_step_as_the_kernels_rows():
    for seed in range(20):
        model, q, guide, cfg, p_d, v_d, share = _case(seed)
        s = model.state(q)
        for step in Step:
            fused = control_step(model, q, step, guide, cfg, desired_mm=p_d,
                                 desired_velocity_mm_s=v_d, vfi_share=share)  # fmt: skip
            given = control_step(
                model, q, step, guide, cfg, desired_mm=p_d, desired_velocity_mm_s=v_d,
                state=s, vfis=_ref_step_vfis(s, step, guide, cfg), vfi_share=share,
            )  # fmt: skip
            assert given.status is fused.status
            _close(given.q_dot, fused.q_dot, _qp_rel(model, q, step, guide, cfg, p_d, v_d, share))
            assert given.distances.keys() == fused.distances.keys()


@pytest.mark.parametrize("with_parameters", [False, True])
def test_step_vfis_equal_the_numpy_vfis(with_parameters):
    for seed in range(40):
        model, q, guide, cfg, *_ = _case(seed)
        a = NOMINAL + np.random.default_rng(seed).uniform(-1, 1, 12) * SPREAD
        s = model.state(q)
        pj = parameter_jacobians(model, s, a) if with_parameters else None
        for step in Step:
            want = _ref_step_vfis(s, step, guide, cfg, pj, a if with_parameters else None)
            got = step_vfis(s, step, guide, cfg, pj, a if with_parameters else None)
            assert len(got) == len(want)
            for g, w in zip(got, want, strict=True):
                assert (g.name, g.safe, g.zone, g.gain) == (w.name, w.safe, w.zone, w.gain)
                assert type(g.distance) is float
                _close(g.distance, w.distance)
                _close(g.jac_q, w.jac_q)
                if with_parameters:
                    _close(g.jac_a, w.jac_a)
                else:
                    assert g.jac_a is None


def test_the_reused_buffers_leave_no_trace_between_steps():
    # the same step twice, with other steps (other sizes, other data) in between, gives
    # the same result bit for bit: nothing of a previous step's QP survives in the buffers
    model, q, guide, cfg, p_d, v_d, share = _case(7)
    kw = {"desired_mm": p_d, "desired_velocity_mm_s": v_d, "vfi_share": share}
    first = control_step(model, q, Step.PUNCTURE, guide, cfg, **kw)
    for seed in range(5):
        m2, q2, g2, c2, p2, v2, s2 = _case(100 + seed)
        for step in Step:
            control_step(
                m2, q2, step, g2, c2, desired_mm=p2, desired_velocity_mm_s=v2, vfi_share=s2
            )
    again = control_step(model, q, Step.PUNCTURE, guide, cfg, **kw)
    np.testing.assert_array_equal(again.q_dot, first.q_dot)
    assert again.q_dot is not first.q_dot and again.task_error is not first.task_error
