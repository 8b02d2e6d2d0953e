"""The load the tissue puts on a bevel tip, from the bevel's geometry and the tissue.

A quasi-static energy balance at the tip, in the spirit of Misra et al. (IJRR 2010,
BioRob 2008), written here in its simplest closed form. Per unit length the tip advances:

- it cuts a crack as wide as the needle: work ``G_c d`` (rupture toughness ``G_c``,
  outer diameter ``d``);
- it pushes the tissue on the bevel's side aside by the needle's diameter to make room
  for the shaft: the tissue's Winkler modulus ``k`` (see
  :meth:`~needlekit.mechanics.materials.TissueSpec.foundation_modulus`) stores
  ``1/2 k d^2``.

So the axial resistance at the tip is ``P = G_c d + 1/2 k d^2`` (N). The sharp point has
no area: the tissue carries ``P`` through the bevel face, whose normal makes the angle
``alpha`` (the bevel angle) with the needle's transverse direction; with Coulomb friction
``mu`` on the face, the resultant's lateral part is

    ``Q = P (1 - mu tan alpha) / (tan alpha + mu)``    (``Q = P cot alpha`` when ``mu = 0``),

pointing from the bevel face toward the bevel's point: the side toward which the needle
bends (the tip's -y axis, :data:`needlekit.conventions.TIP_BEND_DIRECTION`). ``Q`` is
clipped at 0 when friction would reverse it.

The trends follow: a sharper bevel (smaller ``alpha``) and a stiffer or tougher tissue
load the tip more; the bevel's own length ``d / tan(alpha)`` is where the tissue presses
the face rather than the shaft.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from needlekit.mechanics.materials import NeedleSpec, TissueSpec

__all__ = ["TipLoad", "bevel_tip_load"]


@dataclass(frozen=True)
class TipLoad:
    """The bevel's load on the tip (N).

    Attributes
    ----------
    axial_n : float
        Resistance along the needle's axis, against the insertion (``P``).
    lateral_n : float
        Transverse load toward the bevel's point (``Q``), >= 0.
    rupture_n : float
        The part of ``P`` spent cutting (``G_c d``).
    opening_n : float
        The part of ``P`` spent pushing the tissue aside (``1/2 k d^2``).
    """

    axial_n: float
    lateral_n: float
    rupture_n: float
    opening_n: float


def bevel_tip_load(needle: NeedleSpec, tissue: TissueSpec) -> TipLoad:
    """The tip load of a bevel-tip needle advancing through a tissue (module notes).

    Parameters
    ----------
    needle : NeedleSpec
    tissue : TissueSpec

    Returns
    -------
    TipLoad
    """
    d = needle.outer_diameter_mm
    k = tissue.foundation_modulus(needle)
    rupture = tissue.rupture_toughness_n_per_mm * d
    opening = 0.5 * k * d * d
    p = rupture + opening
    tan_a = math.tan(needle.bevel_angle_rad)
    mu = tissue.bevel_friction
    q = max(0.0, p * (1.0 - mu * tan_a) / (tan_a + mu))
    return TipLoad(p, q, rupture, opening)
