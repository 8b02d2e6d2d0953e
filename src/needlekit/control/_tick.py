"""The control step's numerical core as two numba kernels.

:func:`control_qp` builds the whole QP of one control step (task error and Jacobian, Hessian
and gradient, the step's VFI rows and the joint-limit bounds) into buffers the caller keeps
from step to step, in the solver-neutral layout of :mod:`needlekit.control.qp` (DAQP reads
it as it is), so that :func:`needlekit.control.controller.control_step` is one kernel call
and one solver call. :func:`vfi_data` gives the VFIs' distances and their
Jacobians in the joints and (optionally) in the 12 model parameters, which the adaptation
law needs. Both do the arithmetic of the numpy code they replace
(:func:`~needlekit.control.vfi.point_line_sq_distance` and the others) in the same order,
up to the summation order of the small matrix products; the tests compare them with it.

Geometry and gains come packed (:func:`pack_geometry`): ``geo`` (21,) is the guide target,
``l_g``, ``u = -l_g``, the plane's point and normal and the patient cylinder's point and
direction; ``par`` (11,) is ``eta, damping^2, axis_scale_mm, R_g^2, the cone's safe value,
R_p^2, eta_guide, eta_cone, eta_plane, eta_patient, eta_joints``.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from needlekit.control.panda import _points_line_sq_distances
from needlekit.control.qp import NO_BOUND
from needlekit.geometry.segments import closest_segment_params

#: Task kinds: the needle axis (ALIGN), tip and weighted axis, the tip alone.
TASK_AXIS, TASK_TIP_AXIS, TASK_TIP = 0, 1, 2
#: VFI kinds: none (the caller fills the rows), robot points outside the patient
#: cylinder (ALIGN, APPROACH), guide cylinder + cone + plane (PUNCTURE).
VFI_NONE, VFI_PATIENT, VFI_PUNCTURE = 0, 1, 2

#: "No bound" in the QP layout (:data:`needlekit.control.qp.NO_BOUND`).
_INF = NO_BOUND


def pack_geometry(guide, settings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``geo``, ``par`` and the robot points (int64) of a guide line and settings.

    Parameters
    ----------
    guide : GuideLine
    settings : ControllerSettings

    Returns
    -------
    geo : ndarray, shape (21,)
    par : ndarray, shape (11,)
    robot_points : ndarray of int64
    """
    cfg = settings
    cyl = guide.patient_line(cfg.patient_axis)
    geo = np.concatenate(
        [
            guide.target_mm, guide.line.direction, guide.insertion_direction,
            guide.plane.point_mm, guide.plane.normal, cyl.point_mm, cyl.direction,
        ]
    )  # fmt: skip
    par = np.array(
        [
            cfg.eta, cfg.damping**2, cfg.axis_scale_mm, cfg.guide_radius_mm**2,
            2.0 - 2.0 * np.cos(cfg.cone_angle_rad), cfg.patient_radius_mm**2, cfg.eta_guide,
            cfg.eta_cone, cfg.eta_plane, cfg.eta_patient, cfg.eta_joints,
        ],
        dtype=float,
    )  # fmt: skip
    return geo, par, np.asarray(cfg.robot_points, dtype=np.int64)


