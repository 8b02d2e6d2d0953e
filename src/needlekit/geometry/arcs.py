"""Constant-curvature arcs: the motion primitive of a bevel-tip needle.

An arc is ``(spin_rad, kappa_per_mm, length_mm)``: first turn the tip frame about its own
z axis by ``spin_rad``, then insert ``length_mm`` with curvature ``kappa_per_mm``, which
is the body twist ``(0, 0, 1, kappa, 0, 0)`` per mm (bending toward the tip's -y axis,
see :mod:`needlekit.conventions`). In the tip frame the arc ends at

    ``Rz(spin) @ (0, -(1 - cos(kappa l)) / kappa, sin(kappa l) / kappa)``

with orientation ``Rz(spin) @ Rx(kappa l)``. ``kappa = 0`` is a straight segment; a
negative kappa bends toward +y (the same as spinning by pi).

Two implementations of everything: numba kernels (``propagate_arcs``, ``sample_arcs``),
compiled with ``cache=True``, and plain numpy references (``*_reference``) that the
tests hold the kernels to. The kernels never fall back silently.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit._validation import as_poses, unbatch
from needlekit.errors import InvalidInputError

__all__ = [
    "arc_end_unchecked",
    "arc_points_unchecked",
    "arc_transform",
    "min_tangent_dot_unchecked",
    "propagate_arcs",
    "propagate_arcs_reference",
    "sample_arcs",
    "sample_arcs_reference",
    "samples_for_spacing",
]

# ----------------------------------------------------------------------------------------
# argument handling shared by both implementations


def _arc_arrays(
    spin_rad, kappa_per_mm, length_mm
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    spin = np.asarray(spin_rad, dtype=np.float64)
    kappa = np.asarray(kappa_per_mm, dtype=np.float64)
    length = np.asarray(length_mm, dtype=np.float64)
    single = spin.ndim == 0 and kappa.ndim == 0 and length.ndim == 0
    try:
        spin, kappa, length = np.broadcast_arrays(
            np.atleast_1d(spin), np.atleast_1d(kappa), np.atleast_1d(length)
        )
    except ValueError as exc:
        raise InvalidInputError(
            "spin_rad/kappa_per_mm/length_mm",
            f"shapes {spin.shape}, {kappa.shape}, {length.shape} do not broadcast",
        ) from exc
    for name, arr in (("spin_rad", spin), ("kappa_per_mm", kappa), ("length_mm", length)):
        if arr.ndim != 1:
            raise InvalidInputError(
                name, f"expected a number or a 1-D array, got shape {arr.shape}"
            )
        if not np.all(np.isfinite(arr)):
            raise InvalidInputError(name, "must be finite, got NaN or infinity")
    if np.any(length < 0.0):
        raise InvalidInputError("length_mm", f"must be >= 0, got {float(length.min())}")
    return (
        np.ascontiguousarray(spin),
        np.ascontiguousarray(kappa),
        np.ascontiguousarray(length),
        single,
    )


# ----------------------------------------------------------------------------------------
# numpy reference


def _sinc(x: np.ndarray) -> np.ndarray:
    """sin(x) / x, exact at 0 (numpy's sinc is sin(pi x) / (pi x))."""
    return np.sinc(x / np.pi)


def arc_transform(spin_rad, kappa_per_mm, length_mm):
    """Pose of the arc's end in the frame of its start (``start_T_end``).

    Parameters
    ----------
    spin_rad : float or array_like, shape (n,)
        Rotation about the tip's z axis before inserting (rad).
    kappa_per_mm : float or array_like, shape (n,)
        Curvature (1/mm); 0 for a straight segment.
    length_mm : float or array_like, shape (n,)
        Inserted arc length (mm), >= 0.

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)

    Examples
    --------
    A quarter circle of radius 50 mm ends 50 mm to the -y side and 50 mm ahead:

    >>> import numpy as np
    >>> np.round(arc_transform(0.0, 1 / 50, 25 * np.pi)[:3, 3], 9)
    array([  0., -50.,  50.])
    """
    spin, kappa, length, single = _arc_arrays(spin_rad, kappa_per_mm, length_mm)
    phi = kappa * length
    lateral = length * np.sin(0.5 * phi) * _sinc(0.5 * phi)  # (1 - cos phi) / kappa
    axial = length * _sinc(phi)  # sin(phi) / kappa
    cs, ss = np.cos(spin), np.sin(spin)
    cp, sp = np.cos(phi), np.sin(phi)
    n = spin.shape[0]
    out = np.zeros((n, 4, 4))
    # Rz(spin) @ Rx(phi)
    out[:, 0, 0] = cs
    out[:, 0, 1] = -ss * cp
    out[:, 0, 2] = ss * sp
    out[:, 1, 0] = ss
    out[:, 1, 1] = cs * cp
    out[:, 1, 2] = -cs * sp
    out[:, 2, 1] = sp
    out[:, 2, 2] = cp
    # Rz(spin) @ (0, -lateral, axial)
    out[:, 0, 3] = ss * lateral
    out[:, 1, 3] = -cs * lateral
    out[:, 2, 3] = axial
    out[:, 3, 3] = 1.0
    return unbatch(out, single)


def propagate_arcs_reference(world_T_tip, spin_rad, kappa_per_mm, length_mm):
    """Plain numpy version of :func:`propagate_arcs` (the test oracle).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
    spin_rad, kappa_per_mm, length_mm : float or array_like, shape (n,)

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
    """
    poses, spin, kappa, length, single = _broadcast_arc_batch(
        world_T_tip, spin_rad, kappa_per_mm, length_mm
    )
    out = poses @ arc_transform(spin, kappa, length)
    return unbatch(out, single)


def sample_arcs_reference(world_T_tip, spin_rad, kappa_per_mm, length_mm, n_samples: int):
    """Plain numpy version of :func:`sample_arcs` (the test oracle).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
    spin_rad, kappa_per_mm, length_mm : float or array_like, shape (n,)
    n_samples : int

    Returns
    -------
    ndarray, shape (n_samples, 3) or (n, n_samples, 3)
    """
    m = _check_samples(n_samples)
    poses, spin, kappa, length, single = _broadcast_arc_batch(
        world_T_tip, spin_rad, kappa_per_mm, length_mm
    )
    n = spin.shape[0]
    poses = np.broadcast_to(poses, (n, 4, 4))
    frac = np.linspace(0.0, 1.0, m)
    s = length[:, None] * frac[None, :]  # (n, m)
    local = arc_transform(np.repeat(spin, m), np.repeat(kappa, m), s.reshape(-1)).reshape(
        n, m, 4, 4
    )[:, :, :3, 3]
    out = np.einsum("nij,nmj->nmi", poses[:, :3, :3], local) + poses[:, None, :3, 3]
    return unbatch(out, single)


def _check_samples(n_samples) -> int:
    if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer)) or n_samples < 2:
        raise InvalidInputError("n_samples", f"expected an integer >= 2, got {n_samples!r}")
    return int(n_samples)


