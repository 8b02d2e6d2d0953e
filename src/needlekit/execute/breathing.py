"""Breathing: the anatomy moving under the needle, and three ways to insert through it.

**The motion.** Targets and obstacles move together, rigidly, by a periodic respiratory
displacement along ``direction``,

    d(t) = A_k sin^(2n)(pi (t - t_k) / T_k) direction,   t_k <= t < t_k + T_k,

the model of Lujan et al. (1999) with its end-exhale (``d = 0``) at each cycle's start,
the plateau longer for larger ``n`` (``shape``). Each cycle ``k`` draws its amplitude and
period around the nominal ones (SD ``amplitude_jitter`` and ``period_jitter``, fractions;
breath-to-breath variability), from the trial's seed. Presets (:data:`PRESETS`): lung
5 mm and liver 13 mm superior-inferior (the tissue moving inferior, ``-S`` in RAS, as the
diaphragm descends), period 4 s, figures from published motion studies.
The plan is made on the anatomy at end-exhale (``d = 0``), as a breath-hold CT shows it.
A truth whose organ deforms (its ``breathe``, :mod:`needlekit.execute.plugins`) moves it by
``d(t)`` through its own model instead (the ``physical`` truth: through the organ's mesh,
:mod:`needlekit.execute.deforming`), and a needle let go rides with the tissue at its tip.

**The needle in moving tissue.** The robot drives the needle in its own (world) frame; the
tip's place in the tissue is the world place less ``d(t)``. Errors and crossings are judged
there, in the tissue, where the plan was made: the error is the tissue-frame tip's distance
from the target at the end, a crossing the collision model's verdict on the tissue-frame tip
path (as :mod:`needlekit.planning.steerable.moving` judges the tip, not the shaft the tissue
carries).

**The policies** (:class:`Policy`):

- ``ignore``: the robot holds and inserts the needle as if nothing moved; the controller
  takes the sensed (world) tip for the tissue-frame one.
- ``gate``: the needle advances only in the end-exhale window (the known displacement
  at most ``gate_fraction`` of the amplitude); outside it the robot lets go and the needle
  rides with the tissue, and is taken up again when the window opens.
- ``track``: the robot moves the needle with the *known* motion while inserting, and the
  controller works in the known tissue frame (the sensed tip less the known displacement):
  re-planning there is planning against the predicted motion, the moving anatomy's fields
  translated by it, which for a rigid motion of the whole anatomy are the static fields;
  what is left is the error of what is known.

What is known: a respiratory sensor (a belt) gives each breath's shape and phase as it
happens, not the organ's own amplitude, which the controller takes to be the nominal one
(:meth:`BreathingTrace.predicted`): the cycle's amplitude jitter is what it does not know.

Procedure time is the simulated time from the first step to the end of the insertion.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = ["POLICIES", "PRESETS", "Breathing", "BreathingTrace", "Policy"]

#: The insertion policies under breathing.
POLICIES: tuple[str, ...] = ("ignore", "gate", "track")


def _positive(name: str, v) -> float:
    if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
        raise InvalidInputError(name, f"expected a finite number > 0, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class Breathing:
    """A respiratory motion (see the module notes).

    Attributes
    ----------
    amplitude_mm : float
        Nominal peak displacement (end-inhale), 0 to 50 mm.
    direction : tuple of float
        The direction of the inhale displacement (RAS; normalised).
    period_s : float
        Nominal cycle, 1 to 20 s.
    shape : int
        ``n`` of ``sin^(2n)``, 1 to 6.
    amplitude_jitter, period_jitter : float
        SD of each cycle's amplitude and period, as fractions of the nominal ones (0-0.3).
    gate_fraction : float
        ``gate``: the window where the predicted displacement is at most this fraction of
        the amplitude (0-1).
    """

    amplitude_mm: float = 5.0
    direction: tuple = (0.0, 0.0, -1.0)
    period_s: float = 4.0
    shape: int = 2
    amplitude_jitter: float = 0.1
    period_jitter: float = 0.1
    gate_fraction: float = 0.1

    def __post_init__(self) -> None:
        a = self.amplitude_mm
        if not (isinstance(a, (int, float)) and math.isfinite(a) and 0.0 <= a <= 50.0):
            raise InvalidInputError("amplitude_mm", f"expected 0 to 50 mm, got {a!r}")
        if not 1.0 <= _positive("period_s", self.period_s) <= 20.0:
            raise InvalidInputError("period_s", f"expected 1 to 20 s, got {self.period_s!r}")
        if not (isinstance(self.shape, int) and 1 <= self.shape <= 6):
            raise InvalidInputError("shape", f"expected a whole number 1 to 6, got {self.shape!r}")
        for name in ("amplitude_jitter", "period_jitter"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= 0.3):
                raise InvalidInputError(name, f"expected 0 to 0.3, got {v!r}")
        g = self.gate_fraction
        if not (isinstance(g, (int, float)) and math.isfinite(g) and 0.0 < g <= 1.0):
            raise InvalidInputError("gate_fraction", f"expected a fraction in (0, 1], got {g!r}")
        u = np.asarray(self.direction, dtype=float)
        if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-9:
            raise InvalidInputError(
                "direction", f"expected a non-zero 3-vector, got {self.direction!r}"
            )
        object.__setattr__(self, "direction", tuple((u / np.linalg.norm(u)).tolist()))

    def trace(self, rng: np.random.Generator, duration_s: float) -> BreathingTrace:
        """The cycles of one run, drawn from ``rng``, covering ``duration_s``.

        Parameters
        ----------
        rng : numpy.random.Generator
        duration_s : float

        Returns
        -------
        BreathingTrace
        """
        starts, amps, periods = [0.0], [], []
        while starts[-1] <= duration_s:
            amps.append(
                self.amplitude_mm * max(0.0, 1.0 + self.amplitude_jitter * rng.standard_normal())
            )
            periods.append(
                self.period_s * max(0.25, 1.0 + self.period_jitter * rng.standard_normal())
            )
            starts.append(starts[-1] + periods[-1])
        return BreathingTrace(self, np.array(starts[:-1]), np.array(amps), np.array(periods))


#: Presets: figures from published motion studies (superior-inferior, 4 s).
PRESETS: dict[str, Breathing] = {
    "lung": Breathing(amplitude_mm=5.0),
    "liver": Breathing(amplitude_mm=13.0),
}


@dataclass(frozen=True)
class BreathingTrace:
    """One run's breathing: the cycles as they came (start, amplitude, period).

    Attributes
    ----------
    breathing : Breathing
    starts_s, amplitudes_mm, periods_s : ndarray
    """

    breathing: Breathing
    starts_s: np.ndarray
    amplitudes_mm: np.ndarray
    periods_s: np.ndarray

    def _wave(self, t: float) -> tuple[int, float]:
        """The cycle at ``t`` and its ``sin^(2n)`` of the phase (the shape, 0 to 1)."""
        k = max(0, min(int(np.searchsorted(self.starts_s, t, "right")) - 1, len(self.starts_s) - 1))
        x = min(max((t - self.starts_s[k]) / self.periods_s[k], 0.0), 1.0)
        return k, math.sin(math.pi * x) ** (2 * self.breathing.shape)

    def actual(self, t: float) -> np.ndarray:
        """The displacement at ``t`` (mm, RAS).

        Parameters
        ----------
        t : float

        Returns
        -------
        ndarray, shape (3,)
        """
        k, wave = self._wave(t)
        return self.amplitudes_mm[k] * wave * np.asarray(self.breathing.direction)

    def predicted(self, t: float) -> np.ndarray:
        """The displacement as the controller knows it at ``t``: a respiratory sensor (a
        belt) gives the breath's shape and phase as it happens, not the organ's own
        amplitude, taken to be the nominal one.

        Parameters
        ----------
        t : float

        Returns
        -------
        ndarray, shape (3,)
        """
        b = self.breathing
        return b.amplitude_mm * self._wave(t)[1] * np.asarray(b.direction)

    def in_window(self, t: float) -> bool:
        """Whether ``t`` is in the end-exhale window (``gate``), by the known displacement.

        Parameters
        ----------
        t : float

        Returns
        -------
        bool
        """
        b = self.breathing
        return float(np.linalg.norm(self.predicted(t))) <= b.gate_fraction * b.amplitude_mm + 1e-12


class Policy:
    """How the robot inserts through breathing (see the module notes): what moves the
    needle in the world besides the insertion, what the controller's frame is, and when
    the needle may advance.

    Parameters
    ----------
    name : str
        One of :data:`POLICIES`.
    trace : BreathingTrace
    deforming : bool
        The organ deforms: the tissue at a needle let go moves by a share of the belt's
        motion the controller does not know (:meth:`unknown_sigma_mm`), not by all of it.
    """

    def __init__(self, name: str, trace: BreathingTrace, deforming: bool = False) -> None:
        if name not in POLICIES:
            raise InvalidInputError(
                "policy", f"expected one of {', '.join(POLICIES)}, got {name!r}"
            )
        self.name = name
        self.trace = trace
        self.deforming = bool(deforming)

    def may_advance(self, t: float) -> bool:
        """Whether the needle may advance at ``t``.

        Parameters
        ----------
        t : float

        Returns
        -------
        bool
        """
        return self.name != "gate" or self.trace.in_window(t)

    def carried(self, t0: float, t1: float, advanced: bool, tissue=None) -> tuple[np.ndarray, np.ndarray]:
        """The needle's world motion from ``t0`` to ``t1`` besides the insertion, as it
        happened and as the controller knows it.

        Parameters
        ----------
        t0, t1 : float
        advanced : bool
            Whether the needle advanced (the robot held it) in that step.
        tissue : callable, optional
            ``tissue(d0, d1)``: how far the tissue at the tip moves as the displacement
            goes from ``d0`` to ``d1`` (a truth whose organ deforms, ``riding``); without
            it, the tissue moves rigidly, by ``d1 - d0``.

        Returns
        -------
        (ndarray, ndarray), each shape (3,)
            The true shift and the known one (mm, RAS).
        """
        tr = self.trace
        if self.name == "track":  # the robot moves it with the prediction
            shift = tr.predicted(t1) - tr.predicted(t0)
            return shift, shift
        if self.name == "gate" and not advanced:  # let go: it rides with the tissue
            d0, d1 = tr.actual(t0), tr.actual(t1)
            shift = d1 - d0 if tissue is None else np.asarray(tissue(d0, d1), dtype=np.float64)
            return shift, tr.predicted(t1) - tr.predicted(t0)
        zero = np.zeros(3)
        return zero, zero

    def unknown_sigma_mm(self, known_shift) -> float:
        """SD per axis of what the controller does not know of a step's shift: a needle
        riding with the tissue moves with the cycle's own amplitude, not the predicted one;
        in an organ that deforms, by the tissue's own share of it at the tip besides
        (taken as unknown up to the whole shift: the filter then follows the tip sensor).

        Parameters
        ----------
        known_shift : ndarray, shape (3,)

        Returns
        -------
        float
        """
        if self.name != "gate":
            return 0.0
        share = math.hypot(self.trace.breathing.amplitude_jitter, 1.0) if self.deforming else (
            self.trace.breathing.amplitude_jitter
        )
        return share * float(np.linalg.norm(known_shift))

    def control_offset(self, t: float) -> np.ndarray:
        """What the controller subtracts from the sensed tip to get its frame's tip.

        Parameters
        ----------
        t : float

        Returns
        -------
        ndarray, shape (3,)
            The known displacement (``track``), or zero.
        """
        return self.trace.predicted(t) if self.name == "track" else np.zeros(3)
