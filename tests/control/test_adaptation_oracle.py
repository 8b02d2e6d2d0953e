"""The adaptation's fast paths against the implementation they replaced, kept here as the
oracle: the keyframe history (lazy SE(3) projection of merged samples, an incremental
distance matrix for the eviction, per-keyframe rows without allocations) and the
adaptation step (normal equations summed instead of a stacked 6k x 12 matrix).

Tolerances: the keyframe rows and the distances do the oracle's arithmetic with the 3 x 3
products summed in a fixed order instead of by BLAS (a few ulps); the history's decisions
(merge, keyframe, eviction) must be identical. ``J'J`` and ``J'e`` summed keyframe by
keyframe differ from BLAS's sum over the 6k rows by rounding only: 1e-12 relative to the
largest entry (for ``J'e``, whose terms cancel, to the largest sum of absolute terms). The parameter rates come out of a QP whose Hessian has a condition number
up to ~1e9, so they are compared at ``10 eps cond(H)`` (see
``test_control_step_oracle.py``).
"""

import numpy as np
import pytest

from needlekit.control.adaptation import (
    AdaptationSettings,
    MeasurementHistory,
    _rotation_log,
    adaptation_step,
    measurement_error,
)
from needlekit.control.controller import ControllerSettings, GuideLine, Step, step_vfis
from needlekit.control.panda import PandaModel
from needlekit.control.parameters import (
    model_from_parameters,
    parameter_jacobians,
    pose_from_parameters,
    xyz_euler_rate_matrix,
)
from needlekit.control.qp import QPStatus, solve_qp
from needlekit.control.vfi import vfi_row

