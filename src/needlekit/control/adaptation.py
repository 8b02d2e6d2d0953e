"""The adaptation law (Tang et al.'s Eq. 3): estimate the base and needle-tip poses online.

Each new needle-sensor measurement ``y`` (the tip pose in the transmitter frame, taken at a
known joint configuration) updates the 12 parameters ``a`` (:mod:`.parameters`) with the
rate that solves

    min ||J_y,a a_dot + eta_a y_err||^2 + lambda_a^2 ||a_dot||^2
    s.t.  VFI rows in a,   parameter bounds,   x_err^T J_x,a a_dot <= c

- ``y_err = [p_est - p_meas; s * log(R_est R_meas^T)]``: the estimated minus the measured
  tip position, and the rotation between them weighted by ``s`` mm/rad; with a
  :class:`MeasurementHistory` the objective is the mean over keyframes taken at other
  configurations as well (see there why);
- the VFI rows: the step's VFIs with their parameter Jacobians and the remaining share of
  their decay rate (the joints take ``vfi_share``), so the *estimated* distances obey the
  VFIs under the joint action of the robot's motion and the adaptation. Where the estimate
  already violates a VFI the row only forbids making it worse: pulling the estimate back
  in would make it wrong on purpose, and the joints do the pulling;
- the stability row: the adaptation does not increase the controller's task error
  (``c = 0``, the paper's row) outside a small ball; inside it, ``c = eta_a (r^2 -
  ||x_err||^2) / 2`` lets it (``AdaptationSettings.stability_radius_mm``). With ``c = 0``
  everywhere the estimate can never move away from the desired value, which is the only
  way a correction reaches the robot: measured with the paper's uncertainty, the wait at
  the start point then never converges in some trials;
- the bounds keep ``a`` inside the uncertainty box.

``a_dot = 0`` satisfies every row, so the QP is infeasible only when the estimate has left
the uncertainty box; it then gives ``a_dot = 0`` and a logged warning.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from needlekit.control import _adaptation_kernels as _kernels
from needlekit.control._adaptation_kernels import (
    _add_distances,
    _closest_pair,
    _drop_distances,
    _flange_distance,
    _normal_equations,
    _rotation_log,  # noqa: F401 - the kernel's home before; tests import it from here
    _stacked_errors,
)
from needlekit.control.controller import (
    ControllerSettings,
    Step,
    StepVFI,
    task_parameter_jacobian,
)
from needlekit.control.parameters import N_PARAMETERS, ParameterJacobians
from needlekit.control.qp import CROSSED_BOUNDS, QPSolver, QPStatus
from needlekit.control.qp_registry import get_qp_solver
from needlekit.control.vfi import Zone
from needlekit.errors import InvalidInputError

__all__ = [
    "AdaptationOutput",
    "AdaptationSettings",
    "MeasurementHistory",
    "adaptation_step",
    "measurement_error",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AdaptationSettings:
    """Gains and bounds of the adaptation law.

    Attributes
    ----------
    lower, upper : ndarray, shape (12,)
        The box the parameters stay in (the uncertainty ranges around the nominal values).
    eta : float
        eta_a (1/s).
    damping : float
        lambda_a.
    orientation_scale_mm : float
        ``s``: weight of the rotation error rows (mm per rad).
    bound_gain : float
        Rate (1/s) at which a parameter may approach its bound.
    stability_radius_mm : float
        ``r``: inside the ball ``||x_err|| < r`` the stability row lets the adaptation
        increase the task error, at a rate vanishing at the ball's edge (its right-hand side
        is ``max(0, eta (r^2 - ||x_err||^2) / 2)``); outside it is the paper's row
        ``x_err^T J_x,a a_dot <= 0``. ``0`` gives the paper's row everywhere. Units: the
        task error's (mm; axis rows weighted by the controller's ``axis_scale_mm``).
    clamp_vfi_rows : bool
        A VFI row's right-hand side is kept at ``>= 0`` (the estimate is never pulled back
        into a constraint it already violates; the joints do that). False: the rows as
        the VFI law writes them.
    """

    lower: np.ndarray
    upper: np.ndarray
    eta: float = 2.0
    damping: float = 1e-2
    orientation_scale_mm: float = 100.0
    bound_gain: float = 10.0
    stability_radius_mm: float = 1.5
    clamp_vfi_rows: bool = True

    def __post_init__(self) -> None:
        lo = np.asarray(self.lower, dtype=float).reshape(-1)
        hi = np.asarray(self.upper, dtype=float).reshape(-1)
        if lo.shape != (N_PARAMETERS,) or hi.shape != (N_PARAMETERS,) or np.any(lo >= hi):
            raise InvalidInputError("lower", "expected 12 lower bounds below 12 upper bounds")
        object.__setattr__(self, "lower", lo)
        object.__setattr__(self, "upper", hi)


@dataclass(frozen=True)
class AdaptationOutput:
    """One adaptation step.

    Attributes
    ----------
    a_dot : ndarray, shape (12,)
        Parameter rates (zero when the QP was infeasible).
    status : QPStatus
    error : ndarray, shape (6,)
        The measurement error ``y_err`` before the update (mm; rotation rows weighted).
    """

    a_dot: np.ndarray
    status: QPStatus
    error: np.ndarray


def measurement_error(estimated_tip, measured_tip, orientation_scale_mm: float) -> np.ndarray:
    """``[p_est - p_meas; s * log(R_est R_meas^T)]``.

    Parameters
    ----------
    estimated_tip, measured_tip : ndarray, shape (4, 4)
    orientation_scale_mm : float

    Returns
    -------
    ndarray, shape (6,)
    """
    return _kernels.measurement_error(
        np.ascontiguousarray(estimated_tip, dtype=float),
        np.ascontiguousarray(measured_tip, dtype=float),
        float(orientation_scale_mm),
    )


class MeasurementHistory:
    """Keyframes of past needle-sensor measurements, stacked into the adaptation objective.

    One measurement fixes 6 of the 12 parameters: at a single joint configuration a base
    rotation error is indistinguishable from a needle rotation error, and shows only when
    the arm moves (over a 300 mm puncture, 1 deg of base rotation error moves the real tip
    5 mm off the line). Stacking measurements taken at different configurations makes the
    objective of Eq. 3 the least-squares fit of the parameters to all of them, so the
    estimate keeps what the arm's motion has revealed instead of forgetting it.

    Each sample is the flange pose in the *base* frame (independent of the parameters) and
    the measured tip pose. A sample whose flange lies ``spacing_mm`` or ``spacing_deg`` from
    the newest keyframe becomes a keyframe; a sample
    within ``merge_mm`` and ``merge_deg`` of it (the arm at rest) is averaged into it, which
    averages the sensor noise; any other sample enters the objective only as the current
    measurement. The objective is the mean over the keyframes and the current sample.
    Beyond ``capacity`` the older of the two most alike keyframes goes (flange poses
    compared as mm + 100 mm/rad), so the history keeps the configurations that tell the
    parameters apart: a FIFO would, after a long straight puncture, hold only collinear
    keyframes that no longer pin down the base rotation.

    Parameters
    ----------
    capacity : int
    spacing_mm, spacing_deg : float
    merge_mm, merge_deg : float
    """

    def __init__(
        self,
        capacity: int = 40,
        spacing_mm: float = 10.0,
        spacing_deg: float = 5.0,
        merge_mm: float = 0.5,
        merge_deg: float = 0.1,
    ):
        if capacity < 1 or not (0 < merge_mm < spacing_mm and 0 < merge_deg < spacing_deg):
            raise InvalidInputError(
                "history", "expected capacity >= 1 and 0 < merge < spacing (mm and deg)"
            )
        self.capacity = int(capacity)
        self._spacing = (float(spacing_mm), float(np.radians(spacing_deg)))
        self._merge = (float(merge_mm), float(np.radians(merge_deg)))
        # only the newest keyframe takes samples: its first flange pose and its sums
        self._anchor = np.eye(4)
        self._sum = np.zeros((2, 4, 4))
        self._count: list[int] = []
        self._poses = np.empty((0, 2, 4, 4))  # per keyframe: mean flange, mean measured
        self._stale = False  # the newest keyframe's mean is not yet projected from its sum
        self._current: np.ndarray | None = None  # the newest sample when not a keyframe's
        # flange distances between keyframes (all but the newest), as _most_redundant's
        self._dist = np.zeros((self.capacity + 1, self.capacity + 1))

    def __len__(self) -> int:
        return len(self._count)

    @property
    def counts(self) -> np.ndarray:
        """Samples averaged in each keyframe, oldest first."""
        return np.asarray(self._count, dtype=int)

    def add(self, base_T_flange: np.ndarray, measured_tip: np.ndarray) -> None:
        """Add one sample (the flange in the base frame at the sample's configuration).

        Parameters
        ----------
        base_T_flange, measured_tip : ndarray, shape (4, 4)

        Returns
        -------
        None
        """
        sample = np.empty((2, 4, 4))
        sample[0], sample[1] = base_T_flange, measured_tip
        self._current = None
        if self._count:
            dp, angle = _flange_distance(sample[0], self._anchor)
            if dp <= self._merge[0] and angle <= self._merge[1]:
                self._sum += sample
                self._count[-1] += 1
                self._stale = True  # projected onto SE(3) when next read
                return
            if dp < self._spacing[0] and angle < self._spacing[1]:
                self._current = sample
                return
        self._refresh()
        self._anchor, self._sum = sample[0], sample.copy()
        self._count.append(1)
        self._poses = np.concatenate([self._poses, sample[None]])
        k = len(self._count)
        if k >= 3:  # the keyframe before this one joins the distance matrix
            _add_distances(self._dist, self._poses, k - 2)
        if k > self.capacity:
            i = self._most_redundant()
            del self._count[i]
            self._poses = np.delete(self._poses, i, axis=0)
            _drop_distances(self._dist, i, k - 1)

    def _refresh(self) -> None:
        """Project the newest keyframe's averaged samples onto SE(3) (after merges)."""
        if self._stale:
            self._poses[-1] = _mean_poses(self._sum / self._count[-1])
            self._stale = False

    def _most_redundant(self) -> int:
        """The older of the two closest keyframes (the newest is never dropped)."""
        return int(_closest_pair(self._dist, len(self._count) - 1))

    def _entries(self) -> tuple[np.ndarray, np.ndarray]:
        """The keyframes' mean poses, and the current sample as a (0 or 1, 2, 4, 4) array."""
        self._refresh()
        return self._poses, _NO_SAMPLE if self._current is None else self._current[None]

    def normal_equations(self, a, orientation_scale_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """``J' J`` and ``J' e`` of :meth:`stacked` (summed without stacking).

        Parameters
        ----------
        a : ndarray, shape (12,)
        orientation_scale_mm : float

        Returns
        -------
        jtj : ndarray, shape (12, 12)
        jte : ndarray, shape (12,)
        """
        return _normal_equations(*self._entries(), _parameters(a), float(orientation_scale_mm))

    def stacked(self, a, orientation_scale_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Measurement errors and their parameter Jacobians of the keyframes and the
        current sample, at ``a``.

        Parameters
        ----------
        a : ndarray, shape (12,)
        orientation_scale_mm : float

        Returns
        -------
        error : ndarray, shape (6 k,)
            ``[p_est - p_meas; s log(R_est R_meas^T)]`` per entry.
        jacobian : ndarray, shape (6 k, 12)
        """
        return _stacked_errors(*self._entries(), _parameters(a), float(orientation_scale_mm))


_NO_SAMPLE = np.empty((0, 2, 4, 4))


def _mean_poses(poses: np.ndarray) -> np.ndarray:
    """Project averaged 4 x 4 poses back onto SE(3) (the chordal mean of the rotations)."""
    out = np.zeros_like(poses)
    u, _, vt = np.linalg.svd(poses[:, :3, :3])
    d = np.sign(np.linalg.det(u @ vt))
    out[:, :3, :3] = u @ (vt * np.stack([np.ones_like(d), np.ones_like(d), d], axis=1)[:, :, None])
    out[:, :3, 3] = poses[:, :3, 3]
    out[:, 3, 3] = 1.0
    return out


def _parameters(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=float).reshape(N_PARAMETERS)


def adaptation_step(
    a,
    estimated_tip: np.ndarray,
    measured_tip: np.ndarray,
    pj: ParameterJacobians,
    settings: AdaptationSettings,
    *,
    step: Step | None = None,
    task_error=None,
    controller: ControllerSettings | None = None,
    vfis: list[StepVFI] = (),
    vfi_share: float = 0.5,
    history: MeasurementHistory | None = None,
    solver: QPSolver | str | None = None,
) -> AdaptationOutput:
    """Parameter rates from one measurement (Eq. 3).

    Parameters
    ----------
    a : ndarray, shape (12,)
        Current estimate.
    estimated_tip : ndarray, shape (4, 4)
        The tip pose the estimate predicts at the measurement's joint configuration.
    measured_tip : ndarray, shape (4, 4)
        The needle sensor's tip pose.
    pj : ParameterJacobians
        At the measurement's configuration, with the estimate.
    settings : AdaptationSettings
    step : Step, optional
        The controller's step; with ``task_error`` it adds the stability row.
    task_error : ndarray, optional
        The controller's current task error.
    controller : ControllerSettings, optional
    vfis : list of StepVFI
        The step's VFIs at the current configuration with their parameter Jacobians.
    vfi_share : float
        The joints' share of each VFI's decay rate (the adaptation takes the rest).
    history : MeasurementHistory, optional
        Keyframes (including this measurement) whose mean squared error the objective
        drives down instead of this measurement's alone.
    solver : QPSolver or str, optional
        The QP solver (an object or a registered name; default DAQP).

    Returns
    -------
    AdaptationOutput
    """
    a = np.asarray(a, dtype=float)
    err, jtj, jte, scale = _objective(a, estimated_tip, measured_tip, pj, settings, history)
    n = N_PARAMETERS
    rows = [v for v in vfis if v.jac_a is not None]
    vfi = np.array(
        [(v.distance, v.safe, (1.0 - vfi_share) * v.gain, v.zone is Zone.OUTSIDE) for v in rows],
        dtype=float,
    ).reshape(-1, 4)
    vjac = np.array([v.jac_a for v in rows], dtype=float).reshape(-1, n)
    return _adaptation_rates(
        a, err, jtj, jte, scale, vfi, vjac, settings, step, task_error, pj, controller, solver
    )


def _adaptation_rates(
    a, err, jtj, jte, scale, vfi, vjac, settings, step, task_error, pj, controller, solver
) -> AdaptationOutput:
    """The rest of :func:`adaptation_step` from the normal equations and the VFI rows
    (``vfi`` (m, 4) and ``vjac`` (m, 12), as
    :func:`~needlekit.control.controller.step_vfi_rows` gives them)."""
    n = N_PARAMETERS
    stab, stab_rhs = _NO_ROW, 0.0
    if step is not None and task_error is not None:
        jx = task_parameter_jacobian(step, pj, controller or ControllerSettings())
        e = np.asarray(task_error, dtype=float)
        stab = (e @ jx).reshape(1, n)
        r2 = settings.stability_radius_mm**2
        stab_rhs = max(0.0, 0.5 * settings.eta * (r2 - float(e @ e)))
    H, f, A, bu, bl, infeasible = _kernels.adaptation_qp(
        jtj, jte, scale, settings.damping**2, 2.0 * settings.eta * scale, vfi, vjac,
        settings.clamp_vfi_rows, stab, stab_rhs, settings.bound_gain, settings.lower,
        settings.upper, a,
    )  # fmt: skip
    sol = CROSSED_BOUNDS if infeasible else get_qp_solver(solver).solve(H, f, A, bu, bl)
    if sol.status is not QPStatus.OPTIMAL:
        log.warning("adaptation QP %s (exit flag %d): a_dot = 0", sol.status.value, sol.exitflag)
        return AdaptationOutput(np.zeros(n), sol.status, err)
    return AdaptationOutput(sol.x, sol.status, err)


def _objective(a, estimated_tip, measured_tip, pj, settings, history) -> tuple:
    """``(y_err, J'J, J'e, scale)`` of the objective: over the keyframes (their mean,
    ``scale = 1 / k``) or the one measurement."""
    s = settings.orientation_scale_mm
    err = measurement_error(estimated_tip, measured_tip, s)
    if history is not None and len(history):
        jtj, jte = history.normal_equations(a, s)
        return err, jtj, jte, 1.0 / len(history)  # the mean over the keyframes
    jac = np.vstack([pj.tip, s * pj.angular])
    return err, jac.T @ jac, jac.T @ err, 1.0


def adaptation_step_rows(
    a, estimated_tip, measured_tip, pj, settings, vfi, vjac, *, step=None, task_error=None,
    controller=None, history=None, solver=None,
) -> AdaptationOutput:  # fmt: skip
    """:func:`adaptation_step` with the VFIs as rows (``vfi`` (m, 4), ``vjac`` (m, 12):
    :func:`~needlekit.control.controller.step_vfi_rows`, the adaptation's share of the
    gains applied), the same arithmetic without building a :class:`StepVFI` per VFI (the
    adaptation job's path).

    Parameters
    ----------
    a, estimated_tip, measured_tip, pj, settings, step, task_error, controller, history, solver
        As :func:`adaptation_step`.
    vfi : ndarray, shape (m, 4)
    vjac : ndarray, shape (m, 12)

    Returns
    -------
    AdaptationOutput
    """
    err, jtj, jte, scale = _objective(a, estimated_tip, measured_tip, pj, settings, history)
    return _adaptation_rates(
        a, err, jtj, jte, scale, vfi, vjac, settings, step, task_error, pj, controller, solver
    )


_NO_ROW = np.zeros((0, N_PARAMETERS))
_NO_VFI = np.zeros((0, 4))
