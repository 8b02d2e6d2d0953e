"""One insertion of a plan, open loop or closed loop, with the same noise.

Open loop the robot commands the plan's primitives as they are and never looks: the
needle's departures from its model (:mod:`needlekit.execute.needle_sim`) accumulate.
Closed loop an EM sensor on the tip (40 Hz, 0.4 mm and 0.5 deg SD, 5 ms latency by
default; :class:`needlekit.control.em.EMSensor`) feeds a Kalman filter
(:mod:`needlekit.execute.estimator`), and pure pursuit
(:mod:`needlekit.execute.feedback`) steers from the estimate back to the plan; the
insertion stops when the goal is no longer ahead of the estimated tip. Both runs of one
trial draw the needle's radius, the tissue's push and the orientation noise from the same
seed, so they meet the same needle in the same tissue.

Closed loop, a sensing policy (:mod:`needlekit.execute.target_sensing`) says what sees the
target: nothing (``em``: the plan's target, assumed still), CT checkpoints that hold the
insertion for each scan, or continuous tracking; the loop steers to the believed target and
re-plans to it once it has moved. The path is recorded in the world (``points_mm``) and,
for a truth that maps its tissue back (``to_rest``), at rest beside it (``points_rest_mm``).

Every sample, the simulated sensor's or a tracker's, passes the sensor guard
(:mod:`needlekit.execute.guard`) before it reaches the filter; while the guard holds, the
needle does not go in, and when it gives up the insertion ends there. Faults of a profile
(:mod:`needlekit.execute.faults`) are injected into the simulated sensor and the re-plans.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from needlekit.control.em import EMSensorSpec
from needlekit.errors import InvalidInputError
from needlekit.execute.breathing import Policy
from needlekit.execute.calibration import Calibration
from needlekit.execute.faults import (
    REPLAN_OVERRUN_S,
    FaultProfile,
    FaultSchedule,
    FaultySensor,
    fault_seed,
)
from needlekit.execute.feedback import PlanReference
from needlekit.execute.guard import GuardSpec, SensorGuard
from needlekit.execute.needle_sim import ExecutionNoise
from needlekit.execute.physical import MechanicsSettings
from needlekit.execute.plugins import ESTIMATORS, FEEDBACK_LAWS, SENSORS, TRUTHS, Models, Setup
from needlekit.execute.proximity import STOP_CLEARANCE_MM, ProximityStop
from needlekit.execute.replan import Replanner
from needlekit.execute.target_sensing import SensingPolicy, TargetSensing, retarget_reference
from needlekit.execute.tip_path import TipPath
from needlekit.planning.steerable.plan import SteerablePlan

__all__ = ["DEFAULT_SENSOR", "ExecutionRun", "ExecutionSettings", "LoopHooks", "execute_plan"]

#: Closed loop, the insertion stops after this many times its nominal duration (plan length
#: plus overrun at the insertion speed), whatever else: a gate that never opens.
TIME_CAP_FACTOR: float = 20.0

#: A sample due this close (s) to the loop's time is taken at it (module notes in the loop).
SENSOR_SLACK_S: float = 1e-9

#: The simulated tip sensor: 40 Hz, 0.4 mm and 0.5 deg SD, 5 ms latency.
DEFAULT_SENSOR = EMSensorSpec(
    rate_hz=40.0, position_sigma_mm=0.4, orientation_sigma_deg=0.5, latency_s=0.005
)


@dataclass(frozen=True)
class ExecutionSettings:
    """How an insertion runs.

    Attributes
    ----------
    insertion_speed_mm_s : float
    dt_s : float
        Simulation step (the control law runs every step).
    lookahead_mm : float
        Pure pursuit's look-ahead along the plan.
    overrun_mm : float
        Closed loop, the insertion stops at the plan's length plus this, whatever the
        estimate says.
    record_mm : float
        The true tip path is recorded every this much insertion (its clearance is
        certified from those points, less half their gap).
    noise : ExecutionNoise
    sensor : EMSensorSpec
    guard : GuardSpec
        What the closed loop does when its sensor fails (:mod:`needlekit.execute.guard`).
    faults : FaultProfile or None
        Faults injected into the simulated sensor and the re-plans
        (:mod:`needlekit.execute.faults`); None: none.
    models : Models
        The registered truth, sensor, estimator and feedback law the run uses
        (:mod:`needlekit.execute.plugins`).
    mechanics : MechanicsSettings
        The needle and tissue of the ``mechanics`` truth (:mod:`needlekit.execute.physical`).
    model : Calibration or None
        Closed loop, the needle model the estimator, the feedback law and the re-plans use,
        calibrated from insertions of the truth (:mod:`needlekit.execute.calibration`): its
        radius and noise, and the command that carries its curvature out. None: the
        simulator's own radius and noise (the ``kinematic`` truth's legacy set-up).
    tissue : TissueModel or None
        The deforming organ of the ``physical`` truth (:mod:`needlekit.execute.deforming`).
    sensing : SensingPolicy
        Closed loop, what sees the target (:mod:`needlekit.execute.target_sensing`):
        ``em`` (nothing: the plan's target, assumed still), ``checkpoints`` or ``tracking``.
    stop_clearance_mm : float or None
        Closed loop, stop inserting once the estimated tip's certified clearance (the
        anatomy without the margin) is below this, or half the plan's margin if that is
        less (:mod:`needlekit.execute.proximity`); None: never stop.
    """

    insertion_speed_mm_s: float = 2.0
    dt_s: float = 0.005
    lookahead_mm: float = 10.0
    overrun_mm: float = 10.0
    record_mm: float = 0.25
    noise: ExecutionNoise = field(default_factory=ExecutionNoise)
    sensor: EMSensorSpec = DEFAULT_SENSOR
    guard: GuardSpec = field(default_factory=GuardSpec)
    faults: FaultProfile | None = None
    models: Models = field(default_factory=Models)
    mechanics: MechanicsSettings = field(default_factory=MechanicsSettings)
    model: Calibration | None = None
    tissue: object | None = None
    sensing: SensingPolicy = field(default_factory=SensingPolicy)
    stop_clearance_mm: float | None = STOP_CLEARANCE_MM

    def __post_init__(self) -> None:
        for name in ("insertion_speed_mm_s", "dt_s", "lookahead_mm", "record_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidInputError(name, f"expected a finite number > 0, got {v!r}")
        v = self.overrun_mm
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InvalidInputError("overrun_mm", f"expected a finite number >= 0, got {v!r}")
        v = self.stop_clearance_mm
        if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise InvalidInputError(
                "stop_clearance_mm", f"expected a finite number >= 0 or None, got {v!r}"
            )


@dataclass(frozen=True)
class ExecutionRun:
    """One insertion as it went.

    Attributes
    ----------
    closed_loop : bool
    final_error_mm : float
        The true tip's distance from the goal where the insertion stopped.
    points_mm : ndarray, shape (k, 3)
        The true tip path (RAS mm, in the world), every ``record_mm`` of insertion and at
        the end.
    inserted_mm : float
    estimate_error_mm : float or None
        Closed loop, the estimate's distance from the true tip at the end.
    samples : int
        EM samples the filter used.
    replans : int
        Re-plans adopted (closed loop with a :class:`~needlekit.execute.replan.Replanner`).
    replan_latency_s : tuple of float
        The measured time of every re-plan, adopted or not.
    cross_track_mm : ndarray or None
        Closed loop, the true tip's distance from the plan it was following (its nearest
        point), at each recorded point: the deviation a clearance margin has to cover.
    replan_events : tuple of (float, float, SteerablePlan)
        Closed loop, every adopted re-plan: the length inserted when its search started
        and when it applied (the needle went on meanwhile), and the plan.
    procedure_s : float
        Closed loop, the simulated time the insertion took (pauses included).
    guard : dict or None
        Closed loop, the sensor guard's account (:meth:`SensorGuard.record`): the faults
        and holds as ``{"time_s", "kind", "action"}``, the samples rejected by kind.
    faults_injected : tuple of dict
        Closed loop with a fault profile, the faults the run met.
    shaft_loads : dict or None
        The truth's ``shaft_loads()`` at the end, when it has them.
    points_rest_mm : ndarray, shape (k, 3), or None
        A truth with ``to_rest``: each point of ``points_mm`` mapped, when it was recorded,
        to the anatomy at rest (the path the clearance is judged on).
    target : dict or None
        Closed loop under a sensing policy other than ``em``, or with a truth that carries
        the target: :meth:`TargetSensing.record <needlekit.execute.target_sensing.TargetSensing.record>`.
    stopped_near_obstacle : dict or None
        Closed loop with a :class:`~needlekit.execute.proximity.ProximityStop`, when it
        stopped the insertion: ``inserted_mm``, ``estimated_clearance_mm`` (the estimated
        tip's certified clearance there; null where it has none, outside the image) and
        ``stop_mm``.
    """

    closed_loop: bool
    final_error_mm: float
    points_mm: np.ndarray
    inserted_mm: float
    estimate_error_mm: float | None = None
    samples: int = 0
    replans: int = 0
    replan_latency_s: tuple = ()
    cross_track_mm: np.ndarray | None = None
    replan_events: tuple = ()
    procedure_s: float = 0.0
    guard: dict | None = None
    faults_injected: tuple = ()
    shaft_loads: dict | None = None
    points_rest_mm: np.ndarray | None = None
    target: dict | None = None
    stopped_near_obstacle: dict | None = None


@dataclass
class LoopHooks:
    """What a caller attaches to a closed-loop run (all optional).

    Attributes
    ----------
    tick_times : list or None
        Gets the time (s) of every feedback step: the estimator's update and prediction,
        the nearest point and the law (not the simulated needle and sensor, nor a search).
    sensor : object or None
        Takes the simulated sensor's place: ``update(t, true_pose) -> EMSample or None``,
        as :class:`~needlekit.control.em.EMSensor` (e.g. a tracker over OpenIGTLink,
        :class:`needlekit.execute.igtl_link.IGTLTipSensor`).
    observe : callable or None
        Called every ``observe_every_s`` of simulated time, and once at the end, with
        ``(t_s, true_pose, estimated_pose, plan_points_mm, state)``; ``state`` a dict of
        ``inserted_mm``, ``goal_distance_mm`` (estimated), ``replans``, ``phase``
        (``"inserting"``, ``"gated"`` while a gate holds the needle, ``"held"`` while the
        sensor guard holds it, ``"scanning"`` while a checkpoint's scan holds it, ``"done"``,
        ``"aborted"`` when the guard gave up, or ``"stopped"`` when the estimated tip came
        too close to an obstacle).
    observe_every_s : float
    breathing : needlekit.execute.breathing.Policy or None
        The anatomy breathing, and the policy the robot inserts with: the recorded path
        and the final error are then the tip's in the tissue (module notes of
        :mod:`needlekit.execute.breathing`).
    notify : callable or None
        Called with each fault event of the sensor guard as it happens (a dict).
    """

    tick_times: list | None = None
    sensor: object | None = None
    observe: Callable | None = None
    observe_every_s: float = 0.025
    breathing: object | None = None
    notify: Callable | None = None


def _open_loop_commands(plan: SteerablePlan, step_mm: float):
    """The plan's primitives cut into steps of at most ``step_mm``: (spin, kappa, ds)."""
    for spin, kappa, length in plan.primitives:
        n = max(1, math.ceil(length / step_mm))
        for i in range(n):
            yield (spin if i == 0 else 0.0), kappa, length / n


