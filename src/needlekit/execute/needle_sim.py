"""The needle that does not obey its model: a bevel-tip needle in tissue, simulated.

The planner's model is the unicycle of the lecture: spin the tip about its axis, then
insert along an arc of curvature ``kappa <= 1 / r_min`` (duty-cycled spinning gives any
curvature below the needle's own). A real insertion departs from it in three ways, each
drawn here from its own random stream:

- **Orientation noise.** After every step the tip turns by a random rotation (a rotation
  vector ``N(0, s^2 I)`` in the tip frame), ``s = orientation_sigma_rad`` per
  ``reference_interval_s`` of insertion, scaled by ``sqrt(dt / reference_interval_s)``
  for other steps (a random walk). Default pi/2000 rad per 0.1 s, the value
  taken from published simulations of steerable needles.
- **Curvature.** The needle's radius of curvature in this tissue is ``r_min`` plus
  ``N(0, radius_sigma_mm^2)`` (default SD 3 mm), drawn once per insertion: a commanded
  curvature ``kappa`` (a duty cycle ``kappa r_min``) gives ``kappa r_min / r``.
- **Tissue deflection.** The tissue pushes the tip sideways: per millimetre inserted the
  tip moves by a lateral vector drawn once per insertion, perpendicular to the start
  direction, each component ``N(0, deflection_sigma)`` (default 0.01 mm per mm: about
  1 mm off over a 100 mm insertion).

Frames and units follow :mod:`needlekit.conventions`: RAS millimetres, the tip's z axis
the insertion direction, a primitive bending toward the spun tip's -y axis.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import arc_end_unchecked
from needlekit.geometry.so3 import so3_exp_unchecked

__all__ = ["ExecutionNoise", "SimulatedNeedle", "kinematic_truth"]


@dataclass(frozen=True)
class ExecutionNoise:
    """How far the real needle departs from its model (see the module notes).

    Attributes
    ----------
    orientation_sigma_rad : float
        Rotation noise per ``reference_interval_s`` of insertion (rad).
    reference_interval_s : float
        The interval the orientation noise is given for (s).
    radius_sigma_mm : float
        SD of the needle's radius of curvature in the tissue about ``r_min`` (mm).
    deflection_sigma : float
        SD of each component of the tissue's lateral push (mm per mm inserted).
    """

    orientation_sigma_rad: float = math.pi / 2000
    reference_interval_s: float = 0.1
    radius_sigma_mm: float = 3.0
    deflection_sigma: float = 0.01

    def __post_init__(self) -> None:
        for name in ("orientation_sigma_rad", "radius_sigma_mm", "deflection_sigma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidInputError(name, f"expected a finite number >= 0, got {v!r}")
        v = self.reference_interval_s
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise InvalidInputError("reference_interval_s", f"expected a time > 0, got {v!r}")

    @classmethod
    def none(cls) -> ExecutionNoise:
        """A needle that follows its model exactly.

        Returns
        -------
        ExecutionNoise
        """
        return cls(0.0, 0.1, 0.0, 0.0)


class SimulatedNeedle:
    """The true tip of one insertion (see the module notes).

    Parameters
    ----------
    start_pose : ndarray, shape (4, 4)
        The tip where the insertion starts (RAS mm).
    r_min_mm : float
        The needle's nominal radius of curvature (the planner's).
    noise : ExecutionNoise
    rng : numpy.random.Generator
        Draws the radius and the deflection now, the orientation noise as it inserts.

    Attributes
    ----------
    pose : ndarray, shape (4, 4)
        The true tip pose now.
    inserted_mm : float
    radius_mm : float
        The radius of curvature this insertion has.
    deflection : ndarray, shape (3,)
        The tissue's lateral push (world, mm per mm).
    """

    def __init__(self, start_pose, r_min_mm: float, noise: ExecutionNoise, rng) -> None:
        pose = np.array(start_pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InvalidInputError("start_pose", "expected a 4x4 matrix of finite numbers")
        if not (math.isfinite(r_min_mm) and r_min_mm > 0):
            raise InvalidInputError("r_min_mm", f"expected a radius > 0, got {r_min_mm!r}")
        self.pose = np.ascontiguousarray(pose)
        self.noise = noise
        self.rng = rng
        self.r_min_mm = float(r_min_mm)
        # a radius below half the nominal would be another needle: clipped there
        drawn = r_min_mm + rng.normal(0.0, noise.radius_sigma_mm)
        self.radius_mm = max(drawn, 0.5 * r_min_mm)
        z = pose[:3, 2]
        push = rng.normal(0.0, noise.deflection_sigma, 3)
        self.deflection = push - (push @ z) * z
        self.inserted_mm = 0.0

    def step(self, spin_rad: float, kappa_per_mm: float, ds_mm: float, dt_s: float) -> np.ndarray:
        """Spin the tip, then insert ``ds_mm`` at the commanded curvature over ``dt_s``.

        Parameters
        ----------
        spin_rad : float
            Rotation about the tip's axis before inserting.
        kappa_per_mm : float
            Commanded curvature, ``0 <= kappa <= 1 / r_min`` (a duty cycle).
        ds_mm : float
            Inserted length, >= 0.
        dt_s : float
            How long the step takes (scales the orientation noise).

        Returns
        -------
        ndarray, shape (4, 4)
            The true tip pose after the step.
        """
        kappa_true = kappa_per_mm * self.r_min_mm / self.radius_mm
        g = arc_end_unchecked(self.pose, float(spin_rad), float(kappa_true), float(ds_mm))
        sigma = self.noise.orientation_sigma_rad * math.sqrt(dt_s / self.noise.reference_interval_s)
        if sigma > 0 and ds_mm > 0:
            g[:3, :3] = g[:3, :3] @ so3_exp_unchecked(self.rng.normal(0.0, sigma, 3))
        g[:3, 3] += self.deflection * ds_mm
        self.pose = g
        self.inserted_mm += ds_mm
        return g


def kinematic_truth(setup) -> SimulatedNeedle:
    """The ``kinematic`` truth (:data:`needlekit.execute.plugins.TRUTHS`): a
    :class:`SimulatedNeedle` with the run's noise, drawn from the setup's stream.

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    SimulatedNeedle
    """
    return SimulatedNeedle(setup.start_pose, setup.r_min_mm, setup.settings.noise, setup.rng)


def _kinematic_parameters(settings) -> dict:
    return {"noise": asdict(settings.noise)}


kinematic_truth.parameters = _kinematic_parameters