def samples_for_spacing(length_mm: float, spacing_mm: float) -> int:
    """Number of evenly spaced samples along an arc, ends included, with gaps <= spacing.

    Parameters
    ----------
    length_mm : float
        Arc length (>= 0).
    spacing_mm : float
        Largest allowed gap in arc length (> 0).

    Returns
    -------
    int
        At least 2.

    Examples
    --------
    >>> samples_for_spacing(10.0, 0.5)
    21
    """
    if not (np.isfinite(spacing_mm) and spacing_mm > 0):
        raise InvalidInputError("spacing_mm", f"must be a finite number > 0, got {spacing_mm}")
    if not (np.isfinite(length_mm) and length_mm >= 0):
        raise InvalidInputError("length_mm", f"must be a finite number >= 0, got {length_mm}")
    return max(2, math.ceil(length_mm / spacing_mm - 1e-12) + 1)


# ----------------------------------------------------------------------------------------
# numba kernels


@numba.njit(cache=True, inline="always")
def _sinc_nb(x: float) -> float:
    if abs(x) < 1e-4:
        x2 = x * x
        return 1.0 - x2 / 6.0 + x2 * x2 / 120.0
    return math.sin(x) / x


@numba.njit(cache=True, inline="always")
def _local_arc(spin: float, kappa: float, s: float, out: np.ndarray) -> None:
    """Write the 3x4 top of start_T_end for one arc into out."""
    phi = kappa * s
    lateral = s * math.sin(0.5 * phi) * _sinc_nb(0.5 * phi)
    axial = s * _sinc_nb(phi)
    cs, ss = math.cos(spin), math.sin(spin)
    cp, sp = math.cos(phi), math.sin(phi)
    out[0, 0] = cs
    out[0, 1] = -ss * cp
    out[0, 2] = ss * sp
    out[0, 3] = ss * lateral
    out[1, 0] = ss
    out[1, 1] = cs * cp
    out[1, 2] = -cs * sp
    out[1, 3] = -cs * lateral
    out[2, 0] = 0.0
    out[2, 1] = sp
    out[2, 2] = cp
    out[2, 3] = axial


