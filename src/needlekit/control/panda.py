"""The Franka Emika Panda with a needle on its flange: dual-quaternion kinematics.

The arm is the modified Denavit-Hartenberg chain of ``dqrobotics``'s Panda model (link
transform ``rot_x(alpha) trans_x(a) rot_z(theta + q) trans_z(d)``), in mm, with the
Panda's own joint limits (the issue's, from Franka's datasheet; ``dqrobotics`` ships
others) and an explicit base: ``world_T_tip = world_T_base * chain(q) * flange *
flange_T_tip``. The world frame is the EM transmitter's. The needle tip frame's z axis is
the insertion direction (``needlekit.conventions``).

:func:`chain_kinematics` is a numba kernel that returns, in one pass, the tip pose as a
dual quaternion, its 8 x 7 pose Jacobian (``vec8(x_dot) = J q_dot``, dqrobotics'
definition) and every joint axis (direction and point), from which the translation and
needle-axis Jacobians follow. ``dqrobotics`` is its test oracle.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from needlekit.control.dq import _dq_to_matrix, _qmul, dq_from_matrix, dq_mul
from needlekit.errors import InvalidInputError

__all__ = [
    "FLANGE_MM",
    "PANDA_MDH_MM",
    "Q_DOT_MAX",
    "Q_MAX",
    "Q_MIN",
    "ArmState",
    "PandaModel",
    "chain_kinematics",
]

#: MDH table of the Panda (rows theta, d, a, alpha; mm and rad), as in dqrobotics 26.4.0a7.
PANDA_MDH_MM = np.array(
    [
        [0.0] * 7,
        [333.0, 0.0, 316.0, 0.0, 384.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 82.5, -82.5, 0.0, 88.0],
        [0.0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2],
    ]
)
#: Flange offset along the last joint's z axis (mm).
FLANGE_MM = 107.0
#: Panda joint limits (rad and rad/s), Franka's datasheet (the issue's values).
Q_MIN = np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973])
Q_MAX = np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
Q_DOT_MAX = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61])


@nb.njit(cache=True)
def _all_finite(q):
    finite = True
    for i in range(q.shape[0]):
        finite = finite and np.isfinite(q[i])
    return finite


@nb.njit(cache=True)
def _joint_frame(x, step, mdh, q, i):
    """``x rot_x(alpha_i) trans_x(a_i) rot_z(theta_i + q_i)``: the frame joint ``i``
    turns (``step``: scratch, shape (8,))."""
    th, a, al = mdh[0, i] + q[i], mdh[2, i], mdh[3, i]
    ca, sa = np.cos(0.5 * al), np.sin(0.5 * al)
    step[:] = 0.0
    step[0], step[1] = ca, sa
    step[4], step[5] = -0.5 * a * sa, 0.5 * a * ca
    x = dq_mul(x, step)
    ct, st = np.cos(0.5 * th), np.sin(0.5 * th)
    step[:] = 0.0
    step[0], step[3] = ct, st
    return dq_mul(x, step)


@nb.njit(cache=True)
def _along_joint(x, step, mdh, i):
    """``x trans_z(d_i)``: on to the next link."""
    step[:] = 0.0
    step[0], step[7] = 1.0, 0.5 * mdh[1, i]
    return dq_mul(x, step)


@nb.njit(cache=True)
def _tip_matrix(q, mdh, base, tool):
    """The tip pose of :func:`chain_kinematics` (the same products, in the same order) as a
    4x4 matrix, without the Jacobian and axes; and whether ``q`` is finite."""
    finite = _all_finite(q)
    x = base.copy()
    step = np.zeros(8)
    for i in range(q.shape[0]):
        x = _along_joint(_joint_frame(x, step, mdh, q, i), step, mdh, i)
    return _dq_to_matrix(dq_mul(x, tool)), finite


@nb.njit(cache=True)
def chain_kinematics(q, mdh, base, tool):
    """Tip pose, pose Jacobian and joint axes of ``base * MDH chain(q) * tool``.

    Parameters
    ----------
    q : ndarray, shape (n,)
        Joint angles (rad).
    mdh : ndarray, shape (4, n)
        Rows theta, d (mm), a (mm), alpha.
    base, tool : ndarray, shape (8,)
        ``world_T_base`` and ``last-link_T_tip`` as unit dual quaternions.

    Returns
    -------
    x : ndarray, shape (8,)
        Tip pose.
    jac : ndarray, shape (8, n)
        Pose Jacobian, ``vec8(x_dot) = jac q_dot``.
    axes : ndarray, shape (n, 3)
        Unit direction of each joint axis (world).
    origins : ndarray, shape (n + 1, 3)
        A point on each joint axis (the origin of the frame it turns), then the last link's
        frame origin (mm, world).
    """
    n = q.shape[0]
    axes = np.empty((n, 3))
    origins = np.empty((n + 1, 3))
    lines = np.empty((n, 8))
    x = base.copy()
    step = np.zeros(8)
    for i in range(n):
        x = _joint_frame(x, step, mdh, q, i)  # the frame joint i turns
        r0, r1, r2, r3 = x[0], x[1], x[2], x[3]
        # axis direction r k r*, origin 2 d r*
        p = _qmul(r0, r1, r2, r3, 0.0, 0.0, 0.0, 1.0)
        z = _qmul(p[0], p[1], p[2], p[3], r0, -r1, -r2, -r3)
        o = _qmul(x[4], x[5], x[6], x[7], r0, -r1, -r2, -r3)
        axes[i, 0], axes[i, 1], axes[i, 2] = z[1], z[2], z[3]
        origins[i, 0], origins[i, 1], origins[i, 2] = 2.0 * o[1], 2.0 * o[2], 2.0 * o[3]
        # Pluecker line of the joint axis as a dual quaternion: l + eps (o x l)
        lines[i, 0] = 0.0
        lines[i, 1], lines[i, 2], lines[i, 3] = z[1], z[2], z[3]
        lines[i, 4] = 0.0
        ox, oy, oz = 2.0 * o[1], 2.0 * o[2], 2.0 * o[3]
        lines[i, 5] = oy * z[3] - oz * z[2]
        lines[i, 6] = oz * z[1] - ox * z[3]
        lines[i, 7] = ox * z[2] - oy * z[1]
        x = _along_joint(x, step, mdh, i)
    o = _qmul(x[4], x[5], x[6], x[7], x[0], -x[1], -x[2], -x[3])
    origins[n, 0], origins[n, 1], origins[n, 2] = 2.0 * o[1], 2.0 * o[2], 2.0 * o[3]
    x = dq_mul(x, tool)
    jac = np.empty((8, n))
    for i in range(n):  # d x / d q_i = (1/2) l_i x, l_i the joint's line
        c = dq_mul(lines[i], x)
        for k in range(8):
            jac[k, i] = 0.5 * c[k]
    return x, jac, axes, origins


@nb.njit(cache=True)
def _cross_columns(axes: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Columns ``axes[i] x v[i]`` as a (3, n) matrix (``v`` broadcast when it is one row)."""
    n = axes.shape[0]
    out = np.empty((3, n))
    for i in range(n):
        k = i if v.shape[0] == n else 0
        out[0, i] = axes[i, 1] * v[k, 2] - axes[i, 2] * v[k, 1]
        out[1, i] = axes[i, 2] * v[k, 0] - axes[i, 0] * v[k, 2]
        out[2, i] = axes[i, 0] * v[k, 1] - axes[i, 1] * v[k, 0]
    return out