@nb.njit(cache=True)
def vfi_data(kind, tip, axis, jt, ja, axes, origins, ks, geo, with_a, pj_tip, pj_axis, wb, a):
    """Distances of the step's VFIs and their Jacobians.

    Returns
    -------
    d : ndarray, shape (m,)
        Patient: each robot point's squared distance from the cylinder's axis; puncture:
        guide (mm^2), cone (``2 - 2 cos``), plane (mm).
    jq : ndarray, shape (m, n)
        In the joints.
    jp : ndarray, shape (m, 12)
        In the parameters (zeros unless ``with_a``).
    """
    n = jt.shape[1]
    if kind == VFI_PATIENT:
        d, jq = _points_line_sq_distances(axes, origins, ks, geo[15:18], geo[18:21])
        m = ks.shape[0]
        jp = np.zeros((m, 12))
        if with_a:
            c, ell = geo[15:18], geo[18:21]
            for r in range(m):
                p = origins[ks[r]]
                v0, v1, v2 = p[0] - c[0], p[1] - c[1], p[2] - c[2]
                t = v0 * ell[0] + v1 * ell[1] + v2 * ell[2]
                e0, e1, e2 = v0 - t * ell[0], v1 - t * ell[1], v2 - t * ell[2]
                jp[r, 0], jp[r, 1], jp[r, 2] = 2.0 * e0, 2.0 * e1, 2.0 * e2
                # a link point moves with the base: (W_b e_c) x (p - t_b), dotted with 2 perp
                r0, r1, r2 = p[0] - a[0], p[1] - a[1], p[2] - a[2]
                x0 = 2.0 * (r1 * e2 - r2 * e1)
                x1 = 2.0 * (r2 * e0 - r0 * e2)
                x2 = 2.0 * (r0 * e1 - r1 * e0)
                for col in range(3):
                    jp[r, 3 + col] = x0 * wb[0, col] + x1 * wb[1, col] + x2 * wb[2, col]
        return d, jq, jp
    d = np.empty(3)
    jq = np.zeros((3, n))
    jp = np.zeros((3, 12))
    # guide cylinder: squared distance of the tip from the guide line (through the target)
    v0, v1, v2 = tip[0] - geo[0], tip[1] - geo[1], tip[2] - geo[2]
    t = v0 * geo[3] + v1 * geo[4] + v2 * geo[5]
    e0, e1, e2 = v0 - geo[3] * t, v1 - geo[4] * t, v2 - geo[5] * t
    d[0] = e0 * e0 + e1 * e1 + e2 * e2
    # cone: |axis - u|^2
    f0, f1, f2 = axis[0] - geo[6], axis[1] - geo[7], axis[2] - geo[8]
    d[1] = f0 * f0 + f1 * f1 + f2 * f2
    # plane: (tip - point) . normal
    d[2] = (tip[0] - geo[9]) * geo[12] + (tip[1] - geo[10]) * geo[13] + (tip[2] - geo[11]) * geo[14]
    g0, g1, g2 = 2.0 * e0, 2.0 * e1, 2.0 * e2
    u0, u1, u2 = -2.0 * geo[6], -2.0 * geo[7], -2.0 * geo[8]
    for c in range(n):
        jq[0, c] = g0 * jt[0, c] + g1 * jt[1, c] + g2 * jt[2, c]
        jq[1, c] = u0 * ja[0, c] + u1 * ja[1, c] + u2 * ja[2, c]
        jq[2, c] = geo[12] * jt[0, c] + geo[13] * jt[1, c] + geo[14] * jt[2, c]
    if with_a:
        for c in range(12):
            jp[0, c] = g0 * pj_tip[0, c] + g1 * pj_tip[1, c] + g2 * pj_tip[2, c]
            jp[1, c] = u0 * pj_axis[0, c] + u1 * pj_axis[1, c] + u2 * pj_axis[2, c]
            jp[2, c] = geo[12] * pj_tip[0, c] + geo[13] * pj_tip[1, c] + geo[14] * pj_tip[2, c]
    return d, jq, jp