@numba.njit(cache=True)
def _propagate_kernel(poses, spins, kappas, lengths, out):  # pragma: no cover - compiled
    n = out.shape[0]
    one_pose = poses.shape[0] == 1
    local = np.empty((3, 4))
    for k in range(n):
        p = 0 if one_pose else k
        _local_arc(spins[k], kappas[k], lengths[k], local)
        for i in range(3):
            for j in range(4):
                acc = 0.0
                for m in range(3):
                    acc += poses[p, i, m] * local[m, j]
                if j == 3:
                    acc += poses[p, i, 3]
                out[k, i, j] = acc
        out[k, 3, 0] = 0.0
        out[k, 3, 1] = 0.0
        out[k, 3, 2] = 0.0
        out[k, 3, 3] = 1.0


@numba.njit(cache=True)
def _sample_kernel(poses, spins, kappas, lengths, out):  # pragma: no cover - compiled
    n, m = out.shape[0], out.shape[1]
    one_pose = poses.shape[0] == 1
    for k in range(n):
        p = 0 if one_pose else k
        cs, ss = math.cos(spins[k]), math.sin(spins[k])
        # columns of R_world @ Rz(spin) that carry the tip's y and z axes
        yx = poses[p, 0, 0] * (-ss) + poses[p, 0, 1] * cs
        yy = poses[p, 1, 0] * (-ss) + poses[p, 1, 1] * cs
        yz = poses[p, 2, 0] * (-ss) + poses[p, 2, 1] * cs
        zx, zy, zz = poses[p, 0, 2], poses[p, 1, 2], poses[p, 2, 2]
        tx, ty, tz = poses[p, 0, 3], poses[p, 1, 3], poses[p, 2, 3]
        for q in range(m):
            s = lengths[k] * (q / (m - 1))
            half = 0.5 * kappas[k] * s
            sh, ch = math.sin(half), math.cos(half)
            sinc_h = _sinc_nb(half)
            lateral = s * sh * sinc_h  # (1 - cos phi) / kappa
            axial = s * ch * sinc_h  # sin(phi) / kappa = 2 sin(h) cos(h) / kappa
            out[k, q, 0] = tx - yx * lateral + zx * axial
            out[k, q, 1] = ty - yy * lateral + zy * axial
            out[k, q, 2] = tz - yz * lateral + zz * axial


def _broadcast_arc_batch(world_T_tip, spin_rad, kappa_per_mm, length_mm):
    spin, kappa, length, single_arc = _arc_arrays(spin_rad, kappa_per_mm, length_mm)
    poses, single_pose = as_poses(world_T_tip, "world_T_tip")
    n = max(spin.shape[0], poses.shape[0])
    if poses.shape[0] not in (1, n):
        raise InvalidInputError(
            "world_T_tip", f"batch of {poses.shape[0]} poses does not match {spin.shape[0]} arcs"
        )
    if spin.shape[0] not in (1, n):
        raise InvalidInputError(
            "spin_rad", f"{spin.shape[0]} arcs do not match a batch of {poses.shape[0]} poses"
        )
    spin, kappa, length = (_batch(a, n) for a in (spin, kappa, length))
    return poses, spin, kappa, length, single_arc and single_pose


def _batch(a: np.ndarray, n: int) -> np.ndarray:
    """``a`` broadcast to ``(n,)`` as a new writable C-contiguous float64 array, whether or
    not it had to be broadcast (a view of a batch of ``n`` would be read-only, a broadcast
    copy is not): the kernels see one argument type, the one :func:`arc_points_unchecked`
    gives them, and are compiled once, not once for each."""
    return np.array(np.broadcast_to(a, (n,)), dtype=np.float64, order="C")


def propagate_arcs(world_T_tip, spin_rad, kappa_per_mm, length_mm):
    """Tip poses after following arcs from given start poses (numba kernel).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
        Start tip poses in the world frame (RAS, mm). One pose is shared by all arcs.
    spin_rad, kappa_per_mm, length_mm : float or array_like, shape (n,)
        The arcs (see module docstring).

    Returns
    -------
    ndarray, shape (4, 4) or (n, 4, 4)
        ``world_T_tip @ arc_transform(spin, kappa, length)``.
    """
    poses, spin, kappa, length, single = _broadcast_arc_batch(
        world_T_tip, spin_rad, kappa_per_mm, length_mm
    )
    out = np.empty((spin.shape[0], 4, 4))
    _propagate_kernel(poses, spin, kappa, length, out)
    return unbatch(out, single)