@nb.njit(cache=True)
def _points_line_sq_distances(axes, origins, ks, c, ell):
    """Squared distances of link origins ``ks`` from the line (c, ell) and their joint
    Jacobians (origin k moves with the joints before it)."""
    m, n = ks.shape[0], axes.shape[0]
    d = np.empty(m)
    jac = np.zeros((m, n))
    for r in range(m):
        k = ks[r]
        p = origins[k]
        v0, v1, v2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
        t = v0 * ell[0] + v1 * ell[1] + v2 * ell[2]
        e0, e1, e2 = v0 - t * ell[0], v1 - t * ell[1], v2 - t * ell[2]
        d[r] = e0 * e0 + e1 * e1 + e2 * e2
        for i in range(min(k, n)):
            w0, w1, w2 = p[0] - origins[i, 0], p[1] - origins[i, 1], p[2] - origins[i, 2]
            a = axes[i]
            j0 = a[1] * w2 - a[2] * w1
            j1 = a[2] * w0 - a[0] * w2
            j2 = a[0] * w1 - a[1] * w0
            jac[r, i] = 2.0 * (e0 * j0 + e1 * j1 + e2 * j2)
    return d, jac


@nb.njit(cache=True)
def _arm_state(q, mdh, base, tool):
    """Everything :meth:`PandaModel.state` returns, in one compiled call (and whether ``q``
    is finite)."""
    finite = _all_finite(q)
    x, jac, axes, origins = chain_kinematics(q, mdh, base, tool)
    tip = _dq_to_matrix(x)
    p = tip[:3, 3].copy()
    axis = tip[:3, 2].copy()
    jt = _cross_columns(axes, p.reshape(1, 3) - origins[: axes.shape[0]])
    ja = _cross_columns(axes, axis.reshape(1, 3))
    return x, jac, axes, origins, p, axis, jt, ja, finite


