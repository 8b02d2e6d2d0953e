"""numba kernels of the adaptation law (:mod:`needlekit.control.adaptation`): the keyframe
history's rows and normal equations, its flange distances and SE(3) means, and the rotation
log. Private: the adaptation module is their interface.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from needlekit.control.parameters import _xyz_matrix, _xyz_rate

#: Weight of rotation against translation when keyframes are compared (mm per rad).
POSE_DISTANCE_MM_PER_RAD = 100.0


@nb.njit(cache=True)
def _parameter_maps(a):
    """``t_b, R_b, W_b, t_n, R_n, W_n`` of the parameters."""
    return (
        a[:3].copy(), _xyz_matrix(a[3], a[4], a[5]), _xyz_rate(a[3], a[4]),
        a[6:9].copy(), _xyz_matrix(a[9], a[10], a[11]), _xyz_rate(a[9], a[10]),
    )  # fmt: skip


@nb.njit(cache=True)
def _rotation_log(r):
    """Rotation vector of a rotation matrix (accurate near 0 and near pi)."""
    out = np.empty(3)
    _rotation_log_into(r, out)
    return out


@nb.njit(cache=True)
def _rotation_log_into(r, out):
    """:func:`_rotation_log` into ``out`` (no allocation but near pi)."""
    c = min(1.0, max(-1.0, 0.5 * (r[0, 0] + r[1, 1] + r[2, 2] - 1.0)))
    v0, v1, v2 = 0.5 * (r[2, 1] - r[1, 2]), 0.5 * (r[0, 2] - r[2, 0]), 0.5 * (r[1, 0] - r[0, 1])
    s = np.sqrt(v0**2 + v1**2 + v2**2)
    theta = np.arctan2(s, c)
    if theta < 1e-8:
        out[0], out[1], out[2] = v0, v1, v2
        return
    if c > -0.5:
        k = theta / s
        out[0], out[1], out[2] = v0 * k, v1 * k, v2 * k
        return
    # near pi: the axis from the symmetric part, its sign from the skew part
    sym = 0.5 * (r + r.T)
    best, k = -1.0, 0
    for i in range(3):
        d = (sym[i, i] - c) / (1.0 - c)
        if d > best:
            best, k = d, i
    axis = (sym[k] - c * np.eye(3)[k]) / (1.0 - c)
    axis /= np.sqrt(axis[0] ** 2 + axis[1] ** 2 + axis[2] ** 2)
    if axis[0] * v0 + axis[1] * v1 + axis[2] * v2 < 0.0:
        axis = -axis
    out[:] = axis * theta


@nb.njit(cache=True)
def _keyframe_rows(pose, tb, rb, wb, tn, rn, wn, s, err, jac, work):
    """One keyframe's error (6,) and parameter Jacobian (6, 12) into ``err`` and ``jac``
    (whose other entries stay zero): the flange ``pose[0]`` in the base frame, the measured
    tip ``pose[1]`` in the world. ``work``: (4, 3, 3) scratch."""
    rf = work[0]  # the flange's rotation in the world
    rfrn = work[1]
    m = work[2]  # R_est R_meas^T
    v, rel = work[3, 0], work[3, 1]
    for r in range(3):
        v[r] = pose[0, r, 3] + (pose[0, r, 0] * tn[0] + pose[0, r, 1] * tn[1]
                                + pose[0, r, 2] * tn[2])  # fmt: skip
        for c in range(3):
            rf[r, c] = (
                rb[r, 0] * pose[0, 0, c] + rb[r, 1] * pose[0, 1, c] + rb[r, 2] * pose[0, 2, c]
            )
    for r in range(3):
        for c in range(3):
            rfrn[r, c] = rf[r, 0] * rn[0, c] + rf[r, 1] * rn[1, c] + rf[r, 2] * rn[2, c]
    for r in range(3):
        for c in range(3):
            m[r, c] = (
                rfrn[r, 0] * pose[1, c, 0] + rfrn[r, 1] * pose[1, c, 1] + rfrn[r, 2] * pose[1, c, 2]
            )
    for r in range(3):
        tip = tb[r] + (rb[r, 0] * v[0] + rb[r, 1] * v[1] + rb[r, 2] * v[2])
        rel[r] = tip - tb[r]
        err[r] = tip - pose[1, r, 3]
    lg = work[3, 2]
    _rotation_log_into(m, lg)
    for r in range(3):
        err[3 + r] = s * lg[r]
    for c in range(3):
        w0, w1, w2 = wb[0, c], wb[1, c], wb[2, c]
        # d tip / d angles_b: (W_b e_c) x rel
        jac[0, 3 + c] = w1 * rel[2] - w2 * rel[1]
        jac[1, 3 + c] = w2 * rel[0] - w0 * rel[2]
        jac[2, 3 + c] = w0 * rel[1] - w1 * rel[0]
        for r in range(3):
            jac[r, r] = 1.0
            jac[r, 6 + c] = rf[r, c]
            jac[3 + r, 3 + c] = s * wb[r, c]
            jac[3 + r, 9 + c] = s * (
                rf[r, 0] * wn[0, c] + rf[r, 1] * wn[1, c] + rf[r, 2] * wn[2, c]
            )


@nb.njit(cache=True)
def _stacked_errors(poses, extra, a, s):
    """Measurement errors and parameter Jacobians of keyframes and the extra sample (flange in
    the base frame, measured tip in the world) at the parameters ``a``."""
    tb, rb, wb, tn, rn, wn = _parameter_maps(a)
    k = poses.shape[0] + extra.shape[0]
    err = np.empty(6 * k)
    jac = np.zeros((6 * k, 12))
    work = np.empty((4, 3, 3))
    for i in range(k):
        pose = poses[i] if i < poses.shape[0] else extra[i - poses.shape[0]]
        _keyframe_rows(pose, tb, rb, wb, tn, rn, wn, s, err[6 * i : 6 * i + 6],
                       jac[6 * i : 6 * i + 6], work)  # fmt: skip
    return err, jac


@nb.njit(cache=True)
def _add_atb(out, i0, j0, a, ra, ca, b, rb, cb):
    """``out[i0:i0+3, j0:j0+3] += A' B`` for the 3 x 3 blocks ``A = a[ra:ra+3, ca:ca+3]`` and
    ``B = b[rb:rb+3, cb:cb+3]``."""
    for i in range(3):
        for j in range(3):
            out[i0 + i, j0 + j] += (
                a[ra, ca + i] * b[rb, cb + j]
                + a[ra + 1, ca + i] * b[rb + 1, cb + j]
                + a[ra + 2, ca + i] * b[rb + 2, cb + j]
            )


@nb.njit(cache=True)
def _normal_equations(poses, extra, a, s):
    """``J' J`` (12, 12) and ``J' e`` (12,) of :func:`_stacked_errors`, summed keyframe by
    keyframe block by block: a keyframe's rows are ``[I C R_f 0; 0 S_b 0 S_n]`` (3 x 3 blocks,
    position rows over rotation rows)."""
    tb, rb, wb, tn, rn, wn = _parameter_maps(a)
    jtj = np.zeros((12, 12))
    jte = np.zeros(12)
    err = np.empty(6)
    jac = np.zeros((6, 12))
    work = np.empty((4, 3, 3))
    for i in range(poses.shape[0] + extra.shape[0]):
        pose = poses[i] if i < poses.shape[0] else extra[i - poses.shape[0]]
        _keyframe_rows(pose, tb, rb, wb, tn, rn, wn, s, err, jac, work)
        for r in range(3):
            jtj[r, r] += 1.0
            jte[r] += err[r]
            for c in range(3):
                jtj[r, 3 + c] += jac[r, 3 + c]
                jtj[r, 6 + c] += jac[r, 6 + c]
        _add_atb(jtj, 3, 3, jac, 0, 3, jac, 0, 3)  # C'C
        _add_atb(jtj, 3, 3, jac, 3, 3, jac, 3, 3)  # + S_b'S_b
        _add_atb(jtj, 3, 6, jac, 0, 3, jac, 0, 6)  # C'R_f
        _add_atb(jtj, 3, 9, jac, 3, 3, jac, 3, 9)  # S_b'S_n
        _add_atb(jtj, 6, 6, jac, 0, 6, jac, 0, 6)  # R_f'R_f
        _add_atb(jtj, 9, 9, jac, 3, 9, jac, 3, 9)  # S_n'S_n
        for c in range(3):
            jte[3 + c] += (jac[0, 3 + c] * err[0] + jac[1, 3 + c] * err[1]
                           + jac[2, 3 + c] * err[2]) + (jac[3, 3 + c] * err[3]
                           + jac[4, 3 + c] * err[4] + jac[5, 3 + c] * err[5])  # fmt: skip
            jte[6 + c] += jac[0, 6 + c] * err[0] + jac[1, 6 + c] * err[1] + jac[2, 6 + c] * err[2]
            jte[9 + c] += jac[3, 9 + c] * err[3] + jac[4, 9 + c] * err[4] + jac[5, 9 + c] * err[5]
    for r in range(12):
        for c in range(r):
            jtj[r, c] = jtj[c, r]
    return jtj, jte


@nb.njit(cache=True)
def _flange_distance(g, h):
    """Distance (mm) and angle (rad) between two poses' origins and rotations."""
    dp = 0.0
    for r in range(3):
        dp += (g[r, 3] - h[r, 3]) ** 2
    tr = 0.0
    for k in range(3):
        tr += g[0, k] * h[0, k] + g[1, k] * h[1, k] + g[2, k] * h[2, k]
    cos = min(1.0, max(-1.0, (tr - 1.0) / 2.0))
    return np.sqrt(dp), np.arccos(cos)


