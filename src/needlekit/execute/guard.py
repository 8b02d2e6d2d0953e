"""Every sensed tip checked before it steers: the one place a sensor's samples pass through.

A closed-loop insertion steers from its estimate of the tip; a sensor that lies (a tracker
frozen on one value, an EM field distorted by metal, a cable pulled, a matrix of NaN, a
transform of something else) would steer the needle with it. :class:`SensorGuard` sits
between any sensor (the simulated EM sensor, a tracker over OpenIGTLink) and the Kalman
filter, and gives every sample one verdict:

``non_finite``
    a NaN or an infinity in the pose;
``invalid``
    not a rigid pose (its rotation not orthonormal, or a reflection);
``frozen``
    a timestamp that does not advance, or the same value again although the robot moved
    the needle between the moments the two were taken (a sensor on a moving needle never
    repeats itself; a value once found frozen is refused until another one comes);
``jump``
    farther from the last accepted sample than the needle could have moved since (the
    insertion commanded since, times :data:`PLAUSIBLE_SPEED_FACTOR`, what the tissue could
    have carried it, plus the two samples' noise: :data:`PLAUSIBLE_NOISE_SIGMAS`);
``gated``
    its innovation fails the filter's Mahalanobis test (:data:`GATE_CHI2`);

or it is accepted and corrects the estimate. Rejected samples are counted by kind.

When no sample has been accepted for :data:`STALE_S` of the loop's time (input that
stopped, froze, or turned into lies), the guard *holds* the needle: the loop stops
advancing it (:meth:`SensorGuard.may_advance`), and re-plans wait. The hold ends after
:data:`RESUME_SAMPLES` accepted samples in a row, or turns into an abort: at once with
``on_fault="abort"``, after ``hold_timeout_s`` with ``on_fault="hold"`` (the default;
from a confirmation scan's arrival when one is under way: :meth:`SensorGuard.await_settling`).
Every hold, resume and abort is an event ``{"time_s", "kind", "action"}`` (a hold also
says when the last accepted sample came in and was taken, ``last_accepted_s`` and
``last_accepted_taken_s``; a hold whose
reason changes, input that stopped and then came back as lies, is a new ``hold`` event of
the new kind; the timeout runs from the first); so is a
re-plan the loop refused (:meth:`SensorGuard.check_replan`: it failed, or it came back
after the needle had moved on more than :data:`REPLAN_STALE_MM`), the last verified plan
kept.

Times are the loop's simulated clock (seconds), never the wall clock: a run replays.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from dataclasses import dataclass

import numba
import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.estimator import TIME_TOL_S

__all__ = [
    "FAULT_ACTIONS",
    "GATE_CHI2",
    "REJECT_KINDS",
    "GuardSpec",
    "SensorGuard",
]

log = logging.getLogger(__name__)

#: Chi-square quantile of the innovation gate: 6 degrees of freedom (position and
#: orientation), probability 1 - 1e-5 (``scipy.stats.chi2.ppf(1 - 1e-5, 6)``). An honest
#: sample is refused once in 100 000; a 5 mm offset against the default sensor (0.4 mm SD)
#: scores about 80.
GATE_CHI2: float = 33.1

#: The fastest the tip can move per mm of commanded insertion: 1, plus the needle's
#: departures from its model (tissue push 0.01-0.2 mm/mm, curvature spread), doubled
#: for safety.
PLAUSIBLE_SPEED_FACTOR: float = 2.0

#: Two samples' noise, bounded: the difference of two 3-D Gaussian positions of SD s has
#: norm below 5.5 * sqrt(2) * s with probability 1 - 1e-6 (chi with 3 degrees of freedom).
PLAUSIBLE_NOISE_SIGMAS: float = 5.5 * math.sqrt(2.0)

#: Slack (mm) on top of the noise for what a pose sent as float32 loses, and rounding.
PLAUSIBLE_SLACK_MM: float = 0.5

#: No accepted sample for this long (s of the loop's clock) holds the needle: six periods
#: of the default 40 Hz sensor, so that a burst of five lost samples does not, and a
#: failure is caught within 0.5 s with the needle at most 0.3 mm further at 2 mm/s.
STALE_S: float = 0.15

#: Accepted samples in a row that end a hold (75 ms at 40 Hz): one good sample between
#: lies does not release the needle.
RESUME_SAMPLES: int = 3

#: A re-plan that comes back after the needle went on this far (mm) since it was asked
#: planned from a tip that is no longer there: refused, the last verified plan kept.
REPLAN_STALE_MM: float = 1.0

#: How many changes of the insertion the guard remembers, to know whether the needle moved
#: between two samples' moments: 2.5 s of steps at the default 5 ms (the filter places
#: samples up to 0.5 s late).
INSERTION_MEMORY: int = 512

#: A rotation block this far (Frobenius) from orthonormal is no pose.
ORTHONORMAL_TOL: float = 1e-3

#: The verdicts a sample can get besides acceptance (module notes).
REJECT_KINDS: tuple[str, ...] = ("non_finite", "invalid", "frozen", "jump", "gated")

#: What the guard does about a fault.
FAULT_ACTIONS: tuple[str, ...] = ("hold", "resume", "abort", "kept_plan")


@numba.njit(cache=True)
def _pose_checks(g, prev, frozen, good_p):  # pragma: no cover (compiled)
    """One pass over a sample's matrix (the feedback step is hot): whether every entry is
    finite, how far its rotation block is from orthonormal (Frobenius norm of
    ``R^T R - I``), its determinant, whether it equals ``prev`` and ``frozen`` entry for
    entry, and its position's distance from ``good_p``."""
    finite = True
    for i in range(4):
        for j in range(4):
            if not np.isfinite(g[i, j]):
                finite = False
    if not finite:
        return False, 0.0, 0.0, False, False, 0.0
    err = 0.0
    for i in range(3):
        for j in range(3):
            d = g[0, i] * g[0, j] + g[1, i] * g[1, j] + g[2, i] * g[2, j] - (1.0 if i == j else 0.0)
            err += d * d
    det = (g[0, 0] * (g[1, 1] * g[2, 2] - g[1, 2] * g[2, 1])
           - g[0, 1] * (g[1, 0] * g[2, 2] - g[1, 2] * g[2, 0])
           + g[0, 2] * (g[1, 0] * g[2, 1] - g[1, 1] * g[2, 0]))  # fmt: skip
    same_prev = True
    same_frozen = True
    for i in range(4):
        for j in range(4):
            if g[i, j] != prev[i, j]:
                same_prev = False
            if g[i, j] != frozen[i, j]:
                same_frozen = False
    dist = 0.0
    for i in range(3):
        dist += (g[i, 3] - good_p[i]) ** 2
    return True, np.sqrt(err), det, same_prev, same_frozen, np.sqrt(dist)