def execute_plan(
    plan: SteerablePlan,
    goal_mm,
    r_min_mm: float,
    *,
    closed_loop: bool,
    seed,
    settings: ExecutionSettings | None = None,
    replanner: Replanner | None = None,
    hooks: LoopHooks | None = None,
    stop: ProximityStop | None = None,
) -> ExecutionRun:
    """Insert along ``plan`` in simulated tissue (see the module notes).

    Parameters
    ----------
    plan : SteerablePlan
    goal_mm : array_like, shape (3,)
    r_min_mm : float
        The needle's nominal radius of curvature.
    closed_loop : bool
    seed : int or numpy.random.SeedSequence
        The trial's seed: its first child draws the needle and the tissue, its second the
        sensor (the same needle open and closed loop).
    settings : ExecutionSettings, optional
    replanner : Replanner, optional
        Closed loop, re-plan from the estimated tip when it drifts from the plan.
    hooks : LoopHooks, optional
        Closed loop: step timings, another sensor, an observer, breathing.
    stop : ProximityStop, optional
        Closed loop, stop inserting once the estimated tip is this close to an obstacle
        (:mod:`needlekit.execute.proximity`; :func:`~needlekit.execute.trials.run_execute_trial`
        gives one from ``settings.stop_clearance_mm``).

    Returns
    -------
    ExecutionRun
    """
    s = settings or ExecutionSettings()
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    # ss.spawn(2) of a fresh sequence, without spawning from ss (the same draws each call)
    needle_seed, sensor_seed = (
        np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, k), pool_size=ss.pool_size)
        for k in range(2)
    )
    goal = np.asarray(goal_mm, dtype=np.float64)
    setup = Setup(plan.start_pose, goal, float(r_min_mm), s, np.random.default_rng(needle_seed))
    needle = TRUTHS.get(s.models.truth)(setup)
    ds = s.insertion_speed_mm_s * s.dt_s
    path = TipPath(needle, s.record_mm)
    if not closed_loop:
        for spin, kappa, step in _open_loop_commands(plan, ds):
            needle.step(spin, kappa, step, step / s.insertion_speed_mm_s)
            path.record()
        path.end()
        return ExecutionRun(False, path.final_error(goal), np.array(path.points),
                            needle.inserted_mm, shaft_loads=_loads(needle),
                            points_rest_mm=path.rest_array())  # fmt: skip
    return _closed_loop(
        plan,
        goal,
        setup,
        needle,
        (sensor_seed, fault_seed(ss), _target_seed(ss)),
        path,
        replanner,
        hooks or LoopHooks(),
        stop,
    )


