"""A straight needle held by a robot, by mechanics, in an organ that deforms: what the
``mechanics`` and ``physical`` truths add to a multi-needle plan's insertion
(:mod:`needlekit.studies.execute_multi`).

The robot holds the needle's base on its line and does not spin it; the needle is the
elastic rod of docs/mechanics.md, inserted from the plan's entry along the robot's final
axis, its bevel held, to the robot's final depth, so its tip leaves the straight line by
what the bevel's lateral load bends it (:class:`StraightPhysics.insert`: the rod's tip
less the straight line's point at the same depth). Under ``physical`` the organ is the
deforming organ of :mod:`needlekit.execute.deforming` (its Med-RAD mask meshed, linear
elasticity, its held surfaces), its corridor the needle's planned line and its tracked
point the needle's planned target: at each solve of the rod the organ takes the tip's load
and the target is pushed on, and the push at the end of the insertion moves the needle's
real target. The coupling is that truth's, one way; the robot does not see the push (it
aims at the planned target), and the needles placed before stand unloaded (their tips'
loads relax once they stop).

Left out: the robot's own answer to the rod's loads (it holds the base on its line), the
rod's shaft outside the organ (the whole insertion is in one tissue preset), and the placed
needles as obstacles of the rod (the robot's VFIs keep its shaft off them).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.physical import MechanicsSettings, MechanicsTruth
from needlekit.tissue.compliance import resample_polyline
from needlekit.tissue.runtime import DeformingTissue

__all__ = ["STRAIGHT_TRUTHS", "StraightPhysics"]

#: The truths a straight needle held by the robot can have: the rigid line (``kinematic``,
#: the robot's needle goes where it holds it) and the two of mechanics.
STRAIGHT_TRUTHS: tuple[str, ...] = ("kinematic", "mechanics", "physical")

#: Inserted per solve of the rod (mm): 2 mm/s at 40 Hz, as the steerable loop.
_STEP_MM = 0.05


@dataclass(frozen=True)
class StraightPhysics:
    """The needle and the organ a straight insertion goes through (module notes).

    Attributes
    ----------
    truth : str
        ``"mechanics"`` (the rod in tissue that stays) or ``"physical"`` (the rod in the
        deforming organ).
    mechanics : MechanicsSettings
    organ : str or None
        ``"liver"`` or ``"lung"``: the Med-RAD organ (``physical``).
    folder : str or None
        Its Med-RAD patient folder.
    cache_dir : str or None
    use_cache : bool
        The cache the organ's precomputation goes through, as
        :class:`~needlekit.execute.deforming.TissueModel`'s.
    """

    truth: str
    mechanics: MechanicsSettings
    organ: str | None = None
    folder: str | None = None
    cache_dir: str | None = None
    use_cache: bool = True

    def __post_init__(self) -> None:
        if self.truth not in ("mechanics", "physical"):
            raise InvalidInputError("truth", f"expected mechanics or physical, got {self.truth!r}")
        if not isinstance(self.mechanics, MechanicsSettings):
            raise InvalidInputError("mechanics", "expected a MechanicsSettings")
        if self.truth == "physical" and (self.organ is None or self.folder is None):
            raise InvalidInputError("truth", "physical deforms the scenario's organ: it needs a Med-RAD scenario")

    def tissue_model(self, entry_mm, target_mm):
        """The deforming organ of one needle: its planned line the corridor, its planned
        target tracked (cached like the prepared anatomy, by line).

        Parameters
        ----------
        entry_mm, target_mm : array-like, shape (3,)

        Returns
        -------
        needlekit.execute.deforming.TissueModel
        """
        from needlekit.execute.deforming import TissueModel

        a, b = np.asarray(entry_mm, dtype=np.float64), np.asarray(target_mm, dtype=np.float64)
        corridor = resample_polyline(np.array([a, b]), 1.5)
        return TissueModel(self.organ, self.folder, tuple(np.round(corridor, 6).ravel().tolist()),
                           tuple(float(v) for v in b), cache_dir=self.cache_dir,
                           use_cache=self.use_cache)  # fmt: skip

    def insert(self, start_pose, depth_mm: float, planned: tuple, rng) -> dict:
        """Insert the rod from ``start_pose`` (its tip at the entry, z along the robot's
        axis, x its bevel's side) to ``depth_mm``, the bevel held.

        Parameters
        ----------
        start_pose : ndarray, shape (4, 4)
        depth_mm : float
        planned : tuple
            ``(entry_mm, target_mm)``: the needle's planned line (the organ's corridor).
        rng : numpy.random.Generator
            The tissue's inhomogeneity.

        Returns
        -------
        dict
            ``tip_offset_mm`` (3,): the rod's tip less the straight line's point at the same
            depth; ``axis`` (3,): the rod's tip direction; ``target_push_mm`` (3,): how far
            the organ carried the planned target (zero under ``mechanics``); ``tip_force_n``.
        """
        from needlekit.mechanics.insertion import MechanicalNeedle

        if not (np.isfinite(depth_mm) and depth_mm > 0):
            raise InvalidInputError("depth_mm", f"expected a finite depth > 0 mm, got {depth_mm!r}")
        pose = np.asarray(start_pose, dtype=np.float64)
        m = self.mechanics
        rod = MechanicalNeedle(pose, m.needle_spec(), m.tissue_spec(), rng=rng,
                               inhomogeneity=m.inhomogeneity)  # fmt: skip
        if self.truth == "physical":
            from needlekit.execute.deforming import DeformingTruth

            tissue = DeformingTissue(self.tissue_model(*planned).compliance())
            truth = DeformingTruth(rod, 1.0, m.solve_rate_hz, tissue)
        else:
            truth = MechanicsTruth(rod, 1.0, m.solve_rate_hz)
        dt = 1.0 / m.solve_rate_hz
        while truth.inserted_mm < depth_mm - 1e-9:  # a duty cycle of 1: the bevel held
            truth.step(0.0, 1.0, min(_STEP_MM, depth_mm - truth.inserted_mm), dt)
        truth.step(0.0, 0.0, 0.0, dt)  # solve what is pooled
        tip = truth.pose[:3, 3]
        line = pose[:3, 3] + truth.inserted_mm * pose[:3, 2]
        push = np.zeros(3)
        if self.truth == "physical":
            push = truth.target_mm() - truth.target_rest_mm
        return {
            "tip_offset_mm": tip - line,
            "axis": truth.pose[:3, 2].copy(),
            "target_push_mm": push,
            "tip_force_n": float(truth.shaft_loads()["tip_force_n"]),
        }

    def record(self) -> dict:
        """What ``execute.json`` says of the needle and the organ.

        Returns
        -------
        dict
        """
        return {"name": self.truth, "mechanics": asdict(self.mechanics), "organ": self.organ}