#: Stands in for "no such matrix" in :func:`_pose_checks` (never equal to a sample).
_NONE = np.full((4, 4), np.nan)

_ORIGIN = np.zeros(3)


def is_pose(value: np.ndarray) -> bool:
    """Whether a (4, 4) float64 matrix is a pose a filter may take: every entry finite,
    its rotation block within :data:`ORTHONORMAL_TOL` of orthonormal and proper. The
    guard's own screen (:meth:`SensorGuard.admit`) applies it to every tracker sample;
    an image's tip pose goes through it too (:mod:`needlekit.execute.target_sensing`).

    Parameters
    ----------
    value : ndarray, shape (4, 4), float64, C-contiguous

    Returns
    -------
    bool
    """
    finite, ortho, det, _, _, _ = _pose_checks(value, _NONE, _NONE, _ORIGIN)
    return bool(finite) and ortho <= ORTHONORMAL_TOL and det >= 0.0


@dataclass(frozen=True)
class GuardSpec:
    """What the guard does when the input fails.

    Attributes
    ----------
    on_fault : str
        ``"hold"``: hold the needle until good input returns, at most ``hold_timeout_s``,
        then abort; ``"abort"``: abort the insertion at the first hold.
    hold_timeout_s : float
        The longest hold (s) before the insertion is aborted.
    stale_s : float
        No accepted sample for this long holds the needle (at most 0.5 s).
    gate_chi2 : float
        The innovation gate (squared Mahalanobis distance).
    """

    on_fault: str = "hold"
    hold_timeout_s: float = 10.0
    stale_s: float = STALE_S
    gate_chi2: float = GATE_CHI2

    def __post_init__(self) -> None:
        if self.on_fault not in ("hold", "abort"):
            raise InvalidInputError("on_fault", f"expected hold or abort, got {self.on_fault!r}")
        for name, top in (("hold_timeout_s", 3600.0), ("stale_s", 0.5), ("gate_chi2", 1e6)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= top):
                raise InvalidInputError(name, f"expected a number in (0, {top:g}], got {v!r}")