@nb.njit(cache=True)
def control_qp(task, kind, q, tip, axis, jt, ja, axes, origins, ks, geo, par, p_d, v_d,
               q_min, q_max, q_dot_max, share, H, f, A, bu, bl, dist):  # fmt: skip
    """Fill one control step's QP into ``H`` (n, n), ``f`` (n,), ``A`` (m, n), ``bu`` and
    ``bl`` (n + m: bounds on q_dot, then rows; the layout of :mod:`needlekit.control.qp`) and ``dist`` (the VFI distances: patient, its
    smallest; puncture: guide, cone, plane). With ``kind == VFI_NONE`` the rows of ``A`` and
    ``bu[n:]`` are left to the caller.

    Returns
    -------
    err : ndarray
        The task error (a new array).
    infeasible : bool
        A joint's lower bound lies above its upper bound.
    """
    n = q.shape[0]
    eta, damp2, w = par[0], par[1], par[2]
    mt = 6 if task == TASK_TIP_AXIS else 3
    jac = np.empty((mt, n))
    err = np.empty(mt)
    rhs = np.empty(mt)  # eta err - feed-forward
    for r in range(3):
        if task == TASK_AXIS:
            err[r] = axis[r] - geo[6 + r]
            rhs[r] = eta * err[r] - 0.0
            for c in range(n):
                jac[r, c] = ja[r, c]
        else:
            err[r] = tip[r] - p_d[r]
            rhs[r] = eta * err[r] - v_d[r]
            for c in range(n):
                jac[r, c] = jt[r, c]
        if task == TASK_TIP_AXIS:
            err[3 + r] = w * (axis[r] - geo[6 + r])
            rhs[3 + r] = eta * err[3 + r] - 0.0
            for c in range(n):
                jac[3 + r, c] = w * ja[r, c]
    # H = 2 (J'J + damping^2 I), f = 2 J' (eta err - ff)
    for i in range(n):
        s = 0.0
        for r in range(mt):
            s += 2.0 * jac[r, i] * rhs[r]
        f[i] = s
        for j in range(i, n):
            s = 0.0
            for r in range(mt):
                s += jac[r, i] * jac[r, j]
            if i == j:
                s += damp2
            H[i, j] = 2.0 * s
            H[j, i] = 2.0 * s
    # VFI rows: OUTSIDE -J q_dot <= eta (d - d_s); INSIDE J q_dot <= eta (d_s - d)
    if kind != VFI_NONE:
        z = np.zeros((1, 1))
        d, jq, _ = vfi_data(kind, tip, axis, jt, ja, axes, origins, ks, geo, False, z, z, z,
                            geo)  # fmt: skip
        if kind == VFI_PATIENT:
            gain = share * par[9]
            dist[0] = np.inf
            for r in range(d.shape[0]):
                for c in range(n):
                    A[r, c] = -jq[r, c]
                bu[n + r] = gain * (d[r] - par[5])
                dist[0] = min(dist[0], d[r])
        else:
            for c in range(n):
                A[0, c] = jq[0, c]
                A[1, c] = jq[1, c]
                A[2, c] = -jq[2, c]
            bu[n] = share * par[6] * (par[3] - d[0])
            bu[n + 1] = share * par[7] * (par[4] - d[1])
            bu[n + 2] = share * par[8] * (d[2] - 0.0)
            dist[0], dist[1], dist[2] = d[0], d[1], d[2]
    # joint position limits as VFIs, intersected with the velocity limits
    infeasible = False
    ej = par[10]
    for i in range(n):
        lo = ej * (q_min[i] - q[i])
        hi = ej * (q_max[i] - q[i])
        lo = max(-q_dot_max[i], lo)
        hi = min(q_dot_max[i], hi)
        bl[i], bu[i] = lo, hi
        infeasible = infeasible or lo > hi
    for r in range(n, bl.shape[0]):
        bl[r] = -_INF
    return err, infeasible


@nb.njit(cache=True)
def shaft_rows(tip, axis, jt, ja, length, segs, safe2, gain, A, bu, row0, fill):
    """The placed-needle VFIs: the held needle's shaft (``tip - s axis``, ``s`` in
    ``[0, length]``) outside radius ``sqrt(safe2)`` of each placed needle's segment
    ``segs[i, 0] -> segs[i, 1]`` (OUTSIDE zone on the squared distance ``D``, with
    ``D_dot = 2 w . (J_tip - s J_axis) q_dot``, ``w`` the closest points' offset).

    With ``fill`` the rows go to ``A[row0 + i]`` and ``bu[n + row0 + i]`` (n = joints);
    returns the smallest squared distance (mm^2; infinity without segments).
    """
    n = jt.shape[1]
    d1x, d1y, d1z = -length * axis[0], -length * axis[1], -length * axis[2]
    best = np.inf
    for i in range(segs.shape[0]):
        q0x, q0y, q0z = segs[i, 0, 0], segs[i, 0, 1], segs[i, 0, 2]
        d2x, d2y, d2z = segs[i, 1, 0] - q0x, segs[i, 1, 1] - q0y, segs[i, 1, 2] - q0z
        s, t = closest_segment_params(
            tip[0] - q0x, tip[1] - q0y, tip[2] - q0z, d1x, d1y, d1z, d2x, d2y, d2z
        )
        w0 = tip[0] + s * d1x - q0x - t * d2x
        w1 = tip[1] + s * d1y - q0y - t * d2y
        w2 = tip[2] + s * d1z - q0z - t * d2z
        dd = w0 * w0 + w1 * w1 + w2 * w2
        best = min(best, dd)
        if fill:
            sl = s * length
            for c in range(n):
                g = (
                    w0 * (jt[0, c] - sl * ja[0, c])
                    + w1 * (jt[1, c] - sl * ja[1, c])
                    + w2 * (jt[2, c] - sl * ja[2, c])
                )
                A[row0 + i, c] = -2.0 * g
            bu[n + row0 + i] = gain * (dd - safe2)
    return best
