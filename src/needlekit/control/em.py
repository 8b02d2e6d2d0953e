"""Simulated electromagnetic (EM) tracking: 6-DoF sensors with noise, latency and dropouts.

A sensor samples the true pose every ``1 / rate_hz`` s. Each sample gets Gaussian noise:
position ``N(0, sigma_mm^2 I)`` per axis, orientation a rotation whose rotation vector is
``N(0, sigma_rad^2 I)`` (Tang et al. give "1 mm" and "0.2 deg", read here as standard
deviations). It reaches the controller ``latency_s`` later, or never (probability
``dropout_probability``, independently, or in bursts: a lost sample starts a burst whose
length is geometric with mean ``dropout_burst_mean``). Samples carry the time they were
taken, so the controller can pair them with the joint angles of that moment.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import so3_exp_unchecked

__all__ = ["EMSample", "EMSensor", "EMSensorSpec", "noisy_pose"]


@dataclass(frozen=True)
class EMSensorSpec:
    """Rate, noise, latency and dropouts of one sensor.

    Attributes
    ----------
    rate_hz : float
    position_sigma_mm : float
    orientation_sigma_deg : float
    latency_s : float
    dropout_probability : float
        Probability that a sample starts a burst of lost samples.
    dropout_burst_mean : float
        Mean number of samples lost per burst (>= 1).
    outages : tuple of (float, float)
        Scheduled intervals ``[start_s, end_s)`` in which every sample is lost (a cable
        pulled, the transmitter switched off).
    """

    rate_hz: float = 100.0
    position_sigma_mm: float = 1.0
    orientation_sigma_deg: float = 0.2
    latency_s: float = 0.005
    dropout_probability: float = 0.0
    dropout_burst_mean: float = 1.0
    outages: tuple = ()

    def __post_init__(self) -> None:
        try:
            outages = tuple((float(a), float(b)) for a, b in self.outages)
        except (TypeError, ValueError):
            raise InvalidInputError("outages", "expected (start_s, end_s) pairs") from None
        if any(not (np.isfinite(a) and np.isfinite(b) and 0 <= a < b) for a, b in outages):
            raise InvalidInputError("outages", "expected finite 0 <= start_s < end_s")
        object.__setattr__(self, "outages", outages)
        for name in ("rate_hz",):
            if not getattr(self, name) > 0:
                raise InvalidInputError(name, "must be > 0")
        for name in ("position_sigma_mm", "orientation_sigma_deg", "latency_s"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InvalidInputError(name, f"must be a finite number >= 0, got {v!r}")
        if not 0.0 <= self.dropout_probability < 1.0:
            raise InvalidInputError("dropout_probability", "must lie in [0, 1)")
        if not self.dropout_burst_mean >= 1.0:
            raise InvalidInputError("dropout_burst_mean", "must be >= 1")


@dataclass(frozen=True)
class EMSample:
    """One measurement.

    Attributes
    ----------
    taken_s : float
        When the pose was sampled.
    arrives_s : float
        When the controller receives it.
    pose : ndarray, shape (4, 4)
        Measured pose (transmitter frame, mm).
    """

    taken_s: float
    arrives_s: float
    pose: np.ndarray


def noisy_pose(pose, position_sigma_mm: float, orientation_sigma_rad: float, rng) -> np.ndarray:
    """A pose with Gaussian position noise and a random rotation applied.

    Parameters
    ----------
    pose : ndarray, shape (4, 4)
    position_sigma_mm, orientation_sigma_rad : float
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (4, 4)
    """
    out = np.array(pose, dtype=float)
    out[:3, 3] += rng.normal(0.0, position_sigma_mm, 3)
    if orientation_sigma_rad > 0:
        out[:3, :3] = so3_exp_unchecked(rng.normal(0.0, orientation_sigma_rad, 3)) @ out[:3, :3]
    return out


class EMSensor:
    """A simulated EM sensor (see the module notes).

    Parameters
    ----------
    spec : EMSensorSpec
    rng : numpy.random.Generator
    """

    def __init__(self, spec: EMSensorSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.period_s = 1.0 / spec.rate_hz
        self._next_sample_s = 0.0
        self._in_flight: deque[EMSample] = deque()
        self._lost_left = 0
        self.latest: EMSample | None = None
        self.n_taken = 0
        self.n_lost = 0

    @property
    def in_flight(self) -> int:
        """Samples taken but not yet delivered (latency)."""
        return len(self._in_flight)

    def update(self, t: float, true_pose: Callable[[], np.ndarray]) -> EMSample | None:
        """Advance to time ``t``: take due samples, deliver those that have arrived.

        Parameters
        ----------
        t : float
            Current time (s).
        true_pose : callable
            Returns the true pose now (called only when a sample is due).

        Returns
        -------
        EMSample or None
            The newest sample that arrived in this update, if any (also kept in
            :attr:`latest`).
        """
        spec = self.spec
        while self._next_sample_s <= t + 1e-12:
            self.n_taken += 1
            if self._lost_left == 0 and self.rng.random() < spec.dropout_probability:
                mean = spec.dropout_burst_mean
                self._lost_left = 1 if mean <= 1.0 else int(self.rng.geometric(1.0 / mean))
            scheduled = any(a <= self._next_sample_s < b for a, b in spec.outages)
            if scheduled:
                self.n_lost += 1
            elif self._lost_left > 0:
                self._lost_left -= 1
                self.n_lost += 1
            else:
                pose = noisy_pose(
                    true_pose(),
                    spec.position_sigma_mm,
                    np.radians(spec.orientation_sigma_deg),
                    self.rng,
                )
                taken = self._next_sample_s
                self._in_flight.append(EMSample(taken, taken + spec.latency_s, pose))
            self._next_sample_s += self.period_s
        new = None
        while self._in_flight and self._in_flight[0].arrives_s <= t + 1e-12:
            new = self._in_flight.popleft()
        if new is not None:
            self.latest = new
        return new
