"""The transformation-matrix method (lecture Method 2): one arc as a product of
elementary transforms, with closed-form forward and inverse steering.

An arc leaving the origin along +z, bending in the plane at angle ``alpha`` about z
(toward ``(cos alpha, sin alpha, 0)``), with radius ``r`` and turning angle ``phi``::

    g = Rot(z, alpha) Trans(x, OA) Trans(z, AB) Rot(y, phi)
      = [[ca cp, -sa, ca sp, x_n],
         [sa cp,  ca, sa sp, y_n],
         [  -sp,   0,    cp, z_n],
         [    0,   0,     0,   1]]

with ``OA = r (1 - cos phi)``, ``AB = r sin phi``, so the tip ends at
``x_n = r cos(alpha)(1 - cos phi)``, ``y_n = r sin(alpha)(1 - cos phi)``,
``z_n = r sin(phi)``, after an arc length ``l = r phi``.

Inverse steering from a target ``(x_n, y_n, z_n)``: ``k = sqrt(x_n^2 + y_n^2)``,
``alpha = atan2(y_n, x_n)``, ``r = k/2 + z_n^2 / (2k)``, ``phi = pi - 2 atan(z_n / k)``
(computed here as the equal and better-conditioned ``2 atan2(k, z_n)``), ``l = r phi``.

This frame is the twist model's tip frame turned by -pi/2 about z: with spin
``psi = alpha + pi/2``, ``g = arc_transform(psi, 1/r, l) @ Rz(-pi/2)``
(:mod:`needlekit.conventions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_points, as_poses, as_positive, unbatch
from needlekit.constants import ON_AXIS_TOL_MM
from needlekit.errors import InvalidInputError, UnreachableTargetError

__all__ = ["SteeringSolution", "tm_inverse", "tm_pose", "tm_transform", "tm_waypoints"]


def _sinc(x):
    return np.sinc(np.asarray(x) / np.pi)


def _tm_pose_batch(alpha: np.ndarray, kappa: np.ndarray, length: np.ndarray) -> np.ndarray:
    phi = kappa * length
    lateral = length * np.sin(0.5 * phi) * _sinc(0.5 * phi)  # r (1 - cos phi), stable
    axial = length * _sinc(phi)  # r sin phi
    ca, sa, cp, sp = np.cos(alpha), np.sin(alpha), np.cos(phi), np.sin(phi)
    out = np.zeros((alpha.shape[0], 4, 4))
    out[:, 0, 0] = ca * cp
    out[:, 0, 1] = -sa
    out[:, 0, 2] = ca * sp
    out[:, 1, 0] = sa * cp
    out[:, 1, 1] = ca
    out[:, 1, 2] = sa * sp
    out[:, 2, 0] = -sp
    out[:, 2, 2] = cp
    out[:, 0, 3] = ca * lateral
    out[:, 1, 3] = sa * lateral
    out[:, 2, 3] = axial
    out[:, 3, 3] = 1.0
    return out


def _vectors(*named):
    arrays = [np.asarray(v, dtype=np.float64) for _, v in named]
    single = all(a.ndim == 0 for a in arrays)
    try:
        arrays = np.broadcast_arrays(*[np.atleast_1d(a) for a in arrays])
    except ValueError as exc:
        raise InvalidInputError("/".join(n for n, _ in named), "shapes do not broadcast") from exc
    for (name, _), a in zip(named, arrays, strict=True):
        if a.ndim != 1:
            raise InvalidInputError(name, f"expected a number or a 1-D array, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InvalidInputError(name, "must be finite, got NaN or infinity")
    return [np.ascontiguousarray(a) for a in arrays], single


def tm_transform(alpha_rad, phi_rad, radius_mm):
    """The lecture's ``g_i = Rot(z, alpha) Trans(x, OA) Trans(z, AB) Rot(y, phi)``.

    Parameters
    ----------
    alpha_rad : float or array_like, shape (n,)
        Bending-plane angle about z.
    phi_rad : float or array_like, shape (n,)
        Turning angle along the arc (rad).
    radius_mm : float or array_like, shape (n,)
        Radius of curvature, > 0 and finite (use :func:`tm_pose` for straight lines).

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
        Tip pose in the frame of the arc's start.

    Examples
    --------
    >>> import numpy as np
    >>> np.round(tm_transform(0.0, np.pi / 2, 50.0)[:3, 3], 9)
    array([50.,  0., 50.])
    """
    (alpha, phi, radius), single = _vectors(
        ("alpha_rad", alpha_rad), ("phi_rad", phi_rad), ("radius_mm", radius_mm)
    )
    if np.any(radius <= 0):
        raise InvalidInputError("radius_mm", f"must be > 0, got {float(radius.min())}")
    return unbatch(_tm_pose_batch(alpha, 1.0 / radius, radius * phi), single)


def tm_pose(alpha_rad, kappa_per_mm, length_mm):
    """Arc end pose from ``(alpha, curvature, length)``; ``kappa = 0`` is straight.

    Same transform as :func:`tm_transform` with ``r = 1/kappa`` and ``phi = kappa l``,
    evaluated without cancellation for small ``kappa``.

    Parameters
    ----------
    alpha_rad : float or array_like, shape (n,)
        Bending-plane angle about z.
    kappa_per_mm : float or array_like, shape (n,)
        Curvature (1/mm), 0 for a straight segment.
    length_mm : float or array_like, shape (n,)
        Arc length (>= 0).

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
    """
    (alpha, kappa, length), single = _vectors(
        ("alpha_rad", alpha_rad), ("kappa_per_mm", kappa_per_mm), ("length_mm", length_mm)
    )
    if np.any(length < 0):
        raise InvalidInputError("length_mm", "must be >= 0")
    return unbatch(_tm_pose_batch(alpha, kappa, length), single)


@dataclass(frozen=True)
class SteeringSolution:
    """Arc parameters that take the tip to a target (arrays, one entry per target).

    Attributes
    ----------
    alpha_rad : ndarray, shape (n,)
        Bending-plane angle about the tip's z axis (0 for targets on the axis).
    radius_mm : ndarray, shape (n,)
        Radius of curvature (``inf`` for targets straight ahead).
    phi_rad : ndarray, shape (n,)
        Turning angle along the arc, in [0, 2 pi).
    length_mm : ndarray, shape (n,)
        Arc length ``r phi``.
    world_T_start : ndarray, shape (4, 4)
        Tip pose the arcs start from.
    """

    alpha_rad: np.ndarray
    radius_mm: np.ndarray
    phi_rad: np.ndarray
    length_mm: np.ndarray
    world_T_start: np.ndarray

    @property
    def kappa_per_mm(self) -> np.ndarray:
        """Curvature ``1 / radius`` (0 for straight segments)."""
        with np.errstate(divide="ignore"):
            return np.where(np.isinf(self.radius_mm), 0.0, 1.0 / self.radius_mm)

    def end_poses(self) -> np.ndarray:
        """World poses at the arcs' ends (forward steering), shape (n, 4, 4).

        Returns
        -------
        ndarray, shape (n, 4, 4)
            ``world_T_end`` per arc (mm).
        """
        return self.world_T_start @ _tm_pose_batch(
            self.alpha_rad, self.kappa_per_mm, self.length_mm
        )


def tm_inverse(targets, world_T_tip=None, *, r_min_mm: float | None = None) -> SteeringSolution:
    """Inverse steering: the single arc from a tip pose through each target point.

    Parameters
    ----------
    targets : array_like, shape (3,) or (n, 3)
        Target points in the world frame (mm).
    world_T_tip : array_like, shape (4, 4), optional
        Tip pose (default: identity, so targets are in the tip frame).
    r_min_mm : float, optional
        Minimum radius of curvature of the needle; a target whose arc is tighter raises.

    Returns
    -------
    SteeringSolution
        Arrays of length n (1 for a single target).

    Raises
    ------
    UnreachableTargetError
        A target lies on the needle axis behind the tip, or needs a radius below
        ``r_min_mm``.

    Examples
    --------
    >>> import numpy as np
    >>> s = tm_inverse([50.0, 0.0, 50.0])
    >>> float(s.radius_mm[0]), float(np.degrees(s.phi_rad[0]))
    (50.0, 90.0)
    """
    pts, _ = as_points(targets, "targets")
    if world_T_tip is None:
        g = np.eye(4)
    else:
        gb, single = as_poses(world_T_tip, "world_T_tip")
        if not single:
            raise InvalidInputError("world_T_tip", "expected one tip pose (4, 4)")
        g = gb[0]
    local = (pts - g[:3, 3]) @ g[:3, :3]  # R^T (p - t)
    x, y, z = local[:, 0], local[:, 1], local[:, 2]
    k = np.hypot(x, y)
    on_axis = k <= ON_AXIS_TOL_MM
    behind = on_axis & (z < 0.0)
    if np.any(behind):
        i = int(np.flatnonzero(behind)[0])
        raise UnreachableTargetError(
            "targets", f"point {i} lies on the needle axis behind the tip; no arc reaches it"
        )
    safe_k = np.where(on_axis, 1.0, k)
    alpha = np.where(on_axis, 0.0, np.arctan2(y, x))
    finite_radius = 0.5 * safe_k + z * z / (2.0 * safe_k)
    radius = np.where(on_axis, np.inf, finite_radius)
    phi = np.where(on_axis, 0.0, 2.0 * np.arctan2(k, z))
    length = np.where(on_axis, z, finite_radius * phi)
    if r_min_mm is not None:
        r_min = as_positive(r_min_mm, "r_min_mm")
        tight = radius < r_min
        if np.any(tight):
            i = int(np.flatnonzero(tight)[0])
            raise UnreachableTargetError(
                "targets",
                f"point {i} needs a radius of curvature of {radius[i]:.3f} mm, "
                f"below r_min_mm = {r_min:g}",
            )
    return SteeringSolution(alpha, radius, phi, length, g)


def tm_waypoints(solution: SteeringSolution, n_steps: int) -> np.ndarray:
    """Way-point poses along each arc, the turning angle split into equal increments.

    Parameters
    ----------
    solution : SteeringSolution
    n_steps : int
        Increments of ``phi`` (e.g. 45 for 1-degree steps on a 45-degree arc).

    Returns
    -------
    ndarray, shape (n, n_steps + 1, 4, 4)
        World poses from the start (index 0) to the target (index ``n_steps``).
    """
    if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise InvalidInputError("n_steps", f"expected an integer >= 1, got {n_steps!r}")
    frac = np.linspace(0.0, 1.0, n_steps + 1)
    n = solution.alpha_rad.shape[0]
    alpha = np.repeat(solution.alpha_rad, n_steps + 1)
    kappa = np.repeat(solution.kappa_per_mm, n_steps + 1)
    length = (solution.length_mm[:, None] * frac[None, :]).reshape(-1)
    local = _tm_pose_batch(alpha, kappa, length).reshape(n, n_steps + 1, 4, 4)
    return solution.world_T_start @ local
