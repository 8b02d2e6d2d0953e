"""Vector-field inequalities (VFIs): distances between robot and workspace primitives, their
Jacobians, and the linear constraints on joint velocities they give.

A VFI keeps a distance ``d(q)`` on one side of a safe value ``d_s`` by bounding its rate:

- ``Zone.OUTSIDE`` (a forbidden zone, keep ``d >= d_s``): ``d_dot >= -eta (d - d_s)``,
  i.e. the row ``-J_d q_dot <= eta (d - d_s)``;
- ``Zone.INSIDE`` (a safe zone, keep ``d <= d_s``): ``d_dot <= eta (d_s - d)``, i.e.
  ``J_d q_dot <= eta (d_s - d)``.

Either way ``d - d_s`` can approach zero at most exponentially, never cross it; a robot
that starts on the wrong side is pulled back at rate ``eta``. The distances of Tang et al.:

- point to line, **squared** (patient cylinder, Eq. 4: robot points outside radius R_p;
  guide cylinder, Eq. 5: needle tip inside radius R_g);
- line to line angle ``f = |l_n - u|^2 = 2 - 2 cos(phi)`` (Eq. 6: the needle within the cone of
  half-angle theta_o about the insertion direction ``u``);
- signed point to plane (Eq. 7: the tip not past the plane through the target).

Every function takes a point's (or direction's) Jacobian ``(3, n)`` and returns the
distance and its ``(n,)`` Jacobian row, so the same code serves joint velocities and the
adaptation's parameter rates.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = [
    "Line",
    "Plane",
    "Zone",
    "joint_limit_bounds",
    "line_angle_distance",
    "point_line_sq_distance",
    "point_plane_distance",
    "vfi_row",
]


class Zone(enum.Enum):
    """Which side of the safe value the distance must stay on."""

    OUTSIDE = "outside"
    INSIDE = "inside"


def _unit(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float).reshape(-1)
    n = float(np.linalg.norm(v)) if v.shape == (3,) else 0.0
    if not (np.isfinite(n) and n > 1e-12):
        raise InvalidInputError(name, "expected a finite non-zero 3-vector")
    return v / n


def _point(v, name: str) -> np.ndarray:
    v = np.asarray(v, dtype=float).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InvalidInputError(name, "expected a finite 3-vector (mm)")
    return v


@dataclass(frozen=True)
class Line:
    """An infinite line through ``point_mm`` along the unit ``direction``.

    Attributes
    ----------
    point_mm : ndarray, shape (3,)
    direction : ndarray, shape (3,)
    """

    point_mm: np.ndarray
    direction: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "point_mm", _point(self.point_mm, "point_mm"))
        object.__setattr__(self, "direction", _unit(self.direction, "direction"))


@dataclass(frozen=True)
class Plane:
    """The plane through ``point_mm`` with unit ``normal`` (positive side: along it).

    Attributes
    ----------
    point_mm : ndarray, shape (3,)
    normal : ndarray, shape (3,)
    """

    point_mm: np.ndarray
    normal: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "point_mm", _point(self.point_mm, "point_mm"))
        object.__setattr__(self, "normal", _unit(self.normal, "normal"))


def point_line_sq_distance(p, jac_p, line: Line) -> tuple[float, np.ndarray]:
    """Squared distance from a point to a line, and its Jacobian.

    Parameters
    ----------
    p : ndarray, shape (3,)
        The point (mm).
    jac_p : ndarray, shape (3, n)
        ``p_dot = jac_p u``.
    line : Line

    Returns
    -------
    d : float
        ``|(p - c) - l ((p - c) . l)|^2`` (mm^2).
    jac : ndarray, shape (n,)
        ``d_dot = jac u``.
    """
    v = p - line.point_mm
    perp = v - line.direction * float(v @ line.direction)
    return float(perp @ perp), 2.0 * perp @ jac_p


def line_angle_distance(direction, jac_dir, target_direction) -> tuple[float, np.ndarray]:
    """``f = |l - u|^2 = 2 - 2 cos(angle(l, u))`` between a robot direction and a fixed one.

    Parameters
    ----------
    direction : ndarray, shape (3,)
        Unit robot direction ``l`` (e.g. the needle axis).
    jac_dir : ndarray, shape (3, n)
        ``l_dot = jac_dir u``.
    target_direction : array_like, shape (3,)
        Unit direction ``u``.

    Returns
    -------
    f : float
    jac : ndarray, shape (n,)
    """
    u = np.asarray(target_direction, dtype=float)
    diff = direction - u
    return float(diff @ diff), -2.0 * u @ jac_dir


def point_plane_distance(p, jac_p, plane: Plane) -> tuple[float, np.ndarray]:
    """Signed distance from a plane (positive along its normal), and its Jacobian.

    Parameters
    ----------
    p : ndarray, shape (3,)
    jac_p : ndarray, shape (3, n)
    plane : Plane

    Returns
    -------
    d : float
    jac : ndarray, shape (n,)
    """
    return float((p - plane.point_mm) @ plane.normal), plane.normal @ jac_p


def vfi_row(
    distance: float, jac: np.ndarray, safe: float, zone: Zone, gain: float
) -> tuple[np.ndarray, float]:
    """The inequality ``row . u <= rhs`` that keeps ``distance`` on its side of ``safe``.

    Parameters
    ----------
    distance : float
    jac : ndarray, shape (n,)
    safe : float
    zone : Zone
    gain : float
        eta (> 0, 1/s).

    Returns
    -------
    row : ndarray, shape (n,)
    rhs : float

    Examples
    --------
    >>> row, rhs = vfi_row(5.0, np.array([1.0, 0.0]), 2.0, Zone.OUTSIDE, 0.5)
    >>> row.tolist(), rhs
    ([-1.0, -0.0], 1.5)
    """
    if zone is Zone.OUTSIDE:
        return -jac, gain * (distance - safe)
    return jac, gain * (safe - distance)


def joint_limit_bounds(q, q_min, q_max, q_dot_max, gain: float = 1.0):
    """Joint position and velocity limits folded into bounds on ``q_dot``.

    The position limits act as VFIs (``q_dot <= gain (q_max - q)`` and
    ``q_dot >= gain (q_min - q)``), intersected with ``|q_dot| <= q_dot_max``.

    Parameters
    ----------
    q, q_min, q_max, q_dot_max : ndarray, shape (n,)
    gain : float
        1/s.

    Returns
    -------
    lower, upper : ndarray, shape (n,)
    """
    lower = np.maximum(-q_dot_max, gain * (q_min - q))
    upper = np.minimum(q_dot_max, gain * (q_max - q))
    return lower, upper