def sample_arcs(world_T_tip, spin_rad, kappa_per_mm, length_mm, n_samples: int):
    """Points evenly spaced in arc length along arcs, ends included (numba kernel).

    Parameters
    ----------
    world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
        Start tip poses (world frame, mm).
    spin_rad, kappa_per_mm, length_mm : float or array_like, shape (n,)
        The arcs.
    n_samples : int
        Points per arc (>= 2); spacing is ``length_mm / (n_samples - 1)``
        (see :func:`samples_for_spacing`).

    Returns
    -------
    ndarray, shape (n_samples, 3) or (n, n_samples, 3)
        World coordinates (mm).

    Examples
    --------
    >>> import numpy as np
    >>> pts = sample_arcs(np.eye(4), 0.0, 0.0, 10.0, 3)
    >>> pts[:, 2]
    array([ 0.,  5., 10.])
    """
    m = _check_samples(n_samples)
    poses, spin, kappa, length, single = _broadcast_arc_batch(
        world_T_tip, spin_rad, kappa_per_mm, length_mm
    )
    out = np.empty((spin.shape[0], m, 3))
    _sample_kernel(poses, spin, kappa, length, out)
    return unbatch(out, single)


# ----------------------------------------------------------------------------------------
# unchecked entry points for search loops (spatialmath's ``check=False``): the caller
# passes a checked C-contiguous float64 (4, 4) pose and finite numbers; nothing is
# validated or broadcast. Each gives bit for bit what its checked twin gives.


@numba.njit(cache=True)
def arc_end_unchecked(pose, spin, kappa, length):  # pragma: no cover - compiled
    """The pose after one arc from ``pose`` (:func:`propagate_arcs` without its checks).

    Parameters
    ----------
    pose : ndarray, shape (4, 4), float64, C-contiguous
    spin, kappa, length : float

    Returns
    -------
    ndarray, shape (4, 4)
    """
    local = np.empty((3, 4))
    _local_arc(spin, kappa, length, local)
    out = np.empty((4, 4))
    for i in range(3):
        for j in range(4):
            acc = 0.0
            for m in range(3):
                acc += pose[i, m] * local[m, j]
            if j == 3:
                acc += pose[i, 3]
            out[i, j] = acc
    out[3, 0] = 0.0
    out[3, 1] = 0.0
    out[3, 2] = 0.0
    out[3, 3] = 1.0
    return out


@numba.njit(cache=True)
def arc_points_unchecked(pose, spin, kappa, length, n_samples):  # pragma: no cover
    """``sample_arcs(pose, spin, kappa, length, n_samples)`` without its checks.

    Parameters
    ----------
    pose : ndarray, shape (4, 4), float64, C-contiguous
    spin, kappa, length : float
    n_samples : int
        At least 2.

    Returns
    -------
    ndarray, shape (n_samples, 3)
    """
    out = np.empty((1, n_samples, 3))
    _sample_kernel(
        pose.reshape(1, 4, 4),
        np.full(1, spin),
        np.full(1, kappa),
        np.full(1, length),
        out,
    )
    return out[0]


@numba.njit(cache=True)
def min_tangent_dot_unchecked(pose, spin, kappa, length, direction):  # pragma: no cover
    """The smallest ``tangent . direction`` along a whole arc, in closed form (the heading
    check of the planners and of the plan check, exact between any samples).

    Along the arc the tangent is ``sin(phi) u + cos(phi) z`` with ``phi = kappa s``, ``z``
    the pose's z axis and ``u`` its bending direction, so ``tangent . direction`` is
    ``A sin(phi) + B cos(phi) = C cos(phi - psi)``: its minimum over ``phi`` between 0 and
    ``kappa * length`` is ``-C`` where ``phi = psi + pi (mod 2 pi)`` lies in that range,
    else the smaller end.

    Parameters
    ----------
    pose : ndarray, shape (4, 4), float64, C-contiguous
    spin, kappa, length : float
    direction : ndarray, shape (3,)
        A unit vector (the start direction).

    Returns
    -------
    float
    """
    cs, ss = math.cos(spin), math.sin(spin)
    # the tangent Rz(spin) Rx(phi) e_z = (ss sp, -cs sp, cp) in the pose's frame
    a = 0.0
    b = 0.0
    for i in range(3):
        a += (pose[i, 0] * ss - pose[i, 1] * cs) * direction[i]
        b += pose[i, 2] * direction[i]
    end = kappa * length
    lo, hi = min(0.0, end), max(0.0, end)
    best = min(b, a * math.sin(end) + b * math.cos(end))
    psi = math.atan2(a, b)
    k = math.ceil((lo - psi - math.pi) / (2.0 * math.pi))
    if psi + math.pi + 2.0 * math.pi * k <= hi:
        best = min(best, -math.hypot(a, b))
    return best