@dataclass(frozen=True)
class ArmState:
    """Kinematic quantities of the arm at one configuration (world frame, mm).

    Attributes
    ----------
    q : ndarray, shape (7,)
    tip_dq : ndarray, shape (8,)
        Needle tip pose.
    pose_jacobian : ndarray, shape (8, 7)
    tip_mm : ndarray, shape (3,)
    needle_axis : ndarray, shape (3,)
        Unit insertion direction (the tip's z axis).
    tip_jacobian : ndarray, shape (3, 7)
        ``d tip_mm / dt = tip_jacobian q_dot``.
    axis_jacobian : ndarray, shape (3, 7)
        ``d needle_axis / dt = axis_jacobian q_dot``.
    axes, origins : ndarray
        Joint axis directions (7, 3) and points (8, 3; the last is the flange-side link
        frame origin).
    """

    q: np.ndarray
    tip_dq: np.ndarray
    pose_jacobian: np.ndarray
    tip_mm: np.ndarray
    needle_axis: np.ndarray
    tip_jacobian: np.ndarray
    axis_jacobian: np.ndarray
    axes: np.ndarray
    origins: np.ndarray

    def point_jacobian(self, k: int) -> np.ndarray:
        """Translation Jacobian of joint-frame origin ``k`` (moved by joints ``< k``).

        Parameters
        ----------
        k : int
            Index into :attr:`origins`.

        Returns
        -------
        ndarray, shape (3, 7)
        """
        jac = np.zeros((3, len(self.q)))
        m = min(k, len(self.q))
        if m:
            jac[:, :m] = _cross_columns(self.axes[:m], self.origins[k] - self.origins[:m])
        return jac

    def points_line_sq_distances(self, ks, point_mm, direction) -> tuple[np.ndarray, np.ndarray]:
        """Squared distances of joint-frame origins from a line, with their Jacobians.

        Parameters
        ----------
        ks : ndarray of int, shape (m,)
            Indices into :attr:`origins`.
        point_mm, direction : ndarray, shape (3,)
            A point of the line and its unit direction.

        Returns
        -------
        d : ndarray, shape (m,)
            mm^2.
        jac : ndarray, shape (m, 7)
            ``d_dot = jac q_dot``.
        """
        return _points_line_sq_distances(
            self.axes, self.origins, np.asarray(ks, dtype=np.int64), point_mm, direction
        )


def _pose(value, name: str) -> np.ndarray:
    g = np.asarray(value, dtype=float)
    if g.shape != (4, 4) or not np.all(np.isfinite(g)):
        raise InvalidInputError(name, f"expected a finite 4x4 pose, got shape {g.shape}")
    r = g[:3, :3]
    if not (np.allclose(r.T @ r, np.eye(3), atol=1e-8) and np.linalg.det(r) > 0):
        raise InvalidInputError(name, "rotation part is not a rotation matrix")
    return g