NOMINAL = np.array([-650.0, 0.0, -450.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
SPREAD = np.array([50.0] * 3 + [np.radians(10)] * 3 + [10.0] * 3 + [np.radians(5)] * 3)
SETTINGS = AdaptationSettings(NOMINAL - 4 * SPREAD, NOMINAL + 4 * SPREAD)
REL = 1e-12


# ---- the oracle: the history and the adaptation step as they were ------------------------


def _ref_stacked_errors(poses, tb, rb, wb, tn, rn, wn, s):
    k = poses.shape[0]
    err = np.empty(6 * k)
    jac = np.zeros((6 * k, 12))
    for i in range(k):
        f_r, f_p = poses[i, 0, :3, :3], poses[i, 0, :3, 3]
        y_rt, y_p = poses[i, 1, :3, :3].T, poses[i, 1, :3, 3]
        rf = rb @ f_r
        tip = tb + rb @ (f_p + f_r @ tn)
        rel = tip - tb
        o = 6 * i
        err[o : o + 3] = tip - y_p
        err[o + 3 : o + 6] = s * _rotation_log(np.ascontiguousarray(rf @ rn @ y_rt))
        for r in range(3):
            jac[o + r, r] = 1.0
            for c in range(3):
                w = wb[:, c]
                cr = (w[1] * rel[2] - w[2] * rel[1], w[2] * rel[0] - w[0] * rel[2],
                      w[0] * rel[1] - w[1] * rel[0])  # fmt: skip
                jac[o + r, 3 + c] = cr[r]
                jac[o + r, 6 + c] = rf[r, c]
                jac[o + 3 + r, 3 + c] = s * wb[r, c]
        jac[o + 3 : o + 6, 9:12] = s * (rf @ wn)
    return err, jac


def _ref_mean_poses(poses):
    out = np.zeros_like(poses)
    u, _, vt = np.linalg.svd(poses[:, :3, :3])
    d = np.sign(np.linalg.det(u @ vt))
    out[:, :3, :3] = u @ (vt * np.stack([np.ones_like(d), np.ones_like(d), d], axis=1)[:, :, None])
    out[:, :3, 3] = poses[:, :3, 3]
    out[:, 3, 3] = 1.0
    return out


class _RefHistory:
    def __init__(self, capacity=40, spacing_mm=10.0, spacing_deg=5.0, merge_mm=0.5,
                 merge_deg=0.1):  # fmt: skip
        self.capacity = capacity
        self._spacing = (spacing_mm, np.radians(spacing_deg))
        self._merge = (merge_mm, np.radians(merge_deg))
        self._anchor, self._sum = np.eye(4), np.zeros((2, 4, 4))
        self._count: list[int] = []
        self._poses = np.empty((0, 2, 4, 4))
        self._current = None

    def __len__(self):
        return len(self._count)

    def add(self, base_T_flange, measured_tip):
        sample = np.stack([base_T_flange, measured_tip]).astype(float)
        self._current = None
        if self._count:
            dp = float(np.linalg.norm(base_T_flange[:3, 3] - self._anchor[:3, 3]))
            cos = (np.trace(base_T_flange[:3, :3].T @ self._anchor[:3, :3]) - 1.0) / 2.0
            angle = float(np.arccos(np.clip(cos, -1.0, 1.0)))
            if dp <= self._merge[0] and angle <= self._merge[1]:
                self._sum += sample
                self._count[-1] += 1
                self._poses[-1] = _ref_mean_poses(self._sum / self._count[-1])
                return "merged"
            if dp < self._spacing[0] and angle < self._spacing[1]:
                self._current = sample
                return "current"
        self._anchor, self._sum = sample[0], sample.copy()
        self._count.append(1)
        self._poses = np.concatenate([self._poses, sample[None]])
        if len(self._count) > self.capacity:
            k = self._most_redundant()
            del self._count[k]
            self._poses = np.delete(self._poses, k, axis=0)
            return f"evicted {k}"
        return "keyframe"

    def _most_redundant(self):
        flange = self._poses[:-1, 0]
        p = flange[:, :3, 3]
        d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=2)
        cos = (np.einsum("iab,jab->ij", flange[:, :3, :3], flange[:, :3, :3]) - 1.0) / 2.0
        d += 100.0 * np.arccos(np.clip(cos, -1.0, 1.0))
        np.fill_diagonal(d, np.inf)
        i, j = np.unravel_index(int(np.argmin(d)), d.shape)
        return int(min(i, j))

    def stacked(self, a, s):
        poses = self._poses
        if self._current is not None:
            poses = np.concatenate([poses, self._current[None]])
        rb = np.ascontiguousarray(pose_from_parameters(a[:6])[:3, :3])
        rn = np.ascontiguousarray(pose_from_parameters(a[6:])[:3, :3])
        wb, wn = xyz_euler_rate_matrix(a[3:6]), xyz_euler_rate_matrix(a[9:12])
        return _ref_stacked_errors(poses, a[:3].copy(), rb, wb, a[6:9].copy(), rn, wn, s)


def _ref_adaptation_qp(a, est_tip, measured, pj, settings, step, task_error, cfg, vfis, share,
                       history):  # fmt: skip
    s = settings.orientation_scale_mm
    err = measurement_error(est_tip, measured, s)
    if history is not None and len(history):
        y_err, jac = history.stacked(a, s)
        scale = 1.0 / len(history)
    else:
        y_err, jac, scale = err, np.vstack([pj.tip, s * pj.angular]), 1.0
    n = 12
    H = 2.0 * (scale * jac.T @ jac + settings.damping**2 * np.eye(n))
    f = 2.0 * settings.eta * scale * jac.T @ y_err
    rows, rhs = [], []
    for v in vfis:
        r, b = vfi_row(v.distance, v.jac_a, v.safe, v.zone, (1.0 - share) * v.gain)
        rows.append(r)
        rhs.append(max(b, 0.0) if settings.clamp_vfi_rows else b)
    if step is not None and task_error is not None:
        jx = np.vstack([pj.tip, cfg.axis_scale_mm * pj.axis]) if step is not Step.ALIGN else pj.axis
        rows.append(task_error @ jx)
        r2 = settings.stability_radius_mm**2
        rhs.append(max(0.0, 0.5 * settings.eta * (r2 - float(task_error @ task_error))))
    lower = settings.bound_gain * (settings.lower - a)
    upper = settings.bound_gain * (settings.upper - a)
    return H, f, np.array(rows).reshape(-1, n), np.array(rhs), lower, upper, err


# ---- a sensor's samples along a random arm motion -------------------------------------------


def _samples(seed, n):
    """``n`` (base_T_flange, measured tip) pairs: the arm resting (samples to merge), creeping
    (current samples) and moving (new keyframes), with sensor noise."""
    rng = np.random.default_rng(seed)
    truth = model_from_parameters(PandaModel(), NOMINAL + rng.uniform(-1, 1, 12) * SPREAD)
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    out = []
    for _ in range(n):
        q = q + rng.choice([1e-5, 3e-3, 0.15], p=[0.4, 0.3, 0.3]) * rng.normal(size=7)
        q = np.clip(q, truth.q_min, truth.q_max)
        tip = truth.tip_pose(q)
        flange = np.linalg.inv(truth.world_T_base) @ tip @ np.linalg.inv(truth.flange_T_tip)
        noisy = tip.copy()
        noisy[:3, 3] += rng.normal(0, 0.5, 3)
        w = rng.normal(0, np.radians(0.1), 3)
        c, s = np.cos(np.linalg.norm(w)), np.sin(np.linalg.norm(w))
        k = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) / np.linalg.norm(w)
        noisy[:3, :3] = (np.eye(3) + s * k + (1 - c) * k @ k) @ tip[:3, :3]
        out.append((q.copy(), flange, noisy))
    return truth, out


def _close(got, want, rel=REL, terms=None):
    """``got == want`` to ``rel`` of the largest entry, or of the largest sum of absolute
    terms ``terms`` when ``want`` is a sum that cancels."""
    want = np.asarray(want, dtype=float)
    scale = float(np.max(np.abs(want if terms is None else terms))) if want.size else 1.0
    scale = max(1.0, scale)
    np.testing.assert_allclose(got, want, rtol=0, atol=rel * scale)


