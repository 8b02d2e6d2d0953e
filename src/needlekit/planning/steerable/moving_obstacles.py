"""Obstacles that move during an insertion, and the static fields a planner sees of them.

Time is the insertion itself: the needle advances at a constant insertion speed ``v``
(mm/s), so the tip passes the point at arc length ``s`` at ``t = s / v``. A
:class:`MovingObstacle` is a distance field moved rigidly by a :class:`Motion`, a constant
drift plus an optional sinusoid (breathing), with the field as given the obstacle at
``t = 0``. It is seen as a static field where it is at one time
(:meth:`MovingObstacle.at`), everywhere it goes over a time span (:class:`SweptField`), or,
point by point, wherever it may be when the tip can pass that point
(:class:`ArrivalField`). The check of a path against moving obstacles is in
:mod:`needlekit.planning.steerable.moving`, which re-exports these names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from needlekit._validation import as_positive
from needlekit.anatomy.fields import DistanceField, TransformedField
from needlekit.errors import InvalidInputError

__all__ = [
    "ARRIVAL_MAX_GROWTH",
    "SWEEP_STEP_MM",
    "ArrivalField",
    "Motion",
    "MovingObstacle",
    "SweptField",
]

#: Largest obstacle travel (mm) between the time samples of a swept or arrival field (and
#: of the shaft check); half of it is added to the error bound: 0.05 mm.
SWEEP_STEP_MM: float = 0.1
#: Largest growth rate of :class:`ArrivalField`'s window with the distance from the tip
#: (``1 / cos(L / 2R)``: 1.85 for 100 mm left at r_min 50 mm) with which it uses the
#: curvature bound; beyond it (more than 2.64 r_min of length left) the window runs to the
#: end of the insertion.
ARRIVAL_MAX_GROWTH: float = 4.0


def _vector(value, name: str) -> np.ndarray:
    v = np.asarray(value, dtype=float).reshape(-1) if value is not None else np.zeros(3)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InvalidInputError(name, f"expected three finite numbers, got {value!r}")
    return v


@dataclass(frozen=True)
class Motion:
    """A rigid translation over time: constant drift plus an optional sinusoid.

    Attributes
    ----------
    velocity_mm_s : ndarray, shape (3,)
        Drift velocity (mm/s, world RAS).
    amplitude_mm : ndarray, shape (3,)
        Sinusoid amplitude vector (mm); zero for none.
    period_s : float or None
        Sinusoid period (s); needed with a non-zero amplitude.
    phase_deg : float
        Sinusoid phase at ``t = 0`` (deg).

    Examples
    --------
    >>> m = Motion([0.0, 0.0, 1.0], amplitude_mm=[2.0, 0.0, 0.0], period_s=4.0)
    >>> np.round(m.offset_mm([0.0, 1.0, 2.0]), 6).tolist()
    [[0.0, 0.0, 0.0], [2.0, 0.0, 1.0], [0.0, 0.0, 2.0]]
    >>> round(m.max_speed_mm_s, 6)  # |v| + |a| 2 pi / T
    4.141593
    """

    velocity_mm_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    amplitude_mm: np.ndarray = field(default_factory=lambda: np.zeros(3))
    period_s: float | None = None
    phase_deg: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "velocity_mm_s", _vector(self.velocity_mm_s, "velocity_mm_s"))
        object.__setattr__(self, "amplitude_mm", _vector(self.amplitude_mm, "amplitude_mm"))
        waves = bool(np.any(self.amplitude_mm != 0.0))
        if self.period_s is not None:
            object.__setattr__(self, "period_s", as_positive(self.period_s, "period_s"))
        elif waves:
            raise InvalidInputError("period_s", "a sinusoid (amplitude_mm) needs its period")
        phase = float(self.phase_deg)
        if not math.isfinite(phase):
            raise InvalidInputError("phase_deg", f"must be finite, got {self.phase_deg!r}")
        object.__setattr__(self, "phase_deg", phase)

    @property
    def _omega(self) -> float:
        return 0.0 if self.period_s is None else 2.0 * math.pi / self.period_s

    def offset_mm(self, t_s) -> np.ndarray:
        """Displacement from the ``t = 0`` position at times ``t_s``.

        Parameters
        ----------
        t_s : float or array_like, shape (n,)

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
        """
        t = np.asarray(t_s, dtype=float)
        phi = math.radians(self.phase_deg)
        wave = np.sin(self._omega * t + phi) - math.sin(phi)
        return t[..., None] * self.velocity_mm_s + wave[..., None] * self.amplitude_mm

    @property
    def max_speed_mm_s(self) -> float:
        """A bound on the speed: ``|velocity| + |amplitude| 2 pi / period`` (mm/s)."""
        return float(
            np.linalg.norm(self.velocity_mm_s) + np.linalg.norm(self.amplitude_mm) * self._omega
        )

    def to_dict(self) -> dict:
        """JSON-ready motion.

        Returns
        -------
        dict
        """
        return {
            "velocity_mm_s": self.velocity_mm_s.tolist(),
            "amplitude_mm": self.amplitude_mm.tolist(),
            "period_s": self.period_s,
            "phase_deg": self.phase_deg,
        }


def _translated(f: DistanceField, offset: np.ndarray) -> DistanceField:
    pose = np.eye(4)
    pose[:3, 3] = offset
    return TransformedField(f, pose)


@dataclass(frozen=True)
class MovingObstacle:
    """An obstacle moved rigidly over time.

    Attributes
    ----------
    name : str
        Unique beside the static scene's structures.
    field : DistanceField
        The obstacle at ``t = 0`` (world RAS, mm).
    motion : Motion
    color : str, optional
        Display colour.
    """

    name: str
    field: DistanceField
    motion: Motion
    color: str | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name.strip():
            raise InvalidInputError("name", f"a moving obstacle needs a name, got {self.name!r}")
        if not isinstance(self.field, DistanceField):
            raise InvalidInputError(f"{self.name}.field", "expected a DistanceField")
        if not isinstance(self.motion, Motion):
            raise InvalidInputError(f"{self.name}.motion", "expected a Motion")

    def at(self, t_s: float) -> DistanceField:
        """The obstacle at time ``t_s`` (exact: a translation keeps distances).

        Parameters
        ----------
        t_s : float

        Returns
        -------
        DistanceField
        """
        return _translated(self.field, self.motion.offset_mm(float(t_s)))

    def swept(self, t0_s: float, t1_s: float) -> SweptField:
        """Every place the obstacle occupies between two times.

        Parameters
        ----------
        t0_s, t1_s : float
            ``t0_s <= t1_s``.

        Returns
        -------
        SweptField
        """
        return SweptField(self.field, self.motion, t0_s, t1_s)


class SweptField(DistanceField):
    """The union of a moving obstacle's positions over ``[t0, t1]``, from time samples.

    The obstacle is placed at times no more than :data:`SWEEP_STEP_MM` of its travel
    apart; the distance is the smallest over those places. Any instant lies within half a
    gap's travel of a sampled one, so the sampled distance overestimates the distance to
    the swept set by at most that much: it is added to the error bound.

    Parameters
    ----------
    base : DistanceField
        The obstacle at ``t = 0``.
    motion : Motion
    t0_s, t1_s : float
    """

    def __init__(self, base: DistanceField, motion: Motion, t0_s: float, t1_s: float) -> None:
        t0, t1 = float(t0_s), float(t1_s)
        if not (math.isfinite(t0) and math.isfinite(t1) and t1 >= t0):
            raise InvalidInputError("t1_s", f"expected finite times t0 <= t1, got {t0_s}, {t1_s}")
        travel = motion.max_speed_mm_s * (t1 - t0)
        n = max(2, math.ceil(travel / SWEEP_STEP_MM) + 1)
        self.base = base
        self.times_s = np.linspace(t0, t1, n)
        self.offsets_mm = motion.offset_mm(self.times_s)
        self.gap_mm = travel / (n - 1)
        self.error_bound_mm = base.error_bound_mm + 0.5 * self.gap_mm

    @property
    def lipschitz_bound(self) -> float | None:  # the base's, asked for only when needed
        return self.base.lipschitz_bound

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        out = np.full(len(points), np.inf)
        for off in self.offsets_mm:
            np.minimum(out, self.base._signed_distance(points - off), out=out)
        return out

    def bounds(self) -> np.ndarray:
        b = self.base.bounds()
        pad = 0.5 * self.gap_mm
        return np.stack(
            [b[0] + self.offsets_mm.min(axis=0) - pad, b[1] + self.offsets_mm.max(axis=0) + pad]
        )


class ArrivalField(DistanceField):
    """A moving obstacle wherever it may be when the tip passes (a cycle's prediction).

    A cycle plans at ``t0`` from the tip point ``q``, with ``L`` of length left. The tip
    passes a point ``p`` at some arc length ``s`` from ``q``, at ``t0 + s / v``. With
    ``c = |p - q|``, ``s >= c``; and since the path's curvature is at most ``1 / R``
    (``R = r_min``), Schur's comparison theorem bounds the chord of any stretch of length
    ``s <= pi R`` from below by the circular arc's, ``c >= 2 R sin(s / 2R)``, so
    ``s <= 2 R asin(c / 2R)``. When ``L <= pi R`` every passing of ``p`` falls in

        W(p) = [t0 + c / v, t0 + min(L, 2 R asin(min(1, c / 2R))) / v],

    and the field at ``p`` is the smallest distance to the obstacle's places over
    ``W(p)`` (time samples at most :data:`SWEEP_STEP_MM` of travel apart). A plan that
    keeps clear of it keeps clear of the obstacle as it moves, under the motion given.
    (With ``L > pi R``, or so close to it that the window's growth passes
    :data:`ARRIVAL_MAX_GROWTH`, the window is ``[t0 + c / v, t0 + L / v]``.)

    ``W`` moves with ``p``: its ends change by at most ``g |dp| / v``, with ``g`` the
    largest slope of the upper end (``1 / cos(L / 2R)``, at least 1), so the field is
    ``1 + g * max_speed / v`` Lipschitz, not 1. The error bound adds the part of the
    planners' half sample gap
    (:data:`~needlekit.planning.steerable.validity.MOTION_SPACING_MM`) that the excess
    could hide, besides half a time sample's travel.

    Parameters
    ----------
    base : DistanceField
        The obstacle at ``t = 0``.
    motion : Motion
    t0_s : float
    tip_mm : array_like, shape (3,)
    insertion_speed_mm_s : float
    r_min_mm : float
    length_left_mm : float
    """

    def __init__(
        self, base, motion, t0_s, tip_mm, insertion_speed_mm_s, r_min_mm, length_left_mm
    ) -> None:
        from needlekit.planning.steerable.validity import MOTION_SPACING_MM

        self.base, self.motion = base, motion
        self.t0_s, self.tip_mm = float(t0_s), _vector(tip_mm, "tip_mm")
        self.speed = as_positive(insertion_speed_mm_s, "insertion_speed_mm_s")
        self.r_min_mm = as_positive(r_min_mm, "r_min_mm")
        self.length_left_mm = as_positive(length_left_mm, "length_left_mm")
        half_turn = self.length_left_mm / (2.0 * self.r_min_mm)
        growth = 1.0 / math.cos(half_turn) if half_turn < 0.5 * math.pi else math.inf
        self.schur = growth <= ARRIVAL_MAX_GROWTH
        excess = (growth if self.schur else 1.0) * motion.max_speed_mm_s / self.speed
        self._excess = excess
        self.error_bound_mm = (
            base.error_bound_mm + 0.5 * SWEEP_STEP_MM + excess * 0.5 * MOTION_SPACING_MM
        )
        t_end = self.t0_s + self.length_left_mm / self.speed
        self._travel = motion.offset_mm(np.linspace(self.t0_s, t_end, 65))

    @property
    def lipschitz_bound(self) -> float | None:
        """The base's bound plus how fast the window's obstacle can close in per mm of tip
        travel (asked for only when needed)."""
        base_l = self.base.lipschitz_bound
        return None if base_l is None else base_l + self._excess

    def window_s(self, points) -> tuple[np.ndarray, np.ndarray]:
        """Earliest and latest times the tip may pass points.

        Parameters
        ----------
        points : array_like, shape (n, 3)

        Returns
        -------
        lo, hi : ndarray, shape (n,)
        """
        c = np.linalg.norm(np.asarray(points, dtype=float).reshape(-1, 3) - self.tip_mm, axis=1)
        big = self.length_left_mm
        if self.schur:
            r2 = 2.0 * self.r_min_mm
            s_hi = np.minimum(big, r2 * np.arcsin(np.minimum(1.0, c / r2)))
        else:
            s_hi = np.full(c.shape, big)
        s_lo = np.minimum(c, s_hi)  # a point farther than L is never passed: any window
        return self.t0_s + s_lo / self.speed, self.t0_s + s_hi / self.speed

    def _signed_distance(self, points: np.ndarray) -> np.ndarray:
        lo, hi = self.window_s(points)
        span = float((hi - lo).max()) if len(points) else 0.0
        k = max(2, math.ceil(self.motion.max_speed_mm_s * span / SWEEP_STEP_MM) + 1)
        out = np.full(len(points), np.inf)
        for f in np.linspace(0.0, 1.0, k):
            off = self.motion.offset_mm(lo + f * (hi - lo))
            np.minimum(out, self.base._signed_distance(points - off), out=out)
        return out

    def bounds(self) -> np.ndarray:
        b = self.base.bounds()
        # the places over [t0, t0 + L / v], sampled 65 times: pad by a sample gap's travel
        pad = self.motion.max_speed_mm_s * self.length_left_mm / self.speed / 64
        lo, hi = self._travel.min(axis=0) - pad, self._travel.max(axis=0) + pad
        return np.stack([b[0] + lo, b[1] + hi])