@dataclass(frozen=True)
class PandaModel:
    """A Panda at ``world_T_base`` holding a needle whose tip is ``flange_T_tip``.

    Attributes
    ----------
    world_T_base : ndarray, shape (4, 4)
        Robot base in the world (EM transmitter) frame, mm.
    flange_T_tip : ndarray, shape (4, 4)
        Needle tip in the flange frame (z = insertion direction), mm.
    q_min, q_max, q_dot_max : ndarray, shape (7,)
        Joint limits (default: the Panda's).

    Examples
    --------
    >>> m = PandaModel()
    >>> s = m.state(np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0]))
    >>> (s.tip_mm.round(1) + 0.0).tolist(), (s.needle_axis.round(3) + 0.0).tolist()
    ([547.7, 0.0, 651.5], [0.0, 0.0, -1.0])
    """

    world_T_base: np.ndarray = field(default_factory=lambda: np.eye(4))
    flange_T_tip: np.ndarray = field(default_factory=lambda: np.eye(4))
    q_min: np.ndarray = field(default_factory=lambda: Q_MIN.copy())
    q_max: np.ndarray = field(default_factory=lambda: Q_MAX.copy())
    q_dot_max: np.ndarray = field(default_factory=lambda: Q_DOT_MAX.copy())

    def __post_init__(self) -> None:
        object.__setattr__(self, "world_T_base", _pose(self.world_T_base, "world_T_base"))
        object.__setattr__(self, "flange_T_tip", _pose(self.flange_T_tip, "flange_T_tip"))
        for name in ("q_min", "q_max", "q_dot_max"):
            v = np.asarray(getattr(self, name), dtype=float).reshape(-1)
            if v.shape != (7,) or not np.all(np.isfinite(v)):
                raise InvalidInputError(name, "expected 7 finite numbers")
            object.__setattr__(self, name, v)
        if np.any(self.q_min >= self.q_max):
            raise InvalidInputError("q_min", "must lie below q_max for every joint")
        if np.any(self.q_dot_max <= 0):
            raise InvalidInputError("q_dot_max", "must be > 0 for every joint")
        flange = np.eye(4)
        flange[2, 3] = FLANGE_MM
        object.__setattr__(self, "_base_dq", dq_from_matrix(self.world_T_base))
        object.__setattr__(self, "_tool_dq", dq_from_matrix(flange @ self.flange_T_tip))

    def _q(self, q) -> np.ndarray:
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (7,) or not np.isfinite(q).all():
            raise InvalidInputError("q", f"expected 7 finite joint angles, got {q.shape}")
        return q

    def state(self, q) -> ArmState:
        """Every kinematic quantity the controller needs at ``q``.

        Parameters
        ----------
        q : array_like, shape (7,)

        Returns
        -------
        ArmState
        """
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (7,):
            self._q(q)  # raises
        x, jac, axes, origins, p, axis, jt, ja, finite = _arm_state(
            q, PANDA_MDH_MM, self._base_dq, self._tool_dq
        )
        if not finite:
            self._q(q)  # raises
        st = object.__new__(ArmState)  # the frozen dataclass's fields, without its __init__
        st.__dict__.update(
            q=q, tip_dq=x, pose_jacobian=jac, tip_mm=p, needle_axis=axis, tip_jacobian=jt,
            axis_jacobian=ja, axes=axes, origins=origins,
        )  # fmt: skip
        return st

    @functools.cached_property
    def needle_length_mm(self) -> float:
        """The tip's distance from the flange (``|flange_T_tip|`` translation, mm), kept
        once computed (a control step with placed needles reads it every tick).

        Returns
        -------
        float
        """
        return float(np.linalg.norm(self.flange_T_tip[:3, 3]))

    def tip_pose(self, q) -> np.ndarray:
        """``world_T_tip`` at ``q``.

        Parameters
        ----------
        q : array_like, shape (7,)

        Returns
        -------
        ndarray, shape (4, 4)
        """
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (7,):
            self._q(q)  # raises
        pose, finite = _tip_matrix(q, PANDA_MDH_MM, self._base_dq, self._tool_dq)
        if not finite:
            self._q(q)  # raises
        return pose

    def with_parameters(self, world_T_base=None, flange_T_tip=None) -> PandaModel:
        """The same arm with another base or needle transform (e.g. the estimated ones).

        Parameters
        ----------
        world_T_base, flange_T_tip : array_like, shape (4, 4), optional

        Returns
        -------
        PandaModel
        """
        return PandaModel(
            self.world_T_base if world_T_base is None else world_T_base,
            self.flange_T_tip if flange_T_tip is None else flange_T_tip,
            self.q_min,
            self.q_max,
            self.q_dot_max,
        )

    def _with_poses_unchecked(
        self, world_T_base, flange_T_tip, base_dq=None, tool_dq=None
    ) -> PandaModel:
        """:meth:`with_parameters` without validating the poses (callers build proper rigid
        transforms themselves; the adaptation rebuilds the model at every measurement).
        ``base_dq`` and ``tool_dq`` (the tool including the flange), when the caller has
        them already."""
        m = object.__new__(PandaModel)
        if base_dq is None:
            base_dq = dq_from_matrix(world_T_base)
        if tool_dq is None:
            flange = np.eye(4)
            flange[2, 3] = FLANGE_MM
            tool_dq = dq_from_matrix(flange @ flange_T_tip)
        m.__dict__.update(
            world_T_base=world_T_base, flange_T_tip=flange_T_tip, q_min=self.q_min,
            q_max=self.q_max, q_dot_max=self.q_dot_max, _base_dq=base_dq, _tool_dq=tool_dq,
        )  # fmt: skip
        return m

    def reference_robot(self):
        """The same arm as a ``dqrobotics`` ``DQ_SerialManipulatorMDH`` in mm (test oracle).

        Returns
        -------
        dqrobotics.robot_modeling.DQ_SerialManipulatorMDH
        """
        from dqrobotics import DQ
        from dqrobotics.robot_modeling import DQ_SerialManipulatorMDH

        table = np.vstack([PANDA_MDH_MM, np.zeros((1, 7))])  # last row: joint types
        robot = DQ_SerialManipulatorMDH(table)
        robot.set_reference_frame(DQ(self._base_dq))
        robot.set_effector(DQ(self._tool_dq))
        robot.set_lower_q_limit(self.q_min)
        robot.set_upper_q_limit(self.q_max)
        robot.set_lower_q_dot_limit(-self.q_dot_max)
        robot.set_upper_q_dot_limit(self.q_dot_max)
        return robot
