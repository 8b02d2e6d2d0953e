"""Euler and fixed-axis angles: rotation matrices and the angle-rate map omega = T(phi) phi_dot.

An orientation is written as three angles ``phi = (phi1, phi2, phi3)`` about a sequence of
three coordinate axes. needlekit names the 24 sequences exactly as
:meth:`scipy.spatial.transform.Rotation.from_euler` does:

* **Euler angles** (rotating, *intrinsic* axes) are uppercase, e.g. ``"XYZ"``, ``"ZYZ"``:
  each rotation is about an axis of the frame produced by the previous ones, so
  ``"XYZ"`` means ``R = Rx(phi1) @ Ry(phi2) @ Rz(phi3)``.
* **Fixed-axis angles** (*extrinsic* axes) are lowercase, e.g. ``"xyz"``, ``"zyz"``: each
  rotation is about an axis of the fixed world frame, so ``"xyz"`` means
  ``R = Rz(phi3) @ Ry(phi2) @ Rx(phi1)``. Fixed-axis ``"abc"`` at ``(p1, p2, p3)`` is
  the same rotation as Euler ``"CBA"`` at ``(p3, p2, p1)``.

Each set has 6 Tait-Bryan sequences (three different axes; gimbal lock when the middle
angle is +-pi/2) and 6 proper Euler sequences (first axis repeated; gimbal lock when the
middle angle is 0 or pi).

The angle rates ``phi_dot`` map linearly to the angular velocity ``omega`` of the
rotating frame, ``omega = T(phi) @ phi_dot`` (the lecture's relation). ``omega`` is given
either in the world frame (spatial angular velocity, ``hat(omega) = R_dot @ R.T``,
``frame="world"``) or in the rotating body frame (``hat(omega) = R.T @ R_dot``,
``frame="body"``); ``T_body = R.T @ T_world``. Writing the rotation as a left-to-right
product ``R = R_u1(t1) @ R_u2(t2) @ R_u3(t3)`` of elementary rotations (for Euler angles
``(u, t) = (abc, phi1 phi2 phi3)``, for fixed axes ``(u, t) = (cba, phi3 phi2 phi1)``),

    omega_world = e_u1 t1_dot + R_u1(t1) e_u2 t2_dot + R_u1(t1) R_u2(t2) e_u3 t3_dot,

which gives every convention's ``T`` in closed form; ``|det T|`` is ``|cos phi2|``
(Tait-Bryan) or ``|sin phi2|`` (proper Euler) in both frames.

Angles are in radians unless ``degrees=True``; angle *rates* and angular velocities are
always in rad/s. Every function is batch-first: one item or a batch along axis 0.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from needlekit._validation import as_batch, as_rotations, unbatch
from needlekit.constants import GIMBAL_LOCK_TOL
from needlekit.errors import InvalidInputError, SingularityError

__all__ = [
    "CONVENTIONS",
    "EULER_CONVENTIONS",
    "FIXED_AXIS_CONVENTIONS",
    "analytic_jacobian",
    "angular_velocity_to_euler_rates",
    "euler_rate_matrix",
    "euler_rate_matrix_inv",
    "euler_rates_to_angular_velocity",
    "euler_to_matrix",
    "matrix_to_euler",
]

_TAIT_BRYAN = ("xyz", "xzy", "yxz", "yzx", "zxy", "zyx")
_PROPER_EULER = ("xyx", "xzx", "yxy", "yzy", "zxz", "zyz")

#: The 12 Euler-angle conventions (rotating, intrinsic axes; uppercase as in scipy).
EULER_CONVENTIONS: tuple[str, ...] = tuple(s.upper() for s in _TAIT_BRYAN + _PROPER_EULER)
#: The 12 fixed-axis conventions (extrinsic axes; lowercase as in scipy).
FIXED_AXIS_CONVENTIONS: tuple[str, ...] = _TAIT_BRYAN + _PROPER_EULER
#: All 24 conventions: Euler (uppercase) first, then fixed-axis (lowercase).
CONVENTIONS: tuple[str, ...] = EULER_CONVENTIONS + FIXED_AXIS_CONVENTIONS

_FRAMES = ("world", "body")
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


class _Seq(NamedTuple):
    name: str
    intrinsic: bool
    proper: bool  # proper Euler (first axis repeated) rather than Tait-Bryan
    # R = R_{factors[0]} @ R_{factors[1]} @ R_{factors[2]}, each (axis, angle index).
    factors: tuple[tuple[int, int], ...]


def _parse_seq(seq: Any) -> _Seq:
    if not isinstance(seq, str) or seq not in CONVENTIONS:
        raise InvalidInputError(
            "seq",
            "expected one of the 24 conventions: Euler (rotating axes, uppercase) "
            + " ".join(EULER_CONVENTIONS)
            + " or fixed-axis (lowercase) "
            + " ".join(FIXED_AXIS_CONVENTIONS)
            + f"; got {seq!r}",
        )
    axes = [_AXIS_INDEX[c] for c in seq.lower()]
    intrinsic = seq.isupper()
    order = (0, 1, 2) if intrinsic else (2, 1, 0)
    factors = tuple((axes[k], k) for k in order)
    return _Seq(seq, intrinsic, axes[0] == axes[2], factors)


def _check_frame(frame: Any) -> str:
    if not isinstance(frame, str) or frame not in _FRAMES:
        raise InvalidInputError("frame", f"expected 'world' or 'body', got {frame!r}")
    return frame


def _angles_rad(angles: Any, degrees: bool) -> tuple[np.ndarray, np.ndarray, bool]:
    """Return (angles as given, angles in rad), both (n, 3), and the single flag."""
    phi, single = as_batch(angles, "angles", (3,))
    return phi, (np.deg2rad(phi) if degrees else phi), single


def _pair(
    a: np.ndarray, a_single: bool, b: np.ndarray, b_single: bool, b_name: str
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Match the batch sizes of ``angles`` (``a``) and a second argument ``b``.

    A single item is broadcast against a batch; two batches must have the same length.
    """
    na, nb = a.shape[0], b.shape[0]
    if na == nb:
        return a, b, a_single and b_single
    if a_single:
        return np.broadcast_to(a, (nb, *a.shape[1:])), b, False
    if b_single:
        return a, np.broadcast_to(b, (na, *b.shape[1:])), False
    raise InvalidInputError(b_name, f"batch of {nb} items does not match {na} items of angles")


