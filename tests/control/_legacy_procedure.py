"""``run_trial`` as it was before the adaptation could run off the tick (needlekit at
commit e25de54, verbatim but for this header): the oracle of
``ProcedureSettings.adaptation_delay_steps = 0``, which must give the same trial bit for bit.

It calls the same kernels as today's code (kinematics, VFIs, QP, adaptation law), so a
faster kernel changes both alike; only the loop around them is frozen here.
"""

from __future__ import annotations

import math
from collections import deque
from time import perf_counter

import numpy as np

from needlekit.control.adaptation import AdaptationSettings, MeasurementHistory, adaptation_step
from needlekit.control.controller import (
    ControllerSettings,
    GuideLine,
    Step,
    control_step,
    step_vfis,
)
from needlekit.control.dq import dq_to_matrix
from needlekit.control.em import EMSensor, EMSensorSpec
from needlekit.control.parameters import model_from_parameters, parameter_jacobians
from needlekit.control.procedure import (
    _LOG_KEYS,
    Phase,
    ProcedureSettings,
    TrialResult,
    TrialSetup,
    _angle_deg,
    _distance_from_line,
    _rotation_deg,
    log_event,
    quintic,
)
from needlekit.control.qp import QPStatus
from needlekit.geometry.se3 import pose_from_direction
from needlekit.records import Status


