"""The example scenarios in examples/ load and mean what they say."""

from pathlib import Path

import numpy as np
import pytest

from needlekit.anatomy.scene import Role
from needlekit.scenario.loading import load_scenario

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.mark.parametrize("name", ["toy", "lung_phantom", "liver_phantom", "neck_phantom"])
def test_example_loads(name):
    sc = load_scenario(EXAMPLES / f"{name}.yaml")
    assert sc.start is not None and sc.goal is not None
    assert sc.scene.by_role(Role.TARGET)
    # the goal lies inside a target structure
    inside = [
        float(s.field.signed_distance(sc.goal.point_mm)) <= s.field.error_bound_mm
        for s in sc.scene.by_role(Role.TARGET)
    ]
    assert any(inside)
    if sc.start.world_T_tip is not None:
        assert np.allclose(sc.start.world_T_tip[:3, 3], sc.start.point_mm)


@pytest.mark.realdata  # skips, saying why, without the data (tests/conftest.py)
@pytest.mark.slow
def test_medrad_example_loads():
    sc = load_scenario(EXAMPLES / "medrad_lung1.yaml")
    assert sc.start.name == "start1" and sc.goal.name == "target"
    assert sc.needle.r_min_mm == 50 and sc.needle.start_exclusion_mm == 3
    assert sc.scene.name == "Med-RAD lung 1"
