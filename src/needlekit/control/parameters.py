"""The uncertain parameters of the arm: base pose and needle-tip pose (12 numbers).

``a = [t_b (3, mm), angles_b (3, rad), t_n (3, mm), angles_n (3, rad)]``:

- ``world_T_base = Trans(t_b) Rot(angles_b)``: the robot base in the EM transmitter frame;
- ``flange_T_tip = Trans(t_n) Rot(angles_n)``: the needle tip in the flange frame.

Rotations use intrinsic x-y-z Euler angles, ``Rot = R_x(a) R_y(b) R_z(c)`` (as the
adaptive-control reference code does); the uncertainty ranges (+-10 deg, +-5 deg) stay far
from gimbal lock. :func:`parameter_jacobians` gives the tip position's, the tip
orientation's (angular velocity) and the link points' derivatives with respect to ``a`` at
a joint configuration: what the adaptation law (Eq. 3) and the VFIs under adaptation need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from needlekit.control.dq import _dq_from_matrix, _dq_to_matrix
from needlekit.control.panda import FLANGE_MM, ArmState, PandaModel
from needlekit.errors import InvalidInputError
from needlekit.geometry.euler import matrix_to_euler

__all__ = [
    "N_PARAMETERS",
    "ParameterJacobians",
    "model_from_parameters",
    "parameter_jacobians",
    "parameters_from_model",
    "pose_from_parameters",
    "xyz_euler_rate_matrix",
]

#: Base pose (6) and needle-tip pose (6).
N_PARAMETERS = 12


@nb.njit(cache=True)
def _xyz_matrix(a, b, c):
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    r = np.empty((3, 3))
    r[0, 0], r[0, 1], r[0, 2] = cb * cc, -cb * sc, sb
    r[1, 0] = sa * sb * cc + ca * sc
    r[1, 1] = -sa * sb * sc + ca * cc
    r[1, 2] = -sa * cb
    r[2, 0] = -ca * sb * cc + sa * sc
    r[2, 1] = ca * sb * sc + sa * cc
    r[2, 2] = ca * cb
    return r


@nb.njit(cache=True)
def _xyz_rate(a, b):
    # omega = e_x a_dot + R_x e_y b_dot + R_x R_y e_z c_dot
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    w = np.zeros((3, 3))
    w[0, 0], w[0, 2] = 1.0, sb
    w[1, 1], w[1, 2] = ca, -sa * cb
    w[2, 1], w[2, 2] = sa, ca * cb
    return w


def _skew(v) -> np.ndarray:
    """``[v]x`` with ``[v]x w = v x w`` (numpy's cross is slow on tiny arrays)."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def xyz_euler_rate_matrix(angles) -> np.ndarray:
    """``W`` with ``omega = W angles_dot`` for ``R = R_x R_y R_z`` (omega in the frame ``R``
    is expressed in); closed form, equal to
    ``needlekit.geometry.euler.euler_rate_matrix(angles, "XYZ")``.

    Parameters
    ----------
    angles : array_like, shape (3,)

    Returns
    -------
    ndarray, shape (3, 3)
    """
    a = np.asarray(angles, dtype=float).reshape(3)
    return _xyz_rate(a[0], a[1])


def pose_from_parameters(p6) -> np.ndarray:
    """``Trans(t) Rot(angles)`` from ``[t (3, mm), angles (3, rad)]``.

    Parameters
    ----------
    p6 : array_like, shape (6,)

    Returns
    -------
    ndarray, shape (4, 4)

    Examples
    --------
    >>> g = pose_from_parameters([1.0, 2.0, 3.0, 0.0, 0.0, np.pi / 2])
    >>> np.round(g[:3, :3] @ [1.0, 0.0, 0.0], 12).tolist(), g[:3, 3].tolist()
    ([0.0, 1.0, 0.0], [1.0, 2.0, 3.0])
    """
    p = np.asarray(p6, dtype=float).reshape(6)
    g = np.eye(4)
    g[:3, :3] = _xyz_matrix(p[3], p[4], p[5])
    g[:3, 3] = p[:3]
    return g


def _params_from_pose(g: np.ndarray) -> np.ndarray:
    return np.concatenate([g[:3, 3], matrix_to_euler(g[:3, :3], "XYZ")])


def parameters_from_model(model: PandaModel) -> np.ndarray:
    """The 12 parameters of a model's base and needle.

    Parameters
    ----------
    model : PandaModel

    Returns
    -------
    ndarray, shape (12,)
    """
    return np.concatenate(
        [_params_from_pose(model.world_T_base), _params_from_pose(model.flange_T_tip)]
    )


def model_from_parameters(model: PandaModel, a) -> PandaModel:
    """``model`` with its base and needle set from the parameters.

    Parameters
    ----------
    model : PandaModel
    a : array_like, shape (12,)

    Returns
    -------
    PandaModel
    """
    a = np.ascontiguousarray(a, dtype=float).reshape(-1)
    if a.shape != (N_PARAMETERS,) or not np.isfinite(a).all():
        raise InvalidInputError("parameters", f"expected {N_PARAMETERS} finite numbers")
    return model._with_poses_unchecked(*_model_transforms(a, FLANGE_MM))


@nb.njit(cache=True)
def _model_transforms(a, flange_mm):
    """``world_T_base``, ``flange_T_tip`` and their dual quaternions as
    :meth:`PandaModel._with_poses_unchecked` builds them (the tool's includes the flange)."""
    base = np.eye(4)
    base[:3, :3] = _xyz_matrix(a[3], a[4], a[5])
    base[:3, 3] = a[:3]
    tip = np.eye(4)
    tip[:3, :3] = _xyz_matrix(a[9], a[10], a[11])
    tip[:3, 3] = a[6:9]
    tool = tip.copy()  # Trans(0, 0, flange) @ flange_T_tip: row 2 gains flange times row 3
    for c in range(4):
        tool[2, c] = tip[2, c] + flange_mm * tip[3, c]
    return base, tip, _dq_from_matrix(base), _dq_from_matrix(tool)


@dataclass(frozen=True)
class ParameterJacobians:
    """Derivatives of the arm's task quantities with respect to the 12 parameters.

    Attributes
    ----------
    tip : ndarray, shape (3, 12)
        ``d tip_mm / dt = tip @ a_dot``.
    angular : ndarray, shape (3, 12)
        Angular velocity of the tip frame (world) per parameter rate.
    axis : ndarray, shape (3, 12)
        ``d needle_axis / dt = axis @ a_dot``.
    base_rate : ndarray, shape (3, 3)
        ``W_b``: the base's angular velocity per rate of its Euler angles.
    """

    tip: np.ndarray
    angular: np.ndarray
    axis: np.ndarray
    base_rate: np.ndarray

    def point(self, state: ArmState, a, k: int) -> np.ndarray:
        """Jacobian of link-frame origin ``k`` (it depends on the base only).

        Parameters
        ----------
        state : ArmState
        a : ndarray, shape (12,)
        k : int

        Returns
        -------
        ndarray, shape (3, 12)
        """
        jac = np.zeros((3, N_PARAMETERS))
        jac[:, :3] = np.eye(3)
        jac[:, 3:6] = -_skew(state.origins[k] - a[:3]) @ self.base_rate
        return jac


def parameter_jacobians(model: PandaModel, state: ArmState, a) -> ParameterJacobians:
    """Tip position, orientation and axis derivatives with respect to the parameters.

    Parameters
    ----------
    model : PandaModel
        The model built from ``a`` (:func:`model_from_parameters`).
    state : ArmState
        ``model.state(q)``.
    a : array_like, shape (12,)

    Returns
    -------
    ParameterJacobians
    """
    a = np.ascontiguousarray(a, dtype=float)
    tip, ang, axis, wb = _parameter_jacobians(
        state.tip_dq, state.tip_mm, state.needle_axis, model.flange_T_tip, a
    )
    return ParameterJacobians(tip, ang, axis, wb)


@nb.njit(cache=True)
def _neg_skew_times(v, m):
    """``-[v]x m`` for a (3, k) ``m``."""
    out = np.empty((3, m.shape[1]))
    for c in range(m.shape[1]):
        out[0, c] = -0.0 * m[0, c] + v[2] * m[1, c] + -v[1] * m[2, c]
        out[1, c] = -v[2] * m[0, c] + -0.0 * m[1, c] + v[0] * m[2, c]
        out[2, c] = v[1] * m[0, c] + -v[0] * m[1, c] + -0.0 * m[2, c]
    return out


@nb.njit(cache=True)
def _parameter_jacobians(tip_dq, tip_mm, needle_axis, flange_T_tip, a):
    wb = _xyz_rate(a[3], a[4])
    # world_T_flange = world_T_tip * tip_T_flange
    r_tip = _dq_to_matrix(tip_dq)
    r_flange = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            r_flange[r, c] = (
                r_tip[r, 0] * flange_T_tip[c, 0]
                + r_tip[r, 1] * flange_T_tip[c, 1]
                + r_tip[r, 2] * flange_T_tip[c, 2]
            )
    tip = np.zeros((3, N_PARAMETERS))
    ang = np.zeros((3, N_PARAMETERS))
    rel = np.empty(3)
    for r in range(3):
        rel[r] = tip_mm[r] - a[r]
    tip[:, 3:6] = _neg_skew_times(rel, wb)  # (W_b e_c) x r = -[r]x W_b e_c
    wn = _xyz_rate(a[9], a[10])
    for r in range(3):
        tip[r, r] = 1.0
        for c in range(3):
            ang[r, 3 + c] = wb[r, c]
            tip[r, 6 + c] = r_flange[r, c]  # t_n is expressed in the flange frame
            ang[r, 9 + c] = (
                r_flange[r, 0] * wn[0, c] + r_flange[r, 1] * wn[1, c] + r_flange[r, 2] * wn[2, c]
            )
    return tip, ang, _neg_skew_times(needle_axis, ang), wb