def _elementary(axis: int, theta: np.ndarray) -> np.ndarray:
    """Rotations by ``theta`` (n,) rad about coordinate axis ``axis``, shape (n, 3, 3)."""
    c, s = np.cos(theta), np.sin(theta)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    out = np.zeros((theta.shape[0], 3, 3))
    out[:, axis, axis] = 1.0
    out[:, i, i] = c
    out[:, j, j] = c
    out[:, i, j] = -s
    out[:, j, i] = s
    return out


def _matrix_and_rate_world(phi: np.ndarray, sq: _Seq) -> tuple[np.ndarray, np.ndarray]:
    """Return R (n, 3, 3) and the world-frame T (n, 3, 3) for angles ``phi`` (n, 3) rad."""
    (u1, k1), (u2, k2), (u3, k3) = sq.factors
    r1 = _elementary(u1, phi[:, k1])
    r12 = r1 @ _elementary(u2, phi[:, k2])
    rot = r12 @ _elementary(u3, phi[:, k3])
    t = np.zeros_like(rot)
    t[:, u1, k1] = 1.0  # e_u1
    t[:, :, k2] = r1[:, :, u2]  # R_u1(t1) e_u2
    t[:, :, k3] = r12[:, :, u3]  # R_u1(t1) R_u2(t2) e_u3
    return rot, t


