"""The needle model in minimal coordinates: ``Q_dot = J^-1 mu1 u1 + J^-1 mu2 u2``.

``Q = (x, y, z, phi1, phi2, phi3)``: tip position (world, mm) and three orientation angles
in any of the 24 conventions of :mod:`needlekit.geometry.euler`. The body twist of the
3D bevel-tip model (:mod:`needlekit.needle.bevel3d`) is ``V = mu1 u1 + mu2 u2`` with
``mu1 = (0, 0, 1, kappa, 0, 0)`` and ``mu2 = (0, 0, 0, 0, 0, 1)``, and ``V = J(Q) Q_dot``
with the lecture's::

    J = [[R^T, 0], [0, j_A]],   j_A = R^T T_world(phi) = T_body(phi)

(``R^T`` takes the world velocity of the tip into the tip frame; ``j_A`` takes angle
rates to the body angular velocity). So ``Q_dot = J^-1 V`` with
``J^-1 = [[R, 0], [0, T_body(phi)^-1]]``, singular where the angles are gimbal-locked.
"""

from __future__ import annotations

import numpy as np

from needlekit._validation import as_batch, as_poses, unbatch
from needlekit.geometry.euler import (
    euler_rate_matrix,
    euler_rate_matrix_inv,
    euler_to_matrix,
    matrix_to_euler,
)
from needlekit.needle.bevel3d import body_twist

__all__ = ["needle_jacobian", "pose_from_state", "state_from_pose", "state_rates"]


def state_from_pose(world_T_tip, seq: str):
    """Minimal coordinates ``Q = (x, y, z, phi1, phi2, phi3)`` of tip poses.

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
    seq : str
        Orientation convention (one of the 24, e.g. ``"ZYZ"`` or ``"xyz"``).

    Returns
    -------
    ndarray, shape (6,) or (n, 6)
        Position in mm, angles in rad.
    """
    g, single = as_poses(world_T_tip, "world_T_tip")
    angles = matrix_to_euler(g[:, :3, :3], seq)
    return unbatch(np.concatenate([g[:, :3, 3], angles], axis=1), single)


def pose_from_state(state, seq: str):
    """Tip poses from minimal coordinates ``Q`` (inverse of :func:`state_from_pose`).

    Parameters
    ----------
    state : array_like, shape (6,) or (n, 6)
        ``(x_mm, y_mm, z_mm, phi1_rad, phi2_rad, phi3_rad)``.
    seq : str
        Orientation convention of the angles.

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
    """
    q, single = as_batch(state, "state", (6,))
    out = np.zeros((q.shape[0], 4, 4))
    out[:, :3, :3] = euler_to_matrix(q[:, 3:], seq)
    out[:, :3, 3] = q[:, :3]
    out[:, 3, 3] = 1.0
    return unbatch(out, single)


def needle_jacobian(state, seq: str):
    """The lecture's ``J(Q) = [[R^T, 0], [0, j_A]]`` with ``V_body = J Q_dot``.

    Parameters
    ----------
    state : array_like, shape (6,) or (n, 6)
    seq : str

    Returns
    -------
    ndarray, shape (6, 6) or (n, 6, 6)
    """
    q, single = as_batch(state, "state", (6,))
    rot = euler_to_matrix(q[:, 3:], seq)
    out = np.zeros((q.shape[0], 6, 6))
    out[:, :3, :3] = np.transpose(rot, (0, 2, 1))
    out[:, 3:, 3:] = euler_rate_matrix(q[:, 3:], seq, frame="body")
    return unbatch(out, single)


def state_rates(state, u1_mm_s, u2_rad_s, kappa_per_mm, seq: str):
    """``Q_dot = J^-1 mu1 u1 + J^-1 mu2 u2`` for insertion speed u1 and spin rate u2.

    Parameters
    ----------
    state : array_like, shape (6,) or (n, 6)
        ``(x_mm, y_mm, z_mm, phi1_rad, phi2_rad, phi3_rad)``.
    u1_mm_s, u2_rad_s : float or array_like, shape (n,)
    kappa_per_mm : float
    seq : str
        Orientation convention of the angles.

    Returns
    -------
    ndarray, shape (6,) or (n, 6)
        Position rates (mm/s) and angle rates (rad/s).

    Raises
    ------
    SingularityError
        The angles are at gimbal lock, where ``J`` is singular.

    Examples
    --------
    A straight needle moves along its tip's z axis, the third column of R:

    >>> import numpy as np
    >>> state_rates([0, 0, 0, 0.1, 0.2, 0.3], 1.0, 0.0, 0.0, "ZYX")[:3].round(6)
    array([ 0.218351, -0.275096,  0.936293])
    """
    q, single = as_batch(state, "state", (6,))
    xi = np.atleast_2d(body_twist(u1_mm_s, u2_rad_s, kappa_per_mm))
    n = max(q.shape[0], xi.shape[0])
    q = np.broadcast_to(q, (n, 6))
    xi = np.broadcast_to(xi, (n, 6))
    rot = euler_to_matrix(q[:, 3:], seq)
    t_inv = euler_rate_matrix_inv(q[:, 3:], seq, frame="body")
    out = np.empty((n, 6))
    out[:, :3] = np.einsum("nij,nj->ni", rot, xi[:, :3])
    out[:, 3:] = np.einsum("nij,nj->ni", t_inv, xi[:, 3:])
    return unbatch(out, single and xi.shape[0] == 1)
