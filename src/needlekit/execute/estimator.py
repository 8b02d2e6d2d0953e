"""The tip pose estimated from delayed, noisy EM samples: a Kalman filter on SE(3).

State: the tip pose ``(p, R)``. Error: ``p = p_hat + dp`` and ``R = exp(phi^) R_hat``
(world frame), six numbers with covariance ``P``. Between samples the filter moves the
estimate as the planner's model says the commanded motion moves the tip (a spin, then
an arc of the commanded curvature); the error then grows as

    dp' = dp - [R_hat a]x phi,    phi' = phi,

``a`` the step's translation in the tip frame, plus the process noise: the orientation
noise of :class:`~needlekit.execute.needle_sim.ExecutionNoise`, the curvature's spread
(a rotation about the tip's x axis) and the tissue's push (a translation), each per step.
The last two are biases of one insertion that a white process noise stands in for;
``bias_scale`` widens them (default 3), so that the filter does not grow overconfident
over a long insertion.

A sample (:class:`needlekit.control.em.EMSample`) is taken ``latency_s`` before it
arrives: the filter goes back to the estimate of the moment it was taken (it keeps the
steps of the last half second), corrects it, and replays the steps since. The update is
the standard one with ``H = I`` on the innovation ``(z_p - p_hat, log(z_R R_hat^T))``,
the covariance in Joseph form.

**The tilt is not the heading.** The filter's pose is the frame its model moves along
``z``. A needle that bends by mechanics does not travel where its tip points (a pre-bent
tip in soft tissue points up to 19 degrees further into its bend than it goes, for tens of
millimetres: :mod:`needlekit.execute.calibration`). With ``tilt_sigma_rad`` the measured
tilt (the rotation about the tip's own x and y axes) is taken with that much more noise,
``R_meas`` plus ``R diag(s^2, s^2, 0) R^T`` at the estimate's orientation ``R``; the roll
about the axis keeps the sensor's. The heading is then learnt from where the tip goes (the
positions, through the covariance), and a slip that lasts cannot steer the path by it.
``axis_slip_rad`` is the slip itself: a restart from an image (:meth:`TipEstimator.reseed`)
doubts the image's tilt by that much.
"""

from __future__ import annotations

import math
from collections import deque

import numba
import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.needle_sim import ExecutionNoise
from needlekit.geometry.arcs import arc_end_unchecked
from needlekit.geometry.so3 import hat_unchecked, so3_exp_unchecked, so3_log_unchecked

_EYE3 = np.eye(3)
_EYE3.flags.writeable = False

__all__ = ["TipEstimator", "estimator_arguments", "kalman_estimator"]

#: How much of the past the filter keeps to place a late sample (s).
HISTORY_S: float = 0.5

#: A sample taken this close (s) to a step's start was taken at it: a timestamp that
#: crossed the wire as seconds since the epoch (OpenIGTLink) keeps about 0.2 us of them, and
#: a sample placed one step late meets that step's spin as an orientation error.
TIME_TOL_S: float = 1e-6