@pytest.mark.parametrize("capacity", [1, 3, 8, 40])
def test_the_history_takes_the_oracles_decisions_and_gives_its_rows(capacity):
    for seed in range(3):
        _, samples = _samples(seed, 150)
        ref, new = _RefHistory(capacity), MeasurementHistory(capacity)
        a = NOMINAL + np.random.default_rng(seed).uniform(-1, 1, 12) * SPREAD
        what = []
        for i, (_, flange, measured) in enumerate(samples):
            what.append(ref.add(flange, measured))
            new.add(flange, measured)
            np.testing.assert_array_equal(new.counts, ref._count)
            assert (new._current is None) == (ref._current is None)
            if i % 7 == 0 or i == len(samples) - 1:
                want_e, want_j = ref.stacked(a, 100.0)
                got_e, got_j = new.stacked(a, 100.0)
                _close(got_e, want_e)
                _close(got_j, want_j)
                _close(new._poses, ref._poses)
                jtj, jte = new.normal_equations(a, 100.0)
                _close(jtj, want_j.T @ want_j)
                _close(jte, want_j.T @ want_e, terms=np.abs(want_j).T @ np.abs(want_e))
        # the sequence went through every branch
        kinds = {w.split()[0] for w in what}
        assert {"merged", "current"} <= kinds
        assert "evicted" in kinds or capacity == 40


def test_the_adaptation_step_equals_the_oracles():
    ctrl = ControllerSettings()
    bound = 0
    for seed in range(12):
        _, samples = _samples(100 + seed, 80)
        rng = np.random.default_rng(seed)
        a = NOMINAL + rng.uniform(-1, 1, 12) * SPREAD
        est = model_from_parameters(PandaModel(), a)
        ref, new = _RefHistory(), MeasurementHistory()
        for i, (q, flange, measured) in enumerate(samples):
            ref.add(flange, measured)
            new.add(flange, measured)
            if i % 5:
                continue
            s = est.state(q)
            pj = parameter_jacobians(est, s, a)
            est_tip = est.tip_pose(q)
            step = [None, Step.ALIGN, Step.APPROACH, Step.PUNCTURE][i % 4]
            guide = GuideLine(s.tip_mm - 30.0 * s.needle_axis, -s.needle_axis + 0.02)
            vfis = [] if step is None else step_vfis(s, step, guide, ctrl, pj, a)
            task_error = (
                None if step is None else rng.normal(0, 2.0, 3 if step is Step.ALIGN else 6)
            )
            history = None if seed % 4 == 0 else (ref, new)
            settings = AdaptationSettings(
                SETTINGS.lower, SETTINGS.upper, stability_radius_mm=[0.0, 1.5][i % 2],
                clamp_vfi_rows=bool(seed % 3),
            )  # fmt: skip
            H, f, A, b, lo, hi, err = _ref_adaptation_qp(
                a, est_tip, measured, pj, settings, step, task_error, ctrl, vfis, 0.5,
                None if history is None else history[0],
            )  # fmt: skip
            want = solve_qp(H, f, A, b, lo, hi, check=False)
            got = adaptation_step(
                a, est_tip, measured, pj, settings, step=step, task_error=task_error,
                controller=ctrl, vfis=vfis, vfi_share=0.5,
                history=None if history is None else history[1],
            )  # fmt: skip
            assert got.status is want.status
            np.testing.assert_array_equal(got.error, err)
            if want.status is QPStatus.OPTIMAL:
                rel = max(REL, 10 * np.finfo(float).eps * np.linalg.cond(H))
                _close(got.a_dot, want.x, rel)
                bound += bool(np.any(np.minimum(want.x - lo, hi - want.x) < 1e-9))
                bound += bool(len(b) and np.any(np.abs(A @ want.x - b) < 1e-9))
            a = a + 0.01 * (got.a_dot if got.status is QPStatus.OPTIMAL else 0.0)
            est = model_from_parameters(PandaModel(), a)
    assert bound >= 5  # the cases exercise the rows and bounds where they bind


def test_measurement_error_equals_the_numpy_one():
    rng = np.random.default_rng(5)
    for _ in range(200):
        est = pose_from_parameters(rng.normal(0, 100, 6))
        # near the measurement, and (a few) half a turn away: both branches of the log
        delta = rng.normal(0, 0.01 if rng.random() < 0.8 else 1.0, 6)
        if rng.random() < 0.1:
            delta[3:] = [np.pi - 1e-3, 0.0, 0.0]
        meas = est @ pose_from_parameters(delta)
        dr = _rotation_log(np.ascontiguousarray(est[:3, :3] @ meas[:3, :3].T))
        want = np.concatenate([est[:3, 3] - meas[:3, 3], 100.0 * dr])
        _close(measurement_error(est, meas, 100.0), want)