def legacy_run_trial(
    setup: TrialSetup,
    rng: np.random.Generator,
    *,
    procedure: ProcedureSettings | None = None,
    controller: ControllerSettings | None = None,
    adaptation: AdaptationSettings,
    needle_sensor: EMSensorSpec | None = None,
    scope_sensor: EMSensorSpec | None = None,
    timings: list | None = None,
) -> TrialResult:
    """Simulate one puncture from start to end.

    Parameters
    ----------
    setup : TrialSetup
    rng : numpy.random.Generator
        Drives the sensors' noise and dropouts.
    procedure : ProcedureSettings, optional
    controller : ControllerSettings, optional
    adaptation : AdaptationSettings
        Includes the parameter bounds (the uncertainty box).
    needle_sensor, scope_sensor : EMSensorSpec, optional
        The needle-tip and bronchoscope sensors (default: 100 Hz, 1 mm, 0.2 deg, 5 ms).
    timings : list, optional
        Receives ``(phase, adapted, seconds)`` for every control step: the time the
        controller took (guide-line update, adaptation on a new needle sample, convergence
        and loss checks, kinematics, VFIs and the QP), without the simulated robot, sensors
        and logging.

    Returns
    -------
    TrialResult
    """
    ps = procedure or ProcedureSettings()
    cs = controller or ControllerSettings()
    truth = model_from_parameters(setup.arm, setup.true_parameters)
    needle = EMSensor(needle_sensor or EMSensorSpec(), rng)
    scope = EMSensor(scope_sensor or EMSensorSpec(), rng)
    true_guide = GuideLine(setup.target_mm, setup.guide_direction)
    # the bronchoscope sensor at the target, its z axis along l_g
    scope_pose = pose_from_direction(true_guide.target_mm, true_guide.direction)

    a = np.array(setup.nominal_parameters, dtype=float)
    est = model_from_parameters(setup.arm, a)
    q = np.array(setup.q0, dtype=float)
    dt = ps.dt_s
    q_hist: dict[int, np.ndarray] = {}
    window = max(1, round(ps.convergence_window_s * needle.spec.rate_hz))
    recent: deque = deque(maxlen=window)
    history = MeasurementHistory(ps.history_keyframes) if ps.history_keyframes else None
    scope_sum, scope_n = np.zeros(6), 0
    guide = None
    phase, phase_start = Phase.ADAPT, 0.0
    times = {Phase.ADAPT.value: 0.0}
    counts = dict.fromkeys(
        ("steps", "needle_samples", "qp_infeasible", "adaptation_infeasible", "stopped_steps"), 0
    )
    events: list[tuple[float, str]] = []  # (time, what): the robot stopped or resumed
    stopped = False
    status, reason = Status.SOLVED, "target reached"
    puncture_from = None
    log: dict[str, list] = {k: [] for k in _LOG_KEYS}
    true_base_r, true_needle_r = truth.world_T_base[:3, :3], truth.flange_T_tip[:3, :3]
    patient_line = true_guide.patient_line(cs.patient_axis)
    robot_points = np.asarray(cs.robot_points, dtype=np.int64)
    max_line = max_cone = 0.0  # over the whole puncture
    start_line = start_cone = math.nan
    in_line = in_cone = math.nan  # once the real tip has entered the cylinder and the cone
    inside = False
    cone_deg = float(np.degrees(cs.cone_angle_rad))
    min_plane = min_patient = np.inf
    last_task: tuple = (None, None)  # the controller's latest (step, task error)
    step_of = {Phase.ALIGN: Step.ALIGN, Phase.APPROACH: Step.APPROACH, Phase.WAIT: Step.APPROACH}
    step_of[Phase.PUNCTURE] = Step.PUNCTURE
    tick, converged = 0, False
    while phase not in (Phase.DONE, Phase.ABORTED):
        t = tick * dt
        q_hist[tick] = q.copy()
        q_hist.pop(tick - 1000, None)
        true_tip = truth.tip_pose(q)
        sample = needle.update(t, lambda tip=true_tip: tip)
        scope_sample = scope.update(t, lambda: scope_pose)
        tick_phase, tick_start = phase, perf_counter()
        if scope_sample is not None and not (ps.guide_samples and scope_n >= ps.guide_samples):
            scope_sum += np.concatenate([scope_sample.pose[:3, 3], scope_sample.pose[:3, 2]])
            scope_n += 1
            guide = GuideLine(scope_sum[:3] / scope_n, scope_sum[3:] / scope_n)
        if sample is not None:
            counts["needle_samples"] += 1
            q_s = q_hist.get(round(sample.taken_s / dt), q)
            s_s = est.state(q_s)
            est_tip = dq_to_matrix(s_s.tip_dq)
            pj = parameter_jacobians(est, s_s, a)
            if history is not None:
                history.add(
                    np.linalg.inv(est.world_T_base) @ est_tip @ np.linalg.inv(est.flange_T_tip),
                    sample.pose,
                )
            step = step_of.get(phase)
            vfis = [] if step is None or guide is None else step_vfis(s_s, step, guide, cs, pj, a)
            out = adaptation_step(
                a, est_tip, sample.pose, pj, adaptation, step=step,
                task_error=last_task[1] if last_task[0] is step else None,
                controller=cs, vfis=vfis, vfi_share=ps.vfi_share, history=history,
            )  # fmt: skip
            if out.status is not QPStatus.OPTIMAL:
                counts["adaptation_infeasible"] += 1
            a = a + needle.period_s * out.a_dot
            est = model_from_parameters(setup.arm, a)
            recent.append(out.error)  # rotation rows weighted by orientation_scale_mm
            if len(recent) == window:  # changes only with a new sample
                mean = np.mean(recent, axis=0)
                converged = bool(
                    np.linalg.norm(mean[:3]) <= ps.converged_mm
                    and np.degrees(np.linalg.norm(mean[3:]) / adaptation.orientation_scale_mm)
                    <= ps.converged_deg
                )
        # measurement loss
        age = t - (0.0 if needle.latest is None else needle.latest.arrives_s)
        if age > ps.abort_after_s:
            phase, status, reason = Phase.ABORTED, Status.TIMEOUT, "needle sensor lost"
            break
        state = est.state(q)
        q_dot = np.zeros(7)
        if phase is not Phase.ADAPT and (age > ps.stop_after_s) != stopped:
            stopped = not stopped
            events.append((t, "stopped: needle sensor silent" if stopped else "resumed"))
            log_fn = log_event.warning if stopped else log_event.info
            log_fn("t = %.3f s: %s", t, events[-1][1])
        if stopped and phase is not Phase.ADAPT:
            counts["stopped_steps"] += 1
        if phase is Phase.ADAPT:
            if t - phase_start >= ps.adapt_min_s and converged:
                phase, phase_start = Phase.ALIGN, t
        elif guide is not None and age <= ps.stop_after_s:
            step = step_of[phase]
            p_s = guide.start_point(ps.start_distance_mm)
            if phase is Phase.PUNCTURE:
                frac, rate = quintic(t - phase_start, ps.puncture_duration_s)
                p_d = puncture_from + (guide.target_mm - puncture_from) * frac
                v_d = (guide.target_mm - puncture_from) * rate
            else:
                p_d, v_d = p_s, np.zeros(3)
            out = control_step(
                est, q, step, guide, cs, desired_mm=p_d, desired_velocity_mm_s=v_d,
                state=state, vfi_share=ps.vfi_share,
            )  # fmt: skip
            if out.status is not QPStatus.OPTIMAL:
                counts["qp_infeasible"] += 1
            q_dot, last_task = out.q_dot, (step, out.task_error)
            u = guide.insertion_direction
            if phase is Phase.ALIGN and _angle_deg(state.needle_axis, u) <= ps.align_tolerance_deg:
                phase, phase_start = Phase.APPROACH, t
            elif (
                phase is Phase.APPROACH
                and np.linalg.norm(state.tip_mm - p_s) <= ps.approach_tolerance_mm
            ):
                phase, phase_start = Phase.WAIT, t
            elif phase is Phase.WAIT and converged:
                phase, phase_start = Phase.PUNCTURE, t
                puncture_from = p_s
            elif (
                phase is Phase.PUNCTURE and t - phase_start >= ps.puncture_duration_s + ps.settle_s
            ):
                phase = Phase.DONE
            if phase is not Phase.DONE:
                times.setdefault(phase.value, t)
        if phase not in (Phase.PUNCTURE, Phase.DONE) and t - phase_start > ps.phase_timeout_s:
            phase, status, reason = Phase.ABORTED, Status.TIMEOUT, f"{phase.value} timed out"
            break
        if timings is not None:
            timings.append((tick_phase.value, sample is not None, perf_counter() - tick_start))
        # ground truth
        tip_true, axis_true = true_tip[:3, 3], true_tip[:3, 2]
        rel = tip_true - true_guide.target_mm
        to_line = _distance_from_line(tip_true, true_guide.line)
        angle = _angle_deg(axis_true, true_guide.insertion_direction)
        if phase is Phase.PUNCTURE:
            if math.isnan(start_line):
                start_line, start_cone = to_line, angle
            max_line, max_cone = max(max_line, to_line), max(max_cone, angle)
            inside = inside or (to_line <= cs.guide_radius_mm and angle <= cone_deg)
            if inside:
                in_line = to_line if math.isnan(in_line) else max(in_line, to_line)
                in_cone = angle if math.isnan(in_cone) else max(in_cone, angle)
        if phase is Phase.PUNCTURE:
            min_plane = min(min_plane, float(rel @ true_guide.direction))
        elif phase in (Phase.ALIGN, Phase.APPROACH, Phase.WAIT):
            d2, _ = truth.state(q).points_line_sq_distances(
                robot_points, patient_line.point_mm, patient_line.direction
            )
            min_patient = min(min_patient, float(np.sqrt(d2.min())))
        if tick % ps.log_every == 0:
            log["t_s"].append(t)
            log["phase"].append(phase.value)
            log["to_target_mm"].append(float(np.linalg.norm(rel)))
            log["tip_mm"].append(tip_true.copy())
            log["to_line_mm"].append(to_line)
            log["angle_deg"].append(angle)
            log["tip_estimate_error_mm"].append(float(np.linalg.norm(state.tip_mm - tip_true)))
            log["base_error_mm"].append(float(np.linalg.norm(a[:3] - setup.true_parameters[:3])))
            log["base_rotation_error_deg"].append(_rotation_deg(est.world_T_base, true_base_r))
            log["needle_rotation_error_deg"].append(_rotation_deg(est.flange_T_tip, true_needle_r))
            m_line = m_angle = np.nan
            if needle.latest is not None:
                mp = needle.latest.pose
                m_line = _distance_from_line(mp[:3, 3], true_guide.line)
                m_angle = _angle_deg(mp[:3, 2], true_guide.insertion_direction)
            log["measured_to_line_mm"].append(m_line)
            log["measured_angle_deg"].append(m_angle)
            log["needle_error_mm"].append(
                float(np.linalg.norm(a[6:9] - setup.true_parameters[6:9]))
            )
            log["desired_to_target_mm"].append(
                float(np.linalg.norm(p_d - guide.target_mm)) if phase is Phase.PUNCTURE else np.nan
            )
        q = q + dt * q_dot
        tick += 1
        counts["steps"] += 1
    final = truth.tip_pose(q)
    counts["needle_lost"] = needle.n_lost
    miss = float(np.linalg.norm(final[:3, 3] - true_guide.target_mm))
    reached_estimated = reached = False
    if status is Status.SOLVED:
        short = float(np.linalg.norm(est.state(q).tip_mm - guide.target_mm))
        reached_estimated = short <= ps.target_tolerance_mm
        reached = miss <= ps.target_tolerance_mm
        if not reached_estimated:  # by the robot's own estimate
            status, reason = (
                Status.APPROXIMATE,
                f"the puncture stopped {short:.1f} mm short of the target",
            )
        elif not reached:  # the robot believes it is there; the real tip is not
            reason = f"estimated at the target; the real tip ended {miss:.1f} mm from it"

    return TrialResult(
        status,
        reason,
        miss,
        _angle_deg(final[:3, 2], true_guide.insertion_direction),
        max_line,
        max_cone,
        min_plane,
        min_patient,
        start_line,
        start_cone,
        in_line,
        in_cone,
        reached_estimated,
        reached,
        times,
        counts,
        {k: np.asarray(v) for k, v in log.items()},
        events,
    )
