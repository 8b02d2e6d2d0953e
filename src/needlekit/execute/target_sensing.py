"""Sensing the target in the closed loop: what sees it, what the loop believes of it, and
how the loop steers to that belief.

The closed loop runs under one *sensing policy*:

- ``em``: the EM sensor on the tip only. Nothing sees the target: the loop steers to the
  plan's target and assumes it still (the loop as it was before the policies).
- ``checkpoints``: the EM sensor, and CT checkpoints every ``every_mm`` of insertion
  (:class:`~needlekit.execute.imaging.CheckpointImaging`): the insertion holds for the
  scan; the scan's target updates the belief, and the scan's tip pose, once it passes an
  innovation gate, corrects the tip estimate.
- ``tracking``: the EM sensor, and an ultrasound-like tracker that samples the target
  continuously (:class:`~needlekit.execute.imaging.TargetTracking`); the needle keeps going.

The true target is the truth's ``target_mm()`` when it has one (a deforming tissue carries
it), else the plan's goal. The belief is a
:class:`~needlekit.execute.imaging.TargetEstimator` started at the plan's goal; every
target sample passes its gate (:func:`~needlekit.execute.imaging.admit_target`: a sample
not finite, or farther than the tissue can carry the target, is refused and counted).

The loop calls :meth:`TargetSensing.tick` once per control step; it steers to the belief
(the pure-pursuit reference ends there, and the insertion stops when the belief is no
longer ahead of the estimated tip), and when the belief has moved more than
``retarget_mm`` from the goal the followed plan aims at, it re-plans to the belief (or,
without a re-planner, bends the rest of its reference onto it: :func:`retarget_reference`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from needlekit._numbers import MAX_ABS_MM, Bounds
from needlekit.errors import InvalidInputError
from needlekit.execute.feedback import PlanReference
from needlekit.execute.guard import GATE_CHI2, is_pose
from needlekit.execute.imaging import (
    CheckpointImaging,
    CheckpointSpec,
    ImageSample,
    TargetEstimator,
    TargetTracking,
    TrackingSpec,
)

__all__ = ["SENSING_POLICIES", "SensingPolicy", "TargetSensing", "retarget_reference"]

#: The sensing policies, in the order the side-by-side table shows them.
SENSING_POLICIES: tuple[str, ...] = ("em", "checkpoints", "tracking")


@dataclass(frozen=True)
class SensingPolicy:
    """How the closed loop sees the target (see the module notes).

    Attributes
    ----------
    name : str
        One of :data:`SENSING_POLICIES`.
    checkpoints : CheckpointSpec
        The scans of ``checkpoints`` (default every 20 mm, 20 s, 0.5 mm and 1 deg SD).
    tracking : TrackingSpec
        The tracker of ``tracking`` (default 10 Hz, 0.7 mm SD, 100 ms latency).
    retarget_mm : float
        Re-plan to the believed target once it is this far from the goal the followed plan
        aims at.
    drift_sigma_mm : float
        The belief's random walk in time (mm per sqrt(s)): how fast the target may wander.
    push_sigma_mm : float
        Its random walk with the insertion (mm per sqrt(mm) inserted): how far the needle's
        push may carry the target (0: time alone).
    max_target_speed_mm_s : float
        The target gate's bound on its speed.
    tip_gate_chi2 : float
        The innovation gate a scan's tip pose passes before it corrects the tip estimate
        (6 degrees of freedom, as the EM samples' gate).
    """

    name: str = "em"
    checkpoints: CheckpointSpec = field(default_factory=CheckpointSpec)
    tracking: TrackingSpec = field(default_factory=TrackingSpec)
    retarget_mm: float = 0.5
    drift_sigma_mm: float = 0.5
    push_sigma_mm: float = 0.0
    max_target_speed_mm_s: float = 30.0
    tip_gate_chi2: float = GATE_CHI2

    def __post_init__(self) -> None:
        if self.name not in SENSING_POLICIES:
            raise InvalidInputError(
                "sensing", f"expected one of {', '.join(SENSING_POLICIES)}, got {self.name!r}"
            )
        Bounds(0.0, MAX_ABS_MM, low_open=True, unit="mm").check(self.retarget_mm, "retarget_mm")
        Bounds(0.0, 1e6).check(self.tip_gate_chi2, "tip_gate_chi2")


class TargetSensing:
    """The loop's view of the target under one policy: its sensors, its belief, and what
    the run records of them.

    Parameters
    ----------
    policy : SensingPolicy
    goal_mm : ndarray, shape (3,)
        The plan's target.
    true_target : callable or None
        The truth's ``target_mm`` (None: the target stays at ``goal_mm``).
    rng : numpy.random.Generator
        The sensors' noise.

    Attributes
    ----------
    belief : TargetEstimator
    imaging : CheckpointImaging or None
    tracker : TargetTracking or None
    max_displacement_mm : float
        The farthest the true target has been from ``goal_mm`` so far.
    tip_used, tip_refused : int
        Scan tip poses that corrected the tip estimate, and those the gate refused.
    """

    def __init__(self, policy: SensingPolicy, goal_mm, true_target: Callable | None,
                 rng: np.random.Generator) -> None:  # fmt: skip
        self.policy = policy
        self.goal_mm = np.array(goal_mm, dtype=np.float64)
        self._true = true_target
        self.belief = TargetEstimator(self.goal_mm, policy.drift_sigma_mm,
                                      policy.max_target_speed_mm_s, policy.push_sigma_mm)  # fmt: skip
        self.imaging = (
            CheckpointImaging(policy.checkpoints, rng) if policy.name == "checkpoints" else None
        )
        self.tracker = TargetTracking(policy.tracking, rng) if policy.name == "tracking" else None
        self.max_displacement_mm = 0.0
        self.tip_used = 0
        self.tip_refused = 0
        self.tip_reseeded = 0
        self._confirmed_hold: int | None = None  # the gated hold a scan was taken for
        self._confirming = False  # the scan under way was taken for it

    @classmethod
    def of(cls, policy: SensingPolicy, goal_mm, truth, rng: np.random.Generator):
        """The run's target sensing, or None when there is nothing to sense or record: the
        ``em`` policy with a truth that carries no target (the loop then runs as it always
        has).

        Parameters
        ----------
        policy : SensingPolicy
        goal_mm : ndarray, shape (3,)
        truth : object
            The run's truth (its optional ``target_mm()`` is the true target).
        rng : numpy.random.Generator

        Returns
        -------
        TargetSensing or None
        """
        true_target = getattr(truth, "target_mm", None)
        if policy.name == "em" and true_target is None:
            return None
        return cls(policy, goal_mm, true_target, rng)

    @property
    def target_mm(self) -> np.ndarray:
        """The believed target (a new array whenever the belief changes).

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.belief.target_mm

    def true_target(self) -> np.ndarray:
        """The true target now.

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.goal_mm if self._true is None else np.asarray(self._true(), dtype=np.float64)

    def tick(self, t: float, inserted_mm: float, tip_pose, estimator,
             gated_hold: int | None = None) -> bool:  # fmt: skip
        """One control step: the sensors sample, the belief takes what they deliver, a scan
        that arrives corrects the tip estimate.

        A hold of the sensor guard whose reason is the filter's gate (``gated_hold``, its
        number: :attr:`SensorGuard.gated_hold
        <needlekit.execute.guard.SensorGuard.gated_hold>`) is settled by an image, once per
        hold: a confirmation scan is taken at once (it counts toward the dose), and if its
        tip too fails the estimate's gate, the estimate, not the sensor, is what is wrong:
        the filter starts again from the image (:meth:`TipEstimator.reseed
        <needlekit.execute.estimator.TipEstimator.reseed>`), and sensor samples that agree
        with it end the hold. If the image agrees with the estimate, the sensor is what lies
        and the hold goes on to its timeout. The hold does not abort while the scan is under
        way (:attr:`confirmation_due_s`).

        Parameters
        ----------
        t : float
            The loop's time (s).
        inserted_mm : float
        tip_pose : ndarray, shape (4, 4)
            The true tip (what a scan images).
        estimator : Estimator
            The tip estimate a scan corrects.
        gated_hold : int, optional
            The guard's gated hold under way (None: none).

        Returns
        -------
        bool
            Whether a scan holds the needle (it must not go in this step).
        """
        self.belief.predict(t, inserted_mm)
        if self._true is not None:
            d = float(np.linalg.norm(self.true_target() - self.goal_mm))
            self.max_displacement_mm = max(self.max_displacement_mm, d)
        if self.tracker is not None:
            got = self.tracker.update(t, self.true_target)
            if got is not None:
                self.belief.update(t, got.taken_s, got.target_mm,
                                   self.policy.tracking.position_sigma_mm)  # fmt: skip
            return False
        img = self.imaging
        if img is None:
            return False
        confirm = gated_hold is not None and gated_hold != self._confirmed_hold
        if img.due(inserted_mm) or (confirm and not img.scanning):
            img.scan(t, inserted_mm, tip_pose, self.true_target())
            if confirm:
                self._confirmed_hold, self._confirming = gated_hold, True
        got = img.update(t)
        if got is not None:
            self.belief.update(t, got.taken_s, got.target_mm, img.spec.position_sigma_mm,
                               got.depth_mm)  # fmt: skip
            self._correct_tip(t, got, estimator, reseed=self._confirming)
            self._confirming = False
        return img.scanning

    def confirm_arrival(self, t: float, inserted_mm: float, tip_pose) -> bool:
        """The tip believes it has arrived: take a confirmation scan if the policy images
        and has one left (:meth:`CheckpointImaging.may_confirm
        <needlekit.execute.imaging.CheckpointImaging.may_confirm>`). The loop holds the
        needle through it, and goes on if the image shows the target still ahead.

        Parameters
        ----------
        t, inserted_mm : float
        tip_pose : ndarray, shape (4, 4)
            The true tip (what the scan images).

        Returns
        -------
        bool
            Whether a scan was started (False: the insertion ends here). A scan that finds
            the tip arrived ends it: another is taken only after the needle went on by more
            than the image's position noise.
        """
        img = self.imaging
        if img is None or not img.may_confirm(inserted_mm):
            return False
        img.scan(t, inserted_mm, tip_pose, self.true_target(), arrival=True)
        return True

    @property
    def confirmation_due_s(self) -> float | None:
        """When the confirmation scan under way arrives (loop clock, s), None when there is
        none: the guard's hold waits for it (:meth:`SensorGuard.await_settling
        <needlekit.execute.guard.SensorGuard.await_settling>`)."""
        pending = None if self.imaging is None else self.imaging.pending
        return pending.arrives_s if (self._confirming and pending is not None) else None

    def _correct_tip(self, t: float, scan: ImageSample, estimator, reseed: bool = False) -> None:
        """The scan's tip pose, through the innovation gate, into the tip estimate. The
        needle stood still through the scan, so the pose is the tip's now; the filter takes
        it with the image's noise (an estimator without ``R_meas``: with its own). A
        confirmation scan (``reseed``) that fails the gate restarts the estimate from it
        (an estimator without ``reseed``: refused)."""
        pose = np.ascontiguousarray(scan.tip_pose, dtype=np.float64)
        if pose.shape != (4, 4) or not is_pose(pose):  # the guard's screen of a pose
            self.tip_refused += 1
            return
        spec = self.imaging.spec
        kept = getattr(estimator, "R_meas", None)
        if kept is not None:
            rot = math.radians(spec.orientation_sigma_deg)
            estimator.R_meas = np.diag([spec.position_sigma_mm**2] * 3 + [rot**2] * 3)
        try:
            ok = estimator.update(t, pose, self.policy.tip_gate_chi2)
        finally:
            if kept is not None:
                estimator.R_meas = kept
        if ok:
            self.tip_used += 1
        elif reseed and hasattr(estimator, "reseed"):
            estimator.reseed(pose, spec.position_sigma_mm, math.radians(spec.orientation_sigma_deg))
            self.tip_reseeded += 1
        else:
            self.tip_refused += 1

    def moved(self, aim_mm) -> bool:
        """Whether the belief is more than ``retarget_mm`` from ``aim_mm`` (the goal the
        followed plan aims at).

        Parameters
        ----------
        aim_mm : ndarray, shape (3,)

        Returns
        -------
        bool
        """
        return float(np.linalg.norm(self.belief.target_mm - aim_mm)) > self.policy.retarget_mm

    def record(self) -> dict:
        """What the run records of the target at its end.

        Returns
        -------
        dict
            ``sensing`` (the policy), ``target_displacement_mm`` (the true target's distance
            from the plan's at the end) and its ``target_displacement_max_mm`` over the run,
            ``target_error_mm`` (the belief's distance from the true target at the end),
            ``scans``, ``target_samples_used``, ``target_samples_refused`` (by reason),
            ``scan_tip_used``, ``scan_tip_refused`` and ``scan_tip_reseeded`` (the
            confirmation scans that restarted the estimate).
        """
        true = self.true_target()
        moved = float(np.linalg.norm(true - self.goal_mm))
        return {
            "sensing": self.policy.name,
            "target_displacement_mm": moved,
            "target_displacement_max_mm": max(self.max_displacement_mm, moved),
            "target_error_mm": float(np.linalg.norm(self.belief.target_mm - true)),
            "scans": 0 if self.imaging is None else self.imaging.scans,
            "target_samples_used": self.belief.used,
            "target_samples_refused": dict(self.belief.refused),
            "scan_tip_used": self.tip_used,
            "scan_tip_refused": self.tip_refused,
            "scan_tip_reseeded": self.tip_reseeded,
        }


def retarget_reference(ref: PlanReference, index: int, goal_mm, aim_mm) -> PlanReference:
    """The rest of a reference bent onto a new goal: each point past ``index`` moves by
    ``w (goal_mm - aim_mm)``, ``w`` rising linearly with arc length from 0 at ``index`` to
    1 at the end, so that the reference leaves the tip where it is and ends on the new
    goal (what the loop follows without a re-planner).

    Parameters
    ----------
    ref : PlanReference
    index : int
        The reference point nearest the tip.
    goal_mm : array_like, shape (3,)
        The new goal.
    aim_mm : array_like, shape (3,)
        The goal the reference ends on now.

    Returns
    -------
    PlanReference

    Examples
    --------
    >>> import numpy as np
    >>> pts = np.array([[0.0, 0, 0], [0, 0, 1], [0, 0, 2]])
    >>> ref = PlanReference(pts, np.array([0.0, 1, 2]), np.array([0.0, 0, 2]))
    >>> retarget_reference(ref, 0, [2.0, 0, 2], [0.0, 0, 2]).points_mm[:, 0].tolist()
    [0.0, 1.0, 2.0]
    """
    goal = np.asarray(goal_mm, dtype=np.float64)
    arc = ref.arc_mm
    span = float(arc[-1] - arc[index])
    w = np.zeros(len(arc)) if span <= 0 else np.clip((arc - arc[index]) / span, 0.0, 1.0)
    pts = ref.points_mm + w[:, None] * (goal - np.asarray(aim_mm, dtype=np.float64))
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    return PlanReference(pts, np.concatenate([[0.0], np.cumsum(step)]), goal)
