"""The planar (unicycle) model of a bevel-tip needle, lecture Method 1.

State ``(z, y, theta)``: tip position in the insertion plane (mm) and heading angle from
the z axis toward +y (rad). With insertion speed ``v`` (mm/s), bevel side
``bevel = lambda = +1 / -1`` and curvature ``kappa0`` (1/mm)::

    z_dot     = v cos(theta)
    y_dot     = v sin(theta)
    theta_dot = lambda kappa0 v

``lambda = +1`` bends the needle toward +y. In the 3D model's tip frame (tip y-z plane,
no spin) the bevel bends toward -y, i.e. ``lambda = -1``; ``lambda = +1`` is the same
needle spun by pi (:mod:`needlekit.conventions`).

Inverse steering (lecture): the single arc from the origin, heading +z, through a target
``(z, y)`` has radius ``r = (y^2 + z^2) / (2 |y|)`` and length
``l = r atan2(z, r - |y|)``, inserted at ``v = l / dt`` for a sampling time ``dt``.
The lecture's slide writes ``r = (y^2 + z^2) / |y|`` without the factor 2: that is the
circle's diameter, and an arc of that radius misses the target; the factor follows from
``y^2 + z^2 = 2 r |y|`` for a circle tangent to the z axis at the origin (the lecture's
own Method-2 formula ``r = k/2 + z^2/(2k)`` agrees). needlekit uses the corrected form
and its tests check that following the arc returns the target.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_batch, as_positive, unbatch
from needlekit.constants import ON_AXIS_TOL_MM
from needlekit.errors import InvalidInputError, UnreachableTargetError

__all__ = [
    "PlanarSteering",
    "PlanarTrajectory",
    "planar_inverse",
    "planar_rates",
    "planar_steer_waypoints",
    "simulate_planar",
]


def _check_bevel(bevel, name: str = "bevel") -> np.ndarray:
    b = np.asarray(bevel, dtype=np.float64)
    if not np.all(np.isin(b, (-1.0, 1.0))):
        raise InvalidInputError(name, f"must be +1 or -1, got {bevel!r}")
    return b


def planar_rates(state, speed_mm_s, kappa_per_mm, bevel):
    """Time derivative of the planar state: the lecture's matrix form.

    Parameters
    ----------
    state : array_like, shape (3,) or (n, 3)
        ``(z_mm, y_mm, theta_rad)``.
    speed_mm_s : float or array_like, shape (n,)
        Insertion speed v.
    kappa_per_mm : float
        Needle curvature kappa0 (>= 0).
    bevel : {+1, -1} or array_like of them
        Bevel side lambda.

    Returns
    -------
    ndarray, shape (3,) or (n, 3)
        ``(z_dot, y_dot, theta_dot) = [[cos, -sin, 0], [sin, cos, 0], [0, 0, lambda]]
        @ (v, 0, kappa0 v)``.
    """
    x, single = as_batch(state, "state", (3,))
    v = np.broadcast_to(np.asarray(speed_mm_s, dtype=np.float64), (x.shape[0],))
    if not np.all(np.isfinite(v)):
        raise InvalidInputError("speed_mm_s", "must be finite")
    kappa = _check_kappa(kappa_per_mm)
    lam = np.broadcast_to(_check_bevel(bevel), (x.shape[0],))
    th = x[:, 2]
    out = np.stack([v * np.cos(th), v * np.sin(th), lam * kappa * v], axis=1)
    return unbatch(out, single)


def _check_kappa(kappa_per_mm) -> float:
    k = np.asarray(kappa_per_mm, dtype=np.float64)
    if k.ndim != 0 or not np.isfinite(k) or k < 0:
        raise InvalidInputError(
            "kappa_per_mm", f"must be a finite number >= 0, got {kappa_per_mm!r}"
        )
    return float(k)


def _advance(state: np.ndarray, signed_kappa: float, s: np.ndarray) -> np.ndarray:
    """Closed-form planar motion after arc lengths ``s`` (mm) from one state."""
    z0, y0, th0 = state
    dth = signed_kappa * s
    # (sin(th0 + dth) - sin th0) / k and (cos th0 - cos(th0 + dth)) / k, written with
    # sin(dth/2) * sinc so that kappa -> 0 is exact.
    half = 0.5 * dth
    chord = s * np.sinc(half / np.pi)  # 2 sin(half) / k
    mid = th0 + half
    return np.stack([z0 + chord * np.cos(mid), y0 + chord * np.sin(mid), th0 + dth], axis=-1)


@dataclass(frozen=True)
class PlanarTrajectory:
    """Sampled tip trajectory of the planar model.

    Attributes
    ----------
    time_s : ndarray, shape (k,)
    states : ndarray, shape (k, 3)
        ``(z_mm, y_mm, theta_rad)`` at each time.
    """

    time_s: np.ndarray
    states: np.ndarray

    @property
    def final_state(self) -> np.ndarray:
        """State at the end, shape (3,)."""
        return self.states[-1]


def simulate_planar(inputs, kappa_per_mm, *, state0=(0.0, 0.0, 0.0), dt_s: float = 0.01):
    """Forward steering: piecewise-constant inputs to the tip trajectory (closed form).

    Parameters
    ----------
    inputs : array_like, shape (m, 3)
        One row per segment: ``(speed_mm_s, bevel, duration_s)`` with bevel +1 or -1.
    kappa_per_mm : float
        Needle curvature kappa0.
    state0 : array_like, shape (3,)
        Start state ``(z_mm, y_mm, theta_rad)``.
    dt_s : float
        Output sampling interval; segment ends are always included.

    Returns
    -------
    PlanarTrajectory

    Examples
    --------
    Half a circle of radius 50 mm, bending toward +y:

    >>> import numpy as np
    >>> traj = simulate_planar([[10.0, 1, 5 * np.pi]], 1 / 50)
    >>> np.round(traj.final_state, 9)
    array([  0.        , 100.        ,   3.14159265])
    """
    seg, _ = as_batch(inputs, "inputs", (3,))
    _check_bevel(seg[:, 1], "inputs[:, 1] (bevel)")
    if np.any(seg[:, 2] < 0):
        raise InvalidInputError("inputs[:, 2] (duration_s)", "durations must be >= 0")
    kappa = _check_kappa(kappa_per_mm)
    dt = as_positive(dt_s, "dt_s")
    x0, _ = as_batch(state0, "state0", (3,))
    state = x0[0]
    times, states = [np.zeros(1)], [state[None]]
    t0 = 0.0
    for v, lam, dur in seg:
        n = max(1, int(np.ceil(dur / dt - 1e-9)))
        tau = np.linspace(0.0, dur, n + 1)[1:]
        pts = _advance(state, lam * kappa, v * tau)
        times.append(t0 + tau)
        states.append(pts)
        state = pts[-1]
        t0 += dur
    return PlanarTrajectory(np.concatenate(times), np.concatenate(states))


@dataclass(frozen=True)
class PlanarSteering:
    """Single-arc inverse-steering solution in the plane.

    Attributes
    ----------
    radius_mm : float
        Arc radius (``inf`` for a target straight ahead).
    length_mm : float
        Arc length to the target.
    bevel : int
        +1 if the target lies on the +y side (relative to the tip), else -1.
    speed_mm_s : float
        ``length_mm / sampling_time_s``: reaches the target in one sampling time.
    angle_rad : float
        Heading change along the arc, in [0, 2 pi).
    """

    radius_mm: float
    length_mm: float
    bevel: int
    speed_mm_s: float
    angle_rad: float

    @property
    def kappa_per_mm(self) -> float:
        """Curvature 1 / radius (0 for a straight line)."""
        return 0.0 if np.isinf(self.radius_mm) else 1.0 / self.radius_mm

    def inputs(self, sampling_time_s: float) -> np.ndarray:
        """The segment ``(speed_mm_s, bevel, duration_s)`` that follows this arc.

        Pass it to :func:`simulate_planar` together with ``kappa_per_mm=self.kappa_per_mm``;
        arcs of different radii need one call each, since the model's curvature is fixed.

        Parameters
        ----------
        sampling_time_s : float
            Duration of the segment (s); the speed is the arc length over it.

        Returns
        -------
        ndarray, shape (1, 3)
            ``[[speed_mm_s, bevel, duration_s]]``.
        """
        return np.array([[self.length_mm / sampling_time_s, self.bevel, sampling_time_s]])


def planar_inverse(
    target_zy,
    *,
    state=(0.0, 0.0, 0.0),
    sampling_time_s: float = 1.0,
    r_min_mm: float | None = None,
) -> PlanarSteering:
    """Inverse steering: the single arc from a tip state through a target.

    Parameters
    ----------
    target_zy : array_like, shape (2,)
        Target ``(z_mm, y_mm)`` in the plane.
    state : array_like, shape (3,)
        Tip state ``(z_mm, y_mm, theta_rad)`` the arc starts from.
    sampling_time_s : float
        Time to reach the target; sets ``speed_mm_s``.
    r_min_mm : float, optional
        Minimum radius of curvature; a target needing a tighter arc raises.

    Returns
    -------
    PlanarSteering

    Raises
    ------
    UnreachableTargetError
        The target is straight behind the tip, or needs a radius below ``r_min_mm``.

    Examples
    --------
    >>> s = planar_inverse([50.0, 50.0])
    >>> round(s.radius_mm, 9), round(s.length_mm, 9), s.bevel
    (50.0, 78.53981634, 1)
    """
    tgt, _ = as_batch(target_zy, "target_zy", (2,))
    st, _ = as_batch(state, "state", (3,))
    dt = as_positive(sampling_time_s, "sampling_time_s")
    z0, y0, th = st[0]
    dz, dy = tgt[0, 0] - z0, tgt[0, 1] - y0
    # target in the tip's local frame (local z along the heading, local y to its left)
    z = np.cos(th) * dz + np.sin(th) * dy
    y = -np.sin(th) * dz + np.cos(th) * dy
    ay = abs(y)
    if ay <= ON_AXIS_TOL_MM:
        if z < 0.0:
            raise UnreachableTargetError(
                "target_zy", "lies straight behind the needle tip; no forward arc reaches it"
            )
        radius, angle, length = np.inf, 0.0, float(z)
    else:
        radius = (y * y + z * z) / (2.0 * ay)
        angle = float(2.0 * np.arctan2(ay, z))  # == atan2(z, r - |y|) in [0, 2 pi)
        length = radius * angle
    if r_min_mm is not None:
        r_min = as_positive(r_min_mm, "r_min_mm")
        if radius < r_min:
            raise UnreachableTargetError(
                "target_zy",
                f"needs a radius of curvature of {radius:.3f} mm, below r_min_mm = {r_min:g}",
            )
    bevel = 1 if y >= 0.0 else -1
    return PlanarSteering(float(radius), float(length), bevel, float(length) / dt, angle)


def planar_steer_waypoints(
    waypoints_zy, *, state0=(0.0, 0.0, 0.0), sampling_time_s: float = 1.0, r_min_mm=None
) -> tuple[list[PlanarSteering], np.ndarray]:
    """Inverse steering way-point by way-point: one arc per way-point, each from the tip
    state the previous arc left.

    Parameters
    ----------
    waypoints_zy : array_like, shape (m, 2)
    state0 : array_like, shape (3,)
    sampling_time_s : float
        Time per way-point.
    r_min_mm : float, optional

    Returns
    -------
    steps : list of PlanarSteering, length m
    states : ndarray, shape (m + 1, 3)
        Tip state at the start and after each arc.
    """
    wps, _ = as_batch(waypoints_zy, "waypoints_zy", (2,))
    st, _ = as_batch(state0, "state0", (3,))
    state = st[0]
    steps, states = [], [state]
    for wp in wps:
        step = planar_inverse(wp, state=state, sampling_time_s=sampling_time_s, r_min_mm=r_min_mm)
        state = _advance(state, step.bevel * step.kappa_per_mm, np.array([step.length_mm]))[0]
        steps.append(step)
        states.append(state)
    return steps, np.array(states)
