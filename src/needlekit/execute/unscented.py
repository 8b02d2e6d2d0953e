"""The ``unscented`` estimator: the tip pose by an unscented Kalman filter on SE(3).

The Kalman filter of :mod:`needlekit.execute.estimator` carries the error's covariance
through a commanded step by the model's Jacobian, ``dp' = dp - [R_hat a]x phi``: first
order in the orientation error ``phi``. Over a long step with an uncertain heading the true
map is not linear: a tip turned by ``phi`` ends at ``p + exp(phi^) R_hat a``, whose mean lies
short of ``p + R_hat a`` by about ``sigma^2 |a|`` (the arc swings on a circle). The unscented
transform (Julier and Uhlmann 2004) carries ``2n + 1`` sigma poses instead: the estimate and
the estimate moved by each column of ``+-sqrt(n + lambda) L`` (``L L^T = P``, ``n = 6``) in
the filter's error coordinates (``p + dp``, ``exp(phi^) R``), each through the planner's arc
model (:func:`~needlekit.geometry.arcs.arc_end_unchecked`); the propagated poses' errors
about the nominal end give the new mean, which recentres the estimate, and the new
covariance, plus the Kalman filter's process noise. ``alpha = 1``, ``beta = 2``,
``kappa = 0``: ``lambda = 0``, mean weights ``0`` and ``1 / 2n``, the centre's covariance
weight ``2``. Where the map is linear (no orientation uncertainty) it gives the Kalman
filter's covariance exactly.

The measurement is the pose itself (``H = I`` in the error coordinates), linear, so the
update is the Kalman filter's; so are the delayed samples (the steps since a sample was
taken are replayed from the corrected estimate, through the unscented prediction) and the
innovation gate.
"""

from __future__ import annotations

import numpy as np

from needlekit.execute.estimator import TipEstimator, estimator_arguments
from needlekit.geometry.arcs import arc_end_unchecked
from needlekit.geometry.so3 import so3_exp, so3_exp_unchecked, so3_log

__all__ = ["UnscentedTipEstimator", "unscented_estimator"]

#: The sigma points' spread: ``n + lambda`` with ``alpha = 1, kappa = 0`` (``lambda = 0``).
_N = 6
_SPREAD = float(_N)
#: Weights: the mean's (centre, others) and the covariance's centre (``+ 1 - alpha^2 + beta``).
_WM = np.array([0.0] + [1.0 / (2 * _N)] * (2 * _N))
_WC = _WM.copy()
_WC[0] = 2.0


class UnscentedTipEstimator(TipEstimator):
    """An unscented Kalman filter on the tip pose (see the module notes); the parameters,
    attributes and methods of :class:`~needlekit.execute.estimator.TipEstimator`.

    Attributes
    ----------
    last_mean_shift : ndarray, shape (6,)
        The latest prediction's mean error (position mm, rotation rad) by which the
        nominal end was recentred.
    """

    last_mean_shift = np.zeros(6)

    def _propagate(self, pose, P, command):
        spin, kappa, ds, _, shift, _ = command
        new = arc_end_unchecked(pose, spin, kappa, ds)
        if shift is not None:
            new[:3, 3] += shift
        Q = self._process_noise(new, command)
        try:
            L = np.linalg.cholesky(_SPREAD * P)
        except np.linalg.LinAlgError:  # P semi-definite in floating point: its square root
            w, V = np.linalg.eigh(0.5 * (P + P.T))
            L = V * np.sqrt(np.clip(_SPREAD * w, 0.0, None))
        cols = np.concatenate([np.zeros((1, _N)), L.T, -L.T])  # the sigma errors, by row
        turns = so3_exp(cols[:, 3:])
        errors = np.empty((2 * _N + 1, _N))
        rot_new_t = new[:3, :3].T
        ends = np.empty((2 * _N + 1, 3, 3))
        for i in range(2 * _N + 1):
            g = pose.copy()
            g[:3, 3] += cols[i, :3]
            g[:3, :3] = turns[i] @ pose[:3, :3]
            end = arc_end_unchecked(np.ascontiguousarray(g), spin, kappa, ds)
            errors[i, :3] = end[:3, 3] + (0.0 if shift is None else shift) - new[:3, 3]
            ends[i] = end[:3, :3] @ rot_new_t
        errors[:, 3:] = so3_log(ends)
        mean = _WM @ errors
        d = errors - mean
        cov = (d.T * _WC) @ d + Q
        new[:3, 3] += mean[:3]
        new[:3, :3] = so3_exp_unchecked(mean[3:]) @ new[:3, :3]
        self.last_mean_shift = mean
        return np.ascontiguousarray(new), 0.5 * (cov + cov.T)


def unscented_estimator(setup) -> UnscentedTipEstimator:
    """The ``unscented`` estimator (:data:`needlekit.execute.plugins.ESTIMATORS`).

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    UnscentedTipEstimator
    """
    return UnscentedTipEstimator(setup.start_pose, **estimator_arguments(setup))


unscented_estimator.parameters = lambda settings: {
    "bias_scale": 3.0, "alpha": 1.0, "beta": 2.0, "kappa": 0.0,
}  # fmt: skip
