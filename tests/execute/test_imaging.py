"""Imaging checkpoints and target tracking: when they sample, what they deliver and when,
their noise, and the gate every target sample passes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.execute.imaging import (
    CheckpointImaging,
    CheckpointSpec,
    TargetTracking,
    TrackingSpec,
    admit_target,
)


def test_checkpoints_fall_every_twenty_millimetres_and_hold_the_needle_for_the_scan():
    img = CheckpointImaging(CheckpointSpec(), np.random.default_rng(0))
    target = np.array([1.0, 2.0, 3.0])
    scans, t, inserted = [], 0.0, 0.0
    while inserted < 93.0:  # 0.1 mm per 0.05 s (2 mm/s)
        if img.due(inserted):
            img.scan(t, inserted, np.eye(4), target)
        got = img.update(t)
        if got is not None:
            scans.append(got)
        if not img.scanning:
            inserted = round(inserted + 0.1, 10)
        t = round(t + 0.05, 10)
    assert [s.depth_mm for s in scans] == pytest.approx([20.0, 40.0, 60.0, 80.0])
    assert img.scans == 4
    # each scan arrives scan_s after it was taken; the needle stood still meanwhile
    assert [s.arrives_s - s.taken_s for s in scans] == pytest.approx([20.0] * 4)
    assert t == pytest.approx(93.0 / 2.0 + 4 * 20.0, abs=0.1)


def test_scans_and_tracker_samples_have_the_stated_noise():
    rng = np.random.default_rng(3)
    img = CheckpointImaging(CheckpointSpec(every_mm=1.0, scan_s=0.0), rng)
    seen = []
    for k in range(1, 4001):
        img.scan(float(k), float(k), np.eye(4), np.zeros(3))
        seen.append(img.update(float(k)).target_mm)
    sd = np.std(np.array(seen), axis=0, ddof=1)
    # 4000 samples: the SD's relative SE 1 / sqrt(7998), three of them allowed
    assert sd == pytest.approx([0.5] * 3, rel=3 / math.sqrt(7998))
    tr = TargetTracking(TrackingSpec(rate_hz=100.0), np.random.default_rng(4))
    got = [tr.update(k / 100.0, lambda: np.zeros(3)) for k in range(4011)]
    pos = np.array([g.target_mm for g in got if g is not None])
    assert np.std(pos, axis=0, ddof=1) == pytest.approx([0.7] * 3, rel=3 / math.sqrt(2 * 4000))


def test_tracker_samples_arrive_their_latency_late_and_carry_the_time_they_were_taken():
    tr = TargetTracking(TrackingSpec(rate_hz=10.0, position_sigma_mm=0.0, latency_s=0.25),
                        np.random.default_rng(0))  # fmt: skip

    def target_at(t):
        return lambda: np.array([t, 0.0, 0.0])  # moves 1 mm/s along x

    arrivals = {}
    for k in range(0, 101):
        t = k / 100.0
        got = tr.update(t, target_at(t))
        if got is not None:
            arrivals[round(t, 6)] = (got.taken_s, got.target_mm[0])
    # taken every 0.1 s from 0, arriving 0.25 s later; what it saw is where it was then
    assert sorted(arrivals) == pytest.approx([0.25 + 0.1 * k for k in range(8)])
    for t, (taken, x) in arrivals.items():
        assert t - taken == pytest.approx(0.25)
        assert x == pytest.approx(taken)
    assert tr.taken == 11


def test_the_target_gate_refuses_what_is_not_finite_or_moved_too_far():
    last = np.zeros(3)
    assert admit_target([1.0, 0.0, 0.0], last, 0.1, 10.0, 0.0) is None
    assert admit_target([1.01, 0.0, 0.0], last, 0.1, 10.0, 0.0) == "jump"
    assert admit_target([1.01, 0.0, 0.0], last, 0.1, 10.0, 0.01) is None  # within the noise
    assert admit_target([np.nan, 0.0, 0.0], last, 0.1, 10.0, 0.0) == "not_finite"
    assert admit_target([0.0, 0.0], last, 0.1, 10.0, 0.0) == "not_finite"


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: TrackingSpec(rate_hz=0.0), "rate_hz"),
        (lambda: TrackingSpec(latency_s=-0.1), "latency_s"),
        (lambda: TrackingSpec(position_sigma_mm=float("nan")), "position_sigma_mm"),
        (lambda: CheckpointSpec(every_mm=0.0), "every_mm"),
        (lambda: CheckpointSpec(scan_s=float("inf")), "scan_s"),
        (lambda: CheckpointSpec(orientation_sigma_deg=200.0), "orientation_sigma_deg"),
        (lambda: CheckpointSpec(confirm_scans=-1), "confirm_scans"),
        (lambda: CheckpointSpec(confirm_scans=1.5), "confirm_scans"),
        (lambda: CheckpointSpec(confirm_scans=True), "confirm_scans"),
    ],
)
def test_bad_sensor_settings_name_their_field(make, field):
    with pytest.raises(InvalidInputError, match=field):
        make()


def test_the_target_belief_is_the_kalman_update_of_a_random_walk():
    from needlekit.execute.imaging import TargetEstimator

    est = TargetEstimator([0.0, 0.0, 0.0], drift_sigma_mm=1.0)
    # a sample taken at 3 s (SD 1) used at 4 s: the prior where it was taken has variance
    # 3, the gain is 3 / 4; the 1 s of drift since is added to the belief's variance after
    assert est.update(4.0, 3.0, [3.0, 0.0, 0.0], 1.0)
    assert est.target_mm == pytest.approx([2.25, 0.0, 0.0])
    assert est.variance_mm2 == pytest.approx(0.75 + 1.0)
    # the same by brute force: the joint Gaussian of (x_3, x_4, z) conditioned on z
    cov = np.array([[3.0, 3.0, 3.0], [3.0, 4.0, 3.0], [3.0, 3.0, 4.0]])
    gain = cov[1, 2] / cov[2, 2]
    assert est.target_mm[0] == pytest.approx(gain * 3.0)
    assert est.variance_mm2 == pytest.approx(cov[1, 1] - cov[1, 2] ** 2 / cov[2, 2])
    # a sample arriving 20 s late, noise-free, is taken as the truth of its time
    late = TargetEstimator([0.0, 0.0, 0.0], drift_sigma_mm=0.5)
    assert late.update(30.0, 10.0, [0.0, 4.0, 0.0], 0.0)
    assert late.target_mm == pytest.approx([0.0, 4.0, 0.0])
    assert late.variance_mm2 == pytest.approx(0.25 * 20.0)
    # without drift the plan's target is kept: EM alone assumes the target still
    still = TargetEstimator([1.0, 1.0, 1.0], drift_sigma_mm=0.0)
    still.update(10.0, 10.0, [1.2, 1.0, 1.0], 0.5)
    assert still.target_mm == pytest.approx([1.0, 1.0, 1.0])


def test_the_target_beliefs_insertion_clock_averages_scans_of_a_still_needle():
    from needlekit.execute.imaging import TargetEstimator

    # time alone: the 20 s between two scans (SD 0.5) at the same depth add 20 * 0.25
    # mm^2, so the second scan's gain is above 0.95 and the first is all but forgotten
    timed = TargetEstimator([0.0, 0.0, 0.0], drift_sigma_mm=0.5)
    assert timed.update(40.0, 20.0, [1.0, 0.0, 0.0], 0.5, 40.0)
    first = 5.0 * 0.25 / 5.25
    assert timed.update(60.0, 40.0, [0.0, 0.0, 0.0], 0.5, 40.0)
    gain = (first + 5.0) / (first + 5.0 + 0.25)
    assert gain > 0.95 and timed.target_mm[0] == pytest.approx((1.0 - gain) * 5.0 / 5.25)
    assert timed.variance_mm2 == pytest.approx((1.0 - gain) * (first + 5.0) + 5.0)
    # on the insertion's clock (no time drift) the needle stood still: the two scans are
    # two looks at one point, averaged (variance 0.25 / 2 over the prior's)
    pushed = TargetEstimator([0.0, 0.0, 0.0], drift_sigma_mm=0.0, push_sigma_mm=0.2)
    pushed.predict(0.0, 40.0)  # 40 mm in before the first scan: prior 40 * 0.04 = 1.6
    assert pushed.variance_mm2 == pytest.approx(1.6)
    assert pushed.update(20.0, 0.0, [1.0, 0.0, 0.0], 0.5, 40.0)
    assert pushed.update(40.0, 20.0, [0.0, 0.0, 0.0], 0.5, 40.0)
    # brute force: precisions add (1 / 1.6 + 2 / 0.25), the mean is the weighted one
    var = 1.0 / (1.0 / 1.6 + 2.0 / 0.25)
    assert pushed.variance_mm2 == pytest.approx(var)
    assert pushed.target_mm[0] == pytest.approx(var * 1.0 / 0.25)
    # going on 10 mm adds 10 * 0.04 to the variance, however long it takes
    pushed.predict(1000.0, 50.0)
    assert pushed.variance_mm2 == pytest.approx(var + 0.4)


def test_the_target_belief_follows_a_moved_target_and_refuses_a_wild_sample():
    from needlekit.execute.imaging import TargetEstimator

    rng = np.random.default_rng(5)
    est = TargetEstimator([0.0, 0.0, 0.0], drift_sigma_mm=0.5)
    moved = np.array([4.0, -2.0, 1.0])  # the needle pushed it 4.6 mm
    for k in range(1, 201):
        est.update(0.1 * k, 0.1 * k, moved + rng.normal(0.0, 0.7, 3), 0.7)
    assert np.linalg.norm(est.target_mm - moved) < 0.5
    assert not est.update(20.1, 20.1, moved + [40.0, 0.0, 0.0], 0.7)
    assert not est.update(20.2, 20.2, [np.inf, 0.0, 0.0], 0.7)
    assert est.refused == {"jump": 1, "not_finite": 1} and est.used == 200
