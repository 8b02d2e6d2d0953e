"""The records of one simulated puncture (:func:`needlekit.control.procedure.run_trial`):
what goes in (the truth and the prior) and what comes out."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from needlekit.control.panda import PandaModel
from needlekit.errors import InvalidInputError
from needlekit.records import Status

__all__ = ["TrialResult", "TrialSetup"]


@dataclass(frozen=True)
class TrialSetup:
    """The truth and the prior of one trial.

    Attributes
    ----------
    arm : PandaModel
        The arm with its nominal base and needle (the controller's prior).
    true_parameters, nominal_parameters : ndarray, shape (12,)
        The real base and needle, and the initial estimate.
    q0 : ndarray, shape (7,)
    target_mm : ndarray, shape (3,)
    guide_direction : ndarray, shape (3,)
        ``l_g``, pointing out of the patient.
    guide_known : bool
        The robot is given the guide line (``target_mm``, ``guide_direction``: a plan's
        line through the registration) instead of measuring it with the bronchoscope
        sensor (Tang et al.'s setup, the default).
    placed_needles : ndarray, shape (k, 2, 3), optional
        Needles already placed, as the robot believes them (each its tip and its hub end,
        mm): the controller keeps the held needle's shaft off them (placed-needle VFIs).
    placed_needles_true : ndarray, shape (k, 2, 3), optional
        The same needles where they really are: the trial measures the real gap to them.
    """

    arm: PandaModel
    true_parameters: np.ndarray
    nominal_parameters: np.ndarray
    q0: np.ndarray
    target_mm: np.ndarray
    guide_direction: np.ndarray
    guide_known: bool = False
    placed_needles: np.ndarray | None = None
    placed_needles_true: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("placed_needles", "placed_needles_true"):
            v = getattr(self, name)
            if v is None:
                continue
            arr = np.ascontiguousarray(v, dtype=float)
            if arr.ndim != 3 or arr.shape[1:] != (2, 3) or not np.isfinite(arr).all():
                raise InvalidInputError(
                    name, f"expected finite (k, 2, 3) segments, got {arr.shape}"
                )
            if (np.linalg.norm(arr[:, 1] - arr[:, 0], axis=1) <= 1e-9).any():
                raise InvalidInputError(name, "a segment has no length")
            object.__setattr__(self, name, arr if len(arr) else None)


@dataclass(frozen=True)
class TrialResult:
    """What happened in one trial (ground truth unless a name says "estimated").

    Attributes
    ----------
    status : Status
        The one status vocabulary (:class:`needlekit.records.Status`): ``SOLVED`` (the
        target reached, by the robot's estimate), ``APPROXIMATE`` (the puncture stopped
        short of it), ``TIMEOUT`` (a phase ran past its time limit, or the needle sensor
        fell silent past ``abort_after_s``); ``reason`` says which.
    reason : str
    position_error_mm : float
        Final distance from the real tip to the real target.
    angle_error_deg : float
        Final angle between the real needle and the real guide line.
    max_guide_distance_mm, max_cone_angle_deg : float
        Over the whole PUNCTURE, from its first step: the real tip's largest distance from
        the real guide line and the real needle's largest angle to it (whether or not the
        tip ever entered the guide cylinder).
    start_guide_distance_mm, start_cone_angle_deg : float
        The same at the first step of PUNCTURE (the start point is reached within the
        approach tolerance, so the tip may start outside the cylinder; the VFIs then only
        let it come closer).
    max_guide_distance_inside_mm, max_cone_angle_inside_deg : float
        The same once the real tip is inside the guide cylinder and the needle inside the
        cone (the VFIs pull them in when the puncture starts outside); NaN if it never was.
    min_plane_distance_mm : float
        Over the whole PUNCTURE, the smallest signed distance of the tip from the target's
        plane.
    reached_estimated, reached : bool
        The estimated tip ended within ``target_tolerance_mm`` of the measured target (what
        the robot knows), and the real tip within it of the real target (what happened).
    min_patient_distance_mm : float
        Smallest distance of a robot point from the patient cylinder's axis before PUNCTURE.
    phase_times_s : dict
        When each phase began.
    counts : dict
        Control steps, needle samples, lost samples, infeasible QPs, adaptation warnings,
        and the steps the robot stood still because the needle sensor was silent.
    log : dict of ndarray
        Every ``log_every`` steps: ``t_s``, ``phase``, ``to_target_mm``, ``to_line_mm``,
        ``angle_deg`` (real), ``tip_estimate_error_mm`` (estimated vs real tip),
        ``base_error_mm``, ``needle_error_mm`` (estimated vs real translations),
        ``base_rotation_error_deg``, ``needle_rotation_error_deg``, ``desired_to_target_mm``,
        the newest needle sample's ``measured_to_line_mm`` and ``measured_angle_deg``
        (against the real guide line), and the real ``tip_mm`` (rows of 3).
    events : list of (float, str)
        When the robot stopped because the needle sensor fell silent, and when it resumed.
    final_tip_pose, final_estimated_tip_pose : ndarray, shape (4, 4), optional
        The real tip pose at the end, and the robot's estimate of it.
    min_needle_gap_mm : float
        With placed needles: the smallest real surface-to-surface gap between the held
        needle's shaft (tip to flange) and a placed needle, from ALIGN on (NaN without).
    """

    status: Status
    reason: str
    position_error_mm: float
    angle_error_deg: float
    max_guide_distance_mm: float
    max_cone_angle_deg: float
    min_plane_distance_mm: float
    min_patient_distance_mm: float
    start_guide_distance_mm: float = math.nan
    start_cone_angle_deg: float = math.nan
    max_guide_distance_inside_mm: float = math.nan
    max_cone_angle_inside_deg: float = math.nan
    reached_estimated: bool = False
    reached: bool = False
    phase_times_s: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    log: dict = field(default_factory=dict)
    events: list = field(default_factory=list)
    final_tip_pose: np.ndarray | None = None
    final_estimated_tip_pose: np.ndarray | None = None
    min_needle_gap_mm: float = math.nan
