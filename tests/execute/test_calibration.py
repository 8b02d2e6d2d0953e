"""The calibration of the loop's own needle model, against needles whose constants are
known: the kinematic needle without noise (exact), with its default noise (sampling
theory's bounds: three standard errors), and a needle whose radius is not the planner's."""

from __future__ import annotations

import math

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.execute.calibration import Calibration, CalibrationSettings, calibrate
from needlekit.execute.needle_sim import ExecutionNoise, SimulatedNeedle


def kinematic(r_mm: float, noise: ExecutionNoise):
    return lambda pose, rng: SimulatedNeedle(pose, r_mm, noise, rng)


def test_a_needle_without_noise_is_learnt_exactly():
    cal = calibrate(kinematic(50.0, ExecutionNoise.none()), 1 / 50.0,
                    CalibrationSettings(curved=3, straight=2))  # fmt: skip
    assert cal.r_min_mm == pytest.approx(50.0, rel=1e-12)
    for name in ("radius_sigma_mm", "orientation_sigma_rad", "deflection_sigma",
                 "residual_rms_mm", "residual_max_mm", "end_error_mean_mm",
                 "axis_slip_rad"):  # fmt: skip
        assert getattr(cal, name) < 1e-9, name


def test_the_default_noise_is_recovered_within_three_standard_errors():
    noise = ExecutionNoise()
    s = CalibrationSettings(curved=200, straight=100, seed=7)
    cal = calibrate(kinematic(50.0, noise), 1 / 50.0, s)
    # r_i = 50 + N(0, 3^2): the mean's SE 3 / sqrt(200), the SD's 3 / sqrt(2 * 199)
    assert abs(cal.r_min_mm - 50.0) < 3 * 3 / math.sqrt(200)
    assert abs(cal.radius_sigma_mm - 3.0) < 3 * 3 / math.sqrt(398)
    # 200 insertions of 160 steps, three axes: the SD's relative SE 1 / sqrt(2 * 95400)
    assert cal.orientation_sigma_rad == pytest.approx(noise.orientation_sigma_rad, rel=0.01)
    # 100 insertions, two lateral components each: relative SE 1 / sqrt(2 * 200)
    assert cal.deflection_sigma == pytest.approx(noise.deflection_sigma, rel=3 / math.sqrt(400))


class _SlippingNeedle(SimulatedNeedle):
    """A noise-free needle whose tip, with the bevel held, also slips sideways along its
    own x axis by ``slip`` mm per mm inserted (as a pre-bent tip does while its shaft
    catches up)."""

    slip = 0.2

    def step(self, spin_rad, kappa_per_mm, ds_mm, dt_s):
        g = super().step(spin_rad, kappa_per_mm, ds_mm, dt_s)
        if kappa_per_mm > 0:
            g[:3, 3] += self.slip * ds_mm * g[:3, 0]
        return g


def test_a_tip_that_slips_off_its_axis_has_its_drift_learnt_as_position_noise():
    """The model's step cannot predict the slip, so the filter's position noise must cover
    it: the drift per millimetre pooled over every step, curved and straight, is
    ``slip sqrt(curved / (curved + straight) / 2)`` per lateral component."""
    make = lambda p, rng: _SlippingNeedle(p, 50.0, ExecutionNoise.none(), rng)  # noqa: E731
    cal = calibrate(make, 1 / 50.0, CalibrationSettings(curved=4, straight=2))
    # the slip is in the bending plane's normal, so the arc is still learnt exactly
    assert cal.r_min_mm == pytest.approx(50.0, rel=1e-9)
    expected = 0.2 * math.sqrt(4 / 6 / 2)
    assert cal.deflection_sigma == pytest.approx(expected, rel=1e-3)
    # the replay cannot follow the slip: its residual grows with it
    assert cal.residual_max_mm == pytest.approx(0.2 * 80.0, rel=0.05)