def _loads(needle) -> dict | None:
    loads = getattr(needle, "shaft_loads", None)
    return None if loads is None else dict(loads())


def _sensor_and_guard(plan, s, setup, seeds, hooks):
    """The closed loop's sensor (the registered one, its faults, or the hooks'), the guard
    every sample passes through, and the fault schedule (None: none)."""
    sensor_seed, faults_seed = seeds[:2]
    sensor = hooks.sensor
    if sensor is None:
        sensor_setup = replace(setup, rng=np.random.default_rng(sensor_seed))
        sensor = SENSORS.get(s.models.sensor)(sensor_setup)
    schedule = None
    if s.faults is not None:
        nominal = plan.length_mm / s.insertion_speed_mm_s
        schedule = FaultSchedule(s.faults, np.random.default_rng(faults_seed), nominal)
        if hooks.sensor is None:
            sensor = FaultySensor(sensor, schedule)
    carried = 0.0
    if hooks.breathing is not None:  # the fastest the breathing carries the tip: A 2n pi / T
        tr = hooks.breathing.trace
        carried = float(np.max(tr.amplitudes_mm * 2 * tr.breathing.shape * math.pi / tr.periods_s))
    guard = SensorGuard(s.guard, plan.start_pose, s.sensor.position_sigma_mm, carried,
                        hooks.notify)  # fmt: skip
    return sensor, guard, schedule