def _adjugate(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Adjugate and determinant of T (n, 3, 3) from cross products of its columns."""
    c1, c2, c3 = t[:, :, 0], t[:, :, 1], t[:, :, 2]
    adj = np.stack([np.cross(c2, c3), np.cross(c3, c1), np.cross(c1, c2)], axis=1)
    return adj, np.einsum("ni,ni->n", c1, adj[:, 0])


def _check_not_locked(
    det: np.ndarray, phi_given: np.ndarray, sq: _Seq, degrees: bool, single: bool
) -> None:
    bad = np.flatnonzero(np.abs(det) < GIMBAL_LOCK_TOL)
    if bad.size == 0:
        return
    i = int(bad[0])
    where = "angles[1]" if single else f"angles[{i}, 1]"
    unit = "deg" if degrees else "rad"
    if sq.proper:
        kind, lock = "proper Euler", "0 or pi (0 or 180 deg)"
    else:
        kind, lock = "Tait-Bryan", "+-pi/2 (+-90 deg)"
    raise SingularityError(
        "angles",
        f"gimbal lock: the middle angle {where} = {phi_given[i, 1]:.9g} {unit} is at {lock} "
        f"for the {kind} convention {sq.name!r}, so T(phi) is singular "
        f"(|det T| = {abs(det[i]):.2e} < GIMBAL_LOCK_TOL = {GIMBAL_LOCK_TOL:g}) and the "
        "angle rates are undefined",
    )


def _inverse(
    phi_given: np.ndarray, phi: np.ndarray, sq: _Seq, frame: str, degrees: bool, single: bool
) -> np.ndarray:
    """T^-1 (n, 3, 3) in ``frame``, raising SingularityError at gimbal lock."""
    rot, t = _matrix_and_rate_world(phi, sq)
    adj, det = _adjugate(t)
    _check_not_locked(det, phi_given, sq, degrees, single)
    inv = adj / det[:, None, None]
    # T_body = R^T T_world  =>  T_body^-1 = T_world^-1 R.
    return inv @ rot if frame == "body" else inv


def euler_to_matrix(angles: Any, seq: str, *, degrees: bool = False) -> np.ndarray:
    """Rotation matrices from Euler or fixed-axis angles.

    Parameters
    ----------
    angles : array_like, shape (3,) or (n, 3)
        ``(phi1, phi2, phi3)`` in the order of the letters of ``seq``; rad, or deg when
        ``degrees`` is True.
    seq : str
        One of :data:`CONVENTIONS`: uppercase = Euler (intrinsic, rotating axes),
        lowercase = fixed-axis (extrinsic), as in scipy.
    degrees : bool, default False
        Whether ``angles`` are in degrees.

    Returns
    -------
    R : ndarray, shape (3, 3) or (n, 3, 3), float64
        Rotation of the rotated frame relative to the reference frame (columns are the
        rotated axes in reference coordinates). Same result as
        ``Rotation.from_euler(seq, angles, degrees=degrees).as_matrix()``.

    Raises
    ------
    InvalidInputError
        If ``angles`` is not finite or of the wrong shape, or ``seq`` is unknown.

    Examples
    --------
    >>> import numpy as np
    >>> R = euler_to_matrix([90.0, 0.0, 0.0], "ZYX", degrees=True)
    >>> np.round(R @ [1.0, 0.0, 0.0], 12) + 0.0
    array([0., 1., 0.])
    """
    sq = _parse_seq(seq)
    _, phi, single = _angles_rad(angles, degrees)
    rot, _ = _matrix_and_rate_world(phi, sq)
    return unbatch(rot, single)


def matrix_to_euler(R: Any, seq: str, *, degrees: bool = False) -> np.ndarray:
    """Euler or fixed-axis angles of rotation matrices (wraps scipy's ``as_euler``).

    Parameters
    ----------
    R : array_like, shape (3, 3) or (n, 3, 3)
        Proper rotation matrices (orthonormal within ``ROTATION_ORTHONORMAL_TOL``).
    seq : str
        One of :data:`CONVENTIONS` (see :func:`euler_to_matrix`).
    degrees : bool, default False
        Return degrees instead of radians.

    Returns
    -------
    angles : ndarray, shape (3,) or (n, 3), float64
        ``(phi1, phi2, phi3)`` with ``euler_to_matrix(angles, seq) == R``. As in scipy,
        phi1 and phi3 lie in [-pi, pi]; phi2 lies in [-pi/2, pi/2] for Tait-Bryan and in
        [0, pi] for proper Euler sequences.

    Raises
    ------
    InvalidInputError
        If ``R`` is not finite, of the wrong shape or not a rotation, or ``seq`` is unknown.

    Notes
    -----
    At gimbal lock only phi1 +- phi3 is determined; scipy then sets phi3 to zero and emits
    a ``UserWarning``, which is passed on.

    Examples
    --------
    >>> import numpy as np
    >>> R = euler_to_matrix([10.0, 20.0, 30.0], "xyz", degrees=True)
    >>> np.round(matrix_to_euler(R, "xyz", degrees=True), 9)
    array([10., 20., 30.])
    """
    _parse_seq(seq)
    rot, single = as_rotations(R, "R")
    angles = Rotation.from_matrix(rot).as_euler(seq, degrees=degrees)
    return unbatch(np.asarray(angles, dtype=np.float64), single)


def euler_rate_matrix(
    angles: Any, seq: str, *, frame: str = "world", degrees: bool = False
) -> np.ndarray:
    """The matrix T(phi) with omega = T(phi) @ phi_dot.

    Parameters
    ----------
    angles : array_like, shape (3,) or (n, 3)
        Angles ``phi`` in the order of ``seq``; rad, or deg when ``degrees`` is True.
    seq : str
        One of :data:`CONVENTIONS` (see :func:`euler_to_matrix`).
    frame : {"world", "body"}, default "world"
        Frame of ``omega``: ``"world"`` gives the spatial angular velocity
        (``hat(omega) = R_dot @ R.T``), ``"body"`` the angular velocity in the rotating
        frame (``hat(omega) = R.T @ R_dot``); ``T_body = R.T @ T_world``.
    degrees : bool, default False
        Whether ``angles`` are in degrees. ``T`` always maps rates in rad/s to rad/s.

    Returns
    -------
    T : ndarray, shape (3, 3) or (n, 3, 3), float64
        Column k is the angular velocity produced by a unit rate of ``phi[k]``. Defined
        everywhere, including gimbal lock (where it is singular).

    Raises
    ------
    InvalidInputError
        If ``angles`` is not finite or of the wrong shape, or ``seq`` or ``frame`` is
        unknown.

    Examples
    --------
    The lecture's Euler XYZ angles (alpha, beta, gamma) give
    ``T = [[1, 0, sin b], [0, cos a, -sin a cos b], [0, sin a, cos a cos b]]``:

    >>> import numpy as np
    >>> a, b = 0.3, 0.5
    >>> T = euler_rate_matrix([a, b, 0.7], "XYZ")
    >>> bool(np.allclose(T[:, 2], [np.sin(b), -np.sin(a) * np.cos(b), np.cos(a) * np.cos(b)]))
    True
    """
    sq = _parse_seq(seq)
    frame = _check_frame(frame)
    _, phi, single = _angles_rad(angles, degrees)
    rot, t = _matrix_and_rate_world(phi, sq)
    if frame == "body":
        t = np.swapaxes(rot, 1, 2) @ t
    return unbatch(t, single)


def euler_rate_matrix_inv(
    angles: Any, seq: str, *, frame: str = "world", degrees: bool = False
) -> np.ndarray:
    """The inverse of T(phi), phi_dot = T(phi)^-1 @ omega, in closed form.

    Parameters
    ----------
    angles : array_like, shape (3,) or (n, 3)
        Angles ``phi`` in the order of ``seq``; rad, or deg when ``degrees`` is True.
    seq : str
        One of :data:`CONVENTIONS` (see :func:`euler_to_matrix`).
    frame : {"world", "body"}, default "world"
        Frame of ``omega`` (see :func:`euler_rate_matrix`).
    degrees : bool, default False
        Whether ``angles`` are in degrees. Rates are always rad/s.

    Returns
    -------
    T_inv : ndarray, shape (3, 3) or (n, 3, 3), float64
        Computed from the adjugate of ``T`` (cross products of its columns) divided by
        ``det T``, which is +-cos(phi2) (Tait-Bryan) or +-sin(phi2) (proper Euler).

    Raises
    ------
    SingularityError
        Field ``"angles"``, at gimbal lock: ``|det T| < GIMBAL_LOCK_TOL``, i.e. the middle
        angle is at +-pi/2 (Tait-Bryan) or at 0 or pi (proper Euler). The message names
        the first such item.
    InvalidInputError
        If ``angles`` is not finite or of the wrong shape, or ``seq`` or ``frame`` is
        unknown.

    Examples
    --------
    >>> import numpy as np
    >>> phi = [0.1, 0.2, 0.3]
    >>> T = euler_rate_matrix(phi, "ZYZ", frame="body")
    >>> bool(np.allclose(euler_rate_matrix_inv(phi, "ZYZ", frame="body") @ T, np.eye(3)))
    True
    """
    sq = _parse_seq(seq)
    frame = _check_frame(frame)
    phi_given, phi, single = _angles_rad(angles, degrees)
    return unbatch(_inverse(phi_given, phi, sq, frame, degrees, single), single)


def euler_rates_to_angular_velocity(
    angles: Any, angle_rates: Any, seq: str, *, frame: str = "world", degrees: bool = False
) -> np.ndarray:
    """Angular velocity from angle rates, omega = T(phi) @ phi_dot.

    Parameters
    ----------
    angles : array_like, shape (3,) or (n, 3)
        Angles ``phi`` in the order of ``seq``; rad, or deg when ``degrees`` is True.
    angle_rates : array_like, shape (3,) or (n, 3)
        ``phi_dot`` in rad/s, **also when** ``degrees`` is True (the flag applies to
        ``angles`` only). A single item is broadcast against a batch of the other.
    seq : str
        One of :data:`CONVENTIONS` (see :func:`euler_to_matrix`).
    frame : {"world", "body"}, default "world"
        Frame in which ``omega`` is returned (see :func:`euler_rate_matrix`).
    degrees : bool, default False
        Whether ``angles`` are in degrees.

    Returns
    -------
    omega : ndarray, shape (3,) or (n, 3), float64
        Angular velocity in rad/s, in ``frame``.

    Raises
    ------
    InvalidInputError
        If an argument is not finite or of the wrong shape, the batch sizes differ, or
        ``seq`` or ``frame`` is unknown.

    Examples
    --------
    For fixed axes ``"xyz"`` (``R = Rz(phi3) Ry(phi2) Rx(phi1)``) a rate of the last angle
    turns about the world z axis, while the x axis of the first angle has been carried
    along by the later rotations:

    >>> import numpy as np
    >>> phi = [0.4, 0.0, 0.6]
    >>> euler_rates_to_angular_velocity(phi, [0.0, 0.0, 2.0], "xyz")
    array([0., 0., 2.])
    >>> w = euler_rates_to_angular_velocity(phi, [2.0, 0.0, 0.0], "xyz")
    >>> bool(np.allclose(w, [2.0 * np.cos(0.6), 2.0 * np.sin(0.6), 0.0]))
    True
    """
    t = euler_rate_matrix(angles, seq, frame=frame, degrees=degrees)
    t, single_t = (t[None], True) if t.ndim == 2 else (t, False)
    rates, single_r = as_batch(angle_rates, "angle_rates", (3,))
    t, rates, single = _pair(t, single_t, rates, single_r, "angle_rates")
    return unbatch(np.einsum("nij,nj->ni", t, rates), single)


def angular_velocity_to_euler_rates(
    angles: Any, omega: Any, seq: str, *, frame: str = "world", degrees: bool = False
) -> np.ndarray:
    """Angle rates from angular velocity, phi_dot = T(phi)^-1 @ omega.

    Parameters
    ----------
    angles : array_like, shape (3,) or (n, 3)
        Angles ``phi`` in the order of ``seq``; rad, or deg when ``degrees`` is True.
    omega : array_like, shape (3,) or (n, 3)
        Angular velocity in rad/s, expressed in ``frame``. A single item is broadcast
        against a batch of the other.
    seq : str
        One of :data:`CONVENTIONS` (see :func:`euler_to_matrix`).
    frame : {"world", "body"}, default "world"
        Frame of ``omega`` (see :func:`euler_rate_matrix`).
    degrees : bool, default False
        Whether ``angles`` are in degrees; the returned rates are rad/s regardless.

    Returns
    -------
    angle_rates : ndarray, shape (3,) or (n, 3), float64
        ``phi_dot`` in rad/s.

    Raises
    ------
    SingularityError
        Field ``"angles"``, at gimbal lock (see :func:`euler_rate_matrix_inv`).
    InvalidInputError
        If an argument is not finite or of the wrong shape, the batch sizes differ, or
        ``seq`` or ``frame`` is unknown.

    Examples
    --------
    >>> import numpy as np
    >>> phi = np.array([0.2, -0.4, 1.0])
    >>> w = euler_rates_to_angular_velocity(phi, [0.1, 0.2, 0.3], "ZYX")
    >>> np.round(angular_velocity_to_euler_rates(phi, w, "ZYX"), 12)
    array([0.1, 0.2, 0.3])
    """
    t_inv = euler_rate_matrix_inv(angles, seq, frame=frame, degrees=degrees)
    t_inv, single_t = (t_inv[None], True) if t_inv.ndim == 2 else (t_inv, False)
    w, single_w = as_batch(omega, "omega", (3,))
    t_inv, w, single = _pair(t_inv, single_t, w, single_w, "omega")
    return unbatch(np.einsum("nij,nj->ni", t_inv, w), single)


def analytic_jacobian(
    geometric_jacobian: Any, angles: Any, seq: str, *, degrees: bool = False
) -> np.ndarray:
    """Analytic Jacobian J_A = diag(I3, T(phi)^-1) @ J_G for an orientation in ``seq`` angles.

    Parameters
    ----------
    geometric_jacobian : array_like, shape (6, m) or (n, 6, m)
        Geometric Jacobian ``J_G`` with rows ``(v, omega)``: the linear velocity of the
        end-effector point (mm/s per joint rate) and the **world-frame** angular velocity
        (rad/s per joint rate), as in ``(v, omega) = J_G(q) @ q_dot``.
    angles : array_like, shape (3,) or (n, 3)
        Orientation ``phi`` of the end effector at ``q``; rad, or deg when ``degrees``.
        A single item is broadcast against a batch of the other argument.
    seq : str
        One of :data:`CONVENTIONS` (see :func:`euler_to_matrix`).
    degrees : bool, default False
        Whether ``angles`` are in degrees; the angle-rate rows of ``J_A`` are in rad/s
        per joint rate regardless.

    Returns
    -------
    J_A : ndarray, shape (6, m) or (n, 6, m), float64
        ``(p_dot, phi_dot) = J_A @ q_dot``: the first three rows are those of ``J_G``, the
        last three are ``T(phi)^-1 @ J_omega``.

    Raises
    ------
    SingularityError
        Field ``"angles"``, at gimbal lock (see :func:`euler_rate_matrix_inv`).
    InvalidInputError
        If an argument is not finite or of the wrong shape, the batch sizes differ, or
        ``seq`` is unknown.

    Examples
    --------
    >>> import numpy as np
    >>> J_G = np.vstack([np.zeros((3, 3)), np.eye(3)])  # three joints, one per axis
    >>> J_A = analytic_jacobian(J_G, [0.0, 0.0, 0.0], "XYZ")
    >>> bool(np.allclose(J_A[3:], np.eye(3)))
    True
    """
    try:
        shape = np.shape(geometric_jacobian)
    except ValueError as exc:
        raise InvalidInputError("geometric_jacobian", "expected a (6, m) array") from exc
    m = shape[-1] if len(shape) in (2, 3) else 1
    jac, single_j = as_batch(geometric_jacobian, "geometric_jacobian", (6, m))
    t_inv = euler_rate_matrix_inv(angles, seq, frame="world", degrees=degrees)
    t_inv, single_t = (t_inv[None], True) if t_inv.ndim == 2 else (t_inv, False)
    t_inv, jac, single = _pair(t_inv, single_t, jac, single_j, "geometric_jacobian")
    out = np.concatenate([jac[:, :3, :], t_inv @ jac[:, 3:, :]], axis=1)
    return unbatch(out, single)
