"""The adaptation law (Tang et al.'s Eq. 3): estimate the base and needle-tip poses online.

Each new needle-sensor measurement ``y`` (the tip pose in the transmitter frame, taken at a
known joint configuration) updates the 12 parameters ``a`` (:mod:`.parameters`) with the
rate that solves

    min ||J_y,a a_dot + eta_a y_err||^2 + lambda_a^2 ||a_dot||^2
    s.t.  VFI rows in a,   parameter bounds,   x_err^T J_x,a a_dot <= 0

- ``y_err = [p_est - p_meas; s * log(R_est R_meas^T)]``: the estimated minus the measured
  tip position, and the rotation between them weighted by ``s`` mm/rad;
- the VFI rows: the step's VFIs with their parameter Jacobians and the remaining share of
  their decay rate (the joints take ``vfi_share``), so the *estimated* distances obey the
  VFIs under the joint action of the robot's motion and the adaptation;
- the stability row: the adaptation never increases the controller's task error;
- the bounds keep ``a`` inside the uncertainty box.

An infeasible QP gives ``a_dot = 0`` and a logged warning (``a_dot = 0`` satisfies the
stability row, so infeasibility means the estimate already violates a VFI, e.g. after a
noisy measurement).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from needlekit.control.controller import (
    ControllerSettings,
    Step,
    StepVFI,
    task_parameter_jacobian,
)
from needlekit.control.parameters import N_PARAMETERS, ParameterJacobians
from needlekit.control.qp import QPStatus, solve_qp
from needlekit.control.vfi import vfi_row
from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import so3_log

__all__ = ["AdaptationOutput", "AdaptationSettings", "adaptation_step", "measurement_error"]

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
    """

    lower: np.ndarray
    upper: np.ndarray
    eta: float = 2.0
    damping: float = 1e-2
    orientation_scale_mm: float = 100.0
    bound_gain: float = 10.0

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
    dp = estimated_tip[:3, 3] - measured_tip[:3, 3]
    dr = so3_log(estimated_tip[:3, :3] @ measured_tip[:3, :3].T)
    return np.concatenate([dp, orientation_scale_mm * dr])


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

    Returns
    -------
    AdaptationOutput
    """
    a = np.asarray(a, dtype=float)
    s = settings.orientation_scale_mm
    err = measurement_error(estimated_tip, measured_tip, s)
    jac = np.vstack([pj.tip, s * pj.angular])
    n = N_PARAMETERS
    H = 2.0 * (jac.T @ jac + settings.damping**2 * np.eye(n))
    f = 2.0 * settings.eta * jac.T @ err
    rows, rhs = [], []
    for v in vfis:
        if v.jac_a is None:
            continue
        r, b = vfi_row(v.distance, v.jac_a, v.safe, v.zone, (1.0 - vfi_share) * v.gain)
        rows.append(r)
        rhs.append(b)
    if step is not None and task_error is not None:
        jx = task_parameter_jacobian(step, pj, controller or ControllerSettings())
        rows.append(np.asarray(task_error) @ jx)
        rhs.append(0.0)
    lower = settings.bound_gain * (settings.lower - a)
    upper = settings.bound_gain * (settings.upper - a)
    A = np.array(rows).reshape(-1, n)
    sol = solve_qp(H, f, A, np.array(rhs), lower, upper, check=False)
    if sol.status is not QPStatus.OPTIMAL:
        log.warning("adaptation QP %s (exit flag %d): a_dot = 0", sol.status.value, sol.exitflag)
        return AdaptationOutput(np.zeros(n), sol.status, err)
    return AdaptationOutput(sol.x, sol.status, err)