def _closed_loop(plan, goal, setup, needle, seeds, path, replanner, hooks, stop):
    s = setup.settings
    sensor, guard, schedule = _sensor_and_guard(plan, s, setup, seeds, hooks)
    tick_times, observe, seen = hooks.tick_times, hooks.observe, -math.inf
    model = s.model
    if model is not None:  # the loop's own needle model, calibrated (execute.calibration)
        setup = replace(setup, r_min_mm=model.r_min_mm,
                        settings=replace(s, noise=model.noise()))  # fmt: skip
    to_truth = 1.0 if model is None else model.r_min_mm * model.full_duty
    est = ESTIMATORS.get(s.models.estimator)(setup)
    law = FEEDBACK_LAWS.get(s.models.feedback)(setup)
    sensing = TargetSensing.of(s.sensing, goal, needle, np.random.default_rng(seeds[2]))
    aim = goal  # the goal the followed plan aims at (the believed target's, re-planned)
    current, ref = plan, PlanReference.of_plan(plan, goal)
    ds = s.insertion_speed_mm_s * s.dt_s
    limit = plan.length_mm + s.overrun_mm
    index, t, pending, k = 0, 0.0, None, 0
    clock = time.perf_counter
    cross: list[float] = []
    events: list[tuple] = []
    stopped = None
    policy = hooks.breathing
    t_max = TIME_CAP_FACTOR * limit / s.insertion_speed_mm_s
    breathe = None if policy is None else getattr(needle, "breathe", None)
    if breathe is not None and not policy.deforming:  # the organ's motion is not the belt's
        policy = Policy(policy.name, policy.trace, deforming=True)
    while needle.inserted_mm < limit and t < t_max:
        if breathe is not None:  # a truth whose organ breathes through its own model
            breathe(policy.trace.actual(t))
        # a sample due within SENSOR_SLACK_S is due now: the sensor's clock and this loop's
        # add their periods separately, and a sample read a step late sees a moved tip
        sample = sensor.update(t + SENSOR_SLACK_S, lambda: needle.pose)
        c0 = clock()
        guard.admit(t, sample, est, needle.inserted_mm)  # every sample checked, or none used
        if guard.aborted:
            break
        held = guard.holding
        scanning = sensing is not None and sensing.tick(t, needle.inserted_mm, needle.pose, est,
                                                        guard.gated_hold)  # fmt: skip
        if sensing is not None and sensing.confirmation_due_s is not None:
            guard.await_settling(sensing.confirmation_due_s)
        if held or scanning or (policy is not None and not policy.may_advance(t)):
            phase = "held" if held else "scanning" if scanning else "gated"  # it does not go in
            _stand_still(needle, est, policy, t, s.dt_s)
            if phase == "held":
                guard.held_step(s.dt_s)
            k += 1
            t = k * s.dt_s
            path.record(None if policy is None else policy.trace.actual(t))
            if observe is not None and t - seen >= hooks.observe_every_s - 1e-9:
                seen = t
                observe(t, needle.pose, est.pose, ref.points_mm,
                        _state(needle, est.pose, goal, replanner, phase))  # fmt: skip
            continue
        moved = False
        if sensing is not None and sensing.target_mm is not goal:  # the belief changed
            goal = sensing.target_mm  # steer to it, and stop when it is no longer ahead
            ref = PlanReference(ref.points_mm, ref.arc_mm, goal)
            moved = sensing.moved(aim)
            if moved and replanner is None:  # no re-planner: the reference's end bent onto it
                ref, aim = retarget_reference(ref, index, goal, aim), goal
        pose = est.pose
        if policy is not None:  # the controller's frame: the sensed tip less its offset
            pose = pose.copy()
            pose[:3, 3] -= policy.control_offset(t)
        ahead = pose[:3, :3].T @ (goal - pose[:3, 3])
        if ahead[2] <= 1e-3:  # the goal is no longer ahead of the estimated tip
            if sensing is None or not sensing.confirm_arrival(t, needle.inserted_mm, needle.pose):
                break
            # an arrival scan holds the needle: the next steps wait for it as for any scan
            _stand_still(needle, est, policy, t, s.dt_s)
            k += 1
            t = k * s.dt_s
            path.record(None if policy is None else policy.trace.actual(t))
            continue
        if pending is not None and t >= pending[1] - 1e-12:  # the search has returned
            if guard.replan_in_time(t, pending[2], float(needle.inserted_mm)):
                (current, ref), index, aim = pending[0], 0, pending[3]
                if aim is not goal:  # the belief moved on meanwhile
                    ref = PlanReference(ref.points_mm, ref.arc_mm, goal)
                events.append((pending[2], float(needle.inserted_mm), current))
                limit = needle.inserted_mm + ref.arc_mm[-1] + s.overrun_mm
            pending = None
        index = ref.nearest(pose[:3, 3], index)
        off = float(np.linalg.norm(ref.points_mm[index] - pose[:3, 3]))
        if pending is None and replanner is not None:
            dist = float(np.linalg.norm(ahead))
            moved = moved or (sensing is not None and sensing.moved(aim))
            if replanner.due(off, needle.inserted_mm, dist) or (
                moved and replanner.may(needle.inserted_mm, dist)
            ):
                c1 = clock()
                res, took = replanner.replan(pose, needle.inserted_mm,
                                             (current, ref.arc_mm[index]),
                                             goal_mm=None if sensing is None else goal)  # fmt: skip
                fault = None if schedule is None else schedule.replan_fault(t)
                res = guard.check_replan(t, res, fault)
                if res is not None:
                    took += REPLAN_OVERRUN_S if fault == "overrun" else 0.0
                    pending = ((res.plan, PlanReference.of_plan(res.plan, goal)), t + took,
                               float(needle.inserted_mm), goal)  # fmt: skip
                c0 += clock() - c1  # the search is not the feedback step
        if stop is not None and (clear := stop.breached(pose[:3, 3])) is not None:
            stopped = {"inserted_mm": float(needle.inserted_mm),
                       "estimated_clearance_mm": clear if math.isfinite(clear) else None,
                       "stop_mm": stop.stop_mm}  # fmt: skip
            break
        spin, kappa = law(pose, ref, index)
        step = min(ds, float(ahead[2]))  # the last step ends level with the goal
        c1 = clock()
        needle.step(spin, kappa * to_truth, step, s.dt_s)
        c2 = clock()
        if policy is None:
            est.predict(spin, kappa, step, s.dt_s)
        else:  # the needle moved with the robot besides (track)
            shift, known = policy.carried(t, t + s.dt_s, True)
            _carry(needle, shift)
            est.predict(spin, kappa, step, s.dt_s, known, policy.unknown_sigma_mm(known))
        if tick_times is not None:
            tick_times.append(clock() - c2 + (c1 - c0))
        k += 1
        t = k * s.dt_s
        if observe is not None and t - seen >= hooks.observe_every_s - 1e-9:
            seen = t
            observe(t, needle.pose, est.pose, ref.points_mm,
                    _state(needle, est.pose, goal, replanner, "inserting"))  # fmt: skip
        if path.record(None if policy is None else policy.trace.actual(t)):
            true = path.tissue_point()  # the true tip's deviation, where its path is recorded
            cross.append(float(np.linalg.norm(ref.points_mm[ref.nearest(true, index)] - true)))
    path.end(0.0 if policy is None else policy.trace.actual(t))
    if observe is not None:
        observe(t, needle.pose, est.pose, ref.points_mm,
                _state(needle, est.pose, goal, replanner,
                       "aborted" if guard.aborted else "stopped" if stopped else "done"))  # fmt: skip
    est_err = float(np.linalg.norm(needle.pose[:3, 3] - est.pose[:3, 3]))
    adopted, lat = (0, ()) if replanner is None else (replanner.adopted, replanner.latencies_s)
    injected = () if schedule is None else tuple(schedule.to_list())
    return ExecutionRun(True, path.final_error(setup.goal_mm), np.array(path.points),
                        needle.inserted_mm, est_err, guard.accepted, adopted, tuple(lat),
                        np.array(cross), tuple(events), t, guard.record(), injected,
                        _loads(needle), path.rest_array(),
                        None if sensing is None else sensing.record(), stopped)  # fmt: skip


