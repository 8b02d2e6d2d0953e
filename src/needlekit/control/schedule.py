"""The adaptation law (Eq. 3) as a job beside the 1 kHz control tick.

On a robot, a control tick must finish inside the real-time budget (Franka: 1 kHz, about
300 us for user code), and the adaptation that runs once per needle sample (100 Hz) does not
fit one. :func:`needlekit.control.procedure.run_trial` therefore runs it *off the tick* by
default, in a deterministic schedule that models another thread or process
(``D = adaptation_delay_steps > 0``, default :data:`DEFAULT_ADAPTATION_DELAY_STEPS`), or
inline, in the tick of the sample (``ProcedureSettings.adaptation_delay_steps = 0``, the
law as it was first written here):

- the tick of a needle sample only posts the job's inputs (the sample, the joints when it
  was taken, the controller's step, guide line and task error) in a one-slot
  :class:`AdaptationMailbox`; a newer sample replaces a job that is still waiting;
- the worker (:class:`AdaptationWorker`) takes the waiting job when it is idle, with the
  newest parameter estimate (its own last result), and computes the VFIs at the sample's
  joints, the law, the rebuilt estimate and the convergence flag;
- the result is applied at tick ``n + D``, where ``n`` is the tick the job started: from
  then on the controller uses the new estimate (a swap of references, as a real loop would
  read the worker's newest output). The worker is busy until then.

The simulation runs the job at once, outside the timed tick, so the schedule and the results
are deterministic (same seed, same trial), whatever the machine's speed; the job's own time
is recorded as its own kind, to be held against the ``D`` control periods it is allowed
(``needlekit bench control`` counts the overruns).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.control.adaptation import (
    AdaptationSettings,
    MeasurementHistory,
    adaptation_step_rows,
)
from needlekit.control.controller import ControllerSettings, GuideLine, Step, step_vfi_rows
from needlekit.control.dq import dq_to_matrix
from needlekit.control.panda import PandaModel
from needlekit.control.parameters import model_from_parameters, parameter_jacobians
from needlekit.control.qp import QPSolver, QPStatus
from needlekit.control.qp_registry import get_qp_solver
from needlekit.errors import InvalidInputError

__all__ = [
    "DEFAULT_ADAPTATION_DELAY_STEPS",
    "AdaptationJob",
    "AdaptationMailbox",
    "AdaptationUpdate",
    "AdaptationWorker",
    "delay_steps_from_ms",
]

#: The default ``D``: the adaptation off the tick, its update applied 2 control periods (2 ms
#: at 1 kHz) after its job starts. Inline (D = 0) the tick of a needle sample runs the whole
#: law and does not fit Franka's budget on its own (p99 above 300 us); 2 ms covers the
#: job's p99 several times over and stays far below the sensor's 10 ms period, so every
#: sample still becomes a job (docs/control.md, "The adaptation off the control step").
DEFAULT_ADAPTATION_DELAY_STEPS: int = 2

#: How far a delay in ms may lie from a whole number of control periods (rounding of the
#: decimal input, e.g. 0.003 / 0.001).
_PERIODS_ATOL = 1e-9
#: No VFI rows (the robot adapting while it stands still).
_NO_VFI, _NO_ROWS = np.zeros((0, 4)), np.zeros((0, 12))


def delay_steps_from_ms(delay_ms: float, dt_s: float, field: str = "adaptation_delay_ms") -> int:
    """The adaptation delay as a whole number of control periods.

    Parameters
    ----------
    delay_ms : float
        Delay in milliseconds, >= 0.
    dt_s : float
        Control period (s).
    field : str
        Named in the error.

    Returns
    -------
    int

    Raises
    ------
    InvalidInputError
        Negative, not finite, or not a whole number of control periods.

    Examples
    --------
    >>> delay_steps_from_ms(2.0, 0.001)
    2
    """
    period_ms = dt_s * 1e3
    try:
        periods = float(delay_ms) / period_ms
    except (TypeError, ValueError):
        periods = float("nan")
    steps = round(periods) if np.isfinite(periods) else -1
    if steps < 0 or abs(periods - steps) > _PERIODS_ATOL * max(1.0, abs(periods)):
        raise InvalidInputError(
            field,
            f"expected a whole number >= 0 of control periods ({period_ms:g} ms), got {delay_ms!r}",
        )
    return int(steps)


@dataclass(frozen=True)
class AdaptationJob:
    """The inputs a needle sample's tick posts for the adaptation.

    Attributes
    ----------
    posted_tick : int
    measured_pose : ndarray, shape (4, 4)
        The needle sensor's ``world_T_tip`` (mm).
    q : ndarray, shape (7,)
        The joints when the sample was taken.
    step : Step or None
        The controller's step at the sample (None while the robot adapts standing still).
    guide : GuideLine or None
        The guide line then (its VFIs are evaluated at ``q`` in the job).
    task_error : ndarray or None
        The controller's latest task error, if it was of the same step.
    """

    posted_tick: int
    measured_pose: np.ndarray
    q: np.ndarray
    step: Step | None
    guide: GuideLine | None
    task_error: np.ndarray | None


@dataclass(frozen=True)
class AdaptationUpdate:
    """What a job hands back to the control loop.

    Attributes
    ----------
    parameters : ndarray, shape (12,)
        The new estimate ``a + T a_dot`` (``T`` the needle sensor's period).
    model : PandaModel
        The arm rebuilt from it.
    status : QPStatus
        The adaptation QP's.
    converged : bool or None
        Whether the estimate agrees with the sensor over the convergence window; None while
        the window is not yet full (the flag keeps its value).
    """

    parameters: np.ndarray
    model: PandaModel
    status: QPStatus
    converged: bool | None


class AdaptationWorker:
    """What the adaptation owns and updates on each job: the measurement history and the
    window of recent errors behind the convergence flag.

    Parameters
    ----------
    arm : PandaModel
        The arm whose base and needle the parameters replace.
    adaptation : AdaptationSettings
    controller : ControllerSettings
    vfi_share : float
        The joints' share of each VFI's decay rate.
    period_s : float
        The needle sensor's period (the law's integration step).
    history : MeasurementHistory or None
    window : int
        Samples over which the convergence test averages.
    converged_mm, converged_deg : float
        The convergence thresholds.
    solver : QPSolver or str, optional
        The adaptation's QP solver (default DAQP).
    """

    def __init__(
        self,
        arm: PandaModel,
        adaptation: AdaptationSettings,
        controller: ControllerSettings,
        *,
        vfi_share: float,
        period_s: float,
        history: MeasurementHistory | None,
        window: int,
        converged_mm: float,
        converged_deg: float,
        solver: QPSolver | str | None = None,
    ) -> None:
        self.arm, self.adaptation, self.controller = arm, adaptation, controller
        self.vfi_share, self.period_s, self.history = vfi_share, period_s, history
        self.window = window
        # the newest ``window`` measurement errors, oldest first (the first ``_filled`` rows)
        self.recent = np.zeros((window, 6))
        self._filled = 0
        self.converged_mm, self.converged_deg = converged_mm, converged_deg
        self.solver = get_qp_solver(solver)

    def run(self, job: AdaptationJob, a: np.ndarray, est: PandaModel) -> AdaptationUpdate:
        """One step of the law from the estimate ``a``.

        Parameters
        ----------
        job : AdaptationJob
        a : ndarray, shape (12,)
            The parameter estimate the step starts from.
        est : PandaModel
            The arm built from ``a``.

        Returns
        -------
        AdaptationUpdate
        """
        s_s = est.state(job.q)
        est_tip = dq_to_matrix(s_s.tip_dq)
        pj = parameter_jacobians(est, s_s, a)
        if self.history is not None:  # both inverses in one LAPACK call (the same bits)
            base_inv, tip_inv = np.linalg.inv(np.stack((est.world_T_base, est.flange_T_tip)))
            self.history.add(base_inv @ est_tip @ tip_inv, job.measured_pose)
        step, cs = job.step, self.controller
        if step is None or job.guide is None:
            vfi, vjac = _NO_VFI, _NO_ROWS
        else:
            vfi, vjac = step_vfi_rows(s_s, step, job.guide, cs, pj, a, self.vfi_share)
        out = adaptation_step_rows(
            a, est_tip, job.measured_pose, pj, self.adaptation, vfi, vjac, step=step,
            task_error=job.task_error, controller=cs, history=self.history, solver=self.solver,
        )  # fmt: skip
        a = a + self.period_s * out.a_dot
        est = model_from_parameters(self.arm, a)
        converged = None
        if self._filled < self.window:
            self.recent[self._filled] = out.error  # rotation rows weighted by the scale
            self._filled += 1
        else:  # the oldest error leaves the window
            self.recent[:-1] = self.recent[1:]
            self.recent[-1] = out.error
        if self._filled == self.window:  # changes only with a new sample
            mean = np.mean(self.recent, axis=0)
            converged = bool(
                np.linalg.norm(mean[:3]) <= self.converged_mm
                and np.degrees(np.linalg.norm(mean[3:]) / self.adaptation.orientation_scale_mm)
                <= self.converged_deg
            )
        return AdaptationUpdate(a, est, out.status, converged)


class AdaptationMailbox:
    """A one-slot mailbox in front of one adaptation worker, on the control ticks' clock.

    Per tick, in this order: :meth:`due` (the running job's result, if it is due now),
    :meth:`post` (a new sample's job), :meth:`start` (the waiting job, if the worker is
    idle), then :meth:`finish` with the started job's result.

    Parameters
    ----------
    delay_steps : int
        ``D`` >= 1: a job started at tick ``n`` is applied at tick ``n + D``.

    Examples
    --------
    >>> box = AdaptationMailbox(2)
    >>> box.post(0, "sample 0"); box.start(0)
    'sample 0'
    >>> box.finish("update 0"); box.due(1) is None, box.due(2)
    (True, 'update 0')
    """

    def __init__(self, delay_steps: int) -> None:
        if not isinstance(delay_steps, int | np.integer) or delay_steps < 1:
            raise InvalidInputError(
                "adaptation_delay_steps", f"expected a whole number >= 1, got {delay_steps!r}"
            )
        self.delay_steps = int(delay_steps)
        self._waiting = None
        self._running_until: int | None = None  # the tick its result is applied
        self._result = None
        self.posted = self.started = self.replaced = self.applied = 0

    @property
    def busy(self) -> bool:
        """A job started and not yet applied."""
        return self._running_until is not None

    @property
    def waiting(self):
        """The job waiting for the worker, or None."""
        return self._waiting

    def post(self, tick: int, job) -> None:
        """Leave ``job`` for the worker; it replaces a job still waiting.

        Parameters
        ----------
        tick : int
        job : AdaptationJob or any

        Returns
        -------
        None
        """
        if self._waiting is not None:
            self.replaced += 1
        self._waiting = job
        self.posted += 1

    def start(self, tick: int):
        """The job the worker takes at ``tick`` if it is idle (applied at ``tick + D``).

        Parameters
        ----------
        tick : int

        Returns
        -------
        AdaptationJob or None
            None when the worker is busy or nothing waits.
        """
        if self._running_until is not None or self._waiting is None:
            return None
        job, self._waiting = self._waiting, None
        self._running_until = tick + self.delay_steps
        self._result = None
        self.started += 1
        return job

    def finish(self, result) -> None:
        """Hold the started job's result until its tick.

        Parameters
        ----------
        result : AdaptationUpdate or any

        Returns
        -------
        None
        """
        if self._running_until is None:
            raise RuntimeError("finish() without a started job")
        self._result = result

    def due(self, tick: int):
        """The running job's result if ``tick`` is its tick (the worker is then idle).

        Parameters
        ----------
        tick : int

        Returns
        -------
        AdaptationUpdate or None

        Raises
        ------
        RuntimeError
            The result was due at an earlier tick and not taken then.
        """
        if self._running_until is None or tick < self._running_until:
            return None
        if tick > self._running_until or self._result is None:
            raise RuntimeError(f"the job due at tick {self._running_until} was not applied then")
        result, self._result, self._running_until = self._result, None, None
        self.applied += 1
        return result
