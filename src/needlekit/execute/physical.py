"""The ``mechanics`` truth: the needle that bends by mechanics, driven by the loop.

:class:`needlekit.mechanics.insertion.MechanicalNeedle` is an elastic rod held by the
tissue along the channel its tip cuts (docs/mechanics.md). This module puts it behind the
truth protocol of :mod:`needlekit.execute.plugins`:

- **The command.** The loop and the plan speak the planner's unicycle: a curvature
  ``0 <= kappa <= 1 / r_min``, which a robot carries out as a duty cycle ``kappa r_min``
  (the share of the insertion with the bevel held; the rest spins). The rod gets that duty
  cycle: how much the needle then bends is the mechanics', not ``1 / r_min``.
- **Its rate.** The rod is solved at ``solve_rate_hz`` (40 Hz by default, the EM sensor's
  rate): the insertion commanded in between is pooled (its length, the length-weighted
  mean duty cycle) and solved at once with the roll of the latest command, a zero-order
  hold like a robot's servo cycle. Between two solves the tip's pose is the last solved
  one advanced straight along its tangent by what has been inserted since (at 2 mm/s and
  40 Hz, 0.05 mm: an error of ``kappa (0.05 mm)^2 / 2``, below a nanometre at
  ``r = 100 mm``). A spin turns the bevel at once (no solve). A step that inserts nothing
  (the sensor guard holding, a breathing gate) solves what is pooled.
- **Carried.** Moved besides its insertion (a breathing policy: the robot following the
  motion, or the needle let go riding with the tissue), the whole rod moves with it
  (:meth:`MechanicsTruth.carry`): its channel and tip are kept in the rod's own frame,
  offset in the world by what has carried it.
- **Torsion** is left out (the shaft is torsionally rigid: a spin of the base turns the
  bevel by as much).

:class:`MechanicsSettings` names the needle and the tissue (presets of
:mod:`needlekit.mechanics.materials`), a pre-bent tip and the tissue's inhomogeneity.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.mechanics.materials import NeedleSpec, TissueSpec

__all__ = ["MechanicsSettings", "MechanicsTruth", "mechanics_truth"]


@dataclass(frozen=True)
class MechanicsSettings:
    """The needle and the tissue of the ``mechanics`` truth.

    Attributes
    ----------
    needle : str
        A needle preset (``"nitinol"``, ``"steel"``).
    tissue : str
        A tissue preset (``"lung"``, ``"liver"``, ``"plastisol"``, ``"gelatin"``,
        ``"chicken"``).
    prebend_deg : float
        The tip's pre-bend toward the bevel (0: a plain bevel tip), in [0, 90).
    prebend_length_mm : float
        The bent segment's length (> 0 when there is a pre-bend).
    inhomogeneity : float
        SD of the tissue's millimetre-to-millimetre variation of the tip load (a fraction),
        >= 0 (:class:`~needlekit.mechanics.insertion.MechanicalNeedle`).
    solve_rate_hz : float
        How often the rod is solved (> 0).
    """

    needle: str = "nitinol"
    tissue: str = "lung"
    prebend_deg: float = 0.0
    prebend_length_mm: float = 5.0
    inhomogeneity: float = 0.1
    solve_rate_hz: float = 40.0

    def __post_init__(self) -> None:
        NeedleSpec.preset(self.needle)  # a name not among the presets: its error
        TissueSpec.preset(self.tissue)
        checks = (
            ("prebend_deg", 0.0, 90.0, False),
            ("prebend_length_mm", 0.0, 1e3, False),
            ("inhomogeneity", 0.0, 10.0, False),
            ("solve_rate_hz", 0.0, 1e6, True),
        )
        for name, low, high, open_low in checks:
            v = getattr(self, name)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not (ok and (v > low if open_low else v >= low) and v < high):
                side = "(" if open_low else "["
                raise InvalidInputError(name, f"expected a number in {side}{low:g}, {high:g}),"
                                        f" got {v!r}")  # fmt: skip
        if self.prebend_deg > 0 and self.prebend_length_mm <= 0:
            raise InvalidInputError(
                "prebend_length_mm", "expected a length > 0 for a pre-bent tip, got 0"
            )

    def needle_spec(self):
        """The needle as :mod:`needlekit.mechanics` takes it.

        Returns
        -------
        needlekit.mechanics.materials.NeedleSpec
        """
        spec = NeedleSpec.preset(self.needle)
        if self.prebend_deg > 0:
            spec = spec.with_prebend(self.prebend_deg, self.prebend_length_mm)
        return spec

    def tissue_spec(self):
        """The tissue as :mod:`needlekit.mechanics` takes it.

        Returns
        -------
        needlekit.mechanics.materials.TissueSpec
        """
        return TissueSpec.preset(self.tissue)


class MechanicsTruth:
    """The rod behind the truth protocol (see the module notes).

    Parameters
    ----------
    needle : needlekit.mechanics.insertion.MechanicalNeedle
    r_min_mm : float
        The planner's radius: a command ``kappa`` is the duty cycle ``kappa r_min_mm``.
    solve_rate_hz : float

    Attributes
    ----------
    pose : ndarray, shape (4, 4)
    inserted_mm : float
    solves : int
        Rod solves so far.
    """

    def __init__(self, needle, r_min_mm: float, solve_rate_hz: float = 40.0) -> None:
        self.needle = needle
        self.r_min_mm = float(r_min_mm)
        self.period_s = 1.0 / float(solve_rate_hz)
        self._len = 0.0  # pooled since the last solve: length, duty x length, time
        self._duty_len = 0.0
        self._time = 0.0
        self.solves = 0
        self.inserted_mm = needle.inserted_mm
        self.offset_mm = np.zeros(3)  # what has carried the rod besides its insertion
        self.pose = needle.pose.copy()

    def _flush(self) -> None:
        if self._len > 0.0:
            kappa = self._duty_len / self._len * self.needle.kappa_max_per_mm
            self.needle.step(0.0, kappa, self._len, self._time)
            self.solves += 1
        self._len = self._duty_len = self._time = 0.0
        self.pose = self.needle.pose.copy()
        self.pose[:3, 3] += self.offset_mm
        self.inserted_mm = self.needle.inserted_mm

    def carry(self, shift_mm) -> None:
        """Move the whole rod by ``shift_mm`` (world, mm) besides its insertion.

        Parameters
        ----------
        shift_mm : array-like, shape (3,)

        Returns
        -------
        None
        """
        v = np.asarray(shift_mm, dtype=np.float64).reshape(3)
        self.offset_mm = self.offset_mm + v
        self.pose = self.pose.copy()
        self.pose[:3, 3] += v

    def step(self, spin_rad: float, kappa_per_mm: float, ds_mm: float, dt_s: float) -> np.ndarray:
        """Spin the bevel, then insert ``ds_mm`` at the commanded duty cycle.

        Parameters
        ----------
        spin_rad : float
        kappa_per_mm : float
            The planner's curvature: the duty cycle ``kappa r_min``.
        ds_mm, dt_s : float

        Returns
        -------
        ndarray, shape (4, 4)
            The true tip pose after the step.
        """
        if spin_rad != 0.0:
            self.needle.step(float(spin_rad), 0.0, 0.0, 0.0)
        if ds_mm > 0.0:
            duty = max(-1.0, min(1.0, float(kappa_per_mm) * self.r_min_mm))
            self._len += float(ds_mm)
            self._duty_len += duty * float(ds_mm)
        self._time += float(dt_s)
        if self._time >= self.period_s - 1e-12 or (ds_mm <= 0.0 and self._len > 0.0):
            self._flush()
        else:
            g = self.needle.pose.copy()
            g[:3, 3] += self._len * g[:3, 2] + self.offset_mm
            self.pose = g
            self.inserted_mm = self.needle.inserted_mm + self._len
        return self.pose

    def shaft_loads(self) -> dict:
        """The tissue's loads on the needle at the last solve (the loop records them).

        Returns
        -------
        dict
            ``points_mm`` (n, 3) and ``forces_n`` (n, 3) as lists, the tip's row last;
            ``tip_force_n`` and ``shaft_force_n``: the magnitudes at the tip and summed
            along the shaft.
        """
        self._flush()
        pts, forces = self.needle.shaft_loads()
        pts = pts + self.offset_mm
        if len(pts) == 0:
            return {"points_mm": [], "forces_n": [], "tip_force_n": 0.0, "shaft_force_n": 0.0}
        return {
            "points_mm": np.round(pts, 4).tolist(),
            "forces_n": np.round(forces, 6).tolist(),
            "tip_force_n": float(np.linalg.norm(forces[-1])),
            "shaft_force_n": float(np.linalg.norm(forces[:-1], axis=1).sum()),
        }


def mechanics_truth(setup) -> MechanicsTruth:
    """The ``mechanics`` truth (:data:`needlekit.execute.plugins.TRUTHS`): the rod with the
    run's :class:`MechanicsSettings` (``settings.mechanics``), its inhomogeneity drawn from
    the setup's stream.

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    MechanicsTruth
    """
    from needlekit.mechanics.insertion import MechanicalNeedle

    m = setup.settings.mechanics
    needle = MechanicalNeedle(setup.start_pose, m.needle_spec(), m.tissue_spec(),
                              rng=setup.rng, inhomogeneity=m.inhomogeneity)  # fmt: skip
    return MechanicsTruth(needle, setup.r_min_mm, m.solve_rate_hz)


def _mechanics_parameters(settings) -> dict:
    from needlekit.mechanics.insertion import steady_curvature

    m = settings.mechanics
    needle, tissue = m.needle_spec(), m.tissue_spec()
    kappa = steady_curvature(needle, tissue)
    return {
        **asdict(m),
        "needle_spec": asdict(needle),
        "tissue_spec": asdict(tissue),
        "radius_bevel_held_mm": None if kappa <= 0 else 1.0 / kappa,
    }


mechanics_truth.parameters = _mechanics_parameters
