"""One simulated puncture (the three-step procedure with EM sensors at 100 Hz and the
controller at 1 kHz), and the EM sensor model."""

import numpy as np
import pytest

from needlekit.control.adaptation import AdaptationSettings
from needlekit.control.em import EMSensor, EMSensorSpec
from needlekit.control.panda import PandaModel
from needlekit.control.procedure import TrialSetup, quintic, run_trial
from needlekit.errors import InvalidInputError
from needlekit.records import Status

NOMINAL = np.array([-650.0, 0.0, -450.0, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
SPREAD = np.array([200.0] * 3 + [np.radians(10)] * 3 + [10.0] * 3 + [np.radians(5)] * 3)
Q_READY = np.array([0.0, -np.pi / 4, 0.0, -3 * np.pi / 4, 0.0, np.pi / 2, np.pi / 4])


def test_quintic_starts_and_ends_at_rest():
    assert quintic(0.0, 20.0) == (0.0, 0.0) and quintic(20.0, 20.0) == (1.0, 0.0)
    s, v = quintic(10.0, 20.0)
    assert s == 0.5 and v == pytest.approx(1.875 / 20.0)  # peak speed 1.875 / T


def test_em_sensor_rate_latency_noise_and_dropouts():
    rng = np.random.default_rng(0)
    spec = EMSensorSpec(latency_s=0.02, dropout_probability=0.2, dropout_burst_mean=3.0)
    sensor = EMSensor(spec, rng)
    pose = np.eye(4)
    got = [s for k in range(10001) if (s := sensor.update(k * 1e-3, lambda: pose)) is not None]
    assert sensor.n_taken == 1001
    assert len(got) + sensor.in_flight == sensor.n_taken - sensor.n_lost
    assert all(s.arrives_s - s.taken_s == pytest.approx(0.02) for s in got)
    lost = sensor.n_lost / sensor.n_taken
    assert lost == pytest.approx(0.2 * 3 / (1 + 0.2 * 2), abs=0.08)  # bursts of mean 3
    noise = np.array([s.pose[:3, 3] for s in got])
    assert noise.std(axis=0) == pytest.approx([1.0] * 3, rel=0.15)
    with pytest.raises(InvalidInputError, match="dropout_probability"):
        EMSensorSpec(dropout_probability=1.0)


@pytest.mark.slow
def test_a_noise_free_puncture_with_a_known_arm_reaches_the_target_inside_every_constraint():
    setup = TrialSetup(
        PandaModel(), NOMINAL, NOMINAL, Q_READY, np.array([-150.0, 0.0, -250.0]),
        np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0]),
    )  # fmt: skip
    exact = EMSensorSpec(position_sigma_mm=0.0, orientation_sigma_deg=0.0)
    r = run_trial(
        setup,
        np.random.default_rng(0),
        adaptation=AdaptationSettings(NOMINAL - SPREAD, NOMINAL + SPREAD),
        needle_sensor=exact,
        scope_sensor=exact,
    )
    assert r.status is Status.SOLVED
    assert r.position_error_mm < 0.1 and r.angle_error_deg < 0.05  # measured 0.035 mm
    # from the start of the puncture: never farther than where it started or the bounds
    assert r.max_guide_distance_mm <= max(1.5, r.start_guide_distance_mm) + 1e-3
    assert r.max_cone_angle_deg <= max(0.5, r.start_cone_angle_deg) + 1e-3
    # once inside the guide cylinder and the cone, it stays inside
    assert r.max_guide_distance_inside_mm <= 1.5 + 1e-3
    assert r.max_cone_angle_inside_deg <= 0.5 + 1e-3
    assert r.reached and r.reached_estimated
    assert r.min_plane_distance_mm > -0.05  # never noticeably past the target's plane
    assert r.min_patient_distance_mm > 200.0
    phases = list(r.phase_times_s)
    assert phases == ["adapt", "align", "approach", "wait", "puncture"]
    assert r.counts["qp_infeasible"] == 0
    log = r.log
    assert len(log["t_s"]) == len(log["to_target_mm"]) > 100


def _known_arm_trial(needle_sensor):
    setup = TrialSetup(
        PandaModel(), NOMINAL, NOMINAL, Q_READY, np.array([-150.0, 0.0, -250.0]),
        np.array([0.2, -0.1, 1.0]) / np.linalg.norm([0.2, -0.1, 1.0]),
    )  # fmt: skip
    exact = EMSensorSpec(position_sigma_mm=0.0, orientation_sigma_deg=0.0)
    return run_trial(
        setup,
        np.random.default_rng(0),
        adaptation=AdaptationSettings(NOMINAL - SPREAD, NOMINAL + SPREAD),
        needle_sensor=needle_sensor,
        scope_sensor=exact,
    )


@pytest.mark.slow
def test_a_lost_needle_sensor_stops_the_robot_which_resumes_when_it_returns(caplog):
    # half a second without needle samples during the puncture (it runs from about 16 s)
    spec = EMSensorSpec(position_sigma_mm=0.0, orientation_sigma_deg=0.0, outages=[(20.0, 20.5)])
    with caplog.at_level("INFO", logger="needlekit.control.procedure"):
        r = _known_arm_trial(spec)
    assert r.status is Status.SOLVED and r.position_error_mm < 0.1
    assert r.counts["needle_lost"] == 50
    (t_stop, what_stop), (t_go, what_go) = r.events
    assert what_stop.startswith("stopped") and what_go == "resumed"
    # silent from the last sample before 20 s (arriving 5 ms later) for more than 0.1 s
    assert t_stop == pytest.approx(19.99 + 0.005 + 0.1, abs=2e-3)
    assert t_go == pytest.approx(20.5 + 0.005, abs=2e-3)
    assert r.counts["stopped_steps"] == pytest.approx(1000 * (t_go - t_stop), abs=2)
    ts, tips = r.log["t_s"], r.log["tip_mm"]
    still = tips[(ts > t_stop + 1e-3) & (ts < t_go - 1e-3)]
    assert len(still) > 30 and np.ptp(still, axis=0).max() == 0.0  # not a micron of motion
    assert "stopped: needle sensor silent" in caplog.text


@pytest.mark.slow
def test_a_needle_sensor_lost_for_good_aborts_the_trial_with_the_reason():
    spec = EMSensorSpec(position_sigma_mm=0.0, orientation_sigma_deg=0.0, outages=[(20.0, 1e9)])
    r = _known_arm_trial(spec)
    assert r.status is Status.TIMEOUT and r.reason == "needle sensor lost"
    assert r.log["t_s"][-1] == pytest.approx(19.995 + 2.0, abs=0.02)  # after abort_after_s
    assert r.events[0][1].startswith("stopped") and len(r.events) == 1
    with pytest.raises(InvalidInputError, match="outages"):
        EMSensorSpec(outages=[(2.0, 1.0)])