@nb.njit(cache=True)
def _add_distances(dist, poses, k):
    """Keyframe ``k``'s flange distances (mm + 100 mm/rad) to keyframes ``0..k-1``."""
    for j in range(k):
        dp, angle = _flange_distance(poses[k, 0], poses[j, 0])
        dist[k, j] = dist[j, k] = dp + POSE_DISTANCE_MM_PER_RAD * angle


@nb.njit(cache=True)
def _closest_pair(dist, n):
    """The older of the two closest of keyframes ``0..n-1`` (the first pair in row order)."""
    best, keep = np.inf, 0
    for i in range(n):
        for j in range(i + 1, n):
            if dist[i, j] < best:
                best, keep = dist[i, j], i
    return keep


@nb.njit(cache=True)
def _drop_distances(dist, i, n):
    """Remove keyframe ``i`` from the first ``n`` rows and columns."""
    for r in range(i, n - 1):
        for c in range(n):
            dist[r, c] = dist[r + 1, c]
    for c in range(i, n - 1):
        for r in range(n - 1):
            dist[r, c] = dist[r, c + 1]


@nb.njit(cache=True)
def measurement_error(est, meas, s):
    """``[p_est - p_meas; s log(R_est R_meas^T)]`` of two 4 x 4 poses."""
    m = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            m[r, c] = est[r, 0] * meas[c, 0] + est[r, 1] * meas[c, 1] + est[r, 2] * meas[c, 2]
    out = np.empty(6)
    _rotation_log_into(m, out[3:])
    for r in range(3):
        out[r] = est[r, 3] - meas[r, 3]
        out[3 + r] = s * out[3 + r]
    return out


