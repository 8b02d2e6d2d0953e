"""The plug points of an execution: what the simulation believes, what senses the tip, what
estimates it, what steers it, and what re-plans (docs/execute.md, "Plug points").

Each is a :class:`typing.Protocol` below, with a :class:`~needlekit.registry.Registry` of
factories that ``needlekit execute`` picks from by name (``--truth``, ``--sensor``,
``--estimator``, ``--feedback``; ``--replanner`` names a planner of the planner registry).
A factory is called once per run with the run's :class:`Setup` and returns the object the
loop drives. Another package adds its own with ``TRUTHS.register(name, factory)`` (and the
like), or with no code run under the entry-point groups :data:`TRUTH_GROUP`,
:data:`SENSOR_GROUP`, :data:`ESTIMATOR_GROUP` and :data:`FEEDBACK_GROUP`. A factory may
carry ``parameters(settings) -> dict``: what ``execute.json`` records of it.

=========  =================================================================  ==============
kind       needlekit's own                                                    default
=========  =================================================================  ==============
truth      ``kinematic`` (:class:`~needlekit.execute.needle_sim.SimulatedNeedle`),  kinematic
           ``layered`` (:class:`~needlekit.execute.tissue_layers.LayeredNeedle`),
           ``mechanics`` (:class:`~needlekit.execute.physical.MechanicsTruth`),
           ``physical`` (:class:`~needlekit.execute.deforming.DeformingTruth`)
sensor     ``em`` (:class:`~needlekit.control.em.EMSensor`), ``igtl``                em
           (:class:`~needlekit.execute.igtl_link.IGTLTipSensor`)
estimator  ``kalman`` (:class:`~needlekit.execute.estimator.TipEstimator`),        kalman
           ``unscented`` (:class:`~needlekit.execute.unscented.UnscentedTipEstimator`)
feedback   ``pure_pursuit`` (:class:`~needlekit.execute.feedback.PurePursuit`),     pure_pursuit
           ``sliding_mode`` (:class:`~needlekit.execute.sliding_mode.SlidingMode`)
replanner  any steerable planner declaring ``"warm_start"``: ``rcs_star``, ``rcs``  rcs_star
=========  =================================================================  ==============

Every sample of every sensor passes the one sensor guard
(:class:`~needlekit.execute.guard.SensorGuard`) before the estimator sees it, and the
injected faults (``--faults``) wrap whichever sensor runs.

The truth's optional capabilities, used by the loop when the truth has them:

- ``target_mm()``: where the target is now (a target the tissue carries); the final error
  is judged against it, and the sensing policies' sensors sample it
  (:mod:`needlekit.execute.target_sensing`: under ``em`` nothing sees it and the loop
  steers to the plan's target);
- ``to_rest(points)``: points of the deformed tissue mapped to the undeformed anatomy; the
  recorded tip path is mapped so (``points_rest_mm``, beside the world path) and certified
  against the scenario's anatomy;
- ``shaft_loads()``: the loads along the shaft (a dict of numbers or lists), written in the
  run's record at the end of the insertion;
- under breathing (:mod:`needlekit.execute.breathing`): ``breathe(d)`` (the truth moves
  its tissue by the breathing displacement ``d`` through its own model, each tick; its
  ``to_rest`` then maps the world path, not the path less ``d``), ``riding(d0, d1)`` (how
  far the tissue at the tip moves as ``d`` goes from ``d0`` to ``d1``: a needle let go
  rides with it) and ``carry(shift)`` (move the needle besides its insertion, for a truth
  that keeps its pose in a frame of its own).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.registry import Builtin, Registry

if TYPE_CHECKING:
    from needlekit.control.em import EMSample

__all__ = [
    "ESTIMATORS",
    "ESTIMATOR_GROUP",
    "FEEDBACK_GROUP",
    "FEEDBACK_LAWS",
    "SENSORS",
    "SENSOR_GROUP",
    "TRUTHS",
    "TRUTH_GROUP",
    "Estimator",
    "FeedbackLaw",
    "Models",
    "Setup",
    "TipSensor",
    "Truth",
    "check_models",
    "model_record",
]

TRUTH_GROUP = "needlekit.execute.truths"
SENSOR_GROUP = "needlekit.execute.sensors"
ESTIMATOR_GROUP = "needlekit.execute.estimators"
FEEDBACK_GROUP = "needlekit.execute.feedback"


@runtime_checkable
class Truth(Protocol):
    """The needle and the tissue the simulation believes: the true tip.

    Attributes
    ----------
    pose : ndarray, shape (4, 4)
        The true tip pose now (RAS mm; the tip's z axis the insertion direction). The loop
        may translate it (breathing carries the whole needle).
    inserted_mm : float
        Length inserted so far.
    """

    pose: np.ndarray
    inserted_mm: float

    def step(self, spin_rad: float, kappa_per_mm: float, ds_mm: float, dt_s: float) -> np.ndarray:
        """Spin the tip, then insert ``ds_mm`` at the commanded curvature over ``dt_s``.

        Parameters
        ----------
        spin_rad : float
            Rotation about the tip's axis before inserting.
        kappa_per_mm : float
            The commanded curvature, ``0 <= kappa <= 1 / r_min`` (a duty cycle).
        ds_mm : float
            Inserted length, >= 0 (0: nothing moves).
        dt_s : float
            How long the step takes.

        Returns
        -------
        ndarray, shape (4, 4)
            The true tip pose after the step.
        """


@runtime_checkable
class TipSensor(Protocol):
    """What senses the tip: a simulated EM sensor, a tracker."""

    def update(self, t: float, true_pose) -> EMSample | None:
        """The sample that arrives by time ``t``.

        Parameters
        ----------
        t : float
            The loop's time (s).
        true_pose : callable
            ``true_pose()`` gives the true tip (a simulated sensor samples it).

        Returns
        -------
        EMSample or None
            None when no sample arrived.
        """


@runtime_checkable
class Estimator(Protocol):
    """The tip estimate from the commands and the admitted samples.

    Attributes
    ----------
    pose : ndarray, shape (4, 4)
    P : ndarray, shape (6, 6)
        The error's covariance (position, then rotation; world frame).
    last_d2 : float
        The latest sample's squared Mahalanobis distance (the guard's gate reads it).
    """

    pose: np.ndarray
    P: np.ndarray
    last_d2: float

    def predict(self, spin_rad, kappa_per_mm, ds_mm, dt_s, shift_mm=None,
                shift_sigma_mm: float = 0.0) -> None:  # fmt: skip
        """Move the estimate for one commanded step.

        Parameters
        ----------
        spin_rad, kappa_per_mm, ds_mm, dt_s : float
            The command, as :meth:`Truth.step` takes it.
        shift_mm : array_like, shape (3,), optional
            A known translation of the whole needle during the step.
        shift_sigma_mm : float
            SD per axis of what is not known of it.

        Returns
        -------
        None
        """

    def update(self, taken_s: float, measured_pose, gate_d2: float | None = None) -> bool:
        """Correct it with a sample taken at ``taken_s``.

        Parameters
        ----------
        taken_s : float
        measured_pose : ndarray, shape (4, 4)
        gate_d2 : float, optional
            Refuse the sample when its squared Mahalanobis distance exceeds this.

        Returns
        -------
        bool
            False when the gate refused it.
        """

    @property
    def position_sigma_mm(self) -> float:
        """The position uncertainty (root mean variance per axis)."""


@runtime_checkable
class FeedbackLaw(Protocol):
    """The law that steers the estimated tip back to the plan."""

    def __call__(self, pose: np.ndarray, reference, index: int) -> tuple[float, float]:
        """``(spin_rad, kappa_per_mm)`` from the estimated tip ``pose``, the plan's
        :class:`~needlekit.execute.feedback.PlanReference` and the index of its point
        nearest the tip."""


@dataclasses.dataclass(frozen=True)
class Setup:
    """What a factory gets to build its object for one run.

    Attributes
    ----------
    start_pose : ndarray, shape (4, 4)
        Where the insertion starts.
    goal_mm : ndarray, shape (3,)
    r_min_mm : float
        The needle's nominal radius of curvature (the planner's).
    settings : ExecutionSettings
        The run's settings (noise, sensor, step, look-ahead).
    rng : numpy.random.Generator or None
        This object's own random stream (the truth's and the sensor's: from the trial seed).
    link : object or None
        A live OpenIGTLink link (the ``igtl`` sensor).
    tip_name : str or None
        The tracker's transform the ``igtl`` sensor reads.
    """

    start_pose: np.ndarray
    goal_mm: np.ndarray
    r_min_mm: float
    settings: Any
    rng: np.random.Generator | None = None
    link: object | None = None
    tip_name: str | None = None


@dataclasses.dataclass(frozen=True)
class Models:
    """Which registered model of each kind a run uses (the defaults: today's loop).

    Attributes
    ----------
    truth, sensor, estimator, feedback : str
        Names in :data:`TRUTHS`, :data:`SENSORS`, :data:`ESTIMATORS`, :data:`FEEDBACK_LAWS`.
    """

    truth: str = "kinematic"
    sensor: str = "em"
    estimator: str = "kalman"
    feedback: str = "pure_pursuit"


def _callable(kind: str):
    def check(name: str, factory) -> None:
        if not callable(factory):
            raise InvalidInputError(
                f"--{kind}", f"{kind} {name!r}: expected a factory (callable), got "
                f"{type(factory).__name__}"
            )  # fmt: skip

    return check


_HERE = "needlekit.execute"

#: The truths: ``factory(setup) -> Truth``.
TRUTHS = Registry("truth", TRUTH_GROUP, (
    Builtin("kinematic", f"{_HERE}.needle_sim:kinematic_truth",
            summary="the unicycle with orientation noise, a curvature spread and a uniform push"),
    Builtin("layered", f"{_HERE}.tissue_layers:layered_truth",
            summary="the kinematic needle in tissue whose push and stiffness change with depth"),
    Builtin("mechanics", f"{_HERE}.physical:mechanics_truth",
            summary="an elastic rod held by the tissue along its channel, bent by its tip load"),
    Builtin("physical", f"{_HERE}.deforming:physical_truth",
            summary="the mechanics' rod in the organ's FEM, which the needle and breathing move"),
), field="--truth", check=_callable("truth"))  # fmt: skip

#: The tip sensors: ``factory(setup) -> TipSensor``.
SENSORS = Registry("sensor", SENSOR_GROUP, (
    Builtin("em", f"{_HERE}.sensors:em_sensor", summary="the simulated EM tip sensor"),
    Builtin("igtl", f"{_HERE}.sensors:igtl_sensor",
            summary="a tracker's TRANSFORMs over OpenIGTLink (--igtl, --tip-from-igtl)"),
), field="--sensor", check=_callable("sensor"))  # fmt: skip

#: The estimators: ``factory(setup) -> Estimator``.
ESTIMATORS = Registry("estimator", ESTIMATOR_GROUP, (
    Builtin("kalman", f"{_HERE}.estimator:kalman_estimator",
            summary="an extended Kalman filter on SE(3) with delayed samples"),
    Builtin("unscented", f"{_HERE}.unscented:unscented_estimator",
            summary="an unscented Kalman filter on SE(3): the arc model through sigma poses"),
), field="--estimator", check=_callable("estimator"))  # fmt: skip

#: The feedback laws: ``factory(setup) -> FeedbackLaw``.
FEEDBACK_LAWS = Registry("feedback law", FEEDBACK_GROUP, (
    Builtin("pure_pursuit", f"{_HERE}.feedback:pure_pursuit_law",
            summary="the arc through a look-ahead point of the plan (Coulter 1992)"),
    Builtin("sliding_mode", f"{_HERE}.sliding_mode:sliding_mode_law",
            summary="bang-bang spin about the bevel's switching surface (Rucker et al. 2013)"),
), field="--feedback", check=_callable("feedback"))  # fmt: skip

_REGISTRIES = {"truth": TRUTHS, "sensor": SENSORS, "estimator": ESTIMATORS,
               "feedback": FEEDBACK_LAWS}  # fmt: skip


def check_models(models: Models) -> None:
    """Refuse an unknown name of any kind (without importing a built-in's module).

    Parameters
    ----------
    models : Models

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Named by the flag (``--truth`` ...), with the names known and the nearest.
    """
    for kind, registry in _REGISTRIES.items():
        registry.check(getattr(models, kind))


def model_record(kind: str, name: str, settings) -> dict:
    """What ``execute.json`` says of one model: its name, where its factory lives, and its
    parameters (the factory's ``parameters(settings)``, when it has one).

    Parameters
    ----------
    kind : str
        ``"truth"``, ``"sensor"``, ``"estimator"`` or ``"feedback"``.
    name : str
    settings : ExecutionSettings

    Returns
    -------
    dict
    """
    registry = _REGISTRIES[kind]
    factory = registry.get(name)
    describe = getattr(factory, "parameters", None)
    params = dict(describe(settings)) if callable(describe) else {}
    return {"name": name, "factory": registry.target(name), "parameters": params}
