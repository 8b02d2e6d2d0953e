"""The estimator's and the planner's own needle model, calibrated from insertions.

The loop must not be handed the simulator's parameters: a surgeon's filter never knows the
needle it steers that well. It keeps the planner's kinematic model (the unicycle of the
lecture, :mod:`needlekit.needle`) and learns its constants the way a bench calibration
does, from insertions in the same tissue, observed pose by pose:

- **Curvature.** Insertions with the bevel held (full duty), each from its own roll. Along
  one insertion the body-frame rotation increments ``w_k = log(R_k^T R_{k+1})`` average to
  the insertion's curvature vector times the step; ``|mean w_k| / ds`` is its curvature and
  its inverse its radius. ``r_min_mm`` is the mean radius, ``radius_sigma_mm`` their SD
  less the share the orientation noise below gives each insertion's mean (``r^4
  sigma_step^2 / (n ds^2)`` in variance).
- **Orientation noise.** What is left of the increments about that mean, pooled over the
  three axes and every insertion, is the random walk of the tip's orientation; its SD per
  step scales to ``reference_interval_s`` by ``sqrt(reference / dt)``. A needle whose
  curvature drifts along the insertion (the shaft's lag behind the tip, a tissue that
  stiffens) shows that drift here as noise: the model's error is the filter's noise.
- **Drift off the heading.** Each step's displacement less the model's own step from the
  pose before it, ``p_{k+1} - p_k - ds R_k e_z`` with the bevel spinning (zero duty) and
  the calibrated arc's chord with it held: the tissue's push per millimetre, and for a
  needle that bends by mechanics the tip's slip off its own axis as well (a pre-bent tip
  entering soft tissue travels up to 19 degrees off the way it points over its first 30
  mm, while the shaft catches up). ``deflection_sigma`` is the RMS of that drift per
  millimetre, per lateral component, pooled over every step of every insertion, curved
  and straight: the filter's position noise then covers what its model cannot predict.
  For the kinematic needle the drift is its constant push, and the pooled RMS is the
  push's SD as the straight insertions alone give it.

- **The tip's axis against its travel.** A needle that bends by mechanics does not go
  where its tip points: a pre-bent tip in soft tissue points up to 19 degrees further into
  its bend than it travels while the shaft behind it catches up, and again after every
  spin. Each step's travel ``p_{k+1} - p_k`` is compared with the model's direction over
  it (the bisector of the axes ``z_k`` and ``z_{k+1}``, along which an arc's chord runs):
  ``axis_slip_rad`` is the RMS of that angle per lateral component, over every step of
  every insertion, and ``axis_slip_mm`` its correlation length (the integral of its
  autocorrelation along the insertion, pooled, up to the first lag where it falls to
  zero). The slip is a bias that lasts tens of millimetres, not noise: a filter that
  takes the measured tilt as the heading steers the path by it. The estimator is told so
  (:func:`~needlekit.execute.estimator.estimator_arguments`): the kinematic needle's is
  its constant push.

The residuals say how well the calibrated model predicts the needle: every curved insertion
is replayed by the model (the same start, roll and command, the calibrated curvature, no
noise) and the distance between the two tips is taken every recorded millimetre.

The truth is anything that inserts as :class:`needlekit.execute.needle_sim.SimulatedNeedle`
does (``pose``, ``step(spin_rad, kappa_per_mm, ds_mm, dt_s)``): the kinematic needle, or a
needle that bends by mechanics. ``full_duty`` is the command that truth reads as the bevel
held throughout (its own ``1 / r``); the calibrated model's curvature ``kappa`` is then
commanded as ``kappa / kappa_cal * full_duty`` (:meth:`Calibration.command`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from needlekit._numbers import MAX_ABS_MM, MAX_ABS_NUMBER, MAX_CURVATURE_PER_MM, Bounds
from needlekit.errors import InvalidInputError
from needlekit.execute.needle_sim import ExecutionNoise
from needlekit.execute.plugins import TRUTHS, Setup
from needlekit.geometry.arcs import arc_end_unchecked
from needlekit.geometry.so3 import so3_log
from needlekit.records import field_of

__all__ = ["Calibration", "CalibrationSettings", "calibrate", "calibrate_truth"]

#: The orientation noise is stated per this interval (s), as :class:`ExecutionNoise` has it.
REFERENCE_INTERVAL_S: float = 0.1


@dataclass(frozen=True)
class CalibrationSettings:
    """How the calibration inserts.

    Attributes
    ----------
    curved : int
        Insertions with the bevel held, each from its own roll (at least 2).
    straight : int
        Insertions with the bevel spinning (at least 2).
    length_mm : float
        How deep each goes.
    step_mm : float
        The step between two observed poses.
    speed_mm_s : float
        The insertion speed (sets each step's duration, which scales the noise).
    seed : int
    """

    curved: int = 40
    straight: int = 20
    length_mm: float = 80.0
    step_mm: float = 0.5
    speed_mm_s: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("curved", "straight"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 2):
                raise InvalidInputError(name, f"expected a whole number >= 2, got {v!r}")
        for name in ("length_mm", "step_mm"):
            Bounds(0.0, MAX_ABS_MM, low_open=True, unit="mm").check(getattr(self, name), name)
        Bounds(0.0, MAX_ABS_NUMBER, low_open=True, unit="mm/s").check(self.speed_mm_s, "speed_mm_s")
        if self.step_mm * 4 > self.length_mm:
            raise InvalidInputError(
                "step_mm", f"expected at most a quarter of length_mm, got {self.step_mm!r}"
            )
        if not (isinstance(self.seed, int) and not isinstance(self.seed, bool)):
            raise InvalidInputError("seed", f"expected a whole number, got {self.seed!r}")


@dataclass(frozen=True)
class Calibration:
    """The kinematic model learnt from insertions (see the module notes).

    Attributes
    ----------
    r_min_mm : float
        The needle's radius of curvature with the bevel held (the mean over insertions).
    radius_sigma_mm : float
        Its SD over insertions.
    orientation_sigma_rad : float
        The orientation's random walk per ``reference_interval_s`` of insertion.
    reference_interval_s : float
    deflection_sigma : float
        SD of each lateral component of the tissue's push (mm per mm).
    full_duty : float
        The command the truth reads as the bevel held throughout.
    residual_rms_mm, residual_max_mm : float
        The calibrated model's replay against every curved insertion, every millimetre.
    end_error_mean_mm, end_error_sd_mm : float
        The same at the insertions' ends.
    axis_slip_rad : float
        RMS angle, per lateral component, between the tip's axis and its travel.
    axis_slip_mm : float
        That angle's correlation length along the insertion.
    curved, straight : int
        The insertions it was learnt from.
    length_mm, step_mm, speed_mm_s : float
        How they were made.
    """

    r_min_mm: float
    radius_sigma_mm: float
    orientation_sigma_rad: float
    reference_interval_s: float
    deflection_sigma: float
    full_duty: float
    residual_rms_mm: float
    residual_max_mm: float
    end_error_mean_mm: float
    end_error_sd_mm: float
    axis_slip_rad: float
    axis_slip_mm: float
    curved: int
    straight: int
    length_mm: float
    step_mm: float
    speed_mm_s: float

    def noise(self) -> ExecutionNoise:
        """What the filter assumes of the needle.

        Returns
        -------
        ExecutionNoise
        """
        return ExecutionNoise(
            orientation_sigma_rad=self.orientation_sigma_rad,
            reference_interval_s=self.reference_interval_s,
            radius_sigma_mm=self.radius_sigma_mm,
            deflection_sigma=self.deflection_sigma,
        )

    def command(self, kappa_per_mm: float) -> float:
        """The truth's command for a curvature of the calibrated model.

        Parameters
        ----------
        kappa_per_mm : float
            ``0 <= kappa <= 1 / r_min_mm``.

        Returns
        -------
        float
        """
        return kappa_per_mm * self.r_min_mm * self.full_duty

    def to_dict(self) -> dict:
        """The record written beside the results.

        Returns
        -------
        dict
        """
        return {name: getattr(self, name) for name in self.__dataclass_fields__}

    def tilt_sigma_rad(self, sample_spacing_mm: float) -> float:
        """The SD a white measurement noise on the tip's tilt must have to stand for the
        slip (:attr:`axis_slip_rad`, correlated over :attr:`axis_slip_mm`) when the tip
        is measured every ``sample_spacing_mm`` of insertion: the slip's variance times
        the samples one correlation holds, ``2 l / spacing`` (at least 1), so that the
        filter's average of the tilts over a correlation length is as uncertain as one
        slip.

        Parameters
        ----------
        sample_spacing_mm : float
            Insertion between two samples (mm, > 0).

        Returns
        -------
        float
        """
        Bounds(0.0, MAX_ABS_MM, low_open=True, unit="mm").check(sample_spacing_mm, "sample_spacing_mm")
        n = max(1.0, 2.0 * self.axis_slip_mm / sample_spacing_mm)
        return self.axis_slip_rad * math.sqrt(n)

    @classmethod
    def from_dict(cls, data: dict, where: str = "calibration") -> Calibration:
        """Rebuild from :meth:`to_dict`, every field checked.

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.

        Returns
        -------
        Calibration
        """
        values = {}
        for name in cls.__dataclass_fields__:
            kind = "int" if name in ("curved", "straight") else "number"
            optional = name in _ADDED_FIELDS  # a record written before they were learnt
            values[name] = field_of(data, name, where, kind, optional=optional)
            if values[name] is None:
                values[name] = 0.0
        return cls(**values)


#: Calibration fields a record written by an earlier version lacks (read as 0: no slip).
_ADDED_FIELDS = ("axis_slip_rad", "axis_slip_mm")


def _slip(poses: np.ndarray) -> np.ndarray:
    """Each step's travel off the model's direction over it (the bisector of the two axes),
    its lateral part, shape (n, 3): about the angle in radians."""
    travel = np.diff(poses[:, :3, 3], axis=0)
    travel /= np.maximum(np.linalg.norm(travel, axis=1, keepdims=True), 1e-300)
    mid = poses[:-1, :3, 2] + poses[1:, :3, 2]
    mid /= np.maximum(np.linalg.norm(mid, axis=1, keepdims=True), 1e-300)
    return travel - np.sum(travel * mid, axis=1, keepdims=True) * mid


def _correlation_length(series: list[np.ndarray], step: float) -> float:
    """The integral of the pooled autocorrelation of vector series along the insertion
    (mm), summed up to the first lag where it is no longer positive."""
    total = sum(float(np.sum(x * x)) for x in series)
    if total <= 0.0:
        return 0.0
    longest = max(len(x) for x in series)
    length = 0.5  # the lag-0 term of the trapezoid
    for lag in range(1, longest):
        rho = sum(float(np.sum(x[:-lag] * x[lag:])) for x in series if len(x) > lag) / total
        if rho <= 0.0:
            break
        length += rho
    return length * step


def _insert(truth, spin: float, kappa: float, n: int, step: float, dt: float) -> np.ndarray:
    """Poses of one insertion: the start, then after each of ``n`` steps."""
    poses = np.empty((n + 1, 4, 4))
    poses[0] = truth.pose
    for k in range(n):
        poses[k + 1] = truth.step(spin if k == 0 else 0.0, kappa, step, dt)
    return poses


def _spun(pose: np.ndarray, spin: float) -> np.ndarray:
    """``pose`` turned by ``spin`` about its own axis (the first step's spin, seen before
    the step's increments are read)."""
    return arc_end_unchecked(np.ascontiguousarray(pose), float(spin), 0.0, 0.0)


def calibrate(
    make_truth: Callable[[np.ndarray, np.random.Generator], object],
    full_duty: float,
    settings: CalibrationSettings | None = None,
    start_pose=None,
) -> Calibration:
    """Learn the kinematic model of a needle in its tissue from simulated insertions.

    Parameters
    ----------
    make_truth : callable
        ``make_truth(start_pose, rng)`` -> a fresh needle at ``start_pose`` (an object with
        ``pose`` and ``step``; see the module notes). Each insertion gets its own.
    full_duty : float
        The command the truth reads as the bevel held throughout (> 0).
    settings : CalibrationSettings, optional
    start_pose : ndarray, shape (4, 4), optional
        Where every insertion starts (default: the origin, inserting along +z).

    Returns
    -------
    Calibration
    """
    s = settings or CalibrationSettings()
    Bounds(0.0, MAX_CURVATURE_PER_MM, low_open=True, unit="1/mm").check(full_duty, "full_duty")
    start = np.eye(4) if start_pose is None else np.asarray(start_pose, dtype=np.float64)
    if start.shape != (4, 4) or not np.all(np.isfinite(start)):
        raise InvalidInputError("start_pose", "expected a 4x4 matrix of finite numbers")
    n = math.ceil(s.length_mm / s.step_mm - 1e-9)
    step = s.length_mm / n
    dt = step / s.speed_mm_s
    seeds = np.random.SeedSequence(s.seed).spawn(s.curved + s.straight + 1)
    rolls = np.random.default_rng(seeds[-1]).uniform(-math.pi, math.pi, s.curved)
    every = max(1, round(1.0 / step))  # the residuals' spacing: about a millimetre

    radii, residuals, deviations, ends, curved_poses = [], [], [], [], []
    for i in range(s.curved):
        truth = make_truth(start.copy(), np.random.default_rng(seeds[i]))
        poses = _insert(truth, float(rolls[i]), full_duty, n, step, dt)
        rots = poses[:, :3, :3].copy()
        rots[0] = _spun(poses[0], rolls[i])[:3, :3]
        curved_poses.append(np.concatenate([_spun(poses[0], rolls[i])[None], poses[1:]]))
        w = so3_log(np.einsum("kji,kjl->kil", rots[:-1], rots[1:]))
        mean = w.mean(axis=0)
        radii.append(step / max(float(np.linalg.norm(mean)), 1e-300))
        residuals.append(w - mean)
        deviations.append((float(rolls[i]), poses[::every, :3, 3], poses[-1, :3, 3]))
    radii_a = np.array(radii)
    r_min = float(radii_a.mean())
    resid = np.concatenate(residuals)
    dof = 3 * (len(resid) - s.curved)  # each insertion's mean took three
    sigma_step = math.sqrt(float(np.sum(resid**2)) / max(dof, 1))
    # the spread of the radii less the share the orientation noise gave each insertion's
    # mean: var(kappa_i) = sigma_step^2 / (n ds^2), var(r_i) = r^4 var(kappa_i)
    noise_var = r_min**4 * sigma_step**2 / (n * step * step)
    radius_sigma = math.sqrt(max(float(radii_a.var(ddof=1)) - noise_var, 0.0))

    drift = []  # per step, per millimetre: what the model's own step does not explain
    slips = [_slip(poses) for poses in curved_poses]
    for poses in curved_poses:
        for k in range(n):
            model = arc_end_unchecked(np.ascontiguousarray(poses[k]), 0.0, 1.0 / r_min, step)
            drift.append((poses[k + 1, :3, 3] - model[:3, 3]) / step)
    for j in range(s.straight):
        truth = make_truth(start.copy(), np.random.default_rng(seeds[s.curved + j]))
        poses = _insert(truth, 0.0, 0.0, n, step, dt)
        d = poses[1:, :3, 3] - poses[:-1, :3, 3] - poses[:-1, :3, 2] * step
        drift.extend(d / step)
        slips.append(_slip(poses))
    slip_all = np.concatenate(slips)
    axis_slip = math.sqrt(float(np.mean(np.sum(slip_all**2, axis=1))) / 2.0)
    # two lateral components' worth: the push is drawn across the insertion's axis
    deflection = math.sqrt(float(np.mean(np.sum(np.array(drift) ** 2, axis=1))) / 2.0)

    errors = []
    for roll, points, end in deviations:
        model = np.ascontiguousarray(start.copy())
        replay = [model[:3, 3].copy()]
        for k in range(n):
            model = arc_end_unchecked(model, roll if k == 0 else 0.0, 1.0 / r_min, step)
            if (k + 1) % every == 0:
                replay.append(model[:3, 3].copy())
        replay_a = np.array(replay)
        m = min(len(replay_a), len(points))
        errors.append(np.linalg.norm(replay_a[:m] - points[:m], axis=1))
        ends.append(float(np.linalg.norm(model[:3, 3] - end)))
    allerr = np.concatenate(errors)
    ends_a = np.array(ends)
    return Calibration(
        r_min_mm=r_min,
        radius_sigma_mm=radius_sigma,
        orientation_sigma_rad=sigma_step * math.sqrt(REFERENCE_INTERVAL_S / dt),
        reference_interval_s=REFERENCE_INTERVAL_S,
        deflection_sigma=deflection,
        full_duty=float(full_duty),
        residual_rms_mm=float(np.sqrt(np.mean(allerr**2))),
        residual_max_mm=float(allerr.max()),
        end_error_mean_mm=float(ends_a.mean()),
        end_error_sd_mm=float(ends_a.std(ddof=1)),
        axis_slip_rad=axis_slip,
        axis_slip_mm=_correlation_length(slips, step),
        curved=s.curved,
        straight=s.straight,
        length_mm=float(s.length_mm),
        step_mm=float(step),
        speed_mm_s=float(s.speed_mm_s),
    )


def calibrate_truth(settings, start_pose, r_min_mm: float,
                    calibration: CalibrationSettings | None = None) -> Calibration:  # fmt: skip
    """Calibrate the loop's model on the run's own truth (``settings.models.truth``, with
    the run's noise and mechanics), commanded as the plan commands it: ``1 / r_min_mm`` is
    the bevel held throughout.

    Parameters
    ----------
    settings : needlekit.execute.run.ExecutionSettings
    start_pose : ndarray, shape (4, 4)
        Where the calibration's insertions start (the plan's start: the truth's frame).
    r_min_mm : float
        The planner's radius (the command's unit).
    calibration : CalibrationSettings, optional

    Returns
    -------
    Calibration
    """
    factory = TRUTHS.get(settings.models.truth)
    goal = np.asarray(start_pose, dtype=np.float64)[:3, 3]

    def make(pose, rng):
        return factory(Setup(pose, goal, float(r_min_mm), settings, rng))

    return calibrate(make, 1.0 / float(r_min_mm), calibration, start_pose)