@nb.njit(cache=True)
def adaptation_qp(jtj, jte, scale, damp2, f_gain, vfi, vjac, clamp, stab, stab_rhs, bound_gain,
                  lower, upper, a):  # fmt: skip
    """The adaptation QP's ``H``, ``f``, rows, and bounds (``bu``, ``bl``: on ``a_dot``,
    then the rows; the layout of :mod:`needlekit.control.qp`), and whether a bound pair is crossed. ``vfi`` (m, 4): distance, safe
    value, gain, 1 for a forbidden zone (else a safe one), with the rows' Jacobians ``vjac``
    (m, 12); ``stab`` (0 or 1, 12): the stability row, whose right-hand side is
    ``stab_rhs``. ``f_gain``: ``2 eta scale``."""
    n = jtj.shape[0]
    H = np.empty((n, n))
    f = np.empty(n)
    for i in range(n):
        f[i] = f_gain * jte[i]
        for j in range(n):
            H[i, j] = 2.0 * (scale * jtj[i, j] + (damp2 if i == j else damp2 * 0.0))
    mv, ms = vfi.shape[0], stab.shape[0]
    A = np.empty((mv + ms, n))
    bu = np.empty(n + mv + ms)
    bl = np.full(n + mv + ms, -1e30)
    for r in range(mv):
        d, safe, gain = vfi[r, 0], vfi[r, 1], vfi[r, 2]
        outside = vfi[r, 3] != 0.0
        for c in range(n):
            A[r, c] = -vjac[r, c] if outside else vjac[r, c]
        b = gain * (d - safe) if outside else gain * (safe - d)
        # never pull the estimate in: only forbid pushing it out
        bu[n + r] = max(b, 0.0) if clamp else b
    for c in range(n):
        if ms:
            A[mv, c] = stab[0, c]
    if ms:
        bu[n + mv] = stab_rhs
    infeasible = False
    for i in range(n):
        bl[i] = bound_gain * (lower[i] - a[i])
        bu[i] = bound_gain * (upper[i] - a[i])
        infeasible = infeasible or bl[i] > bu[i]
    return H, f, A, bu, bl, infeasible
