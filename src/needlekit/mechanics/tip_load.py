"""The load the tissue puts on a bevel tip, from the bevel's geometry and the tissue.

A quasi-static energy balance at the tip, in the spirit of Misra et al. (IJRR 2010,
BioRob 2008), written here in its simplest closed form. Per unit length the tip advances:

- it cuts a crack as wide as the needle: work ``G_c d`` (rupture toughness ``G_c``,
  outer diameter ``d``);
- it pushes the tissue on the bevel's side aside by the needle's diameter to make room
  for the shaft: the tissue's Winkler modulus ``k`` (see
  :meth:`~needlekit.mechanics.materials.TissueSpec.foundation_modulus`) stores
  ``1/2 k d^2``.

So the axial resistance at the tip is ``P = G_c d + 1/2 k d^2`` (N).

The two parts act at different places. The crack is cut by the bevel's edge, a line with
no area ahead of it, so the rupture part ``G_c d`` pushes back along the axis. The
opening part is the reaction of the tissue the bevel face wedges aside: over the face's
axial length ``L_b = d / tan(alpha)`` the tissue on the bevel's side moves sideways from
0 at the point to ``d`` at the heel, and pushes back on the face, whose normal makes the
angle ``alpha`` (the bevel angle) with the needle's transverse direction. Taking the
face's axial part as ``1/2 k d^2``, with Coulomb friction ``mu`` on the face, its lateral
part is

    ``Q = 1/2 k d^2 (1 - mu tan alpha) / (tan alpha + mu)``
    (``Q = 1/2 k d L_b``, the foundation's reaction summed over the wedge, when ``mu = 0``),

pointing from the bevel face toward the bevel's point: the side toward which the needle
bends (the tip's -y axis, :data:`needlekit.conventions.TIP_BEND_DIRECTION`). ``Q`` is
clipped at 0 when friction would reverse it.

So the face presses no harder than the tissue it wedges can push back. Taking the whole
``P`` through the face (``Q = P cot alpha``), as an earlier form of this model did, asked
0.24-0.33 N of the face in the lung and liver presets, whose rupture toughness (164 J/m^2)
is a hundred times a gel's in tissue a tenth as stiff: 150-530 times what the wedged
tissue can give (0.0006-0.0017 N), and it held the tip ``2 Q lambda / k`` off its channel
(9.7 mm for the nitinol preset in lung). In gels and chicken the two forms differ by a
factor of 1.2-2.6.

The trends follow: a sharper bevel (smaller ``alpha``, a longer face) and a stiffer
tissue load the tip more sideways; a tougher tissue resists the insertion more (``P``)
without pressing the face harder.
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
        Transverse load toward the bevel's point (``Q``, from the wedged tissue), >= 0.
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
    q = max(0.0, opening * (1.0 - mu * tan_a) / (tan_a + mu))
    return TipLoad(p, q, rupture, opening)
