"""One simulated puncture: the three-step procedure of Tang et al. on a Panda guided by EM
sensors, with the adaptive controller running at 1 kHz.

Phases (``Phase``):

0. ``ADAPT``: the robot stands still while the estimate of the base and needle converges
   (the paper's simulations start this way);
1. ``ALIGN``: the needle turns onto the guide line (step 1);
2. ``APPROACH`` then ``WAIT``: the tip goes to the start point 300 mm out along the guide
   line and waits until the estimate agrees with the needle sensor (step 2);
3. ``PUNCTURE``: the tip follows a quintic to the target in ``T`` seconds (step 3), then
   holds for ``settle_s``.

"The estimate agrees" means: over the last ``convergence_window_s`` of needle samples, the
mean estimated-minus-measured position is within ``converged_mm`` and the mean rotation
between them within ``converged_deg`` (averaging keeps the sensor noise out of the test).
The guide line is the running mean of the bronchoscope sensor's samples (the target does
not move). The needle sensor feeds the adaptation law at its own rate, each sample paired
with the joint angles of the moment it was taken: off the tick (the default), its update
applied ``adaptation_delay_steps`` ticks after its job starts (as another process would
run it; :mod:`needlekit.control.schedule`), or inline, in the tick of the sample.

When no needle sample has arrived for ``stop_after_s`` the robot stops (zero joint
velocities) and resumes when samples return; after ``abort_after_s`` the trial aborts with
that reason. Every phase has a time limit, also ending the trial as aborted.
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass
from time import perf_counter
from typing import Any

import numpy as np

from needlekit.control import _tick
from needlekit.control.adaptation import AdaptationSettings, MeasurementHistory
from needlekit.control.controller import ControllerSettings, GuideLine, Step, control_step
from needlekit.control.em import EMSensor, EMSensorSpec
from needlekit.control.parameters import model_from_parameters
from needlekit.control.qp import QPStatus
from needlekit.control.qp_registry import get_qp_solver
from needlekit.control.schedule import (
    DEFAULT_ADAPTATION_DELAY_STEPS,
    AdaptationJob,
    AdaptationMailbox,
    AdaptationWorker,
)
from needlekit.control.trial import TrialResult, TrialSetup
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import pose_from_direction
from needlekit.geometry.so3 import angle_between
from needlekit.records import Status

__all__ = ["Phase", "ProcedureSettings", "TrialResult", "TrialSetup", "quintic", "run_trial"]

log_event = logging.getLogger(__name__)


class Phase(enum.Enum):
    """Where a trial is."""

    ADAPT = "adapt"
    ALIGN = "align"
    APPROACH = "approach"
    WAIT = "wait"
    PUNCTURE = "puncture"
    DONE = "done"
    ABORTED = "aborted"


def quintic(t: float, duration_s: float) -> tuple[float, float]:
    """Fraction ``s(t) = 10 tau^3 - 15 tau^4 + 6 tau^5`` (tau = t / T, clipped) and its rate.

    Parameters
    ----------
    t, duration_s : float

    Returns
    -------
    s, s_dot : float

    Examples
    --------
    >>> quintic(10.0, 20.0)
    (0.5, 0.09375)
    """
    tau = min(max(t / duration_s, 0.0), 1.0)
    s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
    s_dot = 30.0 * tau**2 * (1.0 - tau) ** 2 / duration_s
    return s, s_dot


@dataclass(frozen=True)
class ProcedureSettings:
    """Timing, thresholds and limits of the procedure (s, mm, deg).

    Attributes
    ----------
    dt_s : float
        Control period (1 kHz).
    start_distance_mm : float
        Start point along the guide line (300 mm).
    puncture_duration_s : float
        T of the quintic (20 s in the simulations).
    settle_s : float
        Hold after the quintic ends.
    align_tolerance_deg, approach_tolerance_mm : float
        When ALIGN and APPROACH are done (estimated).
    converged_mm, converged_deg, convergence_window_s : float
        When the estimate agrees with the needle sensor (1.5 mm, 0.5 deg).
    adapt_min_s : float
        Shortest initial adaptation.
    phase_timeout_s : float
        Longest any phase before PUNCTURE may take.
    stop_after_s, abort_after_s : float
        Measurement loss that stops the robot, and that aborts the trial.
    target_tolerance_mm : float
        A puncture whose estimated tip ends farther from the target than this (the arm
        blocked by its joint limits or the constraints) ends as aborted.
    log_every : int
        Record the trajectories every this many control steps.
    vfi_share : float
        The joints' share of each VFI's decay rate (the adaptation takes the rest).
    history_keyframes : int
        Keyframes of past measurements in the adaptation objective
        (:class:`~needlekit.control.adaptation.MeasurementHistory`); 0: the newest
        measurement alone, as Eq. 3 is written.
    guide_samples : int
        Bronchoscope samples averaged into the guide line, after which it stays fixed: 1
        (the default) is the paper's simulation, the guide line from one noisy
        measurement of the target; 100 is the 1 s at 100 Hz of its mannequin experiments;
        0 the running mean of every sample of the trial (the target does not move).
    adaptation_delay_steps : int
        ``D``: D > 0 runs the adaptation off the tick (:mod:`needlekit.control.schedule`):
        the tick posts the job, and its update is applied D control periods after the job
        starts (default :data:`~needlekit.control.schedule.DEFAULT_ADAPTATION_DELAY_STEPS`,
        2 ms: every tick kind inside Franka's 1 kHz budget); 0 runs it inline, in the tick
        of each needle sample (the law as first written here, bit for bit).
    qp_solver : str or QPSolver
        The QP solver of the controller and the adaptation: a registered name
        (:func:`~needlekit.control.qp_registry.get_qp_solver`: ``"daqp"``, the default, or
        ``"quadprog"``) or a :class:`~needlekit.control.qp.QPSolver`.
    """

    dt_s: float = 0.001
    start_distance_mm: float = 300.0
    puncture_duration_s: float = 20.0
    settle_s: float = 1.0
    align_tolerance_deg: float = 1.0
    approach_tolerance_mm: float = 3.0
    converged_mm: float = 1.5
    converged_deg: float = 0.5
    convergence_window_s: float = 0.5
    adapt_min_s: float = 1.0
    phase_timeout_s: float = 30.0
    stop_after_s: float = 0.1
    abort_after_s: float = 2.0
    target_tolerance_mm: float = 3.0
    log_every: int = 10
    vfi_share: float = 0.5
    guide_samples: int = 1
    history_keyframes: int = 40
    adaptation_delay_steps: int = DEFAULT_ADAPTATION_DELAY_STEPS
    qp_solver: Any = "daqp"


_LOG_KEYS = (
    "t_s", "phase", "to_target_mm", "tip_mm", "to_line_mm", "angle_deg",
    "tip_estimate_error_mm", "base_error_mm", "base_rotation_error_deg",
    "needle_rotation_error_deg", "measured_to_line_mm", "measured_angle_deg",
    "needle_error_mm", "desired_to_target_mm",
)  # fmt: skip


def _distance_from_line(p, line) -> float:
    # by scalar arithmetic, twice a tick: np.linalg.norm and @ on 3-vectors took 7 % of a
    # trial (the same bits, checked on 100,000 random lines)
    r0, r1, r2 = (p - line.point_mm).tolist()
    d0, d1, d2 = line.direction.tolist()
    s = r0 * d0 + r1 * d1 + r2 * d2
    x, y, z = r0 - d0 * s, r1 - d1 * s, r2 - d2 * s
    return math.sqrt(x * x + y * y + z * z)


def _angle_deg(u, v) -> float:
    return math.degrees(angle_between(u, v))


def _rotation_deg(pose: np.ndarray, rotation: np.ndarray) -> float:
    # math's acos and degrees on the one number: numpy's clip, arccos and degrees took 3 %
    # of a trial. A logged figure, not a decision: libm's acos is within an ulp of numpy's
    # (whose SIMD loop rounds differently on AVX-512 machines)
    cos = float((np.trace(pose[:3, :3].T @ rotation) - 1.0) / 2.0)
    return math.degrees(math.acos(min(max(cos, -1.0), 1.0)))


def _apply(update, converged: bool, counts: dict) -> tuple:
    """The control loop takes an adaptation job's update: ``(a, est, converged)``."""
    counts["adaptation_infeasible"] += update.status is not QPStatus.OPTIMAL
    flag = converged if update.converged is None else update.converged
    return update.parameters, update.model, flag


def run_trial(
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
        Receives ``(phase, kind, seconds)`` for every control step: the time the
        controller took (guide-line update, adaptation on a new needle sample, convergence
        and loss checks, kinematics, VFIs and the QP), without the simulated robot, sensors
        and logging. ``kind`` is ``"control"``, ``"control+adaptation"`` (a needle sample's
        tick with the adaptation inline, D = 0), or with D > 0 ``"control+apply"`` (the tick
        that applies a job's update) and ``"adaptation_job"`` (the job itself, timed apart
        from the ticks; its phase is the one it started in).

    Returns
    -------
    TrialResult

    Raises
    ------
    InvalidInputError
        ``adaptation_delay_steps`` is not a whole number >= 0, or ``qp_solver`` names no
        registered solver.
    """
    ps = procedure or ProcedureSettings()
    delay = ps.adaptation_delay_steps
    if not isinstance(delay, int | np.integer) or delay < 0:
        raise InvalidInputError(
            "adaptation_delay_steps", f"expected a whole number >= 0, got {delay!r}"
        )
    run = _TrialRun(
        setup, rng, ps, controller or ControllerSettings(), adaptation,
        needle_sensor or EMSensorSpec(), scope_sensor or EMSensorSpec(),
        get_qp_solver(ps.qp_solver),
    )  # fmt: skip
    run.loop(timings)
    return run.result()


class _TrialRun:
    """One trial's state, advanced one 1 kHz tick at a time by :meth:`loop` (the steps of
    :func:`run_trial`: sensing, the samples, the controller, the ground truth, the log)."""

    def __init__(self, setup, rng, ps, cs, adaptation, needle_spec, scope_spec, solver):
        self.setup, self.ps, self.cs, self.adaptation, self.solver = (
            setup,
            ps,
            cs,
            adaptation,
            solver,
        )
        self.truth = model_from_parameters(setup.arm, setup.true_parameters)
        self.needle = EMSensor(needle_spec, rng)
        self.scope = EMSensor(scope_spec, rng)
        self.true_guide = GuideLine(setup.target_mm, setup.guide_direction)
        # the bronchoscope sensor at the target, its z axis along l_g
        self.scope_pose = pose_from_direction(self.true_guide.target_mm, self.true_guide.direction)
        self.a = np.array(setup.nominal_parameters, dtype=float)
        self.est = model_from_parameters(setup.arm, self.a)
        self.q = np.array(setup.q0, dtype=float)
        self.q_hist: dict[int, np.ndarray] = {}
        window = max(1, round(ps.convergence_window_s * self.needle.spec.rate_hz))
        history = MeasurementHistory(ps.history_keyframes) if ps.history_keyframes else None
        self.worker = AdaptationWorker(
            setup.arm, adaptation, cs, vfi_share=ps.vfi_share, period_s=self.needle.period_s,
            history=history, window=window, converged_mm=ps.converged_mm,
            converged_deg=ps.converged_deg, solver=solver,
        )  # fmt: skip
        delay = int(ps.adaptation_delay_steps)
        self.mailbox = AdaptationMailbox(delay) if delay else None
        self.scope_sum, self.scope_n = np.zeros(6), 0
        self.guide = self.true_guide if setup.guide_known else None
        self.placed, self.placed_true = setup.placed_needles, setup.placed_needles_true
        self.min_gap2 = np.inf  # the real shaft's smallest squared distance to a placed needle
        self.phase, self.phase_start = Phase.ADAPT, 0.0
        self.times = {Phase.ADAPT.value: 0.0}
        self.counts = dict.fromkeys(
            ("steps", "needle_samples", "qp_infeasible", "adaptation_infeasible", "stopped_steps"),
            0,
        )
        self.events: list[tuple[float, str]] = []  # (time, what): the robot stopped or resumed
        self.stopped = False
        self.status, self.reason = Status.SOLVED, "target reached"
        self.puncture_from = None
        self.p_d = None  # the desired tip position of the latest control step
        self.log: dict[str, list] = {k: [] for k in _LOG_KEYS}
        self.true_base_r = self.truth.world_T_base[:3, :3]
        self.true_needle_r = self.truth.flange_T_tip[:3, :3]
        self.patient_line = self.true_guide.patient_line(cs.patient_axis)
        self.robot_points = np.asarray(cs.robot_points, dtype=np.int64)
        self.max_line = self.max_cone = 0.0  # over the whole puncture
        self.start_line = self.start_cone = math.nan
        self.in_line = self.in_cone = math.nan  # once the real tip is in the cylinder and cone
        self.inside = False
        self.cone_deg = float(np.degrees(cs.cone_angle_rad))
        self.min_plane = self.min_patient = np.inf
        self.last_task: tuple = (None, None)  # the controller's latest (step, task error)
        self.converged = False

    def loop(self, timings) -> None:
        """Run the ticks until the trial is done or aborted."""
        ps, dt, tick = self.ps, self.ps.dt_s, 0
        while self.phase not in (Phase.DONE, Phase.ABORTED):
            t = tick * dt
            self.q_hist[tick] = self.q.copy()
            self.q_hist.pop(tick - 1000, None)
            true_tip = self.truth.tip_pose(self.q)
            sample = self.needle.update(t, lambda tip=true_tip: tip)
            scope_sample = self.scope.update(t, lambda: self.scope_pose)
            tick_phase, tick_start = self.phase, perf_counter()
            kind = self._take_samples(tick, sample, scope_sample)
            # measurement loss
            latest = self.needle.latest
            age = t - (0.0 if latest is None else latest.arrives_s)
            if age > ps.abort_after_s:
                self.phase, self.status, self.reason = (
                    Phase.ABORTED, Status.TIMEOUT, "needle sensor lost"
                )  # fmt: skip
                break
            state, q_dot = self._control(t, age)
            if self.phase not in (Phase.PUNCTURE, Phase.DONE) and (
                t - self.phase_start > ps.phase_timeout_s
            ):
                self.status, self.reason = Status.TIMEOUT, f"{self.phase.value} timed out"
                self.phase = Phase.ABORTED
                break
            if timings is not None:
                timings.append((tick_phase.value, kind, perf_counter() - tick_start))
            if self.mailbox is not None and (job := self.mailbox.start(tick)) is not None:
                # as another thread or process would run it: not part of the tick
                job_start = perf_counter()
                self.mailbox.finish(self.worker.run(job, self.a, self.est))
                if timings is not None:
                    timings.append((self.phase.value, "adaptation_job", perf_counter() - job_start))
            truth = self._ground_truth(true_tip)
            if tick % ps.log_every == 0:
                self._log_tick(t, state, *truth)
            self.q = self.q + dt * q_dot
            tick += 1
            self.counts["steps"] += 1

    def _take_samples(self, tick: int, sample, scope_sample) -> str:
        """A due adaptation update, the guide line, and a needle sample (adapted inline or
        posted); returns the tick's kind."""
        ps, kind = self.ps, "control"
        if self.mailbox is not None and (update := self.mailbox.due(tick)) is not None:
            self.a, self.est, self.converged = _apply(update, self.converged, self.counts)
            kind = "control+apply"
        if (
            scope_sample is not None
            and not self.setup.guide_known
            and not (ps.guide_samples and self.scope_n >= ps.guide_samples)
        ):
            pose = scope_sample.pose
            self.scope_sum += np.concatenate([pose[:3, 3], pose[:3, 2]])
            self.scope_n += 1
            self.guide = GuideLine(
                self.scope_sum[:3] / self.scope_n, self.scope_sum[3:] / self.scope_n
            )
        if sample is not None:
            self.counts["needle_samples"] += 1
            q_s = self.q_hist.get(round(sample.taken_s / ps.dt_s), self.q)
            step = _STEP_OF.get(self.phase)
            last_step, last_error = self.last_task
            job = AdaptationJob(
                tick, sample.pose, q_s, step, self.guide, last_error if last_step is step else None
            )
            if self.mailbox is None:  # inline, in this tick
                update = self.worker.run(job, self.a, self.est)
                self.a, self.est, self.converged = _apply(update, self.converged, self.counts)
                kind = "control+adaptation"
            else:  # off the tick: the worker takes it after the timed span
                self.mailbox.post(tick, job)
        return kind

    def _control(self, t: float, age: float) -> tuple:
        """Stops and resumptions, the phase logic and the control step: ``(state, q_dot)``."""
        ps, phase = self.ps, self.phase
        state = self.est.state(self.q)
        q_dot = np.zeros(7)
        if phase is not Phase.ADAPT and (age > ps.stop_after_s) != self.stopped:
            self.stopped = not self.stopped
            self.events.append((t, "stopped: needle sensor silent" if self.stopped else "resumed"))
            log_fn = log_event.warning if self.stopped else log_event.info
            log_fn("t = %.3f s: %s", t, self.events[-1][1])
        if self.stopped and phase is not Phase.ADAPT:
            self.counts["stopped_steps"] += 1
        if phase is Phase.ADAPT:
            if t - self.phase_start >= ps.adapt_min_s and self.converged:
                self.phase, self.phase_start = Phase.ALIGN, t
        elif self.guide is not None and age <= ps.stop_after_s:
            q_dot = self._steer(t, state)
        return state, q_dot

    def _steer(self, t: float, state) -> np.ndarray:
        """One control step of the current phase, and the phase's end: the joint velocities."""
        ps, phase, guide = self.ps, self.phase, self.guide
        step = _STEP_OF[phase]
        p_s = guide.start_point(ps.start_distance_mm)
        if phase is Phase.PUNCTURE:
            frac, rate = quintic(t - self.phase_start, ps.puncture_duration_s)
            p_d = self.puncture_from + (guide.target_mm - self.puncture_from) * frac
            v_d = (guide.target_mm - self.puncture_from) * rate
        else:
            p_d, v_d = p_s, np.zeros(3)
        self.p_d = p_d
        out = control_step(
            self.est, self.q, step, guide, self.cs, desired_mm=p_d, desired_velocity_mm_s=v_d,
            state=state, vfi_share=ps.vfi_share, solver=self.solver, placed=self.placed,
        )  # fmt: skip
        if out.status is not QPStatus.OPTIMAL:
            self.counts["qp_infeasible"] += 1
        self.last_task = (step, out.task_error)
        u = guide.insertion_direction
        if phase is Phase.ALIGN and _angle_deg(state.needle_axis, u) <= ps.align_tolerance_deg:
            self.phase, self.phase_start = Phase.APPROACH, t
        elif (
            phase is Phase.APPROACH
            and np.linalg.norm(state.tip_mm - p_s) <= ps.approach_tolerance_mm
        ):
            self.phase, self.phase_start = Phase.WAIT, t
        elif phase is Phase.WAIT and self.converged:
            self.phase, self.phase_start = Phase.PUNCTURE, t
            self.puncture_from = p_s
        elif (
            phase is Phase.PUNCTURE and t - self.phase_start >= ps.puncture_duration_s + ps.settle_s
        ):
            self.phase = Phase.DONE
        if self.phase is not Phase.DONE:
            self.times.setdefault(self.phase.value, t)
        return out.q_dot

    def _ground_truth(self, true_tip: np.ndarray) -> tuple:
        """The real tip against the real guide line, cylinder, cone, plane and the patient:
        ``(tip, tip - target, distance from the line, angle)``."""
        guide, phase = self.true_guide, self.phase
        tip_true, axis_true = true_tip[:3, 3], true_tip[:3, 2]
        if self.placed_true is not None and phase is not Phase.ADAPT:
            self.min_gap2 = min(self.min_gap2, self._shaft_sq_distance(tip_true, axis_true))
        rel = tip_true - guide.target_mm
        to_line = _distance_from_line(tip_true, guide.line)
        angle = _angle_deg(axis_true, guide.insertion_direction)
        if phase is Phase.PUNCTURE:
            if math.isnan(self.start_line):
                self.start_line, self.start_cone = to_line, angle
            self.max_line, self.max_cone = max(self.max_line, to_line), max(self.max_cone, angle)
            self.inside = self.inside or (
                to_line <= self.cs.guide_radius_mm and angle <= self.cone_deg
            )
            if self.inside:
                self.in_line = to_line if math.isnan(self.in_line) else max(self.in_line, to_line)
                self.in_cone = angle if math.isnan(self.in_cone) else max(self.in_cone, angle)
            self.min_plane = min(self.min_plane, float(rel @ guide.direction))
        elif phase in (Phase.ALIGN, Phase.APPROACH, Phase.WAIT):
            line = self.patient_line
            d2, _ = self.truth.state(self.q).points_line_sq_distances(
                self.robot_points, line.point_mm, line.direction
            )
            self.min_patient = min(self.min_patient, float(np.sqrt(d2.min())))
        return tip_true, rel, to_line, angle

    def _shaft_sq_distance(self, tip, axis) -> float:
        """The real shaft's smallest squared distance to a real placed needle's axis."""
        return _tick.shaft_rows(
            tip, axis, _NO_JOINTS, _NO_JOINTS, self.truth.needle_length_mm, self.placed_true, 0.0, 0.0,
            _NO_ROWS, _NO_BOUNDS, 0, False,
        )  # fmt: skip

    def _log_tick(self, t, state, tip_true, rel, to_line, angle) -> None:
        """One row of the trajectories."""
        log, a, true_a, est = self.log, self.a, self.setup.true_parameters, self.est
        guide, phase = self.true_guide, self.phase
        log["t_s"].append(t)
        log["phase"].append(phase.value)
        log["to_target_mm"].append(float(np.linalg.norm(rel)))
        log["tip_mm"].append(tip_true.copy())
        log["to_line_mm"].append(to_line)
        log["angle_deg"].append(angle)
        log["tip_estimate_error_mm"].append(float(np.linalg.norm(state.tip_mm - tip_true)))
        log["base_error_mm"].append(float(np.linalg.norm(a[:3] - true_a[:3])))
        log["base_rotation_error_deg"].append(_rotation_deg(est.world_T_base, self.true_base_r))
        log["needle_rotation_error_deg"].append(_rotation_deg(est.flange_T_tip, self.true_needle_r))
        m_line = m_angle = np.nan
        if self.needle.latest is not None:
            mp = self.needle.latest.pose
            m_line = _distance_from_line(mp[:3, 3], guide.line)
            m_angle = _angle_deg(mp[:3, 2], guide.insertion_direction)
        log["measured_to_line_mm"].append(m_line)
        log["measured_angle_deg"].append(m_angle)
        log["needle_error_mm"].append(float(np.linalg.norm(a[6:9] - true_a[6:9])))
        log["desired_to_target_mm"].append(
            float(np.linalg.norm(self.p_d - self.guide.target_mm))
            if phase is Phase.PUNCTURE
            else np.nan
        )

    def result(self) -> TrialResult:
        """The trial's outcome after :meth:`loop`."""
        ps, counts, status, reason = self.ps, self.counts, self.status, self.reason
        final = self.truth.tip_pose(self.q)
        counts["needle_lost"] = self.needle.n_lost
        if self.mailbox is not None:  # jobs run, and samples a newer one replaced in the box
            counts["adaptation_jobs"] = self.mailbox.started
            counts["adaptation_replaced"] = self.mailbox.replaced
        miss = float(np.linalg.norm(final[:3, 3] - self.true_guide.target_mm))
        reached_estimated = reached = False
        if status is Status.SOLVED:
            short = float(np.linalg.norm(self.est.state(self.q).tip_mm - self.guide.target_mm))
            reached_estimated = short <= ps.target_tolerance_mm
            reached = miss <= ps.target_tolerance_mm
            if not reached_estimated:  # by the robot's own estimate
                status = Status.APPROXIMATE
                reason = f"the puncture stopped {short:.1f} mm short of the target"
            elif not reached:  # the robot believes it is there; the real tip is not
                reason = f"estimated at the target; the real tip ended {miss:.1f} mm from it"
        gap = math.nan
        if self.placed_true is not None and math.isfinite(self.min_gap2):
            gap = math.sqrt(self.min_gap2) - 2.0 * self.cs.needle_radius_mm
        return TrialResult(
            status, reason, miss,
            _angle_deg(final[:3, 2], self.true_guide.insertion_direction),
            self.max_line, self.max_cone, self.min_plane, self.min_patient,
            self.start_line, self.start_cone, self.in_line, self.in_cone,
            reached_estimated, reached, self.times, counts,
            {k: np.asarray(v) for k, v in self.log.items()}, self.events,
            final, self.est.tip_pose(self.q), gap,
        )  # fmt: skip


_NO_JOINTS = np.zeros((3, 0))
_NO_ROWS = np.zeros((0, 0))
_NO_BOUNDS = np.zeros(0)

_STEP_OF = {
    Phase.ALIGN: Step.ALIGN,
    Phase.APPROACH: Step.APPROACH,
    Phase.WAIT: Step.APPROACH,
    Phase.PUNCTURE: Step.PUNCTURE,
}
