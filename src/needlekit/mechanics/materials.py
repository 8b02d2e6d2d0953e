"""Needle and tissue specifications for the mechanics model, checked on construction.

Units throughout: lengths in mm, forces in N, moduli and stresses in MPa (= N/mm^2),
rupture toughness in N/mm (= kJ/m^2; 1 J/m^2 = 0.001 N/mm), angles in rad
(:meth:`NeedleSpec.with_bevel_deg` takes degrees).

A :class:`NeedleSpec` is a tube (or a solid wire when ``inner_diameter_mm = 0``) of
Young's modulus ``youngs_modulus_mpa`` with a bevel of angle ``bevel_angle_rad`` between
the bevel face and the needle's axis. A :class:`TissueSpec` gives the tissue's Young's
modulus, its rupture toughness (the energy per unit area of crack the tip cuts), its
Poisson ratio, the coefficient of friction of the bevel face, and how far behind the tip
the tissue starts to hold the shaft (``unsupported_mm``; ``None`` means the bevel's own
length, ``d / tan(bevel)``).

The foundation modulus ``k`` (N/mm per mm of shaft, so N/mm^2) that the tissue offers the
shaft follows from the tissue's modulus by Vesic's estimate for a beam on an elastic
half-space, doubled because the shaft is embedded (tissue on both sides):

    ``k = 2 * 0.65 * (E_t d^4 / (E I))^(1/12) * E_t / (1 - nu^2)``

Every field is checked before any work: a value out of its physical range raises
:class:`needlekit.errors.InvalidInputError` naming the field.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from needlekit.errors import InvalidInputError

__all__ = ["NEEDLE_PRESETS", "TISSUE_PRESETS", "NeedleSpec", "TissueSpec"]


def _positive(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidInputError(name, f"expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise InvalidInputError(name, f"expected a finite number > 0, got {value!r}")
    return v


def _non_negative(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InvalidInputError(name, f"expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0.0:
        raise InvalidInputError(name, f"expected a finite number >= 0, got {value!r}")
    return v


@dataclass(frozen=True)
class NeedleSpec:
    """A bevel-tip needle (units: mm, MPa, rad).

    Attributes
    ----------
    outer_diameter_mm : float
        Outer diameter, > 0.
    inner_diameter_mm : float
        Lumen diameter, 0 <= inner < outer (0: a solid wire or a stylet-filled needle).
    youngs_modulus_mpa : float
        Young's modulus of the needle's material (MPa), > 0.
    bevel_angle_rad : float
        Angle between the bevel face and the needle's axis, in (0, pi/2).
    name : str
        A label for records.
    prebend_rad : float
        Angle of a pre-bent tip toward the bevel's side, in [0, pi/2) (0: straight).
    prebend_length_mm : float
        Length of the pre-bent tip segment (mm), > 0 when ``prebend_rad > 0``; the
        bend is spread evenly over it (stress-free curvature ``prebend / length``).
    """

    outer_diameter_mm: float
    inner_diameter_mm: float
    youngs_modulus_mpa: float
    bevel_angle_rad: float
    name: str = "needle"
    prebend_rad: float = 0.0
    prebend_length_mm: float = 0.0

    def __post_init__(self) -> None:
        d = _positive("outer_diameter_mm", self.outer_diameter_mm)
        di = _non_negative("inner_diameter_mm", self.inner_diameter_mm)
        if di >= d:
            raise InvalidInputError(
                "inner_diameter_mm",
                f"expected less than outer_diameter_mm ({d}), got {self.inner_diameter_mm!r}",
            )
        _positive("youngs_modulus_mpa", self.youngs_modulus_mpa)
        b = _positive("bevel_angle_rad", self.bevel_angle_rad)
        if not b < math.pi / 2:
            raise InvalidInputError(
                "bevel_angle_rad",
                f"expected an angle in (0, pi/2) rad, got {self.bevel_angle_rad!r}",
            )
        bend = _non_negative("prebend_rad", self.prebend_rad)
        if not bend < math.pi / 2:
            raise InvalidInputError(
                "prebend_rad", f"expected an angle in [0, pi/2) rad, got {self.prebend_rad!r}"
            )
        length = _non_negative("prebend_length_mm", self.prebend_length_mm)
        if bend > 0 and length == 0:
            raise InvalidInputError(
                "prebend_length_mm", "expected a length > 0 for a pre-bent tip, got 0"
            )

    @property
    def rest_curvature_per_mm(self) -> float:
        """Stress-free curvature of the pre-bent tip segment (1/mm); 0 when straight."""
        if self.prebend_rad == 0.0:
            return 0.0
        return self.prebend_rad / self.prebend_length_mm

    @property
    def second_moment_mm4(self) -> float:
        """Second moment of area of the cross-section, ``pi (d^4 - d_i^4) / 64`` (mm^4)."""
        return math.pi * (self.outer_diameter_mm**4 - self.inner_diameter_mm**4) / 64.0

    @property
    def bending_stiffness_nmm2(self) -> float:
        """Flexural rigidity ``E I`` (N mm^2)."""
        return self.youngs_modulus_mpa * self.second_moment_mm4

    @property
    def bevel_length_mm(self) -> float:
        """Axial length of the bevel face, ``d / tan(bevel)`` (mm)."""
        return self.outer_diameter_mm / math.tan(self.bevel_angle_rad)

    def with_bevel_deg(self, bevel_deg: float) -> NeedleSpec:
        """The same needle with another bevel angle (degrees).

        Parameters
        ----------
        bevel_deg : float

        Returns
        -------
        NeedleSpec
        """
        return dataclasses.replace(
            self, bevel_angle_rad=math.radians(_positive("bevel_deg", bevel_deg))
        )

    def with_prebend(self, prebend_deg: float, length_mm: float) -> NeedleSpec:
        """The same needle with a pre-bent tip (degrees, mm).

        Parameters
        ----------
        prebend_deg : float
            Bend toward the bevel's side, in [0, 90) degrees.
        length_mm : float
            Length of the bent segment (mm).

        Returns
        -------
        NeedleSpec
        """
        return dataclasses.replace(
            self,
            prebend_rad=math.radians(_non_negative("prebend_deg", prebend_deg)),
            prebend_length_mm=length_mm,
        )

    @classmethod
    def preset(cls, name: str) -> NeedleSpec:
        """A needle from :data:`NEEDLE_PRESETS` (``"nitinol"``, ``"steel"``).

        Parameters
        ----------
        name : str

        Returns
        -------
        NeedleSpec
        """
        if name not in NEEDLE_PRESETS:
            raise InvalidInputError(
                "needle", f"expected one of {sorted(NEEDLE_PRESETS)}, got {name!r}"
            )
        return NEEDLE_PRESETS[name]


@dataclass(frozen=True)
class TissueSpec:
    """A tissue as the needle meets it (units: MPa, N/mm, mm).

    Attributes
    ----------
    youngs_modulus_mpa : float
        Small-strain Young's modulus (MPa), > 0 (for a neo-Hookean fit, ``E = 6 C10``).
    rupture_toughness_n_per_mm : float
        Energy to cut a unit area of crack (N/mm; 1 J/m^2 = 1e-3 N/mm), >= 0.
    poisson_ratio : float
        In [0, 0.5); soft tissue is nearly incompressible (0.45-0.49).
    bevel_friction : float
        Coulomb friction coefficient on the bevel face, >= 0 (0: frictionless).
    unsupported_mm : float or None
        Length behind the tip over which the tissue does not yet hold the shaft (mm,
        >= 0); None: the bevel's axial length.
    name : str
        A label for records.
    """

    youngs_modulus_mpa: float
    rupture_toughness_n_per_mm: float
    poisson_ratio: float = 0.45
    bevel_friction: float = 0.0
    unsupported_mm: float | None = None
    name: str = "tissue"

    def __post_init__(self) -> None:
        _positive("youngs_modulus_mpa", self.youngs_modulus_mpa)
        _non_negative("rupture_toughness_n_per_mm", self.rupture_toughness_n_per_mm)
        nu = _non_negative("poisson_ratio", self.poisson_ratio)
        if not nu < 0.5:
            raise InvalidInputError(
                "poisson_ratio", f"expected a number in [0, 0.5), got {self.poisson_ratio!r}"
            )
        _non_negative("bevel_friction", self.bevel_friction)
        if self.unsupported_mm is not None:
            _non_negative("unsupported_mm", self.unsupported_mm)

    def foundation_modulus(self, needle: NeedleSpec) -> float:
        """The Winkler modulus ``k`` the tissue offers this needle's shaft (N/mm^2).

        Vesic's estimate for a beam on an elastic half-space, doubled for a shaft
        embedded in tissue on both sides (see the module notes).

        Parameters
        ----------
        needle : NeedleSpec

        Returns
        -------
        float
        """
        e_t = self.youngs_modulus_mpa
        d = needle.outer_diameter_mm
        ratio = e_t * d**4 / needle.bending_stiffness_nmm2
        return 2.0 * 0.65 * ratio ** (1.0 / 12.0) * e_t / (1.0 - self.poisson_ratio**2)

    def unsupported_length(self, needle: NeedleSpec) -> float:
        """Length behind the tip where the tissue does not hold the shaft (mm).

        Parameters
        ----------
        needle : NeedleSpec

        Returns
        -------
        float
        """
        if self.unsupported_mm is not None:
            return float(self.unsupported_mm)
        return needle.bevel_length_mm

    def scaled(self, stiffness_factor: float) -> TissueSpec:
        """The same tissue with its Young's modulus multiplied by ``stiffness_factor``.

        Parameters
        ----------
        stiffness_factor : float
            > 0.

        Returns
        -------
        TissueSpec
        """
        f = _positive("stiffness_factor", stiffness_factor)
        return TissueSpec(
            self.youngs_modulus_mpa * f,
            self.rupture_toughness_n_per_mm,
            self.poisson_ratio,
            self.bevel_friction,
            self.unsupported_mm,
            self.name,
        )

    @classmethod
    def preset(cls, name: str) -> TissueSpec:
        """A tissue from :data:`TISSUE_PRESETS`.

        Parameters
        ----------
        name : str
            ``"plastisol"``, ``"gelatin"``, ``"chicken"``, ``"liver"`` or ``"lung"``.

        Returns
        -------
        TissueSpec
        """
        if name not in TISSUE_PRESETS:
            raise InvalidInputError(
                "tissue", f"expected one of {sorted(TISSUE_PRESETS)}, got {name!r}"
            )
        return TISSUE_PRESETS[name]


#: Needles (docs/mechanics.md gives each value's source).
#: ``nitinol``: the 0.83 mm solid nitinol wire of the JHU steering experiments (Webster et
#: al. 2006; Misra et al. 2010 model that needle family), austenitic modulus 75 GPa, a 30
#: degree bevel. ``steel``: a 22 G (0.718 mm outer, 0.413 mm inner) stainless steel
#: biopsy needle, 200 GPa, a 20 degree bevel.
NEEDLE_PRESETS: dict[str, NeedleSpec] = {
    "nitinol": NeedleSpec(0.83, 0.0, 75_000.0, math.radians(30.0), "nitinol"),
    "steel": NeedleSpec(0.718, 0.413, 200_000.0, math.radians(20.0), "steel"),
}

#: Tissues (docs/mechanics.md gives each value's source and how sure it is).
TISSUE_PRESETS: dict[str, TissueSpec] = {
    # plastisol soft-tissue simulant as in Misra et al. (BioRob 2008, IJRR 2010)
    "plastisol": TissueSpec(0.025, 0.0015, 0.49, 0.0, None, "plastisol"),
    # 10 wt% gelatine: E = 14.8 kPa, G_c = 1.1 J/m^2 (Terzano et al. 2020, citing Forte
    # et al. 2015)
    "gelatin": TissueSpec(0.0148, 0.0011, 0.475, 0.3, None, "gelatin"),
    # ex vivo chicken breast as in Misra et al. (BioRob 2008)
    "chicken": TissueSpec(0.030, 0.010, 0.45, 0.0, None, "chicken"),
    # liver: E ~ 5 kPa (elastography of healthy liver, 4-6 kPa); G_c = 164 J/m^2
    # (porcine liver, needle insertion; Azar and Hayward 2008 report 76-185 J/m^2)
    "liver": TissueSpec(0.005, 0.164, 0.45, 0.0, None, "liver"),
    # inflated lung parenchyma: E ~ 2 kPa (1-5 kPa in the literature); G_c taken as the
    # liver's (no needle-measured lung value found)
    "lung": TissueSpec(0.002, 0.164, 0.40, 0.0, None, "lung"),
}