def test_a_tip_whose_axis_is_not_its_travel_has_the_angle_and_its_correlation_learnt():
    """The slipping needle's curved insertions travel off their axis by
    ``atan(0.2)`` (the slip is across the bisector of the step's axes), its straight ones
    along it: per lateral component ``sin(atan 0.2) sqrt(curved / (curved + straight) / 2)``.
    A constant angle is correlated over the whole insertion: its pooled autocorrelation
    at lag ``L`` of ``n`` steps is ``(n - L) / n``, whose integral is half the insertion."""
    make = lambda p, rng: _SlippingNeedle(p, 50.0, ExecutionNoise.none(), rng)  # noqa: E731
    cal = calibrate(make, 1 / 50.0, CalibrationSettings(curved=4, straight=2))
    assert cal.axis_slip_rad == pytest.approx(0.2 / math.sqrt(1.04) * math.sqrt(4 / 6 / 2), rel=1e-4)
    assert cal.axis_slip_mm == pytest.approx(80.0 / 2, rel=1e-9)
    # sampled every 0.05 mm, one correlation holds 2 * 40 / 0.05 samples
    assert cal.tilt_sigma_rad(0.05) == pytest.approx(cal.axis_slip_rad * math.sqrt(1600), rel=1e-12)
    assert cal.tilt_sigma_rad(1e3) == cal.axis_slip_rad
    # a needle that goes where it points: no slip
    exact = calibrate(kinematic(50.0, ExecutionNoise.none()), 1 / 50.0,
                      CalibrationSettings(curved=3, straight=2))  # fmt: skip
    assert exact.axis_slip_rad < 1e-9


def test_a_needle_that_curves_less_than_planned_is_commanded_in_its_own_units():
    # the truth reads 1/50 as the bevel held, but curves with r = 80 mm in this tissue
    cal = calibrate(lambda p, rng: SimulatedNeedle(p, 50.0, ExecutionNoise.none(), rng),
                    1 / 50.0, CalibrationSettings(curved=2, straight=2))  # fmt: skip
    assert cal.r_min_mm == pytest.approx(50.0, rel=1e-12)
    slow = calibrate(
        lambda p, rng: _Scaled(SimulatedNeedle(p, 50.0, ExecutionNoise.none(), rng), 50 / 80),
        1 / 50.0,
        CalibrationSettings(curved=2, straight=2),
    )
    assert slow.r_min_mm == pytest.approx(80.0, rel=1e-9)
    # the model's full curvature 1/80 is the truth's full duty; half of it, half the duty
    assert slow.command(1 / 80.0) == pytest.approx(1 / 50.0, rel=1e-12)
    assert slow.command(1 / 160.0) == pytest.approx(1 / 100.0, rel=1e-12)


class _Scaled:
    """A needle that bends ``factor`` times what it is told (a stiffer tissue's needle)."""

    def __init__(self, needle, factor):
        self.needle, self.factor = needle, factor

    @property
    def pose(self):
        return self.needle.pose

    def step(self, spin, kappa, ds, dt):
        return self.needle.step(spin, kappa * self.factor, ds, dt)


def test_the_record_round_trips_and_its_fields_are_checked():
    cal = calibrate(kinematic(50.0, ExecutionNoise()), 1 / 50.0,
                    CalibrationSettings(curved=3, straight=2))  # fmt: skip
    assert Calibration.from_dict(cal.to_dict()) == cal
    assert cal.noise().radius_sigma_mm == cal.radius_sigma_mm
    # a record written before the slip was learnt reads as no slip
    older = {k: v for k, v in cal.to_dict().items() if not k.startswith("axis_slip")}
    assert Calibration.from_dict(older).axis_slip_rad == 0.0
    bad = cal.to_dict() | {"r_min_mm": "fifty"}
    with pytest.raises(InvalidInputError, match="r_min_mm"):
        Calibration.from_dict(bad, "execute.json: calibration")


@pytest.mark.parametrize(
    ("field", "kwargs"),
    [("curved", {"curved": 1}), ("straight", {"straight": 0}), ("length_mm", {"length_mm": -1.0}),
     ("step_mm", {"step_mm": 30.0}), ("speed_mm_s", {"speed_mm_s": 0.0}),
     ("seed", {"seed": 1.5})],
)  # fmt: skip
def test_bad_settings_name_their_field(field, kwargs):
    with pytest.raises(InvalidInputError, match=field):
        CalibrationSettings(**kwargs)


def test_bad_calibration_inputs_name_their_field():
    make = kinematic(50.0, ExecutionNoise.none())
    with pytest.raises(InvalidInputError, match="full_duty"):
        calibrate(make, 0.0)
    with pytest.raises(InvalidInputError, match="start_pose"):
        calibrate(make, 0.02, start_pose=np.full((4, 4), np.nan))
