"""The 3D bevel-tip needle model: a tip pose in SE(3) driven by insertion and spin.

With insertion speed ``u1`` (mm/s) and spin rate ``u2`` (rad/s) the tip moves with body
twist::

    xi = u1 * (0, 0, 1, kappa, 0, 0) + u2 * (0, 0, 0, 0, 0, 1),   g_dot = g hat(xi)

(the lecture's ``V = mu1 u1 + mu2 u2``). For inputs held constant over a segment the
motion is exactly ``g(t) = g(0) exp(hat(xi) t)``: a circular arc when ``u2 = 0``, a helix
when both act. Spinning in place (``u1 = 0``) turns the bevel and with it the bending
direction, the tip's -y axis (:mod:`needlekit.conventions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_batch, as_poses, unbatch
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import _se3_exp_batch, hat6

__all__ = [
    "BevelTrajectory",
    "body_twist",
    "pose_rate",
    "propagate_bevel",
    "simulate_bevel",
]


def _check_kappa(kappa_per_mm) -> float:
    k = np.asarray(kappa_per_mm, dtype=np.float64)
    if k.ndim != 0 or not np.isfinite(k) or k < 0:
        raise InvalidInputError(
            "kappa_per_mm", f"must be a finite number >= 0, got {kappa_per_mm!r}"
        )
    return float(k)


def body_twist(u1_mm_s, u2_rad_s, kappa_per_mm):
    """Body twist of the tip for insertion speed u1 and spin rate u2.

    Parameters
    ----------
    u1_mm_s, u2_rad_s : float or array_like, shape (n,)
    kappa_per_mm : float

    Returns
    -------
    ndarray, shape (6,) or (n, 6)
        ``(0, 0, u1, kappa u1, 0, u2)`` ordered ``(v, omega)``.

    Examples
    --------
    >>> body_twist(2.0, 0.5, 0.01)
    array([0.  , 0.  , 2.  , 0.02, 0.  , 0.5 ])
    """
    u1 = np.asarray(u1_mm_s, dtype=np.float64)
    u2 = np.asarray(u2_rad_s, dtype=np.float64)
    single = u1.ndim == 0 and u2.ndim == 0
    u1, u2 = np.broadcast_arrays(np.atleast_1d(u1), np.atleast_1d(u2))
    for name, arr in (("u1_mm_s", u1), ("u2_rad_s", u2)):
        if arr.ndim != 1 or not np.all(np.isfinite(arr)):
            raise InvalidInputError(name, "expected finite numbers, shape () or (n,)")
    kappa = _check_kappa(kappa_per_mm)
    out = np.zeros((u1.shape[0], 6))
    out[:, 2] = u1
    out[:, 3] = kappa * u1
    out[:, 5] = u2
    return unbatch(out, single)


def pose_rate(world_T_tip, u1_mm_s, u2_rad_s, kappa_per_mm):
    """``g_dot = g hat(xi)``: the right-hand side of the model as an ODE.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    u1_mm_s, u2_rad_s, kappa_per_mm : float

    Returns
    -------
    ndarray, shape (4, 4)
    """
    g = np.asarray(world_T_tip, dtype=np.float64)
    if g.shape != (4, 4):
        raise InvalidInputError("world_T_tip", f"expected shape (4, 4), got {g.shape}")
    return g @ hat6(body_twist(u1_mm_s, u2_rad_s, kappa_per_mm))


def _check_inputs(inputs) -> np.ndarray:
    seg, _ = as_batch(inputs, "inputs", (3,))
    if np.any(seg[:, 2] < 0):
        raise InvalidInputError("inputs[:, 2] (duration_s)", "durations must be >= 0")
    return seg


def propagate_bevel(world_T_tip, inputs, kappa_per_mm):
    """Exact tip poses after piecewise-constant inputs.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
        Start pose of the tip (world frame, mm).
    inputs : array_like, shape (m, 3)
        One row per segment: ``(u1_mm_s, u2_rad_s, duration_s)``.
    kappa_per_mm : float
        Needle curvature.

    Returns
    -------
    ndarray, shape (m + 1, 4, 4)
        The start pose and the pose at the end of each segment.

    Examples
    --------
    Insert 25 pi mm on a 50 mm radius: a quarter turn toward the tip's -y axis.

    >>> import numpy as np
    >>> g = propagate_bevel(np.eye(4), [[5.0, 0.0, 5 * np.pi]], 1 / 50)
    >>> np.round(g[-1, :3, 3], 9)
    array([  0., -50.,  50.])
    """
    g0, single = as_poses(world_T_tip, "world_T_tip")
    if not single:
        raise InvalidInputError("world_T_tip", "expected one start pose (4, 4)")
    seg = _check_inputs(inputs)
    xi = body_twist(seg[:, 0], seg[:, 1], kappa_per_mm) * seg[:, 2:3]
    steps = _se3_exp_batch(xi)
    out = np.empty((seg.shape[0] + 1, 4, 4))
    out[0] = g0[0]
    for i in range(seg.shape[0]):
        out[i + 1] = out[i] @ steps[i]
    return out


@dataclass(frozen=True)
class BevelTrajectory:
    """Sampled tip trajectory of the 3D model.

    Attributes
    ----------
    time_s : ndarray, shape (k,)
    world_T_tip : ndarray, shape (k, 4, 4)
    """

    time_s: np.ndarray
    world_T_tip: np.ndarray

    @property
    def points_mm(self) -> np.ndarray:
        """Tip positions, shape (k, 3)."""
        return self.world_T_tip[:, :3, 3]


def simulate_bevel(world_T_tip, inputs, kappa_per_mm, *, dt_s: float = 0.01) -> BevelTrajectory:
    """Forward steering in 3D: inputs to the sampled tip trajectory (exact at every sample).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4)
    inputs : array_like, shape (m, 3)
        ``(u1_mm_s, u2_rad_s, duration_s)`` per segment.
    kappa_per_mm : float
    dt_s : float
        Sampling interval; segment ends are always included.

    Returns
    -------
    BevelTrajectory
    """
    g0, single = as_poses(world_T_tip, "world_T_tip")
    if not single:
        raise InvalidInputError("world_T_tip", "expected one start pose (4, 4)")
    seg = _check_inputs(inputs)
    if not (np.isfinite(dt_s) and dt_s > 0):
        raise InvalidInputError("dt_s", f"must be a finite number > 0, got {dt_s}")
    times, poses = [np.zeros(1)], [g0]
    g, t0 = g0[0], 0.0
    for u1, u2, dur in seg:
        n = max(1, int(np.ceil(dur / dt_s - 1e-9)))
        tau = np.linspace(0.0, dur, n + 1)[1:]
        xi = body_twist(u1, u2, kappa_per_mm)
        local = _se3_exp_batch(xi[None, :] * tau[:, None])
        seg_poses = g @ local
        times.append(t0 + tau)
        poses.append(seg_poses)
        g, t0 = seg_poses[-1], t0 + dur
    return BevelTrajectory(np.concatenate(times), np.concatenate(poses))
