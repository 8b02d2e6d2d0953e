"""Seeing the target: imaging checkpoints (CT, CBCT) and continuous target tracking.

Once the tissue deforms, the target moves under the needle, and an EM sensor on the tip
does not see it. Two kinds of imaging do:

- **Checkpoints** (:class:`CheckpointImaging`). At set insertion depths the insertion
  stops and a volume is scanned: the needle stands still for ``scan_s`` (acquisition,
  reconstruction, finding tip and target), and the scan gives the target's position and
  the tip's pose as the image shows them (``position_sigma_mm``, ``orientation_sigma_deg``:
  localisation in a volume of sub-millimetre voxels). Every scan counts toward the dose.
  Ben-David et al. (JVIR 2018), a patient-mounted CT-guided robot in eight swine, planned
  4.6 +- 1.3 checkpoints (range 2-9) over insertions of 92.9 +- 19.7 mm, about one every
  20 mm: the default spacing here. The scan's duration is not reported there; 20 s is
  this module's assumption, named. When the tip believes it has arrived, a confirmation
  scan checks (``confirm_scans`` of them at most, 2 by default): the needle's own push
  keeps moving the target after the last set checkpoint, ahead of the tip most of all in
  the last millimetres, and if the image shows it still ahead the needle goes on to it.
- **Tracking** (:class:`TargetTracking`). An ultrasound-like sensor follows the target
  continuously: ``rate_hz`` samples of its position, each with noise and arriving
  ``latency_s`` after it was taken; the needle keeps going.

Both are sensors: they sample the simulation's truth (the target where the deformed tissue
has carried it) and deliver samples with the time they were taken. Every target sample
passes :func:`admit_target` before the loop uses it, as every tip sample passes the sensor
guard: not finite, or farther from the last admitted position than the tissue could have
carried it since, and it is refused (counted, named).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from needlekit._numbers import MAX_ABS_MM, MAX_ABS_NUMBER, Bounds
from needlekit.control.em import noisy_pose
from needlekit.errors import InvalidInputError

__all__ = [
    "CheckpointImaging",
    "CheckpointSpec",
    "ImageSample",
    "TargetEstimator",
    "TargetSample",
    "TargetTracking",
    "TrackingSpec",
    "admit_target",
]

_POSITIVE_MM = Bounds(0.0, MAX_ABS_MM, low_open=True, unit="mm")
_NONNEG_MM = Bounds(0.0, MAX_ABS_MM, unit="mm")
_POSITIVE_S = Bounds(0.0, MAX_ABS_NUMBER, low_open=True, unit="s")
_NONNEG_S = Bounds(0.0, MAX_ABS_NUMBER, unit="s")
_RATE = Bounds(0.0, 1e6, low_open=True, unit="Hz")
_DEG = Bounds(0.0, 180.0, unit="deg")


@dataclass(frozen=True)
class CheckpointSpec:
    """Where and how the insertion is scanned.

    Attributes
    ----------
    every_mm : float
        A checkpoint each time this much more has been inserted (the first at
        ``every_mm``).
    scan_s : float
        How long the needle stands still for one scan.
    position_sigma_mm : float
        SD per axis of the target's and the tip's position in the image.
    orientation_sigma_deg : float
        SD of the tip's orientation in the image.
    confirm_scans : int
        Scans at most when the tip believes it has arrived (0: none).
    """

    every_mm: float = 20.0
    scan_s: float = 20.0
    position_sigma_mm: float = 0.5
    orientation_sigma_deg: float = 1.0
    confirm_scans: int = 2

    def __post_init__(self) -> None:
        _POSITIVE_MM.check(self.every_mm, "every_mm")
        if isinstance(self.confirm_scans, bool) or not isinstance(self.confirm_scans, int) \
                or not 0 <= self.confirm_scans <= 100:  # fmt: skip
            raise InvalidInputError("confirm_scans", "expected an integer in [0, 100], "
                                    f"got {self.confirm_scans!r}")  # fmt: skip
        _NONNEG_S.check(self.scan_s, "scan_s")
        _NONNEG_MM.check(self.position_sigma_mm, "position_sigma_mm")
        _DEG.check(self.orientation_sigma_deg, "orientation_sigma_deg")


@dataclass(frozen=True)
class TrackingSpec:
    """A continuous target tracker.

    Attributes
    ----------
    rate_hz : float
    position_sigma_mm : float
        SD per axis of one sample.
    latency_s : float
        From a sample's taking to its arrival.
    """

    rate_hz: float = 10.0
    position_sigma_mm: float = 0.7
    latency_s: float = 0.1

    def __post_init__(self) -> None:
        _RATE.check(self.rate_hz, "rate_hz")
        _NONNEG_MM.check(self.position_sigma_mm, "position_sigma_mm")
        _NONNEG_S.check(self.latency_s, "latency_s")


@dataclass(frozen=True)
class ImageSample:
    """One scan.

    Attributes
    ----------
    taken_s, arrives_s : float
        When the volume was acquired, and when tip and target were found in it.
    target_mm : ndarray, shape (3,)
    tip_pose : ndarray, shape (4, 4)
    depth_mm : float
        The insertion depth of the checkpoint.
    """

    taken_s: float
    arrives_s: float
    target_mm: np.ndarray
    tip_pose: np.ndarray
    depth_mm: float


@dataclass(frozen=True)
class TargetSample:
    """One position of the target.

    Attributes
    ----------
    taken_s, arrives_s : float
    target_mm : ndarray, shape (3,)
    """

    taken_s: float
    arrives_s: float
    target_mm: np.ndarray


class CheckpointImaging:
    """Scans at set insertion depths (see the module notes).

    Parameters
    ----------
    spec : CheckpointSpec
    rng : numpy.random.Generator

    Attributes
    ----------
    scans : int
        Scans taken (the dose count).
    """

    def __init__(self, spec: CheckpointSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.scans = 0
        self._next_mm = spec.every_mm
        self._scanning: ImageSample | None = None
        self.confirmations = 0  # arrival scans taken
        self._confirmed_at_mm = -math.inf  # the depth of the last one

    def due(self, inserted_mm: float) -> bool:
        """Whether the insertion has reached the next checkpoint (and no scan is under way).

        Parameters
        ----------
        inserted_mm : float

        Returns
        -------
        bool
        """
        return self._scanning is None and inserted_mm >= self._next_mm - 1e-9

    def may_confirm(self, inserted_mm: float) -> bool:
        """Whether an arrival scan may be taken: none under way, ``confirm_scans`` not used
        up, and the needle gone on since the last one by more than the image's position
        noise (a scan that found the tip arrived ends the insertion).

        Parameters
        ----------
        inserted_mm : float

        Returns
        -------
        bool
        """
        went_on = inserted_mm > self._confirmed_at_mm + max(self.spec.position_sigma_mm, 1e-9)
        return (self._scanning is None and self.confirmations < self.spec.confirm_scans
                and went_on)  # fmt: skip

    @property
    def pending(self) -> ImageSample | None:
        """The scan under way (its sample, not yet arrived), or None."""
        return self._scanning

    @property
    def scanning(self) -> bool:
        """Whether a scan is under way (the needle stands still)."""
        return self._scanning is not None

    def scan(self, t: float, inserted_mm: float, tip_pose, target_mm,
             arrival: bool = False) -> None:  # fmt: skip
        """Acquire a volume now; its sample arrives ``scan_s`` later.

        Parameters
        ----------
        t, inserted_mm : float
        tip_pose : ndarray, shape (4, 4)
            The true tip.
        target_mm : array_like, shape (3,)
            The true target.
        arrival : bool
            An arrival scan (:meth:`may_confirm`): counted among ``confirmations``.

        Returns
        -------
        None
        """
        if arrival:
            self.confirmations += 1
            self._confirmed_at_mm = float(inserted_mm)
        s = self.spec
        seen_tip = noisy_pose(tip_pose, s.position_sigma_mm,
                              math.radians(s.orientation_sigma_deg), self.rng)  # fmt: skip
        seen_target = np.asarray(target_mm, dtype=np.float64) + self.rng.normal(
            0.0, s.position_sigma_mm, 3
        )
        self._scanning = ImageSample(t, t + s.scan_s, seen_target, seen_tip, float(inserted_mm))
        self.scans += 1
        while self._next_mm <= inserted_mm + 1e-9:
            self._next_mm += s.every_mm

    def update(self, t: float) -> ImageSample | None:
        """The scan's sample once it has arrived (once), else None.

        Parameters
        ----------
        t : float

        Returns
        -------
        ImageSample or None
        """
        got = self._scanning
        if got is not None and got.arrives_s <= t + 1e-12:
            self._scanning = None
            return got
        return None


class TargetTracking:
    """A continuous target tracker (see the module notes).

    Parameters
    ----------
    spec : TrackingSpec
    rng : numpy.random.Generator

    Attributes
    ----------
    taken : int
    """

    def __init__(self, spec: TrackingSpec, rng: np.random.Generator) -> None:
        self.spec = spec
        self.rng = rng
        self.period_s = 1.0 / spec.rate_hz
        self._next_s = 0.0
        self._in_flight: deque[TargetSample] = deque()
        self.taken = 0

    def update(self, t: float, true_target: Callable[[], np.ndarray]) -> TargetSample | None:
        """Take the samples due by ``t``; deliver the newest that has arrived.

        Parameters
        ----------
        t : float
        true_target : callable
            The true target now (called only when a sample is due).

        Returns
        -------
        TargetSample or None
        """
        s = self.spec
        while self._next_s <= t + 1e-12:
            p = np.asarray(true_target(), dtype=np.float64) + self.rng.normal(
                0.0, s.position_sigma_mm, 3
            )
            self._in_flight.append(TargetSample(self._next_s, self._next_s + s.latency_s, p))
            self.taken += 1
            self._next_s += self.period_s
        new = None
        while self._in_flight and self._in_flight[0].arrives_s <= t + 1e-12:
            new = self._in_flight.popleft()
        return new


def admit_target(sample_mm, last_mm, elapsed_s: float, max_speed_mm_s: float,
                 sigma_mm: float) -> str | None:  # fmt: skip
    """Check a target sample before it steers anything.

    Parameters
    ----------
    sample_mm : array_like, shape (3,)
        The sample's position.
    last_mm : array_like, shape (3,)
        The last admitted position (the plan's target before any).
    elapsed_s : float
        Time between their takings.
    max_speed_mm_s : float
        The fastest the tissue can carry the target (breathing, the needle's push).
    sigma_mm : float
        The sample's noise SD per axis (and the last one's): five of them are allowed
        besides the motion.

    Returns
    -------
    str or None
        None when admitted, else why not (``"not_finite"``, ``"jump"``).
    """
    p = np.asarray(sample_mm, dtype=np.float64)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        return "not_finite"
    reach = max_speed_mm_s * max(elapsed_s, 0.0) + 5.0 * math.sqrt(2.0) * sigma_mm + 1e-9
    if float(np.linalg.norm(p - np.asarray(last_mm, dtype=np.float64))) > reach:
        return "jump"
    return None


class TargetEstimator:
    """Where the loop believes the target is: a Kalman filter on its position under a
    random walk on two clocks: each axis gains ``drift_sigma_mm**2`` of variance per second
    and ``push_sigma_mm**2`` per millimetre inserted (the needle's push moves the target
    as the needle goes in, not while it stands still for a scan).

    The filter's state is the target at the time its latest sample was taken. A sample
    taken at ``tau`` (at or after that time) moves the state to ``tau`` (its variance grows
    by the drift meanwhile) and corrects it there; the belief *now* is that mean, with the
    drift since ``tau`` added to its variance. For a random walk that is exact however late
    the sample arrives: what the target did after it was taken is independent of it, and
    its best guess is no motion. A sample taken before the state's time (out of order) is
    applied to the state with the drift between the two added to its noise. Samples pass
    :func:`admit_target` first; a refused one is counted by its reason and changes
    nothing.

    Parameters
    ----------
    target_mm : array_like, shape (3,)
        The plan's target: the belief before any sample.
    drift_sigma_mm : float
        How fast the target may wander (mm per sqrt(s)).
    max_speed_mm_s : float
        The gate's bound on the target's speed.
    push_sigma_mm : float
        How far the insertion may carry it (mm per sqrt(mm) inserted; 0: time alone).

    Attributes
    ----------
    target_mm : ndarray, shape (3,)
    used : int
    refused : dict
        Refused samples by reason.
    """

    def __init__(self, target_mm, drift_sigma_mm: float = 0.5, max_speed_mm_s: float = 30.0,
                 push_sigma_mm: float = 0.0):  # fmt: skip
        self.target_mm = np.array(target_mm, dtype=np.float64)
        Bounds(0.0, MAX_ABS_MM, unit="mm").check(drift_sigma_mm, "drift_sigma_mm")
        Bounds(0.0, MAX_ABS_MM, unit="mm").check(push_sigma_mm, "push_sigma_mm")
        self.push_var = float(push_sigma_mm) ** 2
        self.inserted_mm = 0.0
        self._at_mm = 0.0  # the insertion the state refers to
        Bounds(0.0, MAX_ABS_MM, low_open=True, unit="mm/s").check(max_speed_mm_s,
                                                                     "max_speed_mm_s")  # fmt: skip
        self.drift_var = float(drift_sigma_mm) ** 2
        self.max_speed_mm_s = float(max_speed_mm_s)
        self.t = 0.0
        self._at = 0.0  # the time the state refers to (the latest sample's taking)
        self._var = 0.0  # its variance per axis
        self.used = 0
        self.refused: dict[str, int] = {}

    @property
    def variance_mm2(self) -> float:
        """The belief's variance per axis now (the state's plus the drift since).

        Returns
        -------
        float
        """
        return (self._var + self.drift_var * max(self.t - self._at, 0.0)
                + self.push_var * max(self.inserted_mm - self._at_mm, 0.0))  # fmt: skip

    def predict(self, t: float, inserted_mm: float | None = None) -> None:
        """Advance the belief to time ``t`` and insertion ``inserted_mm`` (its variance
        grows).

        Parameters
        ----------
        t : float
        inserted_mm : float, optional
            How far the needle is in (None: unchanged).

        Returns
        -------
        None
        """
        if t > self.t:
            self.t = t
        if inserted_mm is not None and inserted_mm > self.inserted_mm:
            self.inserted_mm = float(inserted_mm)

    def update(self, t: float, taken_s: float, sample_mm, sigma_mm: float,
               taken_inserted_mm: float | None = None) -> bool:  # fmt: skip
        """Use one sample, if the gate admits it.

        Parameters
        ----------
        t : float
            Now.
        taken_s : float
            When the sample was taken.
        sample_mm : array_like, shape (3,)
        sigma_mm : float
            The sample's noise SD per axis.
        taken_inserted_mm : float, optional
            How far the needle was in when it was taken (None: as far as now).

        Returns
        -------
        bool
            Whether it was used.
        """
        self.predict(t)
        lag = taken_s - self._at  # > 0: the state moves on to the sample's time
        depth = self.inserted_mm if taken_inserted_mm is None else float(taken_inserted_mm)
        lag_mm = depth - self._at_mm
        prior = self._var + self.drift_var * max(lag, 0.0) + self.push_var * max(lag_mm, 0.0)
        why = admit_target(sample_mm, self.target_mm, lag, self.max_speed_mm_s,
                           max(sigma_mm, math.sqrt(prior)))  # fmt: skip
        if why is not None:
            self.refused[why] = self.refused.get(why, 0) + 1
            return False
        r = sigma_mm**2 + self.drift_var * max(-lag, 0.0) + self.push_var * max(-lag_mm, 0.0)
        gain = prior / (prior + r) if prior + r > 0 else 1.0
        self.target_mm = self.target_mm + gain * (np.asarray(sample_mm, dtype=np.float64)
                                                  - self.target_mm)  # fmt: skip
        self._var = (1.0 - gain) * prior
        self._at = max(self._at, taken_s)
        self._at_mm = max(self._at_mm, depth)
        self.used += 1
        return True
