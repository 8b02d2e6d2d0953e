"""The ``layered`` truth: the kinematic needle in tissue whose push and stiffness change
with depth.

Tissue on a needle's way is not one material: skin, fat, muscle, the organ's capsule and
its parenchyma follow one another along the path, and each bends a bevel tip by its own
amount and pushes it its own way. Here the tissue is a stack of layers ``layer_mm`` thick
along the inserted length. In layer ``i`` the needle's radius of curvature is
``r_min + N(0, radius_sigma_mm^2)`` (clipped at half ``r_min``, as
:class:`~needlekit.execute.needle_sim.SimulatedNeedle` does) and the lateral push per
millimetre inserted is drawn perpendicular to the start direction, each component
``N(0, deflection_sigma)``: the uniform needle's two biases, drawn afresh per layer, so that
the departure from the model changes along the depth and a filter that learned one layer's
bias meets another in the next. The orientation noise is the kinematic needle's.

Layer ``i``'s draws come from a stream of their own (the ``i``-th child of one drawn from
the insertion's generator), so a layer is the same whatever the commands were before it.
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.needle_sim import ExecutionNoise, SimulatedNeedle

__all__ = ["DEFAULT_LAYER_MM", "LayeredNeedle", "layered_truth"]

#: The layers' thickness (mm) of the registered ``layered`` truth.
DEFAULT_LAYER_MM: float = 15.0


class LayeredNeedle(SimulatedNeedle):
    """The true tip in layered tissue (see the module notes).

    Parameters
    ----------
    start_pose : ndarray, shape (4, 4)
    r_min_mm : float
    noise : ExecutionNoise
        The orientation noise, and the per-layer spreads of the radius and the push.
    rng : numpy.random.Generator
    layer_mm : float
        Each layer's thickness along the inserted length.

    Attributes
    ----------
    layer : int
        The layer the tip is in.
    radius_mm, deflection
        That layer's radius of curvature and push (as :class:`SimulatedNeedle`'s).
    """

    def __init__(self, start_pose, r_min_mm: float, noise: ExecutionNoise, rng,
                 layer_mm: float = DEFAULT_LAYER_MM) -> None:  # fmt: skip
        if not (isinstance(layer_mm, (int, float)) and math.isfinite(layer_mm) and layer_mm > 0):
            raise InvalidInputError("layer_mm", f"expected a thickness > 0, got {layer_mm!r}")
        super().__init__(start_pose, r_min_mm, noise, rng)
        self.layer_mm = float(layer_mm)
        self._z0 = self.pose[:3, 2].copy()
        self._root = np.random.SeedSequence(int(rng.integers(2**63)))
        self._layers: dict[int, tuple[float, np.ndarray]] = {}
        self.layer = -1
        self._enter(0)

    def layer_draws(self, i: int) -> tuple[float, np.ndarray]:
        """Layer ``i``'s radius of curvature (mm) and push (mm per mm, world).

        Parameters
        ----------
        i : int

        Returns
        -------
        (float, ndarray of shape (3,))
        """
        if i not in self._layers:
            g = np.random.default_rng(np.random.SeedSequence(self._root.entropy, spawn_key=(i,)))
            radius = max(self.r_min_mm + g.normal(0.0, self.noise.radius_sigma_mm),
                         0.5 * self.r_min_mm)  # fmt: skip
            push = g.normal(0.0, self.noise.deflection_sigma, 3)
            self._layers[i] = (float(radius), push - (push @ self._z0) * self._z0)
        return self._layers[i]

    def _enter(self, i: int) -> None:
        self.layer = i
        self.radius_mm, self.deflection = self.layer_draws(i)

    def step(self, spin_rad: float, kappa_per_mm: float, ds_mm: float, dt_s: float) -> np.ndarray:
        """As :meth:`SimulatedNeedle.step`, with the layer the tip is in at the step's start.

        Parameters
        ----------
        spin_rad, kappa_per_mm, ds_mm, dt_s : float

        Returns
        -------
        ndarray, shape (4, 4)
        """
        i = int(self.inserted_mm // self.layer_mm)
        if i != self.layer:
            self._enter(i)
        return super().step(spin_rad, kappa_per_mm, ds_mm, dt_s)


def layered_truth(setup) -> LayeredNeedle:
    """The ``layered`` truth (:data:`needlekit.execute.plugins.TRUTHS`), layers of
    :data:`DEFAULT_LAYER_MM`.

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    LayeredNeedle
    """
    return LayeredNeedle(setup.start_pose, setup.r_min_mm, setup.settings.noise, setup.rng)


layered_truth.parameters = lambda settings: {
    "layer_mm": DEFAULT_LAYER_MM,
    "noise": asdict(settings.noise),
}