def _target_seed(ss: np.random.SeedSequence) -> np.random.SeedSequence:
    """The target sensors' noise: the trial seed's fifth child (the needle, the tip sensor,
    the breathing and the faults draw from the first four), the same under every policy."""
    return np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, 4), pool_size=ss.pool_size)


def _stand_still(needle, est, policy, t: float, dt: float) -> None:
    """A step that does not insert (held, scanning, gated): the estimate waits; under a
    breathing policy the needle, let go, rides with the tissue and the estimate follows
    the predicted motion."""
    if policy is None:
        est.predict(0.0, 0.0, 0.0, dt)
        return
    shift, known = policy.carried(t, t + dt, False, getattr(needle, "riding", None))
    needle.step(0.0, 0.0, 0.0, dt)
    _carry(needle, shift)
    est.predict(0.0, 0.0, 0.0, dt, known, policy.unknown_sigma_mm(known))


def _carry(needle, shift) -> None:
    """Move the needle by ``shift`` besides its insertion: by the truth's own ``carry``
    when it has one (a rod keeps its channel in its own frame), else its pose."""
    carry = getattr(needle, "carry", None)
    if carry is not None:
        carry(shift)
    else:
        needle.pose[:3, 3] += shift


def _state(needle, est_pose, goal, replanner, phase: str) -> dict:
    return {
        "inserted_mm": float(needle.inserted_mm),
        "goal_distance_mm": float(np.linalg.norm(goal - est_pose[:3, 3])),
        "replans": 0 if replanner is None else replanner.adopted,
        "phase": phase,
    }