@numba.njit(cache=True)
def _gain(S, P, y):  # pragma: no cover (compiled)
    """The Kalman gain ``K = P S^-1`` and the squared Mahalanobis distance ``y^T S^-1 y``,
    by one Cholesky factorisation of the 6x6 ``S`` (symmetric positive definite); ``ok``
    False when it is not (the caller then solves by LU)."""
    L = np.zeros((6, 6))
    for i in range(6):
        for j in range(i + 1):
            acc = S[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            if i == j:
                if not acc > 0.0:
                    return np.zeros((6, 6)), 0.0, False
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    X = np.empty((6, 7))
    for c in range(7):
        for i in range(6):
            acc = P[i, c] if c < 6 else y[i]
            for k in range(i):
                acc -= L[i, k] * X[k, c]
            X[i, c] = acc / L[i, i]
        for i in range(5, -1, -1):
            acc = X[i, c]
            for k in range(i + 1, 6):
                acc -= L[k, i] * X[k, c]
            X[i, c] = acc / L[i, i]
    d2 = 0.0
    for i in range(6):
        d2 += y[i] * X[i, 6]
    return X[:, :6].T.copy(), d2, True


def _tilt_block(rot: np.ndarray, var: float) -> np.ndarray:
    """World-frame covariance of rotations about the tip's own x and y axes, each of
    variance ``var``: ``R diag(var, var, 0) R^T``."""
    xy = rot[:, :2]
    return var * (xy @ xy.T)


class TipEstimator:
    """A Kalman filter on the tip pose (see the module notes).

    Parameters
    ----------
    start_pose : ndarray, shape (4, 4)
        The tip where the insertion starts, as the robot placed it.
    start_sigma_mm, start_sigma_rad : float
        How well that is known (SD of position and orientation).
    r_min_mm : float
        The needle's nominal radius (the model the filter predicts with).
    noise : ExecutionNoise
        What the filter assumes of the needle.
    position_sigma_mm, orientation_sigma_rad : float
        The sensor's noise.
    bias_scale : float
        Widens the curvature's and the tissue's share of the process noise.
    tilt_sigma_rad : float
        Added SD of a measured tilt (module notes; default 0: the sensor's alone).
    axis_slip_rad : float
        SD of the tip's axis off its travel (a restart's doubt of an image's tilt).
    """

    def __init__(
        self,
        start_pose,
        *,
        start_sigma_mm: float,
        start_sigma_rad: float,
        r_min_mm: float,
        noise: ExecutionNoise,
        position_sigma_mm: float,
        orientation_sigma_rad: float,
        bias_scale: float = 3.0,
        tilt_sigma_rad: float = 0.0,
        axis_slip_rad: float = 0.0,
    ) -> None:
        g = np.asarray(start_pose, dtype=np.float64)
        for name, value in (("tilt_sigma_rad", tilt_sigma_rad), ("axis_slip_rad", axis_slip_rad)):
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidInputError(name, f"expected a finite number >= 0, got {value!r}")
        if g.shape != (4, 4) or not np.all(np.isfinite(g)):
            raise InvalidInputError("start_pose", "expected a 4x4 matrix of finite numbers")
        self.pose = np.ascontiguousarray(g.copy())
        self.P = np.diag([start_sigma_mm**2] * 3 + [start_sigma_rad**2] * 3)
        self.r_min_mm = float(r_min_mm)
        self.noise = noise
        self.bias_scale = float(bias_scale)
        self.R_meas = np.diag([position_sigma_mm**2] * 3 + [orientation_sigma_rad**2] * 3)
        self.tilt_var = float(tilt_sigma_rad) ** 2
        self.slip_var = float(axis_slip_rad) ** 2
        self.t = 0.0
        self._steps: deque = deque()  # (t before, pose before, P before, command)
        self.n_updates = 0
        self.last_d2 = 0.0  # the latest sample's squared Mahalanobis distance

    def _propagate(self, pose, P, command):
        spin, kappa, ds, _, shift, _ = command
        new = arc_end_unchecked(pose, spin, kappa, ds)
        a = new[:3, 3] - pose[:3, 3]
        if shift is not None:  # a translation of the whole needle (the robot, the tissue)
            new[:3, 3] += shift
        F = np.eye(6)
        F[:3, 3:] = -hat_unchecked(a)
        return new, F @ P @ F.T + self._process_noise(new, command)

    def _process_noise(self, new, command) -> np.ndarray:
        """The process noise ``Q`` of one commanded step ending at ``new``."""
        _, kappa, ds, dt, _, shift_sigma = command
        n = self.noise
        # the needle turns by noise only while it is inserted
        q_rot = (n.orientation_sigma_rad**2) * dt / n.reference_interval_s if ds > 0 else 0.0
        spread = kappa * n.radius_sigma_mm / self.r_min_mm * ds * self.bias_scale
        x = new[:3, 0]
        Q = np.zeros((6, 6))
        # np.eye(3) and np.outer's products, without making the identity or raveling anew
        # each step: the same values
        Q[:3, :3] = _EYE3 * ((n.deflection_sigma * ds * self.bias_scale) ** 2 + shift_sigma**2)
        Q[3:, 3:] = _EYE3 * q_rot + (x[:, None] * x[None, :]) * spread**2
        return Q

    def predict(
        self,
        spin_rad: float,
        kappa_per_mm: float,
        ds_mm: float,
        dt_s: float,
        shift_mm=None,
        shift_sigma_mm: float = 0.0,
    ) -> None:
        """Move the estimate as the model moves the tip for one commanded step.

        Parameters
        ----------
        spin_rad, kappa_per_mm, ds_mm, dt_s : float
            The command (as :meth:`SimulatedNeedle.step` takes it).
        shift_mm : array_like, shape (3,), optional
            A translation of the whole needle during the step, known to the controller
            (the robot following the breathing, or the tissue carrying a needle let go).
        shift_sigma_mm : float
            SD per axis of what is not known of that translation.

        Returns
        -------
        None
        """
        shift = None if shift_mm is None else np.asarray(shift_mm, dtype=np.float64)
        command = (float(spin_rad), float(kappa_per_mm), float(ds_mm), float(dt_s), shift,
                   float(shift_sigma_mm))  # fmt: skip
        self._steps.append((self.t, self.pose, self.P, command))
        while self._steps and self._steps[0][0] < self.t - HISTORY_S:
            self._steps.popleft()
        self.pose, self.P = self._propagate(self.pose, self.P, command)
        self.t += dt_s

    def update(self, taken_s: float, measured_pose, gate_d2: float | None = None) -> bool:
        """Correct the estimate with a sample taken at ``taken_s`` (now or earlier).

        Parameters
        ----------
        taken_s : float
            When the sample was taken (the filter's clock: seconds of commanded steps).
        measured_pose : ndarray, shape (4, 4)
        gate_d2 : float, optional
            The innovation gate: a sample whose squared Mahalanobis distance
            ``y^T S^-1 y`` exceeds it is refused and leaves the estimate as it was.

        Returns
        -------
        bool
            Whether the sample was used (False: refused by the gate).
        """
        z = np.asarray(measured_pose, dtype=np.float64)
        # the estimate of the moment the sample was taken: after every step begun before it
        replay = [s for s in self._steps if s[0] >= taken_s - TIME_TOL_S]
        if replay:
            _, pose, P, _ = replay[0]
        else:
            pose, P = self.pose, self.P
        # the sample passed the sensor guard (a proper rotation) and the estimate stays one
        # (composed with exponentials): the log of their difference needs no check
        y = np.concatenate(
            [z[:3, 3] - pose[:3, 3], so3_log_unchecked(z[:3, :3] @ pose[:3, :3].T)]
        )
        R_meas = self.R_meas
        if self.tilt_var > 0.0:  # the tilt about the tip's own x and y: the slip's doubt
            R_meas = R_meas.copy()
            R_meas[3:, 3:] += _tilt_block(pose[:3, :3], self.tilt_var)
        S = P + R_meas
        K, d2, ok = _gain(S, P, y)
        if not ok:  # S not positive definite in floating point: LU
            sol = np.linalg.solve(S, np.column_stack((P, y)))
            K, d2 = sol[:, :6].T, float(y @ sol[:, 6])
        self.last_d2 = float(d2)
        if gate_d2 is not None and not self.last_d2 <= gate_d2:  # NaN is refused too
            return False
        dx = K @ y
        pose = pose.copy()
        pose[:3, 3] += dx[:3]
        pose[:3, :3] = so3_exp_unchecked(dx[3:]) @ pose[:3, :3]
        pose = np.ascontiguousarray(pose)
        A = np.eye(6) - K
        P = A @ P @ A.T + K @ R_meas @ K.T
        # replay the steps since, from the corrected estimate (and rewrite their history)
        kept = deque(s for s in self._steps if s[0] < taken_s - TIME_TOL_S)
        for t0, _, _, command in replay:
            kept.append((t0, pose, P, command))
            pose, P = self._propagate(pose, P, command)
        self._steps = kept
        self.pose, self.P = pose, P
        self.n_updates += 1
        return True

    def reseed(self, pose, position_sigma_mm: float, orientation_sigma_rad: float) -> None:
        """Start again from ``pose`` (an independent fix of the tip, such as an image),
        its uncertainty that of the fix; the history of steps is dropped.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        position_sigma_mm, orientation_sigma_rad : float

        Returns
        -------
        None
        """
        self.pose = np.ascontiguousarray(np.asarray(pose, dtype=np.float64).copy())
        self.P = np.diag([position_sigma_mm**2] * 3 + [orientation_sigma_rad**2] * 3)
        if self.slip_var > 0.0:  # the image shows the tip's axis, not its travel
            self.P[3:, 3:] += _tilt_block(self.pose[:3, :3], self.slip_var)
        self._steps.clear()

    @property
    def position_sigma_mm(self) -> float:
        """The estimate's position uncertainty: the root of the mean variance per axis.

        Returns
        -------
        float
        """
        return math.sqrt(float(np.trace(self.P[:3, :3])) / 3.0)


def estimator_arguments(setup) -> dict:
    """The filter's arguments from a run's setup: it starts where the robot placed the
    tip, as well known as the sensor measures it, and assumes the run's noise and sensor.

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    dict
        Keyword arguments of :class:`TipEstimator` (and of the other estimators).
    """
    s = setup.settings
    sensor = s.sensor
    out = {
        "start_sigma_mm": sensor.position_sigma_mm,
        "start_sigma_rad": math.radians(sensor.orientation_sigma_deg),
        "r_min_mm": setup.r_min_mm,
        "noise": s.noise,
        "position_sigma_mm": sensor.position_sigma_mm,
        "orientation_sigma_rad": math.radians(sensor.orientation_sigma_deg),
    }
    model = s.model  # a calibrated model knows how far the tip's axis leaves its travel
    if model is not None and model.axis_slip_rad > 0.0:
        out["tilt_sigma_rad"] = model.tilt_sigma_rad(s.insertion_speed_mm_s / sensor.rate_hz)
        out["axis_slip_rad"] = model.axis_slip_rad
    return out


def kalman_estimator(setup) -> TipEstimator:
    """The ``kalman`` estimator (:data:`needlekit.execute.plugins.ESTIMATORS`).

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    TipEstimator
    """
    return TipEstimator(setup.start_pose, **estimator_arguments(setup))


kalman_estimator.parameters = lambda settings: {"bias_scale": 3.0, "history_s": HISTORY_S}
