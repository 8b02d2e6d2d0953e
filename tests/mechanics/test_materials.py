"""Needle and tissue specifications: presets, derived figures, and every bad field named."""

import math

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.mechanics.insertion import MechanicalNeedle
from needlekit.mechanics.materials import NEEDLE_PRESETS, TISSUE_PRESETS, NeedleSpec, TissueSpec
from needlekit.mechanics.tip_load import bevel_tip_load

GOOD_NEEDLE = dict(
    outer_diameter_mm=0.8, inner_diameter_mm=0.4, youngs_modulus_mpa=200e3, bevel_angle_rad=0.5
)
GOOD_TISSUE = dict(youngs_modulus_mpa=0.02, rupture_toughness_n_per_mm=0.001)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("outer_diameter_mm", 0.0),
        ("outer_diameter_mm", -1.0),
        ("outer_diameter_mm", float("nan")),
        ("outer_diameter_mm", "0.8"),
        ("inner_diameter_mm", -0.1),
        ("inner_diameter_mm", 0.8),
        ("inner_diameter_mm", 1.0),
        ("inner_diameter_mm", float("inf")),
        ("youngs_modulus_mpa", 0.0),
        ("youngs_modulus_mpa", float("nan")),
        ("bevel_angle_rad", 0.0),
        ("bevel_angle_rad", math.pi / 2),
        ("bevel_angle_rad", 2.0),
        ("bevel_angle_rad", -0.3),
        ("bevel_angle_rad", True),
        ("prebend_rad", -0.1),
        ("prebend_rad", math.pi / 2),
        ("prebend_length_mm", -1.0),
        ("prebend_length_mm", float("nan")),
    ],
)
def test_bad_needle_field_is_named(field, value):
    with pytest.raises(InvalidInputError) as info:
        NeedleSpec(**{**GOOD_NEEDLE, field: value})
    assert info.value.field == field


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("youngs_modulus_mpa", 0.0),
        ("youngs_modulus_mpa", -0.02),
        ("youngs_modulus_mpa", float("nan")),
        ("rupture_toughness_n_per_mm", -1e-3),
        ("rupture_toughness_n_per_mm", float("inf")),
        ("poisson_ratio", 0.5),
        ("poisson_ratio", -0.1),
        ("bevel_friction", -0.1),
        ("bevel_friction", float("nan")),
        ("unsupported_mm", -1.0),
    ],
)
def test_bad_tissue_field_is_named(field, value):
    with pytest.raises(InvalidInputError) as info:
        TissueSpec(**{**GOOD_TISSUE, field: value})
    assert info.value.field == field


def test_prebend_needs_a_length():
    with pytest.raises(InvalidInputError) as info:
        NeedleSpec(**GOOD_NEEDLE, prebend_rad=0.2)
    assert info.value.field == "prebend_length_mm"
    bent = NeedleSpec(**GOOD_NEEDLE).with_prebend(20.0, 5.0)
    assert bent.rest_curvature_per_mm == pytest.approx(math.radians(20.0) / 5.0)


def test_unknown_presets_are_named():
    with pytest.raises(InvalidInputError, match="needle"):
        NeedleSpec.preset("titanium")
    with pytest.raises(InvalidInputError, match="tissue"):
        TissueSpec.preset("bone")


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"guide_gap_mm": -1.0}, "guide_gap_mm"),
        ({"element_mm": 0.0}, "element_mm"),
        ({"max_substep_mm": float("nan")}, "max_substep_mm"),
        ({"inhomogeneity": -0.1}, "inhomogeneity"),
        ({"inhomogeneity": 0.1}, "rng"),
    ],
)
def test_bad_insertion_arguments_are_named(kwargs, field):
    with pytest.raises(InvalidInputError) as info:
        MechanicalNeedle(np.eye(4), "nitinol", "chicken", **kwargs)
    assert info.value.field == field


def test_bad_start_pose_and_step_arguments():
    with pytest.raises(InvalidInputError, match="start_pose"):
        MechanicalNeedle(np.eye(3), "nitinol", "chicken")
    bad = np.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(InvalidInputError, match="start_pose"):
        MechanicalNeedle(bad, "nitinol", "chicken")
    sim = MechanicalNeedle(np.eye(4), "nitinol", "chicken")
    for args, field in [
        ((float("nan"), 0.0, 1.0, 0.1), "spin_rad"),
        ((0.0, float("inf"), 1.0, 0.1), "kappa_per_mm"),
        ((0.0, 0.0, -1.0, 0.1), "ds_mm"),
        ((0.0, 0.0, 1.0, -0.1), "dt_s"),
    ]:
        with pytest.raises(InvalidInputError) as info:
            sim.step(*args)
        assert info.value.field == field
    assert sim.inserted_mm == 0.0


def test_presets_and_derived_figures():
    assert set(NEEDLE_PRESETS) == {"nitinol", "steel"}
    assert {"plastisol", "gelatin", "chicken", "liver", "lung"} <= set(TISSUE_PRESETS)
    steel = NeedleSpec.preset("steel")
    assert steel.second_moment_mm4 == pytest.approx(math.pi * (0.718**4 - 0.413**4) / 64)
    assert steel.bending_stiffness_nmm2 == pytest.approx(200e3 * steel.second_moment_mm4)
    assert steel.bevel_length_mm == pytest.approx(0.718 / math.tan(math.radians(20)))
    assert steel.with_bevel_deg(45.0).bevel_length_mm == pytest.approx(0.718)
    liver = TissueSpec.preset("liver")
    # Vesic's modulus, doubled for an embedded shaft
    e, d, nu = 0.005, 0.718, 0.45
    k = 1.3 * (e * d**4 / steel.bending_stiffness_nmm2) ** (1 / 12) * e / (1 - nu**2)
    assert liver.foundation_modulus(steel) == pytest.approx(k, rel=1e-12)
    assert liver.unsupported_length(steel) == pytest.approx(steel.bevel_length_mm)
    assert liver.scaled(2.0).youngs_modulus_mpa == pytest.approx(0.01)


def test_tip_load_closed_form():
    needle = NeedleSpec(0.5, 0.0, 75e3, math.radians(30))
    tissue = TissueSpec(0.02, 0.01)
    load = bevel_tip_load(needle, tissue)
    k = tissue.foundation_modulus(needle)
    assert load.rupture_n == pytest.approx(0.01 * 0.5)
    assert load.opening_n == pytest.approx(0.5 * k * 0.25)
    assert load.axial_n == pytest.approx(load.rupture_n + load.opening_n)
    # the face carries the wedged tissue's reaction, summed over the bevel's length
    assert load.lateral_n == pytest.approx(load.opening_n / math.tan(math.radians(30)))
    assert load.lateral_n == pytest.approx(0.5 * k * 0.5 * needle.bevel_length_mm)
    # a tougher tissue resists the insertion more, without pressing the face harder
    tough = bevel_tip_load(needle, TissueSpec(0.02, 0.5))
    assert tough.axial_n > 10 * load.axial_n and tough.lateral_n == load.lateral_n
    # friction on the face lowers the lateral part; enough friction removes it
    rough = TissueSpec(0.02, 0.01, bevel_friction=0.3)
    assert 0 < bevel_tip_load(needle, rough).lateral_n < load.lateral_n
    stuck = TissueSpec(0.02, 0.01, bevel_friction=5.0)
    assert bevel_tip_load(needle, stuck).lateral_n == 0.0
