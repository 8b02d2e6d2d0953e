"""Faults injected into a simulated insertion (``needlekit execute --faults PROFILE``).

A profile draws, from the trial's seed, a schedule of faults over the insertion's nominal
duration; :class:`FaultySensor` applies the sensor's to what the simulated EM sensor
delivers, and the loop asks :meth:`FaultSchedule.replan_fault` about its re-plans. The
kinds:

``dropout``
    no sample arrives (a cable pulled, the sensor out of the field);
``freeze``
    the last sample again and again, with fresh timestamps or (half the time) the same
    one (a tracker whose driver hangs);
``distortion``
    every sample offset by one vector of 5-20 mm (metal near the field generator);
``jitter``
    each sample delayed a further 0-100 ms (a loaded network), in order;
``nan``
    matrices of NaN (a tracker that lost the sensor and says so badly);
``replan``
    every re-plan fails, or (half the time) comes back 1 s late.

Each fault lasts 0.2-2 s and starts between 1 s and 90 % of the nominal duration. The
schedule is the trial seed's fourth child (:func:`fault_seed`): ``--replay-trial K`` replays it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit.control.em import EMSample
from needlekit.errors import InvalidInputError

__all__ = ["FAULT_KINDS", "PROFILES", "Fault", "FaultProfile", "FaultSchedule", "FaultySensor"]

#: The kinds a profile draws from (module notes).
FAULT_KINDS: tuple[str, ...] = ("dropout", "freeze", "distortion", "jitter", "nan", "replan")

#: EM distortion offsets (mm): the range reported near metal in the operating room.
DISTORTION_MM: tuple[float, float] = (5.0, 20.0)
#: A fault's duration (s): from below the guard's stale time to well above it.
DURATION_S: tuple[float, float] = (0.2, 2.0)
#: The extra delay of a jittered sample (s), up to four sensor periods at 40 Hz.
JITTER_S: float = 0.1
#: How late an overrunning re-plan comes back (s).
REPLAN_OVERRUN_S: float = 1.0
#: Faults start no sooner than this (s), and before this fraction of the nominal duration.
FIRST_FAULT_S: float = 1.0
LAST_FAULT_FRACTION: float = 0.9


@dataclass(frozen=True)
class FaultProfile:
    """Which faults a trial meets, and how many.

    Attributes
    ----------
    name : str
    kinds : tuple of str
        Drawn from uniformly, each fault on its own.
    per_trial : int
    """

    name: str
    kinds: tuple
    per_trial: int

    def __post_init__(self) -> None:
        bad = [k for k in self.kinds if k not in FAULT_KINDS]
        if bad or not self.kinds:
            raise InvalidInputError("kinds", f"expected some of {', '.join(FAULT_KINDS)}")
        if not (isinstance(self.per_trial, int) and 0 < self.per_trial <= 100):
            raise InvalidInputError("per_trial", f"expected 1-100, got {self.per_trial!r}")


#: The profiles ``--faults`` takes: one per kind (two faults a trial), and ``mixed`` (four
#: faults a trial of any kind).
PROFILES: dict[str, FaultProfile] = {
    **{k: FaultProfile(k, (k,), 2) for k in FAULT_KINDS},
    "mixed": FaultProfile("mixed", FAULT_KINDS, 4),
}


@dataclass(frozen=True)
class Fault:
    """One scheduled fault.

    Attributes
    ----------
    kind : str
    start_s, end_s : float
    offset_mm : tuple of float
        ``distortion``: the offset (RAS mm).
    variant : str
        ``freeze``: ``"value"`` (fresh timestamps) or ``"stamp"`` (the same one);
        ``replan``: ``"fail"`` or ``"overrun"``.
    """

    kind: str
    start_s: float
    end_s: float
    offset_mm: tuple = ()
    variant: str = ""

    def to_dict(self) -> dict:
        """The fault for a record.

        Returns
        -------
        dict
        """
        out = {"kind": self.kind, "start_s": round(self.start_s, 6), "end_s": round(self.end_s, 6)}
        if self.offset_mm:
            out["offset_mm"] = [round(v, 4) for v in self.offset_mm]
        if self.variant:
            out["variant"] = self.variant
        return out


def fault_seed(seed: np.random.SeedSequence) -> np.random.SeedSequence:
    """The faults' seed: the trial seed's fourth child (the needle, the sensor and the
    breathing have the first three).

    Parameters
    ----------
    seed : numpy.random.SeedSequence

    Returns
    -------
    numpy.random.SeedSequence
    """
    return np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, 3),
                                  pool_size=seed.pool_size)  # fmt: skip


class FaultSchedule:
    """The faults of one trial, drawn from a profile.

    Parameters
    ----------
    profile : FaultProfile
    rng : numpy.random.Generator
    nominal_s : float
        The insertion's nominal duration (plan length over speed).

    Attributes
    ----------
    faults : tuple of Fault
    """

    def __init__(self, profile: FaultProfile, rng: np.random.Generator, nominal_s: float) -> None:
        self.rng = rng
        last = max(LAST_FAULT_FRACTION * nominal_s, FIRST_FAULT_S + 1e-3)
        faults = []
        for _ in range(profile.per_trial):
            kind = profile.kinds[int(rng.integers(len(profile.kinds)))]
            start = float(rng.uniform(FIRST_FAULT_S, last))
            end = start + float(rng.uniform(*DURATION_S))
            offset, variant = (), ""
            if kind == "distortion":
                d = rng.normal(size=3)
                offset = tuple(
                    float(v) for v in d / np.linalg.norm(d) * rng.uniform(*DISTORTION_MM)
                )
            elif kind == "freeze":
                variant = ("value", "stamp")[int(rng.integers(2))]
            elif kind == "replan":
                variant = ("fail", "overrun")[int(rng.integers(2))]
            faults.append(Fault(kind, start, end, offset, variant))
        self.faults = tuple(sorted(faults, key=lambda f: f.start_s))

    def active(self, t: float, kind: str) -> Fault | None:
        """The fault of ``kind`` under way at ``t`` (None: none).

        Parameters
        ----------
        t : float
        kind : str

        Returns
        -------
        Fault or None
        """
        for f in self.faults:
            if f.kind == kind and f.start_s <= t < f.end_s:
                return f
        return None

    def replan_fault(self, t: float) -> str | None:
        """What an injected fault does to a re-plan asked for at ``t``: ``"fail"``,
        ``"overrun"`` or None.

        Parameters
        ----------
        t : float

        Returns
        -------
        str or None
        """
        f = self.active(t, "replan")
        return None if f is None else f.variant

    def to_list(self) -> list[dict]:
        """The schedule for a record.

        Returns
        -------
        list of dict
        """
        return [f.to_dict() for f in self.faults]


class FaultySensor:
    """A sensor whose samples meet the schedule's faults (the sensor's interface:
    ``update(t, true_pose) -> EMSample or None``).

    Parameters
    ----------
    sensor : object
        The sensor underneath (:class:`~needlekit.control.em.EMSensor`).
    schedule : FaultSchedule
    """

    def __init__(self, sensor, schedule: FaultSchedule) -> None:
        self.sensor = sensor
        self.schedule = schedule
        self._last: EMSample | None = None
        self._delayed: list[tuple[float, EMSample]] = []

    def update(self, t: float, true_pose) -> EMSample | None:
        """The sample delivered at ``t``, as the faults under way make it.

        Parameters
        ----------
        t : float
        true_pose : callable

        Returns
        -------
        EMSample or None
        """
        sample = self.sensor.update(t, true_pose)
        sch = self.schedule
        if sample is not None:  # in order: a delayed sample holds back the ones after it
            due = t
            if sch.active(sample.taken_s, "jitter") is not None:
                due += float(sch.rng.uniform(0.0, JITTER_S))
            if self._delayed:
                due = max(due, self._delayed[-1][0])
            self._delayed.append((due, sample))
        newest = None
        while self._delayed and self._delayed[0][0] <= t + 1e-12:
            newest = self._delayed.pop(0)[1]
        return None if newest is None else self._faulted(t, newest)

    def _faulted(self, t: float, sample: EMSample) -> EMSample | None:
        sch = self.schedule
        if sch.active(t, "dropout") is not None:
            return None
        freeze = sch.active(t, "freeze")
        if freeze is not None and self._last is not None:
            taken = self._last.taken_s if freeze.variant == "stamp" else sample.taken_s
            return EMSample(taken, sample.arrives_s, self._last.pose.copy())
        if sch.active(t, "nan") is not None:
            return EMSample(sample.taken_s, sample.arrives_s, np.full((4, 4), np.nan))
        dist = sch.active(t, "distortion")
        if dist is not None:
            pose = sample.pose.copy()
            pose[:3, 3] += dist.offset_mm
            sample = EMSample(sample.taken_s, sample.arrives_s, pose)
        self._last = sample
        return sample