class SensorGuard:
    """The checks every sample passes before it reaches the estimator (module notes).

    Parameters
    ----------
    spec : GuardSpec
    start_pose : ndarray, shape (4, 4)
        The tip where the insertion starts (the robot placed it there): the first
        samples' reference.
    position_sigma_mm : float
        The sensor's position noise (SD per axis).
    carried_speed_mm_s : float
        The fastest the tissue can carry the needle (breathing), besides its insertion.
    notify : callable, optional
        Called with each event (a dict) as it happens (the CLI says it in one line).

    Attributes
    ----------
    events : list of dict
        ``{"time_s", "kind", "action"}`` (a hold also ``last_accepted_s`` and
        ``last_accepted_taken_s``, a resume ``held_s``), in order.
    rejected : collections.Counter
        Rejected samples by kind.
    accepted : int
    holding : bool
    aborted : bool
    held_s : float
        The loop time the needle has spent held.
    """

    def __init__(self, spec: GuardSpec, start_pose, position_sigma_mm: float,
                 carried_speed_mm_s: float = 0.0, notify=None) -> None:  # fmt: skip
        self.spec = spec
        self.slack_mm = PLAUSIBLE_NOISE_SIGMAS * float(position_sigma_mm) + PLAUSIBLE_SLACK_MM
        self.carried_speed_mm_s = float(carried_speed_mm_s)
        self.notify = notify
        self.events: list[dict] = []
        self.rejected: Counter = Counter()
        self.accepted = 0
        self.holding = False
        self.aborted = False
        self.held_s = 0.0
        # the last accepted sample: where, when taken, the insertion then, when it arrived
        self._good_p = np.array(start_pose, dtype=np.float64)[:3, 3].copy()
        self._good_taken = 0.0
        self._good_inserted = 0.0
        self._good_t = 0.0
        self._in_a_row = 0
        # the last sample of any verdict: its time stamp, its value, the insertion then
        self._last_taken = -math.inf
        self._last_value: np.ndarray | None = None
        # (loop time, insertion) where the insertion changed, the latest INSERTION_MEMORY
        self._insertions: deque = deque([(0.0, 0.0)], maxlen=INSERTION_MEMORY)
        self._frozen_value: np.ndarray | None = None
        self._why: str | None = None  # the latest refusal since the last accepted sample
        self._hold_t = 0.0
        self._hold_kind = ""
        self._holds = 0
        self._await_s = -math.inf  # a hold's timeout runs from here at the earliest

    def admit(self, t: float, sample, estimator, inserted_mm: float) -> bool:
        """Judge the sample that arrived at loop time ``t`` (None: none did), correct the
        estimator with it if it passes, and update the hold.

        Parameters
        ----------
        t : float
            The loop's time (s).
        sample : EMSample or None
        estimator : TipEstimator
        inserted_mm : float
            The insertion commanded so far (the robot's own count).

        Returns
        -------
        bool
            Whether the sample was accepted (and used).
        """
        if inserted_mm != self._insertions[-1][1]:  # the insertion as it changes
            self._insertions.append((t, inserted_mm))
        if sample is None:  # the hot path: nothing to judge, and most often nothing due
            if self.holding or t - self._good_t > self.spec.stale_s + 1e-9:
                self._update_hold(t)
            return False
        ok = False
        kind = self._screen(sample, inserted_mm)
        if kind is None and not estimator.update(sample.taken_s, sample.pose, self.spec.gate_chi2):
            kind = "gated"
        if kind is None:
            ok = True
            self.accepted += 1
            self._in_a_row += 1
            self._good_p = sample.pose[:3, 3].copy()
            self._good_taken, self._good_inserted, self._good_t = sample.taken_s, inserted_mm, t
            self._why = None
        else:
            self.rejected[kind] += 1
            self._in_a_row = 0
            self._why = kind
            if self.holding and kind != self._hold_kind:  # held for another reason now
                self._hold_kind = kind
                self._event(t, kind, "hold", **self._last_accepted())
        if self.holding or t - self._good_t > self.spec.stale_s + 1e-9:
            self._update_hold(t)
        return ok

    def _screen(self, sample, inserted_mm: float) -> str | None:
        """The sample's verdict before the filter's gate (None: it passes)."""
        value = sample.pose
        if not (type(value) is np.ndarray and value.dtype == np.float64
                and value.flags.c_contiguous):  # fmt: skip
            value = np.ascontiguousarray(value, dtype=np.float64)
        taken = float(sample.taken_s)
        previous, last_taken = self._last_value, self._last_taken
        if value.shape != (4, 4) or not math.isfinite(taken):
            self._last_value = None
            return "non_finite"
        self._last_value = value
        advanced = taken > last_taken
        self._last_taken = max(last_taken, taken)
        frozen = self._frozen_value
        finite, ortho, det, same_prev, same_frozen, dist = _pose_checks(
            value, _NONE if previous is None else previous,
            _NONE if frozen is None else frozen, self._good_p)  # fmt: skip
        if not finite:
            return "non_finite"
        if ortho > ORTHONORMAL_TOL or det < 0.0:
            return "invalid"
        if not advanced:
            return "frozen"
        if frozen is not None:
            if same_frozen:
                return "frozen"
            self._frozen_value = None
        if same_prev and self._inserted_at(taken) > self._inserted_at(last_taken) + 1e-9:
            self._frozen_value = value  # the same value, though the needle moved between
            return "frozen"
        reach = (PLAUSIBLE_SPEED_FACTOR * (inserted_mm - self._good_inserted)
                 + self.carried_speed_mm_s * max(taken - self._good_taken, 0.0)
                 + self.slack_mm)  # fmt: skip
        return "jump" if dist > reach else None

    def _inserted_at(self, t: float) -> float:
        """The insertion at loop time ``t`` (the oldest remembered before the memory)."""
        found = self._insertions[0][1]
        for when, inserted in reversed(self._insertions):
            if when <= t + TIME_TOL_S:  # a timestamp off by its rounding is at the step
                return inserted
        return found

    def _update_hold(self, t: float) -> None:
        spec = self.spec
        if self.aborted:
            return
        if self.holding:
            if self._in_a_row >= RESUME_SAMPLES:
                self.holding = False
                self._event(t, self._hold_kind, "resume", held_s=round(t - self._hold_t, 6))
            elif t - max(self._hold_t, self._await_s) >= spec.hold_timeout_s - 1e-9:
                self.aborted = True
                self._event(t, self._hold_kind, "abort")
            return
        if t - self._good_t > spec.stale_s + 1e-9:
            self._hold_kind = self._why or "stopped"
            self._hold_t = t
            self._in_a_row = 0
            if spec.on_fault == "abort":
                self.aborted = True
                self._event(t, self._hold_kind, "abort")
            else:
                self.holding = True
                self._holds += 1
                self._event(t, self._hold_kind, "hold", **self._last_accepted())

    @property
    def gated_hold(self) -> int | None:
        """The number of the hold under way when its reason is the filter's gate (the
        sensor and the estimate disagree, the samples otherwise sound), else None: what
        an imaging checkpoint can settle (:meth:`TargetSensing.tick
        <needlekit.execute.target_sensing.TargetSensing.tick>`)."""
        return self._holds if self.holding and self._hold_kind == "gated" else None

    def await_settling(self, until_s: float) -> None:
        """Let a hold's timeout run from ``until_s`` (loop clock, s) at the earliest: a
        confirmation scan that can settle it arrives then (the needle stays held), and the
        sensor then has the whole timeout to agree with the settled estimate.

        Parameters
        ----------
        until_s : float

        Returns
        -------
        None
        """
        self._await_s = max(self._await_s, float(until_s))

    def may_advance(self) -> bool:
        """Whether the loop may insert this step (not held, not aborted).

        Returns
        -------
        bool
        """
        return not (self.holding or self.aborted)

    def held_step(self, dt_s: float) -> None:
        """Count one step of the loop spent held.

        Parameters
        ----------
        dt_s : float

        Returns
        -------
        None
        """
        self.held_s += dt_s

    def check_replan(self, t: float, result, fault: str | None = None):
        """A re-plan's result as the loop may adopt it: None, the last verified plan kept
        and an event recorded, when it failed (its search or its check) or an injected
        fault fails it.

        Parameters
        ----------
        t : float
        result : PlanResult or None
            What the re-planner returned.
        fault : str, optional
            An injected failure: ``"fail"`` fails the result.

        Returns
        -------
        PlanResult or None
        """
        if result is None or fault == "fail":
            self._event(t, "replan_failed", "kept_plan")
            return None
        return result

    def replan_in_time(self, t: float, asked_mm: float, inserted_mm: float) -> bool:
        """Whether a re-plan coming back now may still be adopted: the needle went on at
        most :data:`REPLAN_STALE_MM` since it was asked for (else an event is recorded,
        ``replan_overrun``, and the last verified plan is kept).

        Parameters
        ----------
        t : float
        asked_mm, inserted_mm : float
            The insertion when the re-plan was asked for, and now.

        Returns
        -------
        bool
        """
        if inserted_mm - asked_mm > REPLAN_STALE_MM:
            self._event(t, "replan_overrun", "kept_plan")
            return False
        return True

    def _last_accepted(self) -> dict:
        """When the last accepted sample came in and when it was taken (loop clock, s; 0
        when none was): a hold's account of the last input it trusted."""
        return {"last_accepted_s": round(float(self._good_t), 6),
                "last_accepted_taken_s": round(float(self._good_taken), 6)}  # fmt: skip

    def _event(self, t: float, kind: str, action: str, **extra) -> None:
        event = {"time_s": round(float(t), 6), "kind": kind, "action": action, **extra}
        self.events.append(event)
        log.info("sensor guard: %s at t=%.3f s: %s", kind, t, action)
        if self.notify is not None:
            self.notify(event)

    def record(self) -> dict:
        """The guard's account of one run, for its record.

        Returns
        -------
        dict
            ``faults`` (the events), ``rejected`` (samples by kind), ``accepted``,
            ``holds``, ``held_s`` and ``aborted``.
        """
        return {
            "faults": list(self.events),
            "rejected": {k: int(self.rejected[k]) for k in REJECT_KINDS if self.rejected[k]},
            "accepted": int(self.accepted),
            "holds": self._holds,
            "held_s": round(self.held_s, 6),
            "aborted": bool(self.aborted),
        }
